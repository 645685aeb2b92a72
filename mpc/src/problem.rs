//! The optimal control problem of `docs/spec.md` and its hot path: cost, penalty and gradient by
//! hand-derived reverse mode (the adjoint of the explicit Euler recursion), allocation-free.
//!
//! Decision variables are *scaled*: `u_j[c] = u_ref[c] + scale[j][c] * z_j[c]`, with
//! `scale = 1 / sqrt(H_jj)` where `H_jj` is the Gauss-Newton Hessian diagonal of the
//! objective linearised at hover. Thrust spans 0..19.6 m/s^2 while the angles span +-0.17 rad
//! and early inputs move a 13 s prediction much more than late ones; without this the problem's
//! curvature differs by orders of magnitude between variables, and PANOC's fixed-point
//! residual test stops far from the optimum (see ARCHITECTURE.md).
//!
//! Code map: the problem's definition (`definition.rs`: [`OcpDefinition`],
//! [`ObstacleFormulation`], and [`ControllerMode`], `mav`'s, re-exported); the evaluator's
//! workspace (this file: [`Evaluator`]) and its passes (`passes.rs`: cost, objective,
//! constraints and gradient, with the per-evaluator
//! [`PassCounts`]); the variable scaling (`scaling.rs`: the preconditioner); the lane-parallel
//! forward and adjoint passes over groups of scenarios (`lanes.rs`); the constraints
//! (`constraints.rs`: cylinder and floor values and gradients, the active set); the scalar Euler
//! step and its sine and cosine (`euler.rs`).

mod constraints;
mod definition;
mod euler;
mod lanes;
mod passes;
mod scaling;
#[cfg(test)]
mod tests;

use mav::ModelParams;

use constraints::{ActiveTerm, ObstacleTerm};
pub(crate) use definition::validate_instance;
pub use definition::{ControllerMode, MAX_COAST_TIME_S, ObstacleFormulation, OcpDefinition};
pub(crate) use euler::euler_predict;
pub use passes::{PassCounts, check_gradient};
pub(crate) use scaling::Scaling;
use scaling::hover_impulse_response;

/// The cost, penalty and gradient of one problem instance, with every buffer allocated once.
///
/// ## Memory allocation
/// `M (N + 1)` states of 8 values, `M N` attitude sin/cos quadruples and state residuals of
/// 8 values, room for every constraint as active, and a handful of `3 N` vectors; all
/// allocated in [`Evaluator::new`], none in the solve loop.
#[derive(Debug, Clone)]
pub struct Evaluator {
    // The definition's data, read by the QP fallback's linearization as well.
    pub(crate) m: usize,
    pub(crate) n: usize,
    pub(crate) params: ModelParams,
    pub(crate) dts: Vec<f64>,
    weights: Vec<f64>,
    weight_sum: f64,
    pub(crate) q_x: [f64; 8],
    pub(crate) q_u: [f64; 3],
    pub(crate) q_du: [f64; 3],
    pub(crate) x_ref: [f64; 8],
    pub(crate) u_ref: [f64; 3],
    obstacles: Vec<ObstacleTerm>,
    min_altitude_m: Option<f64>,
    /// [`OcpDefinition::coast_time_s`].
    coast_s: f64,
    /// Constraint values per predicted point (cylinders, then the floor).
    n_con: usize,
    formulation: ObstacleFormulation,
    pub(crate) delay_compensation: bool,
    x0: [f64; 8],
    /// Initial state of each scenario's prediction: `x0`, or with dead-time compensation
    /// `x0` advanced one Euler step of `ts_i` under `u_prev`.
    x0s: Vec<[f64; 8]>,
    u_prev: [f64; 3],
    pub(crate) scaling: Scaling,
    /// The preconditioner's Hessian diagonal, `1 / scale^2`.
    diagonal: Vec<f64>,
    /// Per scenario, per channel: hover impulse energies (for the preconditioner).
    impulse_energy: Vec<[Vec<f64>; 3]>,
    /// Per scenario, per channel: squared hover position responses (for the preconditioner's
    /// penalty part).
    position_response: Vec<[Vec<f64>; 3]>,
    // Work buffers.
    u: Vec<f64>,
    states: Vec<[f64; 8]>,
    /// `(sin phi, cos phi, sin theta, cos theta)` per scenario and step, in the lane layout of
    /// the scenario groups (see [`Evaluator::forward_lanes`]): group `first..first + L` holds
    /// `trig[4 N first ..][(4 j + q) L + lane]`.
    trig: Vec<f64>,
    /// `x_{j+1} - x_ref` per scenario and step, in the lane layout of `trig` with 8 values in
    /// place of 4: the adjoint pass's stage terms, for groups of several scenarios.
    residual: Vec<f64>,
    /// `J_i` without the input terms, per scenario, of the last forward pass.
    state_costs: Vec<f64>,
    /// The constraints the adjoint pass adds (see [`Evaluator::collect_active`]); capacity for
    /// all of them, so pushes never allocate.
    active: Vec<ActiveTerm>,
    /// Where each scenario's entries of `active` begin, and the end: `M + 1` values.
    active_start: Vec<usize>,
    grad_u: Vec<f64>,
    /// Constraint value per scenario, point and cylinder (the gradient in (px, py, pz) is
    /// recomputed in the adjoint pass where the penalty is active: most forward passes are
    /// PANOC's cost-only evaluations, and most constraints are inactive).
    con: Vec<f64>,
    // Cache of the last forward pass, keyed by the bits of `z`.
    last_z: Vec<f64>,
    forward_valid: bool,
    objective: f64,
    /// Passes run over the evaluator's life.
    passes: PassCounts,
}

impl Evaluator {
    pub fn new(def: &OcpDefinition) -> Self {
        let m = def.num_scenarios();
        let n = def.horizon;
        let obstacles = def
            .obstacles
            .iter()
            .map(|c| {
                let r = c.radius_m + def.obstacle_margin_m;
                ObstacleTerm { xo: c.x_m, yo: c.y_m, r2: r * r, zo: c.height_m, r }
            })
            .collect();
        let (impulse_energy, position_response) =
            def.sampling_times_s.iter().map(|&dt| hover_impulse_response(def, dt)).unzip();
        let mut ev = Self {
            m,
            n,
            params: def.model,
            dts: def.sampling_times_s.clone(),
            weights: vec![1.0 / m as f64; m],
            weight_sum: 1.0,
            q_x: def.q_x,
            q_u: def.q_u,
            q_du: def.q_du,
            x_ref: def.x_ref,
            u_ref: def.u_ref,
            obstacles,
            min_altitude_m: def.min_altitude_m,
            coast_s: def.coast_time_s,
            n_con: def.constraints_per_point(),
            formulation: def.formulation,
            delay_compensation: def.delay_compensation,
            x0: [0.0; 8],
            x0s: vec![[0.0; 8]; m],
            u_prev: def.u_ref,
            scaling: Scaling { offset: vec![0.0; 3 * n], scale: vec![1.0; 3 * n] },
            diagonal: vec![1.0; 3 * n],
            impulse_energy,
            position_response,
            u: vec![0.0; 3 * n],
            states: vec![[0.0; 8]; m * (n + 1)],
            trig: vec![0.0; 4 * m * n],
            residual: vec![0.0; 8 * m * n],
            state_costs: vec![0.0; m],
            active: Vec::with_capacity(def.num_constraints()),
            active_start: vec![0; m + 1],
            grad_u: vec![0.0; 3 * n],
            con: vec![0.0; def.num_constraints()],
            last_z: vec![0.0; 3 * n],
            forward_valid: false,
            objective: 0.0,
            passes: PassCounts::default(),
        };
        ev.update_scaling();
        ev
    }

    pub fn num_variables(&self) -> usize {
        3 * self.n
    }

    /// Forward and adjoint passes run since the evaluator was made.
    pub fn pass_counts(&self) -> PassCounts {
        self.passes
    }

    pub fn num_scenarios(&self) -> usize {
        self.m
    }

    pub fn horizon(&self) -> usize {
        self.n
    }

    /// Sets the per-cycle data. The caller has validated lengths and finiteness.
    pub fn set_instance(&mut self, x0: &[f64; 8], u_prev: &[f64; 3], weights: &[f64]) {
        self.x0 = *x0;
        self.u_prev = *u_prev;
        for (x0i, &dt) in self.x0s.iter_mut().zip(&self.dts) {
            *x0i = if self.delay_compensation { euler_predict(&self.params, x0, u_prev, dt) } else { *x0 };
        }
        self.weights.copy_from_slice(weights);
        self.weight_sum = weights.iter().sum();
        self.forward_valid = false;
        self.update_scaling();
    }

    /// Sets [`OcpDefinition::coast_time_s`] (validated by the caller).
    pub(crate) fn set_coast_time(&mut self, coast_s: f64) {
        if coast_s != self.coast_s {
            self.coast_s = coast_s;
            self.forward_valid = false;
        }
    }

    /// Predicted states of scenario `i` after the last forward pass: `N + 1` points.
    pub fn predicted_states(&self, i: usize) -> &[[f64; 8]] {
        let base = i * (self.n + 1);
        &self.states[base..base + self.n + 1]
    }

    /// Inputs of the last forward pass.
    pub fn inputs(&self) -> &[f64] {
        &self.u
    }

    pub fn sampling_times(&self) -> &[f64] {
        &self.dts
    }

    pub fn weights(&self) -> &[f64] {
        &self.weights
    }
}
