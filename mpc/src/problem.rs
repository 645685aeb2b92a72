//! The optimal control problem of `SPEC.md` and its hot path: cost, penalty and gradient by
//! hand-derived reverse mode (the adjoint of the explicit Euler recursion), allocation-free.
//!
//! Decision variables are *scaled*: `u_j[c] = u_ref[c] + scale[j][c] * z_j[c]`, with
//! `scale = 1 / sqrt(H_jj)` where `H_jj` is the Gauss-Newton Hessian diagonal of the
//! objective linearised at hover. Thrust spans 0..19.6 m/s^2 while the angles span +-0.17 rad
//! and early inputs move a 13 s prediction much more than late ones; without this the problem's
//! curvature differs by orders of magnitude between variables, and PANOC's fixed-point
//! residual test stops far from the optimum (see ARCHITECTURE.md).

use std::sync::atomic::{AtomicU64, Ordering};

use mav::{Cylinder, InputBounds, ModelParams, Scenario};

use crate::solver::{MpcError, invalid_input};

/// Forward (prediction) and adjoint passes of every evaluator in the process, for tuning aids
/// (`examples/solve_stats.rs`): deterministic, unlike wall times.
static FORWARD_PASSES: AtomicU64 = AtomicU64::new(0);
static ADJOINT_PASSES: AtomicU64 = AtomicU64::new(0);

/// `(forward passes, adjoint passes)` run so far by every [`Evaluator`] of the process.
pub fn pass_counts() -> (u64, u64) {
    (FORWARD_PASSES.load(Ordering::Relaxed), ADJOINT_PASSES.load(Ordering::Relaxed))
}

/// Which controller of the paper.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ControllerMode {
    /// Standard NMPC: one scenario at the nominal sampling time, weight 1.
    Nmpc,
    /// Multi-stage NMPC: one scenario per sampling time, weighted by delay probability.
    Multistage,
}

impl ControllerMode {
    pub fn name(self) -> &'static str {
        match self {
            ControllerMode::Nmpc => "nmpc",
            ControllerMode::Multistage => "multistage",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "nmpc" => Some(Self::Nmpc),
            "multistage" | "multi-stage" => Some(Self::Multistage),
            _ => None,
        }
    }
}

/// How the cylinder constraint enters the solver.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObstacleFormulation {
    /// The paper's form: `F2 = [R^2 - dx^2 - dy^2]_+ [zo - z]_+ = 0` per point, handled by
    /// OpEn's penalty method (PM). Its units are m^3, its gradient scales with `R (zo - z)^2`
    /// (so a 1.5 m cylinder and a 0.25 m one are penalised very differently), and the penalty
    /// must grow large to push violations to zero, which makes PANOC's problem stiff.
    PaperPenalty,
    /// `g = min(R - d, zo - z) <= 0` per point (horizontal distance `d` to the axis), handled
    /// by OpEn's augmented Lagrangian (ALM) with multipliers warm-started across cycles. The
    /// same feasible set, in metres for every cylinder, and exact feasibility with a moderate
    /// penalty. The default.
    DistanceAlm,
}

/// A cylinder as the constraint sees it: inflated radius squared, precomputed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ObstacleTerm {
    pub xo: f64,
    pub yo: f64,
    pub r2: f64,
    pub zo: f64,
    pub r: f64,
}

/// What to solve: everything of the optimal control problem except the current state, the
/// last applied input and the scenario weights, which change every cycle.
#[derive(Debug, Clone, PartialEq)]
pub struct OcpDefinition {
    pub model: ModelParams,
    pub bounds: InputBounds,
    pub obstacles: Vec<Cylinder>,
    /// Added to every cylinder radius in the constraint, m.
    pub obstacle_margin_m: f64,
    pub formulation: ObstacleFormulation,
    pub horizon: usize,
    /// One prediction per sampling time, s.
    pub sampling_times_s: Vec<f64>,
    pub q_x: [f64; 8],
    pub q_u: [f64; 3],
    pub q_du: [f64; 3],
    pub x_ref: [f64; 8],
    pub u_ref: [f64; 3],
    /// Optional floor: every predicted point of every scenario keeps `z >= min_altitude_m`
    /// (the constraint `min_altitude_m - z <= 0`, in the same formulation as the cylinders).
    /// `None` in paper mode, whose model has no floor.
    pub min_altitude_m: Option<f64>,
    /// Dead-time compensation: scenario `i` first holds the last applied input for its own
    /// sampling time `ts_i` (the round-trip delay it stands for, during which the previous
    /// command stays on), then applies the plan. Off in paper mode (the paper predicts from
    /// the measured state at once).
    pub delay_compensation: bool,
}

impl OcpDefinition {
    /// The problem of `scenario` for `mode`, with the controller's `obstacle_margin_m` unless
    /// the scenario pins its own.
    pub fn from_scenario(
        scenario: &Scenario,
        mode: ControllerMode,
        obstacle_margin_m: f64,
        formulation: ObstacleFormulation,
    ) -> Self {
        let sampling_times_s = match mode {
            ControllerMode::Nmpc => vec![scenario.nmpc_sampling_time_s],
            ControllerMode::Multistage => scenario.sampling_times_s.clone(),
        };
        let g = scenario.model.gravity_mps2;
        let mut x_ref = [0.0; 8];
        x_ref[..3].copy_from_slice(&scenario.goal_m);
        Self {
            model: scenario.model,
            bounds: scenario.bounds,
            obstacles: scenario.obstacles.clone(),
            // A scenario may pin its own margin (scenario files do, with dead-time compensation).
            obstacle_margin_m: scenario.obstacle_margin_m.unwrap_or(obstacle_margin_m),
            formulation,
            horizon: scenario.horizon,
            sampling_times_s,
            q_x: scenario.q_x,
            q_u: scenario.q_u,
            q_du: scenario.q_du,
            x_ref,
            u_ref: [g, 0.0, 0.0],
            min_altitude_m: scenario.min_altitude_m,
            delay_compensation: scenario.delay_compensation,
        }
    }

    pub fn num_scenarios(&self) -> usize {
        self.sampling_times_s.len()
    }

    /// Number of decision variables, `3 N`.
    pub fn num_variables(&self) -> usize {
        3 * self.horizon
    }

    /// Constraint values per predicted point: one per cylinder, and the floor when set.
    pub fn constraints_per_point(&self) -> usize {
        self.obstacles.len() + usize::from(self.min_altitude_m.is_some())
    }

    /// Number of constraint values (ALM's `F1` or PM's `F2`): one per scenario, predicted point
    /// and cylinder (and the floor).
    pub fn num_constraints(&self) -> usize {
        self.num_scenarios() * self.horizon * self.constraints_per_point()
    }
}

/// Checks the per-cycle data of a problem with `m` scenarios: the state, the last applied
/// input and the scenario weights. Shared by [`crate::Mpc`] and [`crate::QpFallback`], so both
/// reject the same inputs with errors naming the same fields.
pub(crate) fn validate_instance(
    m: usize,
    x0: &[f64; 8],
    u_prev: &[f64; 3],
    weights: &[f64],
) -> Result<(), MpcError> {
    if let Some(i) = x0.iter().position(|v| !v.is_finite()) {
        return Err(invalid_input(format!("x0[{i}]"), "must be finite"));
    }
    if let Some(i) = u_prev.iter().position(|v| !v.is_finite()) {
        return Err(invalid_input(format!("u_prev[{i}]"), "must be finite"));
    }
    if weights.len() != m {
        return Err(invalid_input("weights", format!("must hold {m} values, got {}", weights.len())));
    }
    if let Some(i) = weights.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(invalid_input(format!("weights[{i}]"), "must be finite and >= 0"));
    }
    if weights.iter().sum::<f64>() <= 0.0 {
        return Err(invalid_input("weights", "must not all be zero"));
    }
    Ok(())
}

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

/// A constraint the penalty's gradient sees: `c g + y > 0` at a step of a scenario.
#[derive(Debug, Clone, Copy)]
struct ActiveTerm {
    step: usize,
    constraint: usize,
    value: f64,
}

/// Most scenarios the lane-parallel passes process together (see
/// [`Evaluator::forward_lanes`]); more form several groups.
const MAX_LANES: usize = 8;

/// `$self.$method::<L>(args)` with the const `L` equal to `$width`, one of `1..=MAX_LANES`.
macro_rules! with_lanes {
    ($width:expr, $self:ident . $method:ident ( $($arg:expr),* )) => {
        match $width {
            1 => $self.$method::<1>($($arg),*),
            2 => $self.$method::<2>($($arg),*),
            3 => $self.$method::<3>($($arg),*),
            4 => $self.$method::<4>($($arg),*),
            5 => $self.$method::<5>($($arg),*),
            6 => $self.$method::<6>($($arg),*),
            7 => $self.$method::<7>($($arg),*),
            8 => $self.$method::<8>($($arg),*),
            w => unreachable!("scenario group of {w}"),
        }
    };
}

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
        };
        ev.update_scaling();
        ev
    }

    pub fn num_variables(&self) -> usize {
        3 * self.n
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

    /// Jacobi preconditioner from the hover Gauss-Newton Hessian diagonal for the current
    /// weights: `H[j][c] = sum_i w_i E_i[c][N-j-1] + 2 W (Qu[c] + Qdu[c] (1 + [j < N-1]))`.
    fn update_scaling(&mut self) {
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
    /// position response of each channel along its own axis. With the penalty at 1e3..1e4 this
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

    fn ensure_forward(&mut self, z: &[f64]) {
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
    fn forward_inputs(&mut self) {
        FORWARD_PASSES.fetch_add(1, Ordering::Relaxed);
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
    fn group_width(&self, first: usize) -> usize {
        (self.m - first).min(MAX_LANES)
    }

    /// Forward pass of scenarios `first..first + L` together, step-outer and scenario-inner.
    ///
    /// The scenarios are independent chains (own `dt` and `x0`) driven by the same inputs.
    /// With the scenarios of a group in the lanes of `[f64; L]` arrays, LLVM vectorizes each
    /// step's arithmetic across them (SSE2: two lanes per instruction), which matters because
    /// the pass is bound by instruction throughput, not by the chains' latency. Every lane
    /// does exactly the operations of the scalar recursion in the same order (Rust never
    /// contracts `a * b + c` into an FMA), so the results are bit-identical to one scenario
    /// at a time.
    fn forward_lanes<const L: usize>(&mut self, first: usize) {
        // Fields as locals: the stores into the outputs would otherwise make LLVM reload every
        // field of `self` after each of them.
        let Self {
            n,
            params,
            dts,
            x0s,
            x_ref,
            q_x,
            obstacles,
            formulation,
            min_altitude_m,
            n_con,
            u,
            states,
            trig,
            residual,
            con,
            state_costs,
            ..
        } = self;
        let (n, n_con, x_ref, q_x, formulation) = (*n, *n_con, *x_ref, *q_x, *formulation);
        let p = *params;
        let (g, ax, ay, az) = (p.gravity_mps2, p.drag_x_per_s, p.drag_y_per_s, p.drag_z_per_s);
        let (kr, kp) = (p.gain_roll / p.tau_roll_s, p.gain_pitch / p.tau_pitch_s);
        let (ir, ip) = (1.0 / p.tau_roll_s, 1.0 / p.tau_pitch_s);
        let n_obs = obstacles.len();
        let dt: [f64; L] = lanes(|l| dts[first + l]);
        let mut x: [[f64; L]; 8] = std::array::from_fn(|k| lanes(|l| x0s[first + l][k]));
        // Scenario `first + l`'s predictions are `states[l * (n + 1)..]`.
        let states = &mut states[first * (n + 1)..(first + L) * (n + 1)];
        for l in 0..L {
            states[l * (n + 1)] = x0s[first + l];
        }
        // Scenario `first + l`'s constraint values are `con[l * n * n_con..]`.
        let con = &mut con[first * n * n_con..(first + L) * n * n_con];
        let mut state_cost = [0.0f64; L];
        let trig = trig[4 * n * first..4 * n * (first + L)].chunks_exact_mut(4 * L);
        let residual = residual[8 * n * first..8 * n * (first + L)].chunks_exact_mut(8 * L);
        for (j, (u, (trig, residual))) in u.chunks_exact(3).zip(trig.zip(residual)).enumerate() {
            let (sr, cr) = sin_cos_lanes(&x[6]);
            let (sp, cp) = sin_cos_lanes(&x[7]);
            for (q, v) in [sr, cr, sp, cp].iter().enumerate() {
                trig[q * L..(q + 1) * L].copy_from_slice(v);
            }
            let (t, rd, pd) = (u[0], u[1], u[2]);
            x = [
                lanes(|l| x[0][l] + dt[l] * x[3][l]),
                lanes(|l| x[1][l] + dt[l] * x[4][l]),
                lanes(|l| x[2][l] + dt[l] * x[5][l]),
                lanes(|l| x[3][l] + dt[l] * (t * cr[l] * sp[l] - ax * x[3][l])),
                lanes(|l| x[4][l] + dt[l] * (-t * sr[l] - ay * x[4][l])),
                lanes(|l| x[5][l] + dt[l] * (t * cr[l] * cp[l] - g - az * x[5][l])),
                lanes(|l| x[6][l] + dt[l] * (kr * rd - ir * x[6][l])),
                lanes(|l| x[7][l] + dt[l] * (kp * pd - ip * x[7][l])),
            ];
            for l in 0..L {
                states[l * (n + 1) + j + 1] = std::array::from_fn(|k| x[k][l]);
            }
            for k in 0..8 {
                for l in 0..L {
                    let e = x[k][l] - x_ref[k];
                    state_cost[l] += q_x[k] * e * e;
                    // For one scenario the adjoint pass reads the states instead: these stores
                    // would be all overhead. For several, they also make LLVM vectorize this
                    // loop over the lanes (it does not without them: callgrind).
                    if L > 1 {
                        residual[k * L + l] = e;
                    }
                }
            }
            // `con` keeps its layout (scenario, point, constraint): OpEn reads it as F1, and
            // the penalty sums it in that order.
            if L == 1 {
                // One scenario: a point's values are contiguous, and LLVM vectorizes over the
                // cylinders, as it did before the lanes.
                let row = &mut con[j * n_con..(j + 1) * n_con];
                let (px, py, pz) = (x[0][0], x[1][0], x[2][0]);
                let cylinders = obstacles.iter().zip(&mut row[..n_obs]);
                match formulation {
                    ObstacleFormulation::PaperPenalty => cylinders.for_each(|(ob, c)| {
                        *c = constraint_value(ObstacleFormulation::PaperPenalty, ob, px, py, pz);
                    }),
                    ObstacleFormulation::DistanceAlm => cylinders.for_each(|(ob, c)| {
                        *c = constraint_value(ObstacleFormulation::DistanceAlm, ob, px, py, pz);
                    }),
                }
            } else {
                // Several: over the lanes, cylinder by cylinder (fewer instructions, callgrind).
                let point = |l: usize| (l * n + j) * n_con;
                for (o, ob) in obstacles.iter().enumerate() {
                    // One arm per formulation, so that the lane loops are branch-free.
                    let value: [f64; L] = match formulation {
                        ObstacleFormulation::PaperPenalty => lanes(|l| {
                            constraint_value(ObstacleFormulation::PaperPenalty, ob, x[0][l], x[1][l], x[2][l])
                        }),
                        ObstacleFormulation::DistanceAlm => lanes(|l| {
                            constraint_value(ObstacleFormulation::DistanceAlm, ob, x[0][l], x[1][l], x[2][l])
                        }),
                    };
                    for (l, v) in value.into_iter().enumerate() {
                        con[point(l) + o] = v;
                    }
                }
            }
            if let Some(floor) = *min_altitude_m {
                for l in 0..L {
                    con[(l * n + j) * n_con + n_obs] = floor_value(formulation, floor, x[2][l]);
                }
            }
        }
        state_costs[first..first + L].copy_from_slice(&state_cost);
    }

    fn input_cost(&self) -> f64 {
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

    fn penalty_term(&self, c: f64, y: &[f64]) -> f64 {
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
        ADJOINT_PASSES.fetch_add(1, Ordering::Relaxed);
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

    /// Whether any constraint enters the penalty term of `psi(z; c, y)` at `z`: the same test
    /// as the adjoint pass's active set ([`Evaluator::collect_active`]).
    pub(crate) fn has_penalty_terms(&mut self, z: &[f64], c: f64, y: &[f64]) -> bool {
        self.ensure_forward(z);
        any_penalty_term(&self.con, y, c)
    }

    /// Lists the constraints with `c g + y > 0` (those the penalty's gradient sees) with that
    /// value, scenario by scenario in `con` order; scenario `i`'s are
    /// `active[active_start[i]..active_start[i + 1]]`. Most are inactive: one contiguous pass
    /// here spares the adjoint pass a test per point.
    fn collect_active(&mut self, c: f64, multipliers: &[f64]) {
        let Self { m, n, n_con, con, active, active_start, .. } = self;
        let (m, n_con) = (*m, *n_con);
        let block = *n * n_con;
        active.clear();
        for i in 0..m {
            active_start[i] = active.len();
            if c <= 0.0 {
                continue;
            }
            // Without multipliers for the whole scenario, none (`c g + 0`).
            let y = multipliers.get(i * block..(i + 1) * block).unwrap_or(&[]);
            for_each_positive(
                &con[i * block..(i + 1) * block],
                y,
                |g, y| c * g + y,
                |k, v| active.push(ActiveTerm { step: k / n_con, constraint: k % n_con, value: v }),
            );
        }
        active_start[m] = active.len();
    }

    /// Adjoint pass of the forward pass's group `first..first + G`, one scenario at a time:
    /// with two or more lanes (SSE2 holds two), the adjoint states and their weights no longer
    /// fit in the 16 registers, and the spills cost more than the lanes save (callgrind:
    /// 2 lanes as many instructions as 1, 5 lanes 30 % more). `adjoint_lanes` keeps the lanes
    /// for wider vectors.
    fn adjoint_group<const G: usize>(&mut self, first: usize) {
        for offset in 0..G {
            self.adjoint_lanes::<G, 1>(first, offset);
        }
    }

    /// Adjoint pass of scenarios `group + offset..group + offset + L` of the forward group
    /// `group..group + G` together, adding their input sensitivities to `grad_u`: backward
    /// over the steps, lane-parallel over the scenarios as in [`Evaluator::forward_lanes`],
    /// with the same operations per lane as one scenario at a time. The scenarios'
    /// contributions to each input are added in scenario order (the sub-groups of a group in
    /// order, the lanes of a sub-group in order), the order of the scalar pass, so `grad_u` is
    /// bit-identical too.
    fn adjoint_lanes<const G: usize, const L: usize>(&mut self, group: usize, offset: usize) {
        let first = group + offset;
        // Fields as locals, as in `forward_lanes`; `grad_u` is the only output.
        let Self {
            n,
            params,
            dts,
            weights,
            q_x,
            x_ref,
            u,
            states,
            trig,
            residual,
            grad_u,
            active,
            active_start,
            obstacles,
            formulation,
            min_altitude_m,
            ..
        } = self;
        let (n, q_x, x_ref) = (*n, *q_x, *x_ref);
        let p = *params;
        let (ax, ay, az) = (p.drag_x_per_s, p.drag_y_per_s, p.drag_z_per_s);
        let (kr, kp) = (p.gain_roll / p.tau_roll_s, p.gain_pitch / p.tau_pitch_s);
        let (ir, ip) = (1.0 / p.tau_roll_s, 1.0 / p.tau_pitch_s);
        let dt: [f64; L] = lanes(|l| dts[first + l]);
        let wq: [[f64; L]; 8] = std::array::from_fn(|k| lanes(|l| 2.0 * weights[first + l] * q_x[k]));
        // The forward pass's layout: lane `l` here is lane `offset + l` of its group.
        let trig = &trig[4 * n * group..4 * n * (group + G)];
        let residual = &residual[8 * n * group..8 * n * (group + G)];
        // Per lane, the active constraints of the steps not yet visited (they run backward) are
        // `active[start..end]`, and `next` is the step of the last of them (`n`: none).
        let start: [usize; L] = std::array::from_fn(|l| active_start[first + l]);
        let mut end: [usize; L] = std::array::from_fn(|l| active_start[first + l + 1]);
        let mut next: [usize; L] =
            std::array::from_fn(|l| if end[l] > start[l] { active[end[l] - 1].step } else { n });
        // The adjoint state `l` of each scenario, as `lam[k][lane]`.
        let mut lam = [[0.0f64; L]; 8];
        let steps = u.chunks_exact(3).zip(grad_u.chunks_exact_mut(3)).zip(trig.chunks_exact(4 * G));
        for (j, (((u, grad_u), trig), residual)) in steps.zip(residual.chunks_exact(8 * G)).enumerate().rev()
        {
            // Stage terms at x_{j+1}: `x - x_ref` as the forward pass computed it.
            if G == 1 {
                let x = &states[first * (n + 1) + j + 1];
                for k in 0..8 {
                    lam[k][0] += wq[k][0] * (x[k] - x_ref[k]);
                }
            } else {
                for k in 0..8 {
                    for l in 0..L {
                        lam[k][l] += wq[k][l] * residual[k * G + offset + l];
                    }
                }
            }
            // The active constraints at x_{j+1} (usually none), in constraint order.
            for l in 0..L {
                if next[l] != j {
                    continue;
                }
                let mut lo = end[l];
                while lo > start[l] && active[lo - 1].step == j {
                    lo -= 1;
                }
                let x = &states[(first + l) * (n + 1) + j + 1];
                for term in &active[lo..end[l]] {
                    let dg =
                        constraint_gradient(obstacles, *formulation, *min_altitude_m, term.constraint, x);
                    lam[0][l] += term.value * dg[0];
                    lam[1][l] += term.value * dg[1];
                    lam[2][l] += term.value * dg[2];
                }
                end[l] = lo;
                next[l] = if lo > start[l] { active[lo - 1].step } else { n };
            }
            // Input sensitivity of x_{j+1} = x_j + dt f(x_j, u_j).
            let [sr, cr, sp, cp]: [[f64; L]; 4] =
                std::array::from_fn(|q| lanes(|l| trig[q * G + offset + l]));
            let t = u[0];
            let g0 = lanes::<L>(|l| {
                dt[l] * (cr[l] * sp[l] * lam[3][l] - sr[l] * lam[4][l] + cr[l] * cp[l] * lam[5][l])
            });
            let g1 = lanes::<L>(|l| dt[l] * kr * lam[6][l]);
            let g2 = lanes::<L>(|l| dt[l] * kp * lam[7][l]);
            // In scenario order, as the sum has always been taken.
            for l in 0..L {
                grad_u[0] += g0[l];
                grad_u[1] += g1[l];
                grad_u[2] += g2[l];
            }
            // Adjoint: l_j = (I + dt Fx(x_j, u_j))^T l_{j+1}.
            let l6 = lanes::<L>(|l| {
                lam[6][l]
                    + dt[l]
                        * (-t * sr[l] * sp[l] * lam[3][l]
                            - t * cr[l] * lam[4][l]
                            - t * sr[l] * cp[l] * lam[5][l]
                            - ir * lam[6][l])
            });
            let l7 = lanes::<L>(|l| {
                lam[7][l]
                    + dt[l] * (t * cr[l] * cp[l] * lam[3][l] - t * cr[l] * sp[l] * lam[5][l] - ip * lam[7][l])
            });
            for l in 0..L {
                lam[3][l] += dt[l] * (lam[0][l] - ax * lam[3][l]);
                lam[4][l] += dt[l] * (lam[1][l] - ay * lam[4][l]);
                lam[5][l] += dt[l] * (lam[2][l] - az * lam[5][l]);
            }
            lam[6] = l6;
            lam[7] = l7;
        }
    }

    /// Gradient in `(px, py, pz)` of constraint `o` of a point (cylinders, then the floor) at
    /// state `x`.
    #[inline]
    fn constraint_gradient(&self, o: usize, x: &[f64; 8]) -> [f64; 3] {
        constraint_gradient(&self.obstacles, self.formulation, self.min_altitude_m, o, x)
    }

    /// Overwrites `grad_u` with the gradient of `W * input_cost`.
    fn input_cost_gradient(&mut self) {
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

/// [`sin_cos_small`] of every lane: the series everywhere, then libm in the rare lanes out of
/// the series' range. The same values lane by lane. The range test is one branch for all
/// lanes: with a branch per lane, LLVM moves the series into each lane's branch, and it no
/// longer vectorizes.
#[inline(always)]
fn sin_cos_lanes<const L: usize>(x: &[f64; L]) -> ([f64; L], [f64; L]) {
    let mut s = lanes(|l| sin_series(x[l]));
    let mut c = lanes(|l| cos_series(x[l]));
    // `|` rather than `||`: no branch per lane.
    if x.iter().fold(false, |out, v| out | (v.abs() > 0.5)) {
        sin_cos_large_lanes(x, &mut s, &mut c);
    }
    (s, c)
}

/// Whether any `c g_k + y_k > 0` (`y_k` = 0 past the end of `y`; none for `c <= 0`): a constraint
/// in the augmented Lagrangian `(c / 2) sum_k [g_k + y_k / c]_+^2`, or in the penalty method's
/// `F2` with `y` empty.
fn any_penalty_term(g: &[f64], y: &[f64], c: f64) -> bool {
    let mut any = false;
    if c > 0.0 {
        for_each_positive(g, y, |g, y| c * g + y, |_, _| any = true);
    }
    any
}

/// `visit(k, v)`, in increasing `k`, for every `k` with `v = value(g[k], y[k]) > 0`, where
/// `y[k]` is 0 past the end of `y`. The values are computed four at a time (vectorized) and
/// tested with one branch, as most are not positive; the values and the visits are the same,
/// in the same order, as one `k` at a time.
#[inline(always)]
fn for_each_positive(
    g: &[f64],
    y: &[f64],
    value: impl Fn(f64, f64) -> f64,
    mut visit: impl FnMut(usize, f64),
) {
    let (g_y, g_alone) = g.split_at(y.len().min(g.len()));
    let y = &y[..g_y.len()];
    let mut visit_positive = |k: usize, v: f64| {
        if v > 0.0 {
            visit(k, v);
        }
    };
    let (g4, y4) = (g_y.chunks_exact(4), y.chunks_exact(4));
    let (g_rest, y_rest) = (g4.remainder(), y4.remainder());
    for (chunk, (g, y)) in g4.zip(y4).enumerate() {
        let v: [f64; 4] = std::array::from_fn(|t| value(g[t], y[t]));
        // `max` skips NaN, which is not positive either.
        if v[0].max(v[1]).max(v[2].max(v[3])) > 0.0 {
            for (t, v) in v.into_iter().enumerate() {
                visit_positive(4 * chunk + t, v);
            }
        }
    }
    let rest = g_y.len() - g_rest.len();
    for (t, (g, y)) in g_rest.iter().zip(y_rest).enumerate() {
        visit_positive(rest + t, value(*g, *y));
    }
    for (t, g) in g_alone.iter().enumerate() {
        visit_positive(g_y.len() + t, value(*g, 0.0));
    }
}

/// libm's `(sin, cos)` in the lanes out of the series' range (see [`sin_cos_lanes`]).
#[cold]
#[inline(never)]
fn sin_cos_large_lanes<const L: usize>(x: &[f64; L], s: &mut [f64; L], c: &mut [f64; L]) {
    for l in 0..L {
        if x[l].abs() > 0.5 {
            (s[l], c[l]) = x[l].sin_cos();
        }
    }
}

/// The Taylor series of `sin` to x^13 (see [`sin_cos_small`]).
#[inline(always)]
fn sin_series(x: f64) -> f64 {
    let x2 = x * x;
    x * (1.0
        + x2 * (-1.0 / 6.0
            + x2 * (1.0 / 120.0
                + x2 * (-1.0 / 5040.0
                    + x2 * (1.0 / 362_880.0 + x2 * (-1.0 / 39_916_800.0 + x2 * (1.0 / 6_227_020_800.0)))))))
}

/// The Taylor series of `cos` to x^14 (see [`sin_cos_small`]).
#[inline(always)]
fn cos_series(x: f64) -> f64 {
    let x2 = x * x;
    1.0 + x2
        * (-0.5
            + x2 * (1.0 / 24.0
                + x2 * (-1.0 / 720.0
                    + x2 * (1.0 / 40_320.0
                        + x2 * (-1.0 / 3_628_800.0
                            + x2 * (1.0 / 479_001_600.0 + x2 * (-1.0 / 87_178_291_200.0)))))))
}

/// `[f(0), .., f(L - 1)]`: one value per lane (scenario of a group) of the lane-parallel passes.
#[inline(always)]
fn lanes<const L: usize>(f: impl FnMut(usize) -> f64) -> [f64; L] {
    std::array::from_fn(f)
}

/// One constraint value alone at position `(px, py, pz)`: the same arithmetic as
/// [`constraint`] without the gradient's divisions.
#[inline(always)]
fn constraint_value(formulation: ObstacleFormulation, ob: &ObstacleTerm, px: f64, py: f64, pz: f64) -> f64 {
    let (dx, dy) = (px - ob.xo, py - ob.yo);
    let hz = ob.zo - pz;
    match formulation {
        ObstacleFormulation::PaperPenalty => {
            let hc = ob.r2 - dx * dx - dy * dy;
            if hc > 0.0 && hz > 0.0 { hc * hz } else { 0.0 }
        }
        ObstacleFormulation::DistanceAlm => {
            let d = (dx * dx + dy * dy).sqrt().max(1e-9);
            let radial = ob.r - d;
            if radial <= hz { radial } else { hz }
        }
    }
}

/// [`Evaluator::constraint_gradient`] from the fields it reads.
#[inline]
fn constraint_gradient(
    obstacles: &[ObstacleTerm],
    formulation: ObstacleFormulation,
    min_altitude_m: Option<f64>,
    o: usize,
    x: &[f64; 8],
) -> [f64; 3] {
    match obstacles.get(o) {
        Some(ob) => constraint(formulation, ob, x).1,
        None => floor_constraint(formulation, min_altitude_m.unwrap_or(0.0), x).1,
    }
}

/// One constraint value and its gradient with respect to `(px, py, pz)`.
#[inline]
fn constraint(formulation: ObstacleFormulation, ob: &ObstacleTerm, x: &[f64; 8]) -> (f64, [f64; 3]) {
    let (dx, dy) = (x[0] - ob.xo, x[1] - ob.yo);
    let hz = ob.zo - x[2];
    match formulation {
        ObstacleFormulation::PaperPenalty => {
            let hc = ob.r2 - dx * dx - dy * dy;
            if hc > 0.0 && hz > 0.0 {
                (hc * hz, [-2.0 * dx * hz, -2.0 * dy * hz, -hc])
            } else {
                (0.0, [0.0; 3])
            }
        }
        ObstacleFormulation::DistanceAlm => {
            // The axis itself is never a solution; keep the gradient finite there.
            let d = (dx * dx + dy * dy).sqrt().max(1e-9);
            let radial = ob.r - d;
            if radial <= hz { (radial, [-dx / d, -dy / d, 0.0]) } else { (hz, [0.0, 0.0, -1.0]) }
        }
    }
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

/// The floor constraint `min_altitude_m - z <= 0` and its gradient in `(px, py, pz)`: in metres
/// for ALM, as a hinge `[min_altitude_m - z]_+ = 0` for the penalty method.
#[inline]
fn floor_constraint(formulation: ObstacleFormulation, min_altitude_m: f64, x: &[f64; 8]) -> (f64, [f64; 3]) {
    let below = min_altitude_m - x[2];
    match formulation {
        ObstacleFormulation::PaperPenalty if below <= 0.0 => (0.0, [0.0; 3]),
        _ => (below, [0.0, 0.0, -1.0]),
    }
}

/// The floor constraint's value alone at altitude `pz`: the same as [`floor_constraint`].
#[inline(always)]
fn floor_value(formulation: ObstacleFormulation, min_altitude_m: f64, pz: f64) -> f64 {
    let below = min_altitude_m - pz;
    match formulation {
        ObstacleFormulation::PaperPenalty if below <= 0.0 => 0.0,
        _ => below,
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

#[cfg(test)]
mod tests {
    use super::*;
    use mav::{Dynamics, MavModel, euler_step};
    use proptest::prelude::*;

    fn evaluator(
        mode: ControllerMode,
        formulation: ObstacleFormulation,
        x0: [f64; 8],
        weights: &[f64],
    ) -> Evaluator {
        let def = OcpDefinition::from_scenario(&Scenario::paper_2(), mode, 0.1, formulation);
        let mut ev = Evaluator::new(&def);
        ev.set_instance(&x0, &[9.81, 0.01, -0.02], weights);
        ev
    }

    #[test]
    fn forward_pass_is_the_euler_model_of_mav() {
        let x0 = [3.0, 0.5, 0.7, 0.2, 1.1, -0.3, 0.05, -0.08];
        let mut ev = evaluator(ControllerMode::Multistage, ObstacleFormulation::DistanceAlm, x0, &[0.2; 5]);
        let n = ev.num_variables();
        let z: Vec<f64> = (0..n).map(|k| ((k % 7) as f64 - 3.0) * 0.3).collect();
        ev.objective(&z);
        let u = ev.inputs().to_vec();
        let model = MavModel::default();
        for (i, &dt) in [0.05, 0.07, 0.1, 0.2, 0.33].iter().enumerate() {
            let mut x = mav::State::from(x0);
            for j in 0..ev.horizon() {
                let uj = mav::Input::new(u[3 * j], u[3 * j + 1], u[3 * j + 2]);
                x = euler_step(&model, &x, &uj, dt);
                let p = ev.predicted_states(i)[j + 1];
                for k in 0..8 {
                    assert!(
                        (p[k] - x[k]).abs() <= 1e-9 * (1.0 + x[k].abs()),
                        "scenario {i} step {j} state {k}"
                    );
                }
            }
        }
        // and the derivative used is the model's
        let d = model.derivative(&mav::State::from(x0), &mav::Input::new(9.81, 0.0, 0.0));
        assert!(d.iter().all(|v| v.is_finite()));
    }

    fn arb_z(n: usize) -> impl Strategy<Value = Vec<f64>> {
        prop::collection::vec(-1.0f64..1.0, n)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]

        #[test]
        fn gradient_matches_finite_differences_single_scenario(
            z in arb_z(120), px in 2.5f64..3.8, py in 0.5f64..4.5, vy in 0.0f64..2.0,
            c in prop::sample::select(vec![0.0, 1e2, 1e4]),
            y_scale in 0.0f64..50.0,
            paper_form in any::<bool>(),
        ) {
            let form = if paper_form { ObstacleFormulation::PaperPenalty } else { ObstacleFormulation::DistanceAlm };
            let x0 = [px, py, 0.8, 0.1, vy, 0.0, 0.02, -0.03];
            let mut ev = evaluator(ControllerMode::Nmpc, form, x0, &[1.0]);
            let nc = 40 * 3;
            let y: Vec<f64> = if paper_form { Vec::new() } else { (0..nc).map(|k| y_scale * ((k % 5) as f64) / 5.0).collect() };
            prop_assert!(check_gradient(&mut ev, &z, c, &y).is_ok(), "{:?}", check_gradient(&mut ev, &z, c, &y));
        }

        #[test]
        fn gradient_matches_finite_differences_five_scenarios(
            z in arb_z(120), px in 2.5f64..3.8, py in 0.5f64..4.5, vy in 0.0f64..2.0,
            w in prop::collection::vec(0.0f64..1.0, 5),
            c in prop::sample::select(vec![0.0, 1e2, 1e4]),
            y_scale in 0.0f64..50.0,
            paper_form in any::<bool>(),
        ) {
            let form = if paper_form { ObstacleFormulation::PaperPenalty } else { ObstacleFormulation::DistanceAlm };
            let mut w = w;
            w[2] += 0.1;
            let x0 = [px, py, 0.8, 0.1, vy, 0.0, 0.02, -0.03];
            let mut ev = evaluator(ControllerMode::Multistage, form, x0, &w);
            let nc = 5 * 40 * 3;
            let y: Vec<f64> = if paper_form { Vec::new() } else { (0..nc).map(|k| y_scale * ((k % 5) as f64) / 5.0).collect() };
            prop_assert!(check_gradient(&mut ev, &z, c, &y).is_ok(), "{:?}", check_gradient(&mut ev, &z, c, &y));
        }
    }

    #[test]
    fn obstacles_are_active_in_the_gradient_tests() {
        // A state heading straight at the 0.4 m cylinder: some predicted point is inside, for
        // one scenario and for five, both forms, with and without ALM multipliers.
        let x0 = [2.8, 2.0, 0.8, 0.0, 1.5, 0.0, 0.0, 0.0];
        for (mode, weights) in [(ControllerMode::Nmpc, vec![1.0]), (ControllerMode::Multistage, vec![0.2; 5])]
        {
            for form in [ObstacleFormulation::PaperPenalty, ObstacleFormulation::DistanceAlm] {
                let mut ev = evaluator(mode, form, x0, &weights);
                let z = vec![0.0; 120];
                let with = ev.cost(&z, 1e3, &[]);
                let without = ev.cost(&z, 0.0, &[]);
                assert!(with > without, "{mode:?} {form:?}: penalty must be active");
                assert!(check_gradient(&mut ev, &z, 1e3, &[]).is_ok(), "{mode:?} {form:?}");
                if form == ObstacleFormulation::DistanceAlm {
                    let nc = weights.len() * 40 * 3;
                    let y: Vec<f64> = (0..nc).map(|k| 20.0 * ((k % 5) as f64)).collect();
                    assert!(ev.cost(&z, 1e3, &y) > with, "{mode:?}: multipliers add terms");
                    assert!(check_gradient(&mut ev, &z, 1e3, &y).is_ok(), "{mode:?} with multipliers");
                }
            }
        }
        // Far from every cylinder nothing is active: the penalty adds nothing, and the gradient
        // is the objective's.
        let far = [8.0, -6.0, 0.8, 0.0, -0.5, 0.0, 0.0, 0.0];
        for (mode, weights) in [(ControllerMode::Nmpc, vec![1.0]), (ControllerMode::Multistage, vec![0.2; 5])]
        {
            let mut ev = evaluator(mode, ObstacleFormulation::DistanceAlm, far, &weights);
            let z = vec![0.0; 120];
            assert_eq!(ev.cost(&z, 1e3, &[]), ev.cost(&z, 0.0, &[]), "{mode:?}");
            assert!(check_gradient(&mut ev, &z, 1e3, &[]).is_ok(), "{mode:?}");
        }
    }

    #[test]
    fn a_penalty_term_is_active_where_c_g_plus_y_is_positive() {
        assert!(!any_penalty_term(&[-0.1, -0.2], &[], 1e3));
        assert!(any_penalty_term(&[-0.1, 0.001], &[], 1e3));
        // A multiplier keeps a satisfied constraint in the augmented Lagrangian...
        assert!(any_penalty_term(&[-0.1, -0.2], &[101.0, 0.0], 1e3));
        // ...until the constraint is satisfied by more than y / c.
        assert!(!any_penalty_term(&[-0.1, -0.2], &[99.0, 0.0], 1e3));
    }

    #[test]
    fn small_angle_sin_cos_matches_libm() {
        for k in -1000..=1000 {
            let x = k as f64 * 0.6e-3;
            let (s, c) = sin_cos_small(x);
            assert!((s - x.sin()).abs() <= 2e-16, "sin({x})");
            assert!((c - x.cos()).abs() <= 2e-16, "cos({x})");
        }
        assert_eq!(sin_cos_small(2.0), 2.0f64.sin_cos());
    }

    #[test]
    fn the_penalty_preconditioner_adds_curvature_only_for_active_constraints() {
        // Far from every cylinder: nothing active, the hover scaling is unchanged.
        let x0 = [0.0, 8.0, 1.5, 0.0, 0.0, 0.0, 0.0, 0.0];
        let mut ev = evaluator(ControllerMode::Multistage, ObstacleFormulation::DistanceAlm, x0, &[0.2; 5]);
        let hover = ev.scaling.scale.clone();
        let u: Vec<f64> = (0..120).map(|k| [9.81, 0.0, 0.0][k % 3]).collect();
        ev.objective_at_inputs(&u);
        ev.update_scaling_with_penalty(1e3, &[], 0.0);
        assert_eq!(ev.scaling.scale, hover);
        // Heading into the 0.4 m cylinder: the inputs before an active point get stiffer.
        let x0 = [2.8, 2.0, 0.8, 0.0, 1.5, 0.0, 0.0, 0.0];
        let mut ev = evaluator(ControllerMode::Multistage, ObstacleFormulation::DistanceAlm, x0, &[0.2; 5]);
        let hover = ev.scaling.scale.clone();
        ev.objective_at_inputs(&u);
        assert!(ev.constraint_values().iter().any(|g| *g > 0.0));
        ev.update_scaling_with_penalty(1e3, &[], 0.0);
        assert!(ev.scaling.scale.iter().zip(&hover).all(|(a, b)| a <= b));
        assert!(ev.scaling.scale.iter().zip(&hover).any(|(a, b)| a < b));
    }

    #[test]
    fn scaling_round_trips_and_maps_the_box() {
        let ev = evaluator(ControllerMode::Multistage, ObstacleFormulation::DistanceAlm, [0.0; 8], &[0.2; 5]);
        let u: Vec<f64> = (0..120).map(|k| [12.0, 0.1, -0.1][k % 3]).collect();
        let mut z = vec![0.0; 120];
        let mut back = vec![0.0; 120];
        ev.to_scaled(&u, &mut z);
        ev.to_inputs(&z, &mut back);
        for (a, b) in u.iter().zip(&back) {
            assert!((a - b).abs() < 1e-12);
        }
        let (mut lo, mut hi) = (vec![0.0; 120], vec![0.0; 120]);
        ev.scaled_bounds(&mav::InputBounds::paper(9.81), &mut lo, &mut hi);
        let mut u_lo = vec![0.0; 120];
        ev.to_inputs(&lo, &mut u_lo);
        assert!((u_lo[0] - 0.0).abs() < 1e-12 && (u_lo[1] + std::f64::consts::PI / 18.0).abs() < 1e-12);
    }

    /// The evaluator's passes one scenario at a time, as they were before the lane-parallel
    /// ones (the oracle of `lane_parallel_passes_are_bit_identical_to_one_scenario_at_a_time`):
    /// `(cost, gradient in z, constraint values, predicted states)` at inputs `ev.u`.
    fn scalar_reference(ev: &Evaluator, c: f64, y: &[f64]) -> (f64, Vec<f64>, Vec<f64>, Vec<[f64; 8]>) {
        let (m, n, n_con) = (ev.m, ev.n, ev.n_con);
        let e = crate::qp::EulerCoeffs::new(&ev.params);
        let (kr, kp) = (e.kr, e.kp);
        let n_obs = ev.obstacles.len();
        let mut states = vec![[0.0; 8]; m * (n + 1)];
        let mut trig = vec![[0.0; 4]; m * n];
        let mut con = vec![0.0; m * n * n_con];
        // Forward pass.
        let mut objective = 0.0;
        for i in 0..m {
            let dt = ev.dts[i];
            let states = &mut states[i * (n + 1)..(i + 1) * (n + 1)];
            let trig = &mut trig[i * n..(i + 1) * n];
            let con = &mut con[i * n * n_con..(i + 1) * n * n_con];
            let mut x = ev.x0s[i];
            states[0] = x;
            let mut state_cost = 0.0;
            for (j, u) in ev.u.chunks_exact(3).enumerate() {
                let (sr, cr) = sin_cos_small(x[6]);
                let (sp, cp) = sin_cos_small(x[7]);
                trig[j] = [sr, cr, sp, cp];
                x = e.step(&x, u, dt, [sr, cr, sp, cp]);
                states[j + 1] = x;
                for ((xk, rk), qk) in x.iter().zip(&ev.x_ref).zip(&ev.q_x) {
                    let e = xk - rk;
                    state_cost += qk * e * e;
                }
                for (ob, c) in ev.obstacles.iter().zip(&mut con[j * n_con..j * n_con + n_obs]) {
                    *c = constraint(ev.formulation, ob, &x).0;
                }
                if let Some(floor) = ev.min_altitude_m {
                    con[j * n_con + n_obs] = floor_constraint(ev.formulation, floor, &x).0;
                }
            }
            objective += ev.weights[i] * state_cost;
        }
        objective += ev.weight_sum * ev.input_cost();
        let mut penalty = 0.0;
        if c > 0.0 {
            for (k, g) in con.iter().enumerate() {
                let v = g + y.get(k).map_or(0.0, |y| y / c);
                if v > 0.0 {
                    penalty += v * v;
                }
            }
            penalty *= 0.5 * c;
        }
        // Adjoint pass.
        let w2 = 2.0 * ev.weight_sum;
        let mut grad_u = vec![0.0; 3 * n];
        for j in 0..n {
            for ch in 0..3 {
                let k = 3 * j + ch;
                let u = ev.u[k];
                let prev = if j == 0 { ev.u_prev[ch] } else { ev.u[k - 3] };
                let mut gk = ev.q_u[ch] * (u - ev.u_ref[ch]) + ev.q_du[ch] * (u - prev);
                if j + 1 < n {
                    gk -= ev.q_du[ch] * (ev.u[k + 3] - u);
                }
                grad_u[k] = w2 * gk;
            }
        }
        for i in 0..m {
            let dt = ev.dts[i];
            let w2 = 2.0 * ev.weights[i];
            let wq: [f64; 8] = std::array::from_fn(|k| w2 * ev.q_x[k]);
            let states = &states[i * (n + 1) + 1..(i + 1) * (n + 1)];
            let con = &con[i * n * n_con..(i + 1) * n * n_con];
            let y = y.get(i * n * n_con..(i + 1) * n * n_con).unwrap_or(&[]);
            let mut l = [0.0f64; 8];
            for j in (0..n).rev() {
                let x = &states[j];
                for k in 0..8 {
                    l[k] += wq[k] * (x[k] - ev.x_ref[k]);
                }
                if c > 0.0 {
                    for o in j * n_con..(j + 1) * n_con {
                        let v = c * con[o] + y.get(o).copied().unwrap_or(0.0);
                        if v > 0.0 {
                            let dg = ev.constraint_gradient(o - j * n_con, x);
                            l[0] += v * dg[0];
                            l[1] += v * dg[1];
                            l[2] += v * dg[2];
                        }
                    }
                }
                let [sr, cr, sp, cp] = trig[i * n + j];
                let t = ev.u[3 * j];
                grad_u[3 * j] += dt * (cr * sp * l[3] - sr * l[4] + cr * cp * l[5]);
                grad_u[3 * j + 1] += dt * kr * l[6];
                grad_u[3 * j + 2] += dt * kp * l[7];
                e.adjoint_step(&mut l, dt, t, [sr, cr, sp, cp]);
            }
        }
        let grad = grad_u.iter().zip(&ev.scaling.scale).map(|(g, s)| g * s).collect();
        (objective + penalty, grad, con, states)
    }

    /// Every scenario count from 1 to past a group (`MAX_LANES`), both formulations, with and
    /// without the floor, dead-time compensation and multipliers, attitudes in and out of the
    /// series' range, and active constraints: the same bits as one scenario at a time.
    #[test]
    fn lane_parallel_passes_are_bit_identical_to_one_scenario_at_a_time() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for m in [1usize, 2, 3, 4, 5, 7, 8, 9, 13] {
            for (form, floor, compensation) in [
                (ObstacleFormulation::DistanceAlm, None, false),
                (ObstacleFormulation::DistanceAlm, Some(0.4), true),
                (ObstacleFormulation::PaperPenalty, None, true),
                (ObstacleFormulation::PaperPenalty, Some(0.4), false),
            ] {
                let mut def =
                    OcpDefinition::from_scenario(&Scenario::paper_2(), ControllerMode::Multistage, 0.1, form);
                def.sampling_times_s = (0..m).map(|i| 0.05 + 0.025 * i as f64).collect();
                def.min_altitude_m = floor;
                def.delay_compensation = compensation;
                let mut ev = Evaluator::new(&def);
                let n = ev.num_variables();
                for point in 0..4 {
                    // Heading at the cylinders (active constraints); attitudes beyond 0.5 rad
                    // (libm's sin and cos) in every other point.
                    let angle = if point % 2 == 1 { 0.8 } else { 0.1 };
                    let x0 = [
                        rng.random_range(2.6..3.4),
                        rng.random_range(1.0..3.0),
                        rng.random_range(0.3..1.0),
                        0.0,
                        rng.random_range(0.5..1.5),
                        0.0,
                        rng.random_range(-angle..angle),
                        rng.random_range(-angle..angle),
                    ];
                    let weights: Vec<f64> = (0..m).map(|_| rng.random_range(0.0..1.0)).collect();
                    ev.set_instance(&x0, &[9.81, 0.01, -0.02], &weights);
                    let z: Vec<f64> = (0..n).map(|_| rng.random_range(-3.0..3.0)).collect();
                    let y: Vec<f64> = match point {
                        0 => Vec::new(),
                        _ => (0..def.num_constraints()).map(|_| rng.random_range(0.0..20.0)).collect(),
                    };
                    for c in [0.0, 1e3] {
                        let mut grad = vec![0.0; n];
                        let mut con = vec![0.0; def.num_constraints()];
                        let cost = ev.cost(&z, c, &y);
                        ev.gradient(&z, c, &y, &mut grad);
                        ev.constraints(&z, &mut con);
                        let (ref_cost, ref_grad, ref_con, ref_states) = scalar_reference(&ev, c, &y);
                        let case = format!(
                            "M = {m}, {form:?}, floor {floor:?}, compensation {compensation}, point {point}, c = {c}"
                        );
                        assert_eq!(cost.to_bits(), ref_cost.to_bits(), "cost: {case}");
                        assert_eq!(bits(&grad), bits(&ref_grad), "gradient: {case}");
                        assert_eq!(bits(&con), bits(&ref_con), "constraints: {case}");
                        for i in 0..m {
                            let states = &ref_states[i * (n / 3 + 1)..(i + 1) * (n / 3 + 1)];
                            let state_bits =
                                |s: &[[f64; 8]]| s.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
                            assert_eq!(
                                state_bits(ev.predicted_states(i)),
                                state_bits(states),
                                "states of scenario {i}: {case}"
                            );
                        }
                        if point == 2 && c > 0.0 && m == 5 {
                            assert!(con.iter().any(|g| *g > 0.0), "some constraint active: {case}");
                        }
                    }
                }
            }
        }
    }
}
