//! The linearization: each scenario's nominal Euler trajectory, the position sensitivities
//! `S_k = d p_k / d u`, and the Gauss-Newton Hessian and gradient of the objective, by one
//! forward sensitivity pass and one adjoint pass per input.

use mav::ModelParams;

use super::QpFallback;

impl QpFallback {
    /// Nominal trajectories, position sensitivities, Gauss-Newton Hessian and gradient.
    pub(super) fn linearize(&mut self) {
        let (m, n) = (self.evaluator.m, self.evaluator.n);
        let nv = 3 * n;
        let e = EulerCoeffs::new(&self.evaluator.params);
        let EulerCoeffs { ax, ay, az, kr, kp, ir, ip, .. } = e;
        let u = &self.nominal;
        self.hess.iter_mut().for_each(|h| *h = 0.0);
        self.grad.iter_mut().for_each(|h| *h = 0.0);
        for i in 0..m {
            let dt = self.evaluator.dts[i];
            let w2 = 2.0 * self.weights[i];
            let base = i * (n + 1);
            // Nominal forward pass (from the state after the dead time, with compensation).
            let mut x = if self.evaluator.delay_compensation {
                crate::problem::euler_predict(&self.evaluator.params, &self.x0, &self.u_prev, dt)
            } else {
                self.x0
            };
            self.states[base] = x;
            for j in 0..n {
                let (sr, cr) = x[6].sin_cos();
                let (sp, cp) = x[7].sin_cos();
                self.trig[i * n + j] = [sr, cr, sp, cp];
                x = e.step(&x, &u[3 * j..3 * j + 3], dt, [sr, cr, sp, cp]);
                self.states[base + j + 1] = x;
            }
            // Gradient of the state cost at the nominal inputs: one adjoint pass.
            let mut l = [0.0f64; 8];
            for j in (0..n).rev() {
                let xs = &self.states[base + j + 1];
                for k in 0..8 {
                    l[k] += w2 * self.evaluator.q_x[k] * (xs[k] - self.evaluator.x_ref[k]);
                }
                let [sr, cr, sp, cp] = self.trig[i * n + j];
                let t = u[3 * j];
                self.grad[3 * j] += dt * (cr * sp * l[3] - sr * l[4] + cr * cp * l[5]);
                self.grad[3 * j + 1] += dt * kr * l[6];
                self.grad[3 * j + 2] += dt * kp * l[7];
                e.adjoint_step(&mut l, dt, t, [sr, cr, sp, cp]);
            }
            // Hessian and position sensitivities: per input, a forward sensitivity pass and an
            // adjoint pass.
            for v in 0..nv {
                let (jv, c) = (v / 3, v % 3);
                let [sr, cr, sp, cp] = self.trig[i * n + jv];
                // s = d x_{jv+1} / d u_v = dt B_jv e_c
                let mut s = [0.0f64; 8];
                match c {
                    0 => {
                        s[3] = dt * cr * sp;
                        s[4] = -dt * sr;
                        s[5] = dt * cr * cp;
                    }
                    1 => s[6] = dt * kr,
                    _ => s[7] = dt * kp,
                }
                // Points before jv + 1 do not depend on u_v (and are never read for it).
                self.col[jv + 1] = s;
                self.sens[(i * n + jv) * nv + v] = [s[0], s[1], s[2]];
                for j in jv + 1..n {
                    let [sr, cr, sp, cp] = self.trig[i * n + j];
                    let t = u[3 * j];
                    s = [
                        s[0] + dt * s[3],
                        s[1] + dt * s[4],
                        s[2] + dt * s[5],
                        s[3] + dt * (-ax * s[3] - t * sr * sp * s[6] + t * cr * cp * s[7]),
                        s[4] + dt * (-ay * s[4] - t * cr * s[6]),
                        s[5] + dt * (-az * s[5] - t * sr * cp * s[6] - t * cr * sp * s[7]),
                        s[6] - dt * ir * s[6],
                        s[7] - dt * ip * s[7],
                    ];
                    self.col[j + 1] = s;
                    self.sens[(i * n + j) * nv + v] = [s[0], s[1], s[2]];
                }
                // Adjoint: H[(j, c'), v] = B_j^T lambda_{j+1}, lambda_k = A_k^T lambda_{k+1} + 2 w Q s_k.
                let mut l = [0.0f64; 8];
                for j in (jv..n).rev() {
                    let s = &self.col[j + 1];
                    for k in 0..8 {
                        l[k] += w2 * self.evaluator.q_x[k] * s[k];
                    }
                    let [sr, cr, sp, cp] = self.trig[i * n + j];
                    let row = 3 * j;
                    self.hess[v * nv + row] += dt * (cr * sp * l[3] - sr * l[4] + cr * cp * l[5]);
                    self.hess[v * nv + row + 1] += dt * kr * l[6];
                    self.hess[v * nv + row + 2] += dt * kp * l[7];
                    if j > jv {
                        e.adjoint_step(&mut l, dt, u[3 * j], [sr, cr, sp, cp]);
                    }
                }
            }
        }
        // `hess[v nv + r]` holds H[r][v] for r >= 3 (v / 3): mirror into the upper triangle.
        for v in 0..nv {
            for r in (3 * (v / 3))..nv {
                if r > v {
                    self.hess[r * nv + v] = self.hess[v * nv + r];
                }
            }
        }
        // Input cost W sum_j |u_j - u_r|^2_Qu + |u_j - u_{j-1}|^2_Qdu: Hessian and gradient.
        let wsum: f64 = self.weights.iter().sum();
        let (q_u, q_du, u_ref) = (self.evaluator.q_u, self.evaluator.q_du, self.evaluator.u_ref);
        for j in 0..n {
            for c in 0..3 {
                let k = 3 * j + c;
                let uk = u[k];
                let prev = if j == 0 { self.u_prev[c] } else { u[k - 3] };
                let mut gk = q_u[c] * (uk - u_ref[c]) + q_du[c] * (uk - prev);
                let mut diag = q_u[c] + q_du[c];
                if j + 1 < n {
                    gk -= q_du[c] * (u[k + 3] - uk);
                    diag += q_du[c];
                    self.hess[k * nv + k + 3] -= 2.0 * wsum * q_du[c];
                    self.hess[(k + 3) * nv + k] -= 2.0 * wsum * q_du[c];
                }
                self.grad[k] += 2.0 * wsum * gk;
                self.hess[k * nv + k] += 2.0 * wsum * diag;
            }
        }
    }
}

/// The coefficients of the MAV's Euler map that the linearization (and the evaluator's scalar
/// test reference) use, computed once per pass so that both round the same way.
#[derive(Debug, Clone, Copy)]
pub(crate) struct EulerCoeffs {
    pub g: f64,
    pub ax: f64,
    pub ay: f64,
    pub az: f64,
    /// Attitude gains over their time constants.
    pub kr: f64,
    pub kp: f64,
    /// Inverse attitude time constants.
    pub ir: f64,
    pub ip: f64,
}

impl EulerCoeffs {
    pub fn new(p: &ModelParams) -> Self {
        Self {
            g: p.gravity_mps2,
            ax: p.drag_x_per_s,
            ay: p.drag_y_per_s,
            az: p.drag_z_per_s,
            kr: p.gain_roll / p.tau_roll_s,
            kp: p.gain_pitch / p.tau_pitch_s,
            ir: 1.0 / p.tau_roll_s,
            ip: 1.0 / p.tau_pitch_s,
        }
    }

    /// `x + dt f(x, u)` with `trig` the `(sin, cos)` of `x`'s roll and pitch.
    #[inline]
    pub fn step(&self, x: &[f64; 8], u: &[f64], dt: f64, trig: [f64; 4]) -> [f64; 8] {
        let [sr, cr, sp, cp] = trig;
        let Self { g, ax, ay, az, kr, kp, ir, ip } = *self;
        let (t, rd, pd) = (u[0], u[1], u[2]);
        [
            x[0] + dt * x[3],
            x[1] + dt * x[4],
            x[2] + dt * x[5],
            x[3] + dt * (t * cr * sp - ax * x[3]),
            x[4] + dt * (-t * sr - ay * x[4]),
            x[5] + dt * (t * cr * cp - g - az * x[5]),
            x[6] + dt * (kr * rd - ir * x[6]),
            x[7] + dt * (kp * pd - ip * x[7]),
        ]
    }

    /// `l <- (I + dt Fx(x, u))^T l` (`trig` of `x`, thrust `t`).
    #[inline]
    pub fn adjoint_step(&self, l: &mut [f64; 8], dt: f64, t: f64, trig: [f64; 4]) {
        let [sr, cr, sp, cp] = trig;
        let Self { ax, ay, az, ir, ip, .. } = *self;
        let l6 = l[6] + dt * (-t * sr * sp * l[3] - t * cr * l[4] - t * sr * cp * l[5] - ir * l[6]);
        let l7 = l[7] + dt * (t * cr * cp * l[3] - t * cr * sp * l[5] - ip * l[7]);
        l[3] += dt * (l[0] - ax * l[3]);
        l[4] += dt * (l[1] - ay * l[4]);
        l[5] += dt * (l[2] - az * l[5]);
        l[6] = l6;
        l[7] = l7;
    }
}
