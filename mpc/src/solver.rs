//! The controller workspace: OpEn's ALM/PM + PANOC on the scaled problem, warm start, budgets,
//! and the per-solve report.
//!
//! Code map: the settings and the budget (`settings.rs`: [`MpcSettings`], [`SolveBudget`]);
//! the report (`report.rs`: [`SolveStatus`], [`SolveReport`]); the warm start (`warm_start.rs`:
//! setting, advancing and shifting plans and multipliers); the outer loop over OpEn's ALM/PM
//! steps (`alm.rs`). This file holds the workspace [`Mpc`] and [`Mpc::solve`].

mod alm;
mod panoc;
mod report;
mod settings;
#[cfg(test)]
mod tests;
mod warm_start;

use std::cell::RefCell;

use optimization_engine::alm::AlmCache;
use optimization_engine::panoc::PANOCCache;

use crate::error::MpcError;
use crate::problem::{Evaluator, MAX_COAST_TIME_S, ObstacleFormulation, OcpDefinition, validate_instance};

use alm::AlmRun;
pub use report::{INSIDE_TOLERANCE_M, SolveReport, SolveStatus};
pub use settings::{InactiveSetTolerances, MAX_MULTIPLIER, MpcSettings, PanocSolver, SolveBudget};
pub use warm_start::{shift_plan_into, shifted_plan};

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
    /// Our PANOC's workspace ([`PanocSolver::Own`]); its Lipschitz estimate carries across
    /// outer iterations and cycles.
    panoc: panoc::Panoc,
    /// The restoration phase's shifted multipliers and the iterate it started from.
    restoration_multipliers: Vec<f64>,
    restoration_z: Vec<f64>,
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
        check_coast_time(def.formulation, def.coast_time_s)?;
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
            panoc: panoc::Panoc::new(n, lbfgs_memory),
            restoration_multipliers: vec![0.0; n1],
            restoration_z: vec![0.0; n],
            def,
        })
    }

    /// Sets the problem's [`OcpDefinition::coast_time_s`] from the next solve on (the fail-safe
    /// check's range follows the delays measured, and the coast with it). `Err` (nothing
    /// changes) outside `[0, MAX_COAST_TIME_S]`, or above 0 with the penalty form.
    pub fn set_coast_time(&mut self, coast_time_s: f64) -> Result<(), MpcError> {
        check_coast_time(self.def.formulation, coast_time_s)?;
        self.def.coast_time_s = coast_time_s;
        self.evaluator.get_mut().set_coast_time(coast_time_s);
        Ok(())
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

    /// The ALM multipliers of the last solve (empty in the penalty formulation): what
    /// [`Mpc::set_warm_multipliers`] takes to start another solve where this one ended.
    pub fn multipliers(&self) -> &[f64] {
        &self.multipliers
    }

    /// The first input of the last solution, within the input bounds.
    pub fn first_input(&self) -> [f64; 3] {
        [self.solution[0], self.solution[1], self.solution[2]]
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
        let passes_before = self.evaluator.borrow().pass_counts();
        let AlmRun { status, iterations, outer_iterations, elapsed: solve_time, penalty } =
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
        let status = status.with_clearance(min_clearance_m);
        if status != SolveStatus::NumericalFailure {
            // Keep the penalty that was needed (warm start of the outer loop); relax it
            // when no predicted point (nor its coast) enters an inflated cylinder any more.
            let s = &self.settings;
            self.penalty = if violation == 0.0 { penalty / s.penalty_update_factor } else { penalty }
                .clamp(s.initial_penalty, s.max_penalty);
        }
        self.has_solution = true;
        self.shift_solution_into_warm_start();
        let passes = self.evaluator.borrow().pass_counts().since(passes_before);
        Ok(SolveReport {
            status,
            iterations,
            outer_iterations,
            solve_time,
            cost,
            constraint_violation: violation,
            penalty_parameter: penalty,
            min_clearance_m,
            passes,
        })
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

/// [`OcpDefinition::coast_time_s`] is in range and the formulation has it.
fn check_coast_time(formulation: ObstacleFormulation, coast_time_s: f64) -> Result<(), MpcError> {
    if !(coast_time_s.is_finite() && (0.0..=MAX_COAST_TIME_S).contains(&coast_time_s)) {
        return Err(MpcError::InvalidProblem(format!(
            "coast_time_s must be in [0, {MAX_COAST_TIME_S}] s, got {coast_time_s}"
        )));
    }
    if coast_time_s > 0.0 && formulation != ObstacleFormulation::DistanceAlm {
        return Err(MpcError::InvalidProblem("coast_time_s > 0 needs the distance_alm formulation".into()));
    }
    Ok(())
}
