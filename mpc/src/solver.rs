//! The controller workspace: OpEn's ALM/PM + PANOC on the scaled problem, warm start, budgets,
//! and the per-solve report.

use std::cell::RefCell;
use std::time::Duration;

use optimization_engine::alm::{AlmCache, AlmOptimizer, AlmProblem};
use optimization_engine::constraints::Rectangle;
use optimization_engine::core::ExitStatus;
use optimization_engine::panoc::PANOCCache;
use optimization_engine::{FunctionCallResult, SolverError};

use crate::problem::{Evaluator, ObstacleFormulation, OcpDefinition, validate_instance};

/// Default upper bound of the multiplier box `Y` OpEn's ALM requires (compact, inside the dual
/// cone).
pub const MAX_MULTIPLIER: f64 = 1e9;

/// Least time left before a deadline for another OpEn call: below it the solve stops with
/// `Deadline` (an OpEn call whose time is up before its first PANOC iteration does no work).
const MIN_CALL_DURATION: Duration = Duration::from_micros(20);

/// Settings of the solver (validated in [`Mpc::new`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MpcSettings {
    /// Added to every cylinder radius in the constraint, m. The penalty lets solutions cut
    /// into the constraint by a little, and delayed inputs make the plant drift from the
    /// prediction; the margin keeps the true clearance non-negative.
    pub obstacle_margin_m: f64,
    /// How the cylinder constraint enters the solver.
    pub formulation: ObstacleFormulation,
    /// PANOC's fixed-point residual tolerance, in scaled variables, for multi-stage problems
    /// (more than one scenario); standard NMPC uses `single_scenario_tolerance`.
    pub tolerance: f64,
    /// Inner (AKKT) tolerance of the ALM/PM outer loop, in units of the cost gradient, for
    /// multi-stage problems; standard NMPC uses `single_scenario_akkt_tolerance`.
    pub akkt_tolerance: f64,
    /// `tolerance` of standard NMPC (one scenario). OpEn stops when `γ |r| < tolerance` (and
    /// the AKKT residual, also times `γ`, is below its tolerance), with `γ = 0.95 / L` and `L`
    /// the Lipschitz estimate of the gradient: the same number is a much looser test where
    /// active long-horizon penalties make `L` large (multi-stage) than where they do not.
    /// Measured (BENCHMARKS.md, issue 3): at 3e-2 / 1e-1 the NMPC's costs stay within 1 % of
    /// the careful reference on every sampled loop state with 10 iterations at the median
    /// (25 at 1e-3 / 1e-2), while multi-stage solves at those values miss by up to 40 %.
    pub single_scenario_tolerance: f64,
    /// `akkt_tolerance` of standard NMPC (one scenario); see `single_scenario_tolerance`.
    pub single_scenario_akkt_tolerance: f64,
    /// `lbfgs_memory` of standard NMPC (one scenario). Measured (BENCHMARKS.md, issue 3): at
    /// the NMPC tolerances, memories 5, 7 and 10 cost the same per solve; 7 kept every
    /// sampled loop state within 1 % of the reference and no predicted clearance below zero.
    pub single_scenario_lbfgs_memory: usize,
    /// Largest accepted constraint violation: `|F2|` for the penalty method, `|y+ - y| / c`
    /// (the ALM's infeasibility, m for the distance form) for the augmented Lagrangian.
    pub constraint_tolerance: f64,
    /// Penalty parameter of the first outer iteration (and floor for later solves).
    pub initial_penalty: f64,
    /// Largest penalty parameter. Past a point a larger penalty only ill-conditions the
    /// problem: with the shared input sequence some predicted point of the long-horizon
    /// scenarios can stay inside a cylinder whatever the inputs, and an uncapped penalty
    /// method then multiplies its parameter every outer iteration without bound.
    pub max_penalty: f64,
    /// Factor by which the penalty grows when the violation does not shrink enough.
    pub penalty_update_factor: f64,
    /// Outer (penalty) iterations per solve.
    pub max_outer_iterations: usize,
    /// PANOC iterations per solve, summed over the outer iterations: the lockstep budget.
    pub max_inner_iterations: usize,
    /// L-BFGS memory of PANOC for multi-stage problems; standard NMPC uses
    /// `single_scenario_lbfgs_memory`.
    pub lbfgs_memory: usize,
    /// PANOC iterations per outer iteration; `None`: whatever is left of the solve's budget.
    /// Measured (BENCHMARKS.md, issue 3): caps of 20-100 did not reduce the solves that stop
    /// at the budget.
    pub max_inner_iterations_per_outer: Option<usize>,
    /// Upper bound of every ALM multiplier (the box `Y`), in units of the cost per metre of
    /// violation. Where a point of a long-horizon scenario stays inside an inflated cylinder
    /// whatever the inputs, its multiplier grows every outer iteration and cycle up to this
    /// bound; measured (BENCHMARKS.md, issue 3), a bound of 100 halves the solves that stop at
    /// the iteration budget but lets standard NMPC cut deeper into the cylinders.
    pub max_multiplier: f64,
    /// Adds the penalty's Gauss-Newton diagonal of the constraints that are active or within
    /// this distance of active at the warm start (and at each outer iteration's start) to the
    /// preconditioner, m; `None` keeps the objective's hover diagonal alone. Measured
    /// (BENCHMARKS.md, issue 3): with the hover sensitivities it made multi-stage solves slower,
    /// so it is off by default.
    pub penalty_preconditioner_slack_m: Option<f64>,
    /// Standard NMPC (one scenario) only: warm-start each cycle from the last plan shifted by
    /// the time since the last cycle's sample, in whole sampling times, instead of by one step
    /// (see [`crate::CycleController::step`]). Off by default: the protocol shifts by
    /// one step, and the paper-1 result depends on it (measured: with it the NMPC no longer
    /// stalls in front of the cylinder; BENCHMARKS.md).
    pub warm_start_by_elapsed_time: bool,
    /// Multi-stage only (opt-in): PANOC's tolerances for an outer iteration that starts with no
    /// constraint term in the augmented Lagrangian (no predicted point with `c g + y > 0`),
    /// where the Lipschitz constant is the objective's alone and OpEn's `γ`-scaled tests mean
    /// what they mean for standard NMPC (see `single_scenario_tolerance`). `None` (default):
    /// `tolerance` and `akkt_tolerance` throughout. Measured (BENCHMARKS.md, issue 3, sixth
    /// pass): with [`InactiveSetTolerances::MEASURED`] the multi-stage median along the paper
    /// loops drops from 0.22-0.27 ms to 0.13-0.15 ms at a little lower accuracy (61 of 70
    /// sampled states within 1 % of the reference, against 65 of 73), but the closed
    /// loops change, and the default paper-1 run then dives into the ground (paper mode has
    /// no floor), so it is not the default.
    pub inactive_set: Option<InactiveSetTolerances>,
}

/// See [`MpcSettings::inactive_set`]. A result of such an outer iteration is accepted only if it
/// still has no constraint term and a small projected gradient, a test that does not scale with
/// OpEn's step `γ`: within one PANOC call the Lipschitz estimate only grows, so a constraint
/// that became active on the way can leave `γ` small and the loose test met far from a
/// solution. A result that fails is handed to the next outer iteration (which then uses the
/// multi-stage tolerances if a term is active).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InactiveSetTolerances {
    /// PANOC's fixed-point residual tolerance, scaled variables.
    pub tolerance: f64,
    /// PANOC's AKKT tolerance.
    pub akkt_tolerance: f64,
    /// Largest accepted projected-gradient residual `|z - P(z - grad psi(z))|` at the result,
    /// in the scaled variables (where the objective's hover Hessian diagonal is 1).
    pub gradient_tolerance: f64,
}

impl InactiveSetTolerances {
    /// The values measured in BENCHMARKS.md (issue 3, sixth pass): 1e-2 and 3e-2 are
    /// standard NMPC's kind of test at the multi-stage objective's Lipschitz constant (~25 in
    /// the scaled variables), and 0.5 rejects the 3-5 % of results whose residual is an order
    /// above the rest (median 0.18, 90th percentile 0.29, largest 12 along the paper loops).
    pub const MEASURED: Self = Self { tolerance: 1e-2, akkt_tolerance: 3e-2, gradient_tolerance: 0.5 };
}

impl Default for MpcSettings {
    fn default() -> Self {
        Self {
            obstacle_margin_m: 0.1,
            formulation: ObstacleFormulation::DistanceAlm,
            tolerance: 1e-3,
            akkt_tolerance: 1e-2,
            single_scenario_tolerance: 3e-2,
            single_scenario_akkt_tolerance: 1e-1,
            single_scenario_lbfgs_memory: 7,
            constraint_tolerance: 0.02,
            initial_penalty: 1e3,
            max_penalty: 1e4,
            penalty_update_factor: 5.0,
            max_outer_iterations: 8,
            max_inner_iterations: 200,
            lbfgs_memory: 10,
            max_inner_iterations_per_outer: None,
            max_multiplier: MAX_MULTIPLIER,
            penalty_preconditioner_slack_m: None,
            warm_start_by_elapsed_time: false,
            inactive_set: None,
        }
    }
}

impl MpcSettings {
    /// Names the first invalid setting.
    pub fn validate(&self) -> Result<(), MpcError> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        let bad = |field: &'static str, reason: &'static str| Err(MpcError::InvalidSetting { field, reason });
        if !(self.obstacle_margin_m.is_finite() && self.obstacle_margin_m >= 0.0) {
            return bad("obstacle_margin_m", "must be finite and >= 0");
        }
        for (field, v) in [
            ("tolerance", self.tolerance),
            ("akkt_tolerance", self.akkt_tolerance),
            ("single_scenario_tolerance", self.single_scenario_tolerance),
            ("single_scenario_akkt_tolerance", self.single_scenario_akkt_tolerance),
            ("constraint_tolerance", self.constraint_tolerance),
            ("initial_penalty", self.initial_penalty),
        ] {
            if !pos(v) {
                return bad(field, "must be finite and > 0");
            }
        }
        if !(self.max_penalty.is_finite() && self.max_penalty >= self.initial_penalty) {
            return bad("max_penalty", "must be finite and >= initial_penalty");
        }
        if !(self.penalty_update_factor.is_finite() && self.penalty_update_factor > 1.0 + 1e-9) {
            return bad("penalty_update_factor", "must be finite and > 1");
        }
        if self.max_outer_iterations == 0 {
            return bad("max_outer_iterations", "must be > 0");
        }
        if self.penalty_preconditioner_slack_m.is_some_and(|v| !v.is_finite()) {
            return bad("penalty_preconditioner_slack_m", "must be finite");
        }
        if !pos(self.max_multiplier) {
            return bad("max_multiplier", "must be finite and > 0");
        }
        if self.max_inner_iterations_per_outer == Some(0) {
            return bad("max_inner_iterations_per_outer", "must be > 0");
        }
        if self.lbfgs_memory == 0 {
            return bad("lbfgs_memory", "must be > 0");
        }
        if self.single_scenario_lbfgs_memory == 0 {
            return bad("single_scenario_lbfgs_memory", "must be > 0");
        }
        if let Some(t) = &self.inactive_set {
            for (field, v) in [
                ("inactive_set.tolerance", t.tolerance),
                ("inactive_set.akkt_tolerance", t.akkt_tolerance),
                ("inactive_set.gradient_tolerance", t.gradient_tolerance),
            ] {
                if !pos(v) {
                    return bad(field, "must be finite and > 0");
                }
            }
        }
        Ok(())
    }

    /// PANOC's `(tolerance, akkt_tolerance, lbfgs_memory)` for a problem of `num_scenarios`
    /// scenarios.
    pub fn panoc_for(&self, num_scenarios: usize) -> (f64, f64, usize) {
        if num_scenarios == 1 {
            (
                self.single_scenario_tolerance,
                self.single_scenario_akkt_tolerance,
                self.single_scenario_lbfgs_memory,
            )
        } else {
            (self.tolerance, self.akkt_tolerance, self.lbfgs_memory)
        }
    }
}

/// Bad input or settings: no solve was attempted and nothing changed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MpcError {
    #[error("invalid setting `{field}`: {reason}")]
    InvalidSetting { field: &'static str, reason: &'static str },
    #[error("invalid problem: {0}")]
    InvalidProblem(String),
    #[error("invalid `{field}`: {reason}")]
    InvalidInput { field: String, reason: String },
}

pub(crate) fn invalid_input(field: impl Into<String>, reason: impl Into<String>) -> MpcError {
    MpcError::InvalidInput { field: field.into(), reason: reason.into() }
}

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SolveStatus {
    /// Tolerances met, constraint violation within tolerance.
    Converged,
    /// The iteration budget ran out; the best iterate is returned: OpEn's, the feasible
    /// (projected) half step with the smallest fixed-point residual of the last inner problem,
    /// that is, the iterate closest to stationary for the multipliers and penalty reached.
    IterationLimit,
    /// The wall-clock budget ran out (real time only); the best iterate is returned, as for
    /// `IterationLimit` (the warm start when no PANOC iteration ran).
    Deadline,
    /// A non-finite value appeared; the warm start is returned unchanged.
    NumericalFailure,
}

impl SolveStatus {
    pub fn name(self) -> &'static str {
        match self {
            SolveStatus::Converged => "converged",
            SolveStatus::IterationLimit => "iteration_limit",
            SolveStatus::Deadline => "deadline",
            SolveStatus::NumericalFailure => "numerical_failure",
        }
    }
}

/// What a solve may spend. In lockstep only iteration counts bound a solve, so that runs are
/// bit-identical; in real time a wall-clock deadline is added.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SolveBudget {
    /// Overrides `MpcSettings::max_inner_iterations` when set.
    pub max_inner_iterations: Option<usize>,
    /// Wall-clock limit of the whole solve.
    pub deadline: Option<Duration>,
}

/// The outcome of one solve.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SolveReport {
    pub status: SolveStatus,
    /// PANOC iterations, summed over the outer iterations.
    pub iterations: usize,
    pub outer_iterations: usize,
    /// Wall-clock time measured by the solver.
    pub solve_time: Duration,
    /// The spec's objective `sum_i w_i J_i` at the returned inputs (no penalty, unscaled).
    pub cost: f64,
    /// `|F2|` at the returned inputs (0 when no predicted point enters an inflated cylinder).
    pub constraint_violation: f64,
    /// Penalty parameter of the last outer iteration.
    pub penalty_parameter: f64,
    /// Smallest true clearance (no margin) of any predicted point of any scenario, m.
    pub min_clearance_m: f64,
}

/// The controller workspace: problem, solver memory, warm start. Allocated once, solved every
/// cycle.
///
/// ## Memory allocation
/// The evaluator buffers (see [`Evaluator`]), OpEn's ALM and PANOC caches (`O(L n)` for
/// L-BFGS memory `L` and `n = 3N` variables), and a few `3N` and `M N n_obs` vectors.
pub struct Mpc {
    def: OcpDefinition,
    settings: MpcSettings,
    evaluator: RefCell<Evaluator>,
    alm_cache: AlmCache,
    /// A second cache at the [`MpcSettings::inactive_set`] tolerances (OpEn fixes the tolerance
    /// of a cache when it is made); multi-stage problems with that option only.
    inactive_cache: Option<AlmCache>,
    /// The multipliers an outer iteration started from, and the gradient at its result: the
    /// acceptance test of an inactive-set outer iteration.
    multipliers_in: Vec<f64>,
    gradient: Vec<f64>,
    z: Vec<f64>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    solution: Vec<f64>,
    warm: Vec<f64>,
    /// ALM multipliers: of the last solve, and shifted by one step for the next.
    multipliers: Vec<f64>,
    warm_multipliers: Vec<f64>,
    lagrange_box_lo: Vec<f64>,
    lagrange_box_hi: Vec<f64>,
    c_set_hi: Vec<f64>,
    has_solution: bool,
    penalty: f64,
}

impl Mpc {
    pub fn new(def: OcpDefinition, settings: MpcSettings) -> Result<Self, MpcError> {
        settings.validate()?;
        if def.horizon == 0 || def.sampling_times_s.is_empty() {
            return Err(MpcError::InvalidProblem("needs a horizon and at least one sampling time".into()));
        }
        if def.sampling_times_s.iter().any(|t| !(t.is_finite() && *t > 0.0)) {
            return Err(MpcError::InvalidProblem("sampling times must be finite and > 0".into()));
        }
        let evaluator = Evaluator::new(&def);
        let n = def.num_variables();
        let nc = def.num_constraints();
        let (n1, n2) = match def.formulation {
            ObstacleFormulation::DistanceAlm => (nc, 0),
            ObstacleFormulation::PaperPenalty => (0, nc),
        };
        let (tolerance, _, lbfgs_memory) = settings.panoc_for(def.num_scenarios());
        let panoc_cache = PANOCCache::new(n, tolerance, lbfgs_memory);
        let alm_cache = AlmCache::new(panoc_cache, n1, n2);
        let inactive_cache = settings
            .inactive_set
            .filter(|_| def.num_scenarios() > 1)
            .map(|t| AlmCache::new(PANOCCache::new(n, t.tolerance, lbfgs_memory), n1, n2));
        let mut warm = vec![0.0; n];
        for j in 0..def.horizon {
            warm[3 * j..3 * j + 3].copy_from_slice(&def.u_ref);
        }
        Ok(Self {
            settings,
            evaluator: RefCell::new(evaluator),
            alm_cache,
            inactive_cache,
            multipliers_in: vec![0.0; n1],
            gradient: vec![0.0; n],
            z: vec![0.0; n],
            lo: vec![0.0; n],
            hi: vec![0.0; n],
            solution: warm.clone(),
            warm,
            multipliers: vec![0.0; n1],
            warm_multipliers: vec![0.0; n1],
            lagrange_box_lo: vec![0.0; n1],
            lagrange_box_hi: vec![settings.max_multiplier; n1],
            c_set_hi: vec![0.0; n1],
            has_solution: false,
            penalty: settings.initial_penalty,
            def,
        })
    }

    pub fn definition(&self) -> &OcpDefinition {
        &self.def
    }

    pub fn settings(&self) -> &MpcSettings {
        &self.settings
    }

    /// The last solution: `N` inputs, flattened `[T, phi_d, theta_d, ...]`.
    pub fn solution(&self) -> &[f64] {
        &self.solution
    }

    /// The first input of the last solution, within the input bounds.
    pub fn first_input(&self) -> [f64; 3] {
        [self.solution[0], self.solution[1], self.solution[2]]
    }

    /// Replaces the warm start of the next solve (`N x 3` inputs, clipped to the bounds).
    pub fn set_warm_start(&mut self, u: &[f64]) -> Result<(), MpcError> {
        if u.len() != self.warm.len() {
            return Err(invalid_input(
                "warm_start",
                format!("must hold {} values ({} x 3), got {}", self.warm.len(), self.def.horizon, u.len()),
            ));
        }
        if let Some(k) = u.iter().position(|v| !v.is_finite()) {
            return Err(invalid_input(format!("warm_start[{}][{}]", k / 3, k % 3), "must be finite"));
        }
        for (k, (w, v)) in self.warm.iter_mut().zip(u).enumerate() {
            *w = v.clamp(self.def.bounds.min[k % 3], self.def.bounds.max[k % 3]);
        }
        Ok(())
    }

    /// Shifts the warm start (inputs and multipliers) by `steps` more steps, the last one
    /// repeated: for a controller whose cycle lasted that many more of its sampling times.
    pub fn advance_warm_start(&mut self, steps: usize) {
        let horizon = self.def.horizon;
        let steps = steps.min(horizon - 1);
        if steps == 0 {
            return;
        }
        let n = self.warm.len();
        self.warm.copy_within(3 * steps.., 0);
        for j in horizon - steps..horizon {
            let last =
                [self.warm[n - 3 * steps - 3], self.warm[n - 3 * steps - 2], self.warm[n - 3 * steps - 1]];
            self.warm[3 * j..3 * j + 3].copy_from_slice(&last);
        }
        let n_con = self.def.constraints_per_point();
        if n_con > 0 && !self.warm_multipliers.is_empty() {
            for i in 0..self.def.num_scenarios() {
                let block = &mut self.warm_multipliers[i * horizon * n_con..(i + 1) * horizon * n_con];
                block.copy_within(steps * n_con.., 0);
                for j in horizon - steps..horizon {
                    let (head, tail) = block.split_at_mut(j * n_con);
                    tail[..n_con]
                        .copy_from_slice(&head[(horizon - steps - 1) * n_con..(horizon - steps) * n_con]);
                }
            }
        }
    }

    /// Forgets the previous solution: the next solve starts from hover.
    pub fn reset_warm_start(&mut self) {
        for j in 0..self.def.horizon {
            self.warm[3 * j..3 * j + 3].copy_from_slice(&self.def.u_ref);
        }
        self.has_solution = false;
        self.penalty = self.settings.initial_penalty;
        self.warm_multipliers.iter_mut().for_each(|y| *y = 0.0);
    }

    /// Shifts the last solution by one step into the warm start (last input repeated).
    fn shift_solution_into_warm_start(&mut self) {
        self.warm.copy_from_slice(&self.solution);
        self.warm_multipliers.copy_from_slice(&self.multipliers);
        self.advance_warm_start(1);
    }

    /// Solves from state `x0` with last applied input `u_prev` and scenario weights.
    ///
    /// Warm-starts from the previous solution shifted by one step (or from what
    /// [`Mpc::set_warm_start`] set). On success the solution is available through
    /// [`Mpc::solution`], whatever the status; with `NumericalFailure` it is the warm start.
    pub fn solve(
        &mut self,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        weights: &[f64],
        budget: &SolveBudget,
    ) -> Result<SolveReport, MpcError> {
        validate_instance(self.def.num_scenarios(), x0, u_prev, weights)?;
        let (status, iterations, outer_iterations, solve_time, penalty) =
            self.solve_scaled(x0, u_prev, weights, budget);
        if status == SolveStatus::NumericalFailure {
            self.solution.copy_from_slice(&self.warm);
        }
        // The returned inputs are within the bounds by construction (box projection); clip
        // anyway so that rounding in the unscaling can never leave the box.
        for (k, u) in self.solution.iter_mut().enumerate() {
            *u = u.clamp(self.def.bounds.min[k % 3], self.def.bounds.max[k % 3]);
        }
        let (cost, violation, min_clearance_m) = self.evaluate_solution();
        if status != SolveStatus::NumericalFailure {
            // Keep the penalty that was needed (warm start of the outer loop); relax it
            // when no predicted point enters an inflated cylinder any more.
            let s = &self.settings;
            self.penalty = if violation == 0.0 { penalty / s.penalty_update_factor } else { penalty }
                .clamp(s.initial_penalty, s.max_penalty);
        }
        self.has_solution = true;
        self.shift_solution_into_warm_start();
        Ok(SolveReport {
            status,
            iterations,
            outer_iterations,
            solve_time,
            cost,
            constraint_violation: violation,
            penalty_parameter: penalty,
            min_clearance_m,
        })
    }

    #[allow(clippy::type_complexity)]
    fn solve_scaled(
        &mut self,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        weights: &[f64],
        budget: &SolveBudget,
    ) -> (SolveStatus, usize, usize, Duration, f64) {
        let s = self.settings;
        let (_, akkt_tolerance, _) = s.panoc_for(self.def.num_scenarios());
        let mut c = self.penalty.clamp(s.initial_penalty, s.max_penalty);
        let nc = self.def.num_constraints();
        let alm_multipliers = self.def.formulation == ObstacleFormulation::DistanceAlm;
        {
            let mut ev = self.evaluator.borrow_mut();
            ev.set_instance(x0, u_prev, weights);
            let y: &[f64] = if alm_multipliers { &self.warm_multipliers } else { &[] };
            let slack = s.penalty_preconditioner_slack_m;
            rescale(
                &mut ev,
                &self.def.bounds,
                slack,
                y,
                &self.warm,
                c,
                &mut self.z,
                &mut self.lo,
                &mut self.hi,
            );
        }
        let alm = self.def.formulation == ObstacleFormulation::DistanceAlm && nc > 0;
        let pm = self.def.formulation == ObstacleFormulation::PaperPenalty && nc > 0;
        let evaluator = &self.evaluator;
        // OpEn passes xi = (c, y): the penalty parameter, then the ALM multipliers (if any).
        let split = |xi: &[f64]| -> (f64, usize) { (xi.first().copied().unwrap_or(0.0), 1.min(xi.len())) };
        let psi = |z: &[f64], xi: &[f64], cost: &mut f64| -> FunctionCallResult {
            let (c, from) = split(xi);
            *cost = evaluator.borrow_mut().cost(z, c, &xi[from..]);
            if cost.is_finite() { Ok(()) } else { Err(SolverError::NotFiniteComputation("cost")) }
        };
        let d_psi = |z: &[f64], xi: &[f64], grad: &mut [f64]| -> FunctionCallResult {
            let (c, from) = split(xi);
            evaluator.borrow_mut().gradient(z, c, &xi[from..], grad);
            Ok(())
        };
        let mapping = |z: &[f64], out: &mut [f64]| -> FunctionCallResult {
            evaluator.borrow_mut().constraints(z, out);
            Ok(())
        };
        // The outer loop is driven here, one OpEn ALM/PM outer step per call, so that the
        // penalty stays capped while the multipliers keep improving: OpEn's own loop would
        // multiply the penalty without bound when the violation stalls.
        // A budget of zero runs no iteration: the warm start comes back with `IterationLimit`.
        let max_total = budget.max_inner_iterations.unwrap_or(s.max_inner_iterations);
        let mut iterations = 0;
        let mut elapsed = Duration::ZERO;
        let mut previous_violation = f64::INFINITY;
        let mut status = SolveStatus::IterationLimit;
        let mut outer = 0;
        while outer < s.max_outer_iterations && iterations < max_total {
            outer += 1;
            let max_inner =
                (max_total - iterations).min(s.max_inner_iterations_per_outer.unwrap_or(usize::MAX));
            let remaining = match budget.deadline {
                Some(d) => match d.checked_sub(elapsed) {
                    Some(r) if r >= MIN_CALL_DURATION => Some(r),
                    _ => {
                        status = SolveStatus::Deadline;
                        break;
                    }
                },
                None => None,
            };
            let problem = AlmProblem::new(
                Rectangle::new(Some(&self.lo), Some(&self.hi)),
                alm.then(|| Rectangle::new(None, Some(&self.c_set_hi))),
                alm.then(|| Rectangle::new(Some(&self.lagrange_box_lo), Some(&self.lagrange_box_hi))),
                psi,
                d_psi,
                alm.then_some(mapping),
                pm.then_some(mapping),
                if alm { nc } else { 0 },
                if pm { nc } else { 0 },
            );
            // The inactive-set tolerances when the option is on and no constraint term is active
            // at the start point (the constraint values come from the forward pass PANOC's
            // first evaluation reuses).
            let y: &[f64] = if alm_multipliers { &self.warm_multipliers } else { &[] };
            let inactive = match (&mut self.inactive_cache, s.inactive_set) {
                (Some(cache), Some(t)) if !evaluator.borrow_mut().has_penalty_terms(&self.z, c, y) => {
                    Some((cache, t))
                }
                _ => None,
            };
            if inactive.is_some() {
                self.multipliers_in.copy_from_slice(&self.warm_multipliers);
            }
            let inactive_tolerances = inactive.as_ref().map(|(_, t)| *t);
            let (cache, akkt_tolerance) = match inactive {
                Some((cache, t)) => (cache, t.akkt_tolerance),
                None => (&mut self.alm_cache, akkt_tolerance),
            };
            let mut optimizer = AlmOptimizer::new(cache, problem)
                .with_max_outer_iterations(1)
                .with_max_inner_iterations(max_inner)
                .with_delta_tolerance(s.constraint_tolerance)
                .with_epsilon_tolerance(akkt_tolerance)
                .with_initial_inner_tolerance(akkt_tolerance);
            if nc > 0 {
                optimizer = optimizer.with_initial_penalty(c);
            }
            if alm {
                optimizer = optimizer.with_initial_lagrange_multipliers(&self.warm_multipliers);
            }
            if let Some(r) = remaining {
                optimizer = optimizer.with_max_duration(r);
            }
            let solved = if remaining.is_some() {
                // OpEn 0.12's ALM panics (an assertion on the inner residual it has not
                // computed yet) when its time is up before its first inner solve, which a
                // preempted thread can meet even with `MIN_CALL_DURATION` left: that is the
                // deadline, not a crash of the controller. Any other panic is a bug and goes
                // on unwinding.
                match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| optimizer.solve(&mut self.z)))
                {
                    Ok(solved) => solved,
                    Err(payload) if is_open_time_up_before_first_solve(payload.as_ref()) => {
                        status = SolveStatus::Deadline;
                        break;
                    }
                    Err(payload) => std::panic::resume_unwind(payload),
                }
            } else {
                optimizer.solve(&mut self.z)
            };
            let Ok(report) = solved else {
                status = SolveStatus::NumericalFailure;
                break;
            };
            if report.num_outer_iterations() == 0 {
                // The time was up before the first inner solve (a used cache does not panic):
                // nothing was solved, and the multipliers OpEn reports are an earlier solve's.
                status = SolveStatus::Deadline;
                break;
            }
            iterations += report.num_inner_iterations();
            elapsed += report.solve_time();
            let violation = if alm {
                // OpEn's ALM infeasibility |y+ - y| / c: the violation in metres.
                let y_plus = report.lagrange_multipliers().as_deref().unwrap_or(&[]);
                let dy =
                    y_plus.iter().zip(&self.warm_multipliers).map(|(a, b)| (a - b) * (a - b)).sum::<f64>();
                if y_plus.len() == self.warm_multipliers.len() {
                    self.warm_multipliers.copy_from_slice(y_plus);
                    self.multipliers.copy_from_slice(y_plus);
                }
                dy.sqrt() / c
            } else {
                report.f2_norm()
            };
            // OpEn's ALM exit test needs a previous outer iteration, which a one-step call
            // never has; PANOC stops early only when it has converged, so an inner count below
            // the cap is inner convergence.
            let mut inner_converged = report.num_inner_iterations() < max_inner;
            let mut accepted = true;
            if let Some(t) = inactive_tolerances
                && (inner_converged || report.exit_status() == ExitStatus::Converged)
            {
                let mut ev = evaluator.borrow_mut();
                let y: &[f64] = if alm_multipliers { &self.multipliers_in } else { &[] };
                accepted = !ev.has_penalty_terms(&self.z, c, y) && {
                    ev.gradient(&self.z, c, y, &mut self.gradient);
                    projected_gradient_norm(&self.z, &self.gradient, &self.lo, &self.hi)
                        <= t.gradient_tolerance
                };
                inner_converged &= accepted;
            }
            match report.exit_status() {
                ExitStatus::NotConvergedOutOfTime => {
                    status = SolveStatus::Deadline;
                    break;
                }
                ExitStatus::Converged if accepted => {
                    status = SolveStatus::Converged;
                    break;
                }
                ExitStatus::Converged => {}
                ExitStatus::NotConvergedIterations
                    if inner_converged && violation <= s.constraint_tolerance =>
                {
                    status = SolveStatus::Converged;
                    break;
                }
                ExitStatus::NotConvergedIterations => {}
            }
            if nc == 0 {
                break;
            }
            if violation > 0.1 * previous_violation {
                c = (c * s.penalty_update_factor).min(s.max_penalty);
            }
            previous_violation = violation;
            if s.penalty_preconditioner_slack_m.is_some() {
                // Each outer iteration restarts PANOC: rescale for the new active set.
                let mut ev = evaluator.borrow_mut();
                ev.to_inputs(&self.z, &mut self.solution);
                let y: &[f64] = if alm_multipliers { &self.warm_multipliers } else { &[] };
                let slack = s.penalty_preconditioner_slack_m;
                rescale(
                    &mut ev,
                    &self.def.bounds,
                    slack,
                    y,
                    &self.solution,
                    c,
                    &mut self.z,
                    &mut self.lo,
                    &mut self.hi,
                );
            }
        }
        // A failed OpEn call, or a solution that is not finite: the counts of the work done so
        // far, and the caller falls back to the warm start.
        if status == SolveStatus::NumericalFailure || self.z.iter().any(|v| !v.is_finite()) {
            return (SolveStatus::NumericalFailure, iterations, outer, elapsed, c);
        }
        self.evaluator.borrow().to_inputs(&self.z, &mut self.solution);
        (status, iterations, outer, elapsed, c)
    }

    /// Objective, `|F2|` and true clearance at `self.solution`.
    fn evaluate_solution(&mut self) -> (f64, f64, f64) {
        let mut ev = self.evaluator.borrow_mut();
        let cost = ev.objective_at_inputs(&self.solution);
        let mut min_clearance = f64::INFINITY;
        for i in 0..ev.num_scenarios() {
            for x in &ev.predicted_states(i)[1..] {
                let (c, _) = mav::geometry::min_clearance(&self.def.obstacles, x[0], x[1], x[2]);
                min_clearance = min_clearance.min(c);
            }
        }
        // Violation at the solution: the norm of the positive parts of the constraint values.
        let violation = ev.constraint_values().iter().map(|v| v.max(0.0).powi(2)).sum::<f64>().sqrt();
        (cost, violation, min_clearance)
    }

    /// Predicted states of every scenario at the last solution: `M` trajectories of `N + 1`.
    pub fn predictions(&self) -> Vec<Vec<[f64; 8]>> {
        self.predictions_of(&self.solution)
    }

    /// Predicted states of every scenario under inputs `u` (`N x 3`, flattened) from the last
    /// solve's instance: `M` trajectories of `N + 1`.
    pub fn predictions_of(&self, u: &[f64]) -> Vec<Vec<[f64; 8]>> {
        let mut ev = self.evaluator.borrow_mut();
        ev.objective_at_inputs(u);
        (0..ev.num_scenarios()).map(|i| ev.predicted_states(i).to_vec()).collect()
    }

    /// Objective of arbitrary inputs for the current instance (used by accuracy checks).
    pub fn objective_of(&self, u: &[f64]) -> f64 {
        self.evaluator.borrow_mut().objective_at_inputs(u)
    }

    pub fn has_solution(&self) -> bool {
        self.has_solution
    }
}

/// `plan` (`N x 3` inputs, flattened) shifted one step into `out`, the last input repeated: the
/// warm start of the cycle after the one that flew `plan`'s first input.
pub fn shift_plan_into(plan: &[f64], out: &mut [f64]) {
    let n = plan.len();
    out[..n - 3].copy_from_slice(&plan[3..]);
    out[n - 3..].copy_from_slice(&plan[n - 3..]);
}

/// [`shift_plan_into`] into a new vector.
pub fn shifted_plan(plan: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; plan.len()];
    shift_plan_into(plan, &mut out);
    out
}

/// `|z - P(z - grad)|` with `P` the projection on the box `[lo, hi]`: the fixed-point residual
/// of a unit projected-gradient step, zero exactly at a stationary point of the box-constrained
/// problem.
/// The panic of OpEn 0.12's ALM when its time is up before its first inner solve on a fresh cache
/// (`with_last_problem_norm_fpr` asserts on the residual it has not computed yet).
fn is_open_time_up_before_first_solve(payload: &(dyn std::any::Any + Send)) -> bool {
    let message = payload
        .downcast_ref::<&str>()
        .copied()
        .or_else(|| payload.downcast_ref::<String>().map(String::as_str));
    message.is_some_and(|m| m.contains("last_problem_norm_fpr"))
}

fn projected_gradient_norm(z: &[f64], grad: &[f64], lo: &[f64], hi: &[f64]) -> f64 {
    let mut acc = 0.0;
    for k in 0..z.len() {
        let r = z[k] - (z[k] - grad[k]).clamp(lo[k], hi[k]);
        acc += r * r;
    }
    acc.sqrt()
}

/// Sets the preconditioner for inputs `u` and penalty `c` (with the penalty part when
/// `slack_m` is set), and the scaled variables `z` and their bounds to match.
#[allow(clippy::too_many_arguments)]
fn rescale(
    ev: &mut Evaluator,
    bounds: &mav::InputBounds,
    slack_m: Option<f64>,
    multipliers: &[f64],
    u: &[f64],
    c: f64,
    z: &mut [f64],
    lo: &mut [f64],
    hi: &mut [f64],
) {
    if let Some(slack) = slack_m {
        ev.objective_at_inputs(u);
        ev.update_scaling_with_penalty(c, multipliers, slack);
    }
    ev.scaled_bounds(bounds, lo, hi);
    ev.to_scaled(u, z);
    for ((z, lo), hi) in z.iter_mut().zip(lo.iter()).zip(hi.iter()) {
        *z = z.clamp(*lo, *hi);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::ControllerMode;
    use mav::Scenario;

    fn mpc_for(scenario: &Scenario, mode: ControllerMode, settings: MpcSettings) -> Mpc {
        let def =
            OcpDefinition::from_scenario(scenario, mode, settings.obstacle_margin_m, settings.formulation);
        Mpc::new(def, settings).expect("valid settings")
    }

    const W5: [f64; 5] = [0.05, 0.15, 0.45, 0.30, 0.05];

    #[test]
    fn solves_the_paper_start_safely_within_bounds() {
        for formulation in [ObstacleFormulation::DistanceAlm, ObstacleFormulation::PaperPenalty] {
            let s = Scenario::paper_2();
            let mut mpc =
                mpc_for(&s, ControllerMode::Multistage, MpcSettings { formulation, ..Default::default() });
            let r = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &SolveBudget::default()).expect("valid");
            assert_ne!(r.status, SolveStatus::NumericalFailure);
            assert!(r.cost.is_finite() && r.cost > 0.0);
            assert!(r.min_clearance_m >= 0.0, "{formulation:?}: predicted clearance {}", r.min_clearance_m);
            let u = mpc.first_input();
            assert!(s.bounds.contains(&mav::Input::from(u)));
            assert!(u[0] > 9.81, "climbs towards the goal 1 m up: {u:?}");
        }
    }

    #[test]
    fn a_warm_started_second_solve_is_cheaper() {
        let s = Scenario::paper_3();
        let mut mpc = mpc_for(&s, ControllerMode::Nmpc, MpcSettings::default());
        let first = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &[1.0], &SolveBudget::default()).expect("valid");
        let second = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &[1.0], &SolveBudget::default()).expect("valid");
        assert!(second.iterations <= first.iterations, "{} > {}", second.iterations, first.iterations);
    }

    #[test]
    fn the_warm_start_advances_by_whole_steps_repeating_the_last_input() {
        let s = Scenario::paper_2();
        let mut mpc = mpc_for(&s, ControllerMode::Nmpc, MpcSettings::default());
        let n = s.horizon;
        let plan: Vec<f64> = (0..3 * n).map(|k| [9.0, 0.01, -0.01][k % 3] + 0.001 * (k / 3) as f64).collect();
        let zero = SolveBudget { max_inner_iterations: Some(0), deadline: None };
        for steps in [0, 1, 3, n - 1, n + 5] {
            mpc.set_warm_start(&plan).expect("valid");
            mpc.advance_warm_start(steps);
            // A zero budget returns the warm start as the solution (through the scaling: to
            // rounding).
            mpc.solve(&s.start, &[9.81, 0.0, 0.0], &[1.0], &zero).expect("valid");
            let got = mpc.solution();
            let shift = steps.min(n - 1);
            for j in 0..3 * n {
                let from = 3 * (j / 3 + shift).min(n - 1) + j % 3;
                assert!(
                    (got[j] - plan[from]).abs() < 1e-12,
                    "steps {steps}, value {j}: {} vs {}",
                    got[j],
                    plan[from]
                );
            }
        }
    }

    #[test]
    fn advancing_the_warm_start_shifts_each_scenarios_multipliers_by_points() {
        let s = Scenario::paper_2();
        let mut mpc = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
        let (n, nc, m) = (s.horizon, mpc.def.constraints_per_point(), mpc.def.num_scenarios());
        assert_eq!(mpc.warm_multipliers.len(), m * n * nc);
        let value = |i: usize, j: usize, c: usize| (1000 * i + 10 * j + c) as f64;
        for i in 0..m {
            for j in 0..n {
                for c in 0..nc {
                    mpc.warm_multipliers[(i * n + j) * nc + c] = value(i, j, c);
                }
            }
        }
        mpc.advance_warm_start(3);
        for i in 0..m {
            for j in 0..n {
                for c in 0..nc {
                    let from = (j + 3).min(n - 1);
                    assert_eq!(mpc.warm_multipliers[(i * n + j) * nc + c], value(i, from, c), "{i} {j} {c}");
                }
            }
        }
    }

    #[test]
    fn the_iteration_budget_is_respected_and_reported() {
        let s = Scenario::paper_1();
        let settings = MpcSettings { max_outer_iterations: 1, ..Default::default() };
        let mut mpc = mpc_for(&s, ControllerMode::Multistage, settings);
        let budget = SolveBudget { max_inner_iterations: Some(2), deadline: None };
        let r = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &budget).expect("valid");
        assert_eq!(r.status, SolveStatus::IterationLimit);
        assert!(r.iterations <= 2);
        assert!(s.bounds.contains(&mav::Input::from(mpc.first_input())));
    }

    #[test]
    fn a_wall_clock_deadline_stops_the_solve_with_its_best_iterate_inside_the_bounds() {
        // Real time: a deadline too short for even one PANOC iteration of the paper-1 start
        // (a hard solve: 200 iterations without one) ends the solve with `Deadline`.
        let s = Scenario::paper_1();
        let mut mpc = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
        let budget = SolveBudget { max_inner_iterations: None, deadline: Some(Duration::from_nanos(1)) };
        let r = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &budget).expect("valid");
        assert_eq!(r.status, SolveStatus::Deadline, "{r:?}");
        assert!(r.iterations < MpcSettings::default().max_inner_iterations, "{r:?}");
        assert!(mpc.solution().iter().all(|u| u.is_finite()));
        for u in mpc.solution().chunks(3) {
            assert!(s.bounds.contains(&mav::Input::new(u[0], u[1], u[2])), "{u:?}");
        }
        assert!(r.cost.is_finite() && r.min_clearance_m.is_finite(), "{r:?}");
        // Deadlines that run out inside the solve, one outer iteration or another: a status,
        // never a panic, and a plan inside the bounds.
        for micros in [20, 21, 30, 50, 100, 300, 1000, 3000] {
            let budget =
                SolveBudget { max_inner_iterations: None, deadline: Some(Duration::from_micros(micros)) };
            let r = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &budget).expect("valid");
            assert_ne!(r.status, SolveStatus::NumericalFailure, "{micros} us: {r:?}");
            assert!(mpc.solution().iter().all(|u| u.is_finite()));
        }
        // A generous deadline changes nothing against no deadline (lockstep's iteration budget).
        let mut timed = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
        let mut counted = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
        let long = SolveBudget { max_inner_iterations: None, deadline: Some(Duration::from_secs(3600)) };
        let a = timed.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &long).expect("valid");
        let b = counted.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &SolveBudget::default()).expect("valid");
        assert_eq!((a.status, a.iterations), (b.status, b.iterations));
        assert_eq!(timed.solution(), counted.solution());
    }

    #[test]
    fn the_panic_of_an_open_call_out_of_time_before_its_first_solve_is_recognized() {
        // OpEn's own panic, reproduced on a fresh cache with no time at all: the solver turns
        // exactly this one into `Deadline` (and lets any other panic unwind).
        let cache = AlmCache::new(PANOCCache::new(2, 1e-5, 3), 0, 0);
        let (lo, hi) = ([-1.0, -1.0], [1.0, 1.0]);
        let cost = |u: &[f64], _: &[f64], c: &mut f64| -> FunctionCallResult {
            *c = u[0] * u[0] + u[1] * u[1];
            Ok(())
        };
        let grad = |u: &[f64], _: &[f64], g: &mut [f64]| -> FunctionCallResult {
            g[0] = 2.0 * u[0];
            g[1] = 2.0 * u[1];
            Ok(())
        };
        type NoMapping = fn(&[f64], &mut [f64]) -> FunctionCallResult;
        let problem = AlmProblem::new(
            Rectangle::new(Some(&lo), Some(&hi)),
            None::<Rectangle>,
            None::<Rectangle>,
            cost,
            grad,
            None::<NoMapping>,
            None::<NoMapping>,
            0,
            0,
        );
        let mut cache = cache;
        let mut u = [0.5, 0.5];
        let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            AlmOptimizer::new(&mut cache, problem).with_max_duration(Duration::ZERO).solve(&mut u)
        }));
        match outcome {
            Err(payload) => assert!(is_open_time_up_before_first_solve(payload.as_ref())),
            Ok(r) => panic!("OpEn no longer panics out of time (the guard can go): {r:?}"),
        }
        assert!(!is_open_time_up_before_first_solve(&"index out of bounds"));
        assert!(!is_open_time_up_before_first_solve(&String::from("already borrowed")));
    }

    #[test]
    fn bad_input_is_refused_naming_the_field_and_changes_nothing() {
        let s = Scenario::paper_1();
        let mut mpc = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
        let before = mpc.solution().to_vec();
        let mut x0 = s.start;
        x0[4] = f64::NAN;
        let e = mpc.solve(&x0, &[9.81, 0.0, 0.0], &W5, &SolveBudget::default());
        assert_eq!(e, Err(invalid_input("x0[4]", "must be finite")));
        let e = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &[1.0], &SolveBudget::default());
        assert!(matches!(e, Err(MpcError::InvalidInput { field, .. }) if field == "weights"));
        let e = mpc.solve(&s.start, &[9.81, f64::INFINITY, 0.0], &W5, &SolveBudget::default());
        assert!(matches!(e, Err(MpcError::InvalidInput { field, .. }) if field == "u_prev[1]"));
        let e = mpc.set_warm_start(&[1.0; 7]);
        assert!(matches!(e, Err(MpcError::InvalidInput { field, .. }) if field == "warm_start"));
        assert_eq!(mpc.solution(), &before[..]);
        assert!(matches!(
            MpcSettings { penalty_update_factor: 1.0, ..Default::default() }.validate(),
            Err(MpcError::InvalidSetting { field: "penalty_update_factor", .. })
        ));
    }

    #[test]
    fn standard_nmpc_has_its_own_panoc_tolerances_and_memory() {
        let s = MpcSettings {
            tolerance: 1e-3,
            akkt_tolerance: 1e-2,
            lbfgs_memory: 10,
            single_scenario_tolerance: 3e-2,
            single_scenario_akkt_tolerance: 1e-1,
            single_scenario_lbfgs_memory: 7,
            ..Default::default()
        };
        assert_eq!(s.panoc_for(1), (3e-2, 1e-1, 7));
        assert_eq!(s.panoc_for(5), (1e-3, 1e-2, 10));
        for (bad, field) in [
            (MpcSettings { single_scenario_tolerance: f64::NAN, ..s }, "single_scenario_tolerance"),
            (MpcSettings { single_scenario_akkt_tolerance: 0.0, ..s }, "single_scenario_akkt_tolerance"),
            (MpcSettings { single_scenario_lbfgs_memory: 0, ..s }, "single_scenario_lbfgs_memory"),
        ] {
            assert!(matches!(bad.validate(), Err(MpcError::InvalidSetting { field: f, .. }) if f == field));
        }
        // A tighter NMPC tolerance costs iterations on the same problem: the setting is used.
        let scenario = Scenario::paper_1();
        let x0 = [0.2, 3.0, 0.9, 0.1, 1.2, 0.05, 0.02, -0.01];
        let iterations = |settings: MpcSettings| {
            let mut mpc = mpc_for(&scenario, ControllerMode::Nmpc, settings);
            mpc.solve(&x0, &[9.81, 0.0, 0.0], &[1.0], &SolveBudget::default()).expect("valid").iterations
        };
        let tight =
            MpcSettings { single_scenario_tolerance: 1e-6, single_scenario_akkt_tolerance: 1e-5, ..s };
        assert!(iterations(tight) > iterations(s), "{} vs {}", iterations(tight), iterations(s));
    }

    #[test]
    fn inactive_set_tolerances_are_validated_naming_the_field() {
        let t = InactiveSetTolerances::MEASURED;
        let with = |t: InactiveSetTolerances| MpcSettings { inactive_set: Some(t), ..Default::default() };
        assert_eq!(with(t).validate(), Ok(()));
        for (bad, field) in [
            (InactiveSetTolerances { tolerance: f64::NAN, ..t }, "inactive_set.tolerance"),
            (InactiveSetTolerances { akkt_tolerance: 0.0, ..t }, "inactive_set.akkt_tolerance"),
            (
                InactiveSetTolerances { gradient_tolerance: f64::INFINITY, ..t },
                "inactive_set.gradient_tolerance",
            ),
        ] {
            assert!(
                matches!(with(bad).validate(), Err(MpcError::InvalidSetting { field: f, .. }) if f == field)
            );
        }
    }

    /// Paper-2 with its cylinders moved 20 m away, out of reach whatever the inputs do: no
    /// constraint term ever.
    fn open_space() -> Scenario {
        let mut s = Scenario::paper_2();
        for c in &mut s.obstacles {
            c.x_m += 20.0;
        }
        s
    }

    /// Report and solution bits of one solve from a fresh workspace.
    fn solve_bits(
        scenario: &Scenario,
        mode: ControllerMode,
        settings: MpcSettings,
        x0: &[f64; 8],
        weights: &[f64],
    ) -> (SolveReport, Vec<u64>) {
        let mut mpc = mpc_for(scenario, mode, settings);
        let r = mpc.solve(x0, &[9.81, 0.0, 0.0], weights, &SolveBudget::default()).expect("valid");
        (r, mpc.solution().iter().map(|v| v.to_bits()).collect())
    }

    #[test]
    fn inactive_set_tolerances_apply_where_no_constraint_term_is_active() {
        let loose = MpcSettings { inactive_set: Some(InactiveSetTolerances::MEASURED), ..Default::default() };
        let open_space = open_space();
        let x0 = [3.1, 1.2, 0.6, 0.1, 1.4, 0.2, 0.05, -0.02];
        let (tight_report, _) =
            solve_bits(&open_space, ControllerMode::Multistage, MpcSettings::default(), &x0, &W5);
        let (loose_report, _) = solve_bits(&open_space, ControllerMode::Multistage, loose, &x0, &W5);
        assert_eq!(loose_report.status, SolveStatus::Converged);
        assert!(
            loose_report.iterations < tight_report.iterations,
            "{} vs {} iterations",
            loose_report.iterations,
            tight_report.iterations
        );
        // The looser test still stops close to the optimum on this smooth problem.
        let gap = (loose_report.cost - tight_report.cost) / tight_report.cost;
        assert!(gap.abs() < 1e-2, "cost gap {gap}");

        // Inside the inflated radius of a cylinder, moving towards it: the first predicted points
        // cannot leave it, so a term is active at every outer iteration and the solve is the
        // one of the default settings, bit for bit.
        let scenario = Scenario::paper_2();
        let c = scenario.obstacles[1];
        let x0 = [c.x_m + c.radius_m + 0.05, c.y_m, 1.0, -0.5, 0.0, 0.0, 0.0, 0.0];
        let (a, a_bits) = solve_bits(&scenario, ControllerMode::Multistage, MpcSettings::default(), &x0, &W5);
        let (b, b_bits) = solve_bits(&scenario, ControllerMode::Multistage, loose, &x0, &W5);
        assert!(a.constraint_violation > 0.0, "a term must be active");
        assert_eq!((a.iterations, a.cost.to_bits(), a_bits), (b.iterations, b.cost.to_bits(), b_bits));

        // Standard NMPC ignores the option (it has its own tolerances).
        let x0 = [3.1, 1.2, 0.6, 0.1, 1.4, 0.2, 0.05, -0.02];
        let (a, a_bits) = solve_bits(&open_space, ControllerMode::Nmpc, MpcSettings::default(), &x0, &[1.0]);
        let (b, b_bits) = solve_bits(&open_space, ControllerMode::Nmpc, loose, &x0, &[1.0]);
        assert_eq!((a.iterations, a.cost.to_bits(), a_bits), (b.iterations, b.cost.to_bits(), b_bits));
    }

    #[test]
    fn an_inactive_set_result_must_have_a_small_projected_gradient() {
        // A gradient tolerance no result can meet: every inactive-set outer iteration is
        // handed on, so the solve runs all its outer iterations and never reports convergence.
        let open_space = open_space();
        let unreachable =
            InactiveSetTolerances { gradient_tolerance: 1e-300, ..InactiveSetTolerances::MEASURED };
        let s = MpcSettings { inactive_set: Some(unreachable), ..Default::default() };
        let x0 = [3.1, 1.2, 0.6, 0.1, 1.4, 0.2, 0.05, -0.02];
        let (r, _) = solve_bits(&open_space, ControllerMode::Multistage, s, &x0, &W5);
        assert_eq!(r.status, SolveStatus::IterationLimit);
        assert_eq!(r.outer_iterations, s.max_outer_iterations);
    }

    #[test]
    fn projected_gradient_norm_is_the_unit_step_residual_on_the_box() {
        let (lo, hi) = ([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]);
        // Interior: the gradient itself; at a bound, only the part pointing into the box.
        assert_eq!(projected_gradient_norm(&[0.0, 0.0, 0.0], &[0.3, 0.0, -0.4], &lo, &hi), 0.5);
        assert_eq!(projected_gradient_norm(&[1.0, -1.0, 0.0], &[-2.0, -5.0, 0.0], &lo, &hi), 2.0);
        assert_eq!(projected_gradient_norm(&[0.5, 0.0, 0.0], &[-3.0, 0.0, 0.0], &lo, &hi), 0.5);
    }

    #[test]
    fn solves_are_deterministic() {
        let s = Scenario::paper_2();
        let x0 = [3.1, 1.2, 0.6, 0.1, 1.4, 0.2, 0.05, -0.02];
        let run = || {
            let mut mpc = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
            let r = mpc.solve(&x0, &[10.0, 0.01, 0.0], &W5, &SolveBudget::default()).expect("valid");
            (r.cost.to_bits(), r.iterations, mpc.solution().iter().map(|v| v.to_bits()).collect::<Vec<_>>())
        };
        assert_eq!(run(), run());
    }

    #[test]
    fn a_numerical_failure_returns_the_warm_start_inside_the_bounds() {
        let s = Scenario::paper_1();
        let mut mpc = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
        // Finite but absurd: the predicted cost overflows to infinity.
        let x0 = [0.0, 0.0, 0.0, 1e200, 1e200, 1e200, 0.0, 0.0];
        let r = mpc.solve(&x0, &[9.81, 0.0, 0.0], &W5, &SolveBudget::default()).expect("valid input");
        assert_eq!(r.status, SolveStatus::NumericalFailure);
        assert_eq!(mpc.first_input(), [9.81, 0.0, 0.0]);
    }
}
