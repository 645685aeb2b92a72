//! The evaluator's passes: the forward pass (predictions, objective, constraint values, cached
//! by the bits of `z`), the penalty, and the adjoint pass's gradient; with the passes counted
//! per evaluator.

use super::Evaluator;
use super::constraints::for_each_positive;
use super::lanes::{MAX_LANES, with_lanes};

/// Forward (prediction) and adjoint passes an [`Evaluator`] ran: the work of a solve counted
/// deterministically, unlike wall times (returned per solve in `SolveReport::passes`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct PassCounts {
    pub forward: u64,
    pub adjoint: u64,
}

impl PassCounts {
    /// The passes run since `earlier` (a count taken from the same evaluator before).
    pub fn since(self, earlier: PassCounts) -> PassCounts {
        PassCounts { forward: self.forward - earlier.forward, adjoint: self.adjoint - earlier.adjoint }
    }
}

impl Evaluator {
    pub(super) fn ensure_forward(&mut self, z: &[f64]) {
        if self.forward_valid && self.last_z.iter().zip(z).all(|(a, b)| a.to_bits() == b.to_bits()) {
            return;
        }
        self.last_z.copy_from_slice(z);
        for k in 0..z.len() {
            self.u[k] = self.scaling.offset[k] + self.scaling.scale[k] * z[k];
        }
        self.forward_inputs();
        self.forward_valid = true;
    }

    /// Forward pass on `self.u`: predictions of every scenario, the objective, and every
    /// constraint value.
    pub(super) fn forward_inputs(&mut self) {
        self.passes.forward += 1;
        let mut first = 0;
        while first < self.m {
            let width = self.group_width(first);
            with_lanes!(width, self.forward_lanes(first));
            first += width;
        }
        // Scenario 0 first, as the sum has always been taken.
        let mut objective = 0.0;
        for (w, state_cost) in self.weights.iter().zip(&self.state_costs) {
            objective += w * state_cost;
        }
        objective += self.weight_sum * self.input_cost();
        self.objective = objective;
    }

    /// Scenarios `first..first + width` form the next group of the lane-parallel passes: at
    /// most [`MAX_LANES`].
    pub(super) fn group_width(&self, first: usize) -> usize {
        (self.m - first).min(MAX_LANES)
    }

    pub(super) fn input_cost(&self) -> f64 {
        let mut cost = 0.0;
        let mut prev = self.u_prev;
        for j in 0..self.n {
            for c in 0..3 {
                let u = self.u[3 * j + c];
                let e = u - self.u_ref[c];
                let d = u - prev[c];
                cost += self.q_u[c] * e * e + self.q_du[c] * d * d;
                prev[c] = u;
            }
        }
        cost
    }

    /// `psi(z; c, y) = sum_i w_i J_i + (c / 2) sum_k [g_k + y_k / c]_+^2`: OpEn's augmented
    /// Lagrangian for `g <= 0` (with `y` empty it is the penalty method's `(c / 2) |F2|^2`, as
    /// `F2 >= 0`).
    pub fn cost(&mut self, z: &[f64], penalty: f64, multipliers: &[f64]) -> f64 {
        self.ensure_forward(z);
        self.objective + self.penalty_term(penalty, multipliers)
    }

    pub(super) fn penalty_term(&self, c: f64, y: &[f64]) -> f64 {
        if c <= 0.0 {
            return 0.0;
        }
        let mut acc = 0.0;
        // Past the end of `y`, `g + 0 / c` is `g + 0`: `c > 0`.
        for_each_positive(&self.con, y, |g, y| g + y / c, |_, v| acc += v * v);
        0.5 * c * acc
    }

    /// The spec's objective `sum_i w_i J_i` alone, at `z`.
    pub fn objective(&mut self, z: &[f64]) -> f64 {
        self.ensure_forward(z);
        self.objective
    }

    /// The spec's objective at inputs `u` (unscaled).
    pub fn objective_at_inputs(&mut self, u: &[f64]) -> f64 {
        self.u.copy_from_slice(u);
        self.forward_inputs();
        self.forward_valid = false;
        self.objective
    }

    /// The constraint mapping at `z` (ALM's `F1` or PM's `F2`, by formulation).
    pub fn constraints(&mut self, z: &[f64], out: &mut [f64]) {
        self.ensure_forward(z);
        out.copy_from_slice(&self.con);
    }

    /// Constraint values of the last forward pass.
    pub fn constraint_values(&self) -> &[f64] {
        &self.con
    }

    /// Gradient of `psi(z; c, y)` with respect to the scaled variables.
    pub fn gradient(&mut self, z: &[f64], penalty: f64, multipliers: &[f64], grad: &mut [f64]) {
        self.ensure_forward(z);
        self.passes.adjoint += 1;
        self.input_cost_gradient();
        self.collect_active(penalty, multipliers);
        let mut first = 0;
        while first < self.m {
            let width = self.group_width(first);
            with_lanes!(width, self.adjoint_group(first));
            first += width;
        }
        for k in 0..grad.len() {
            grad[k] = self.grad_u[k] * self.scaling.scale[k];
        }
    }

    /// Adjoint pass of the forward pass's group `first..first + G`, one scenario at a time:
    /// with two or more lanes (SSE2 holds two), the adjoint states and their weights no longer
    /// fit in the 16 registers, and the spills cost more than the lanes save (callgrind:
    /// 2 lanes as many instructions as 1, 5 lanes 30 % more). `adjoint_lanes` keeps the lanes
    /// for wider vectors.
    pub(super) fn adjoint_group<const G: usize>(&mut self, first: usize) {
        for offset in 0..G {
            self.adjoint_lanes::<G, 1>(first, offset);
        }
    }

    /// Overwrites `grad_u` with the gradient of `W * input_cost`.
    pub(super) fn input_cost_gradient(&mut self) {
        // Fields as locals (see `forward_lanes`), and the inputs step by step without indexing.
        let Self { u, u_prev, u_ref, q_u, q_du, grad_u, weight_sum, .. } = self;
        let (u_ref, q_u, q_du) = (*u_ref, *q_u, *q_du);
        let w2 = 2.0 * *weight_sum;
        let mut prev = *u_prev;
        let mut next_inputs = u.chunks_exact(3).skip(1);
        for (g, u) in grad_u.chunks_exact_mut(3).zip(u.chunks_exact(3)) {
            let next = next_inputs.next();
            for c in 0..3 {
                let mut gc = q_u[c] * (u[c] - u_ref[c]) + q_du[c] * (u[c] - prev[c]);
                if let Some(next) = next {
                    gc -= q_du[c] * (next[c] - u[c]);
                }
                g[c] = w2 * gc;
                prev[c] = u[c];
            }
        }
    }
}

/// Test support, shared by this module's unit tests and `tests/gradient_options.rs`: central
/// finite differences of [`Evaluator::cost`] against [`Evaluator::gradient`], coordinate by
/// coordinate. `Err` names the first variable whose adjoint derivative disagrees (relative to
/// the largest gradient component).
#[doc(hidden)]
pub fn check_gradient(ev: &mut Evaluator, z: &[f64], c: f64, y: &[f64]) -> Result<(), String> {
    let n = z.len();
    let mut grad = vec![0.0; n];
    ev.gradient(z, c, y, &mut grad);
    let mut zp = z.to_vec();
    let scale = grad.iter().fold(1.0f64, |m, g| m.max(g.abs()));
    for k in 0..n {
        let h = 1e-6 * (1.0 + z[k].abs());
        zp[k] = z[k] + h;
        let fp = ev.cost(&zp, c, y);
        zp[k] = z[k] - h;
        let fm = ev.cost(&zp, c, y);
        zp[k] = z[k];
        let fd = (fp - fm) / (2.0 * h);
        if (fd - grad[k]).abs() > 2e-5 * scale {
            return Err(format!(
                "variable {k}: adjoint {} vs finite difference {fd} (scale {scale})",
                grad[k]
            ));
        }
    }
    Ok(())
}
