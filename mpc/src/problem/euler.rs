//! The scalar Euler step of the prediction model and the sine and cosine it uses: the
//! reference the lane-parallel passes match bit for bit.

use mav::ModelParams;

/// `(sin x, cos x)`. Predicted attitudes stay near the inputs' +-pi/18, where Taylor series to
/// x^13 / x^14 are exact to rounding (truncation below 3e-17 for |x| <= 0.5) and several times
/// cheaper than libm's `sincos`, which was a quarter of the solve time (callgrind); larger
/// angles fall back to libm.
#[inline(always)]
pub(crate) fn sin_cos_small(x: f64) -> (f64, f64) {
    if x.abs() > 0.5 {
        return x.sin_cos();
    }
    (sin_series(x), cos_series(x))
}

/// The Taylor series of `sin` to x^13 (see [`sin_cos_small`]).
#[inline(always)]
pub(super) fn sin_series(x: f64) -> f64 {
    let x2 = x * x;
    x * (1.0
        + x2 * (-1.0 / 6.0
            + x2 * (1.0 / 120.0
                + x2 * (-1.0 / 5040.0
                    + x2 * (1.0 / 362_880.0 + x2 * (-1.0 / 39_916_800.0 + x2 * (1.0 / 6_227_020_800.0)))))))
}

/// The Taylor series of `cos` to x^14 (see [`sin_cos_small`]).
#[inline(always)]
pub(super) fn cos_series(x: f64) -> f64 {
    let x2 = x * x;
    1.0 + x2
        * (-0.5
            + x2 * (1.0 / 24.0
                + x2 * (-1.0 / 720.0
                    + x2 * (1.0 / 40_320.0
                        + x2 * (-1.0 / 3_628_800.0
                            + x2 * (1.0 / 479_001_600.0 + x2 * (-1.0 / 87_178_291_200.0)))))))
}

/// One Euler step of the prediction model (the same arithmetic as the forward pass).
#[inline]
pub(crate) fn euler_predict(p: &ModelParams, x: &[f64; 8], u: &[f64; 3], dt: f64) -> [f64; 8] {
    let (sr, cr) = sin_cos_small(x[6]);
    let (sp, cp) = sin_cos_small(x[7]);
    let t = u[0];
    [
        x[0] + dt * x[3],
        x[1] + dt * x[4],
        x[2] + dt * x[5],
        x[3] + dt * (t * cr * sp - p.drag_x_per_s * x[3]),
        x[4] + dt * (-t * sr - p.drag_y_per_s * x[4]),
        x[5] + dt * (t * cr * cp - p.gravity_mps2 - p.drag_z_per_s * x[5]),
        x[6] + dt * (p.gain_roll / p.tau_roll_s * u[1] - x[6] / p.tau_roll_s),
        x[7] + dt * (p.gain_pitch / p.tau_pitch_s * u[2] - x[7] / p.tau_pitch_s),
    ]
}
