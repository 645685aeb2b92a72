//! The solver's settings (validated data with documented defaults) and the budget of one solve.

use std::time::Duration;

use crate::error::MpcError;
use crate::problem::ObstacleFormulation;

/// Default upper bound of the multiplier box `Y` OpEn's ALM requires (compact, inside the dual
/// cone).
pub const MAX_MULTIPLIER: f64 = 1e9;

/// Settings of the solver (validated in [`Mpc::new`](super::Mpc::new)).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MpcSettings {
    /// Whose PANOC solves the inner problems: OpEn 0.12's (inside its ALM/PM) or ours
    /// (`solver/panoc.rs`, inside our ALM/PM loop). See [`PanocSolver`].
    pub solver: PanocSolver,
    /// [`PanocSolver::Own`] only: its scale-free stopping test, `|R|² / 2 <= cost_gap_tolerance
    /// |ψ|` with `R` the gradient mapping in the scaled variables (unit hover curvature): the
    /// cost gap a unit-curvature model predicts, as a fraction of the cost; it does not depend
    /// on the Lipschitz estimate. Multi-stage problems; standard NMPC uses
    /// `single_scenario_cost_gap_tolerance`. Measured (`lab accuracy`, `lab fresh`;
    /// BENCHMARKS.md "The solver"): at 1e-2 23 of 56 sampled loop solves ended 1-7 % above the
    /// careful reference, most of them "converged" after a few iterations; 1e-3 doubles the
    /// median iterations (4 to 7) and keeps them fewer than OpEn's (14).
    pub cost_gap_tolerance: f64,
    /// `cost_gap_tolerance` of standard NMPC (one scenario). Measured: at 1e-2 one sampled
    /// state in ten ends 1-2 % above the reference (the single-scenario cost is smaller near the
    /// goal, where the unit-curvature model is optimistic), so it is tighter.
    pub single_scenario_cost_gap_tolerance: f64,
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
    /// Measured (`lab accuracy`; BENCHMARKS.md, "The solver"): at 3e-2 / 1e-1 the NMPC's costs stay within 1 % of
    /// the careful reference on every sampled loop state with 10 iterations at the median
    /// (25 at 1e-3 / 1e-2), while multi-stage solves at those values miss by up to 40 %.
    pub single_scenario_tolerance: f64,
    /// `akkt_tolerance` of standard NMPC (one scenario); see `single_scenario_tolerance`.
    pub single_scenario_akkt_tolerance: f64,
    /// `lbfgs_memory` of standard NMPC (one scenario). Measured (`lab accuracy`): at
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
    /// PANOC iterations per solve with OpEn's PANOC, summed over the outer iterations: the
    /// lockstep budget.
    pub max_inner_iterations: usize,
    /// The same budget with ours ([`PanocSolver::Own`]). Measured along the paper loops (`lab
    /// accuracy`, BENCHMARKS.md "The solver"): about a fifth of the multi-stage solves stop at
    /// any budget from 100 to 5,000 iterations (paper-2's start, paper-3's passage: the
    /// scenarios' predictions threading the cylinders), so the budget sets the 99th percentile
    /// of the solve time; at 100 instead of 200 the sampled solves stay as close to the careful
    /// reference (67 of 69 within 1 %, against 64 of 69), the loops take a third fewer
    /// iterations and the paper runs reach their goals clear of the cylinders.
    pub own_max_inner_iterations: usize,
    /// L-BFGS memory of PANOC for multi-stage problems; standard NMPC uses
    /// `single_scenario_lbfgs_memory`.
    pub lbfgs_memory: usize,
    /// PANOC iterations per outer iteration; `None`: whatever is left of the solve's budget.
    /// Measured (`lab accuracy`): caps of 20-100 did not reduce the solves that stop
    /// at the budget.
    pub max_inner_iterations_per_outer: Option<usize>,
    /// Upper bound of every ALM multiplier (the box `Y`), in units of the cost per metre of
    /// violation. Where a point of a long-horizon scenario stays inside an inflated cylinder
    /// whatever the inputs, its multiplier grows every outer iteration and cycle up to this
    /// bound; measured (`lab accuracy`), a bound of 100 halves the solves that stop at
    /// the iteration budget but lets standard NMPC cut deeper into the cylinders.
    pub max_multiplier: f64,
    /// Adds the penalty's Gauss-Newton diagonal of the constraints that are active or within
    /// this distance of active at the warm start (and at each outer iteration's start) to the
    /// preconditioner, m; `None` keeps the objective's hover diagonal alone. Measured
    /// (`lab fixed-instances`): with the hover sensitivities it made multi-stage solves slower,
    /// so it is off by default.
    pub penalty_preconditioner_slack_m: Option<f64>,
    /// Standard NMPC (one scenario) only: warm-start each cycle from the last plan shifted by
    /// the time since the last cycle's sample, in whole sampling times, instead of by one step
    /// (see [`crate::CycleController::step`]). Off by default: `docs/spec.md`'s protocol shifts by
    /// one step, and the paper-1 result depends on it (measured: with it the NMPC no longer
    /// stalls in front of the cylinder; BENCHMARKS.md).
    pub warm_start_by_elapsed_time: bool,
    /// Multi-stage only (opt-in): PANOC's tolerances for an outer iteration that starts with no
    /// constraint term in the augmented Lagrangian (no predicted point with `c g + y > 0`),
    /// where the Lipschitz constant is the objective's alone and OpEn's `γ`-scaled tests mean
    /// what they mean for standard NMPC (see `single_scenario_tolerance`). `None` (default):
    /// `tolerance` and `akkt_tolerance` throughout. Measured (`lab accuracy
    /// --inactive-set measured`, recorded in docs/notebook/benchmarks-history.md): with [`InactiveSetTolerances::MEASURED`] the multi-stage median along the paper
    /// loops drops from 0.22-0.27 ms to 0.13-0.15 ms at a little lower accuracy (61 of 70
    /// sampled states within 1 % of the reference, against 65 of 73), but the closed
    /// loops change, and the default paper-1 run then dives into the ground (paper mode has
    /// no floor), so it is not the default.
    pub inactive_set: Option<InactiveSetTolerances>,
    /// [`PanocSolver::Own`], distance formulation: PANOC iterations of a restoration phase run
    /// when a solve ends at its budget with its plan predicted inside a cylinder: the
    /// augmented Lagrangian at `restoration_penalty` with every constraint shifted outwards by
    /// `restoration_shift_m` (the multipliers raised by `penalty x shift`), from the plan
    /// reached; its result is kept only if its plan is clear. 0: no restoration. Measured on
    /// cold solves of OpEn's paper-loop states with no margin (`lab fresh 4 --mode multistage
    /// --obstacle-margin-m 0`, BENCHMARKS.md "Cold solves from another implementation's
    /// states"): 30 iterations at 1e6 and 3 mm leave 2 of 73 plans inside a cylinder (15
    /// without) and 69 of 73 within 1 % of the best known clear cost (57); 50 iterations: the
    /// same counts, more time; a 1 cm shift: 67 of 73 (plans further out cost more).
    pub restoration_iterations: usize,
    /// The penalty of the restoration phase.
    pub restoration_penalty: f64,
    /// How far outside the inflated cylinders the restoration phase aims, m.
    pub restoration_shift_m: f64,
    /// How far outside the inflated cylinders a second restoration phase aims when the first
    /// leaves the plan inside, m: from the first's result, with the same iterations and
    /// penalty; 0: no second phase. Measured the same way as `restoration_iterations`: at
    /// 2 cm the two multi-stage plans the first phase left inside (paper-1 cycles 12 and 20, 6.1
    /// and 1.0 cm) come out clear (by 4.6 mm and 1.5 cm) and so does the one NMPC plan (paper-1
    /// cycle 20, 2.1 cm; then within 1 % of the best known clear cost, 97 of 97), no other
    /// answer changing; at 1 cm only multi-stage cycle 20 comes out; at 3 cm all three, at a
    /// higher cost (NMPC cycle 20 then 2.2 % above the best known); at 5-10 cm higher still.
    pub restoration_retry_shift_m: f64,
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
    /// The values measured with `lab accuracy` (docs/notebook/benchmarks-history.md): 1e-2 and 3e-2 are
    /// standard NMPC's kind of test at the multi-stage objective's Lipschitz constant (~25 in
    /// the scaled variables), and 0.5 rejects the 3-5 % of results whose residual is an order
    /// above the rest (median 0.18, 90th percentile 0.29, largest 12 along the paper loops).
    pub const MEASURED: Self = Self { tolerance: 1e-2, akkt_tolerance: 3e-2, gradient_tolerance: 0.5 };
}

/// Whose PANOC runs the solve (`MpcSettings::solver`): `OpEn` applies `tolerance`,
/// `akkt_tolerance` and the single-scenario ones; `Own` its `cost_gap_tolerance`s, with the same
/// ALM/PM outer loop, budgets and multiplier update. Defined with the scenario, which can name it.
pub use mav::PanocSolver;

impl Default for MpcSettings {
    fn default() -> Self {
        Self {
            solver: PanocSolver::OpEn,
            cost_gap_tolerance: 1e-3,
            single_scenario_cost_gap_tolerance: 1e-4,
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
            own_max_inner_iterations: 100,
            lbfgs_memory: 10,
            max_inner_iterations_per_outer: None,
            max_multiplier: MAX_MULTIPLIER,
            penalty_preconditioner_slack_m: None,
            warm_start_by_elapsed_time: false,
            inactive_set: None,
            restoration_iterations: 30,
            restoration_penalty: 1e6,
            restoration_shift_m: 0.003,
            restoration_retry_shift_m: 0.02,
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
            ("cost_gap_tolerance", self.cost_gap_tolerance),
            ("single_scenario_cost_gap_tolerance", self.single_scenario_cost_gap_tolerance),
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
        if !pos(self.restoration_penalty) {
            return bad("restoration_penalty", "must be finite and > 0");
        }
        if !(self.restoration_shift_m.is_finite() && self.restoration_shift_m >= 0.0) {
            return bad("restoration_shift_m", "must be finite and >= 0");
        }
        if !(self.restoration_retry_shift_m.is_finite() && self.restoration_retry_shift_m >= 0.0) {
            return bad("restoration_retry_shift_m", "must be finite and >= 0");
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

    /// The PANOC iterations a solve may spend by default: `max_inner_iterations` or
    /// `own_max_inner_iterations`, by solver.
    pub fn inner_budget(&self) -> usize {
        match self.solver {
            PanocSolver::OpEn => self.max_inner_iterations,
            PanocSolver::Own => self.own_max_inner_iterations,
        }
    }

    /// Our PANOC's `cost_gap_tolerance` for a problem of `num_scenarios` scenarios.
    pub fn cost_gap_tolerance_for(&self, num_scenarios: usize) -> f64 {
        if num_scenarios == 1 { self.single_scenario_cost_gap_tolerance } else { self.cost_gap_tolerance }
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

/// What a solve may spend. In lockstep only iteration counts bound a solve, so that runs are
/// bit-identical; in real time a wall-clock deadline is added.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SolveBudget {
    /// Overrides `MpcSettings::inner_budget` when set.
    pub max_inner_iterations: Option<usize>,
    /// Wall-clock limit of the whole solve.
    pub deadline: Option<Duration>,
}
