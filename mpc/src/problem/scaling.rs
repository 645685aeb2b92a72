//! The scaled variables `u = offset + scale * z` and the Jacobi preconditioner that sets the
//! scale: the hover Gauss-Newton Hessian diagonal of the objective, plus the penalty's for the
//! constraints that are active or nearly so.

use mav::InputBounds;

use super::{Evaluator, OcpDefinition};

/// Per-variable affine scaling `u = offset + scale * z`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Scaling {
    pub offset: Vec<f64>,
    pub scale: Vec<f64>,
}

/// Impulse responses of each input channel through the hover linearisation, with
/// `s_1 = B e_c`, `s_{m+1} = A s_m`: the energy `energy[c][n-1] = sum_{m=1..n} |s_m|^2_{2 Qx}`,
/// and the squared position response along the channel's own axis (z for thrust, y for roll,
/// x for pitch: the only one at hover), `position[c][m-1] = s_m[axis]^2`.
pub(crate) fn hover_impulse_response(def: &OcpDefinition, dt: f64) -> ([Vec<f64>; 3], [Vec<f64>; 3]) {
    let p = &def.model;
    let g = p.gravity_mps2;
    let n = def.horizon;
    let mut out = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    let mut position = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    for (c, (energy, pos)) in out.iter_mut().zip(position.iter_mut()).enumerate() {
        let axis = [2, 1, 0][c];
        // s = B e_c for the Euler map at hover (T = g, phi = theta = 0).
        let mut s = [0.0f64; 8];
        match c {
            0 => s[5] = dt,
            1 => s[6] = dt * p.gain_roll / p.tau_roll_s,
            _ => s[7] = dt * p.gain_pitch / p.tau_pitch_s,
        }
        let mut acc = 0.0;
        for (e, r) in energy.iter_mut().zip(pos.iter_mut()) {
            acc += (0..8).map(|k| 2.0 * def.q_x[k] * s[k] * s[k]).sum::<f64>();
            *e = acc;
            *r = s[axis] * s[axis];
            // s <- A s, A = I + dt * Fx(hover)
            let next = [
                s[0] + dt * s[3],
                s[1] + dt * s[4],
                s[2] + dt * s[5],
                s[3] + dt * (-p.drag_x_per_s * s[3] + g * s[7]),
                s[4] + dt * (-p.drag_y_per_s * s[4] - g * s[6]),
                s[5] + dt * (-p.drag_z_per_s * s[5]),
                s[6] - dt * s[6] / p.tau_roll_s,
                s[7] - dt * s[7] / p.tau_pitch_s,
            ];
            s = next;
        }
    }
    (out, position)
}

impl Evaluator {
    /// Jacobi preconditioner from the hover Gauss-Newton Hessian diagonal for the current
    /// weights: `H[j][c] = sum_i w_i E_i[c][N-j-1] + 2 W (Qu[c] + Qdu[c] (1 + [j < N-1]))`.
    pub(super) fn update_scaling(&mut self) {
        let n = self.n;
        for j in 0..n {
            for c in 0..3 {
                let mut h = 0.0;
                for (i, w) in self.weights.iter().enumerate() {
                    h += w * self.impulse_energy[i][c][n - j - 1];
                }
                let rate_terms = if j + 1 < n { 2.0 } else { 1.0 };
                h += 2.0 * self.weight_sum * (self.q_u[c] + self.q_du[c] * rate_terms);
                let k = 3 * j + c;
                self.diagonal[k] = h;
                self.scaling.scale[k] = if h > 1e-12 { 1.0 / h.sqrt() } else { 1.0 };
                self.scaling.offset[k] = self.u_ref[c];
            }
        }
        self.forward_valid = false;
    }

    /// Adds the penalty's Gauss-Newton diagonal to the hover preconditioner: for every
    /// constraint of the last forward pass that is active or nearly so (`g + y / c > -slack_m`),
    /// `c (dg/du)^2` with `dg/du` from the constraint's gradient in position and the hover
    /// position response of each channel along its own axis (a coast's gradient in velocity
    /// is left out: an approximation, and the preconditioner is off by default). With the penalty at 1e3..1e4 this
    /// term dominates the curvature of the inputs that move an active point, which the
    /// objective's diagonal alone misses by orders of magnitude.
    pub(crate) fn update_scaling_with_penalty(&mut self, penalty: f64, multipliers: &[f64], slack_m: f64) {
        self.update_scaling();
        let (m, n, n_con) = (self.m, self.n, self.n_con);
        if penalty > 0.0 && n_con > 0 {
            for i in 0..m {
                for jj in 0..n {
                    for o in 0..n_con {
                        let k = (i * n + jj) * n_con + o;
                        let v = self.con[k] + multipliers.get(k).map_or(0.0, |y| y / penalty);
                        if v <= -slack_m {
                            continue;
                        }
                        let x = &self.states[i * (n + 1) + jj + 1];
                        let dg = self.constraint_gradient(o, x);
                        for (c, axis) in [2usize, 1, 0].into_iter().enumerate() {
                            let a = penalty * dg[axis] * dg[axis];
                            if a == 0.0 {
                                continue;
                            }
                            let response = &self.position_response[i][c];
                            for j in 0..=jj {
                                self.diagonal[3 * j + c] += a * response[jj - j];
                            }
                        }
                    }
                }
            }
        }
        for (s, h) in self.scaling.scale.iter_mut().zip(&self.diagonal) {
            *s = if *h > 1e-12 { 1.0 / h.sqrt() } else { 1.0 };
        }
        self.forward_valid = false;
    }

    /// Scaled variables from inputs.
    pub fn to_scaled(&self, u: &[f64], z: &mut [f64]) {
        for k in 0..z.len() {
            z[k] = (u[k] - self.scaling.offset[k]) / self.scaling.scale[k];
        }
    }

    /// Inputs from scaled variables.
    pub fn to_inputs(&self, z: &[f64], u: &mut [f64]) {
        for k in 0..z.len() {
            u[k] = self.scaling.offset[k] + self.scaling.scale[k] * z[k];
        }
    }

    /// Box bounds of the scaled variables.
    pub fn scaled_bounds(&self, bounds: &InputBounds, lo: &mut [f64], hi: &mut [f64]) {
        for k in 0..lo.len() {
            let c = k % 3;
            lo[k] = (bounds.min[c] - self.scaling.offset[k]) / self.scaling.scale[k];
            hi[k] = (bounds.max[c] - self.scaling.offset[k]) / self.scaling.scale[k];
        }
    }
}
