//! The outer loop of the solve, driven here one OpEn ALM/PM outer step at a time, so that the
//! penalty stays capped while the multipliers keep improving: OpEn's own loop would multiply
//! the penalty without bound when the violation stalls. Each step is a named function; the
//! loop in [`Mpc::solve_scaled`] only adds up the work and decides whether to go on.

use std::time::{Duration, Instant};

use optimization_engine::alm::{AlmOptimizer, AlmOptimizerStatus, AlmProblem};
use optimization_engine::constraints::Rectangle;
use optimization_engine::core::ExitStatus;
use optimization_engine::{FunctionCallResult, SolverError};

use super::panoc::{PanocStatus, SmoothCost};
use super::{INSIDE_TOLERANCE_M, InactiveSetTolerances, Mpc, PanocSolver, SolveBudget, SolveStatus};
use crate::problem::{Evaluator, ObstacleFormulation};

/// The inner problem of our ALM/PM: `ψ(z; c, y)` of the evaluator (see [`Evaluator::cost`]).
struct AugmentedLagrangian<'a> {
    evaluator: &'a mut Evaluator,
    penalty: f64,
    multipliers: &'a [f64],
}

impl SmoothCost for AugmentedLagrangian<'_> {
    fn cost(&mut self, z: &[f64]) -> f64 {
        self.evaluator.cost(z, self.penalty, self.multipliers)
    }

    fn cost_and_gradient(&mut self, z: &[f64], grad: &mut [f64]) -> f64 {
        let f = self.evaluator.cost(z, self.penalty, self.multipliers);
        self.evaluator.gradient(z, self.penalty, self.multipliers, grad);
        f
    }
}

/// Whose multipliers an inner solve of ours takes: none (the penalty method), the warm ones
/// (an outer step of the ALM), or the restoration phase's.
#[derive(Debug, Clone, Copy)]
enum InnerMultipliers {
    None,
    Warm,
    Restoration,
}

/// Least time left before a deadline for another OpEn call: below it the solve stops with
/// `Deadline` (an OpEn call whose time is up before its first PANOC iteration does no work).
const MIN_CALL_DURATION: Duration = Duration::from_micros(20);

/// What the outer loop returns to [`Mpc::solve`].
pub(super) struct AlmRun {
    pub status: SolveStatus,
    /// PANOC iterations, summed over the outer iterations.
    pub iterations: usize,
    pub outer_iterations: usize,
    /// OpEn's measured time, summed over its calls.
    pub elapsed: Duration,
    /// The penalty parameter of the last outer iteration.
    pub penalty: f64,
}

/// One OpEn outer step that ran, with what the loop needs from it.
struct OuterStep {
    inner_iterations: usize,
    solve_time: Duration,
    exit_status: ExitStatus,
    /// The constraint violation after the step, m (ALM) or `|F2|` (PM).
    violation: f64,
    /// The inner problem converged (below its iteration cap; for an inactive-set step, also
    /// accepted).
    inner_converged: bool,
    /// An inactive-set step's result passed its acceptance test (always true otherwise).
    accepted: bool,
}

impl OuterStep {
    /// The status the solve ends with after this step, or `None` to go on.
    fn verdict(&self, constraint_tolerance: f64) -> Option<SolveStatus> {
        match self.exit_status {
            ExitStatus::NotConvergedOutOfTime => Some(SolveStatus::Deadline),
            ExitStatus::Converged if self.accepted => Some(SolveStatus::Converged),
            ExitStatus::Converged => None,
            ExitStatus::NotConvergedIterations
                if self.inner_converged && self.violation <= constraint_tolerance =>
            {
                Some(SolveStatus::Converged)
            }
            ExitStatus::NotConvergedIterations => None,
        }
    }
}

impl Mpc {
    /// The outer loop on the scaled problem: sets the instance and the scaling, then runs one
    /// OpEn outer step at a time until one ends the solve, the outer or inner budget is spent,
    /// or the problem has no constraints. The solution (unscaled) is in `self.solution` unless
    /// the status is `NumericalFailure`.
    pub(super) fn solve_scaled(
        &mut self,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        weights: &[f64],
        budget: &SolveBudget,
    ) -> AlmRun {
        let s = self.settings;
        let mut c = self.penalty.clamp(s.initial_penalty, s.max_penalty);
        let nc = self.def.num_constraints();
        self.start_instance(x0, u_prev, weights, c);
        let own_alm = s.solver == PanocSolver::Own
            && self.def.formulation == ObstacleFormulation::DistanceAlm
            && nc > 0;
        // A budget of zero runs no iteration: the warm start comes back with `IterationLimit`.
        let max_total = budget.max_inner_iterations.unwrap_or(s.inner_budget());
        let mut iterations = 0;
        let mut elapsed = Duration::ZERO;
        let mut previous_violation = f64::INFINITY;
        let mut status = SolveStatus::IterationLimit;
        let mut outer = 0;
        while outer < s.max_outer_iterations && iterations < max_total {
            outer += 1;
            let max_inner =
                (max_total - iterations).min(s.max_inner_iterations_per_outer.unwrap_or(usize::MAX));
            let step = match time_left(budget, elapsed)
                .and_then(|remaining| self.outer_step(c, max_inner, remaining))
            {
                Ok(step) => step,
                Err(end) => {
                    status = end;
                    break;
                }
            };
            iterations += step.inner_iterations;
            elapsed += step.solve_time;
            // A plan predicted inside a cylinder's true surface is not a solution, however small
            // the violation the tolerance lets through (with a margin below the constraint
            // tolerance, or multipliers at their cap): the loop goes on, the penalty raised.
            let mut inside = false;
            if let Some(end) = step.verdict(s.constraint_tolerance) {
                inside = end == SolveStatus::Converged && nc > 0 && self.plan_inside_obstacle();
                if !inside {
                    status = end;
                    break;
                }
            }
            if nc == 0 {
                break;
            }
            if inside || step.violation > 0.1 * previous_violation {
                c = (c * s.penalty_update_factor).min(s.max_penalty);
            }
            previous_violation = step.violation;
            if s.penalty_preconditioner_slack_m.is_some() {
                self.rescale_at_solution(c);
            }
        }
        // Not on a budget of zero: its caller asked for the warm start, unsolved.
        if own_alm
            && status == SolveStatus::IterationLimit
            && max_total > 0
            && s.restoration_iterations > 0
            && self.plan_inside_obstacle()
        {
            let (its, time) = self.restore_clearance(budget, elapsed);
            iterations += its;
            elapsed += time;
        }
        // A failed OpEn call, or a solution that is not finite: the counts of the work done so
        // far, and the caller falls back to the warm start.
        if status == SolveStatus::NumericalFailure || self.z.iter().any(|v| !v.is_finite()) {
            status = SolveStatus::NumericalFailure;
        } else {
            self.evaluator.borrow().to_inputs(&self.z, &mut self.solution);
        }
        AlmRun { status, iterations, outer_iterations: outer, elapsed, penalty: c }
    }

    /// Whether a predicted point (after the first) of a scenario at `self.z` lies more than
    /// [`INSIDE_TOLERANCE_M`] inside a cylinder's true surface (no margin). One forward pass,
    /// none when the evaluator is already at `self.z`.
    fn plan_inside_obstacle(&mut self) -> bool {
        let mut ev = self.evaluator.borrow_mut();
        ev.objective(&self.z);
        (0..ev.num_scenarios()).any(|i| {
            ev.predicted_states(i)[1..].iter().any(|x| {
                mav::geometry::min_clearance(&self.def.obstacles, x[0], x[1], x[2]).0 < -INSIDE_TOLERANCE_M
            })
        })
    }

    /// The restoration phase ([`MpcSettings::restoration_iterations`]): our PANOC on the
    /// augmented Lagrangian at the restoration penalty with the constraints shifted outwards,
    /// from `self.z`; when its plan is still inside a cylinder, once more from its result with
    /// the constraints shifted further ([`MpcSettings::restoration_retry_shift_m`]). The first
    /// clear plan is kept; with none, the plan it started from comes back. Returns the
    /// iterations and the time it took.
    fn restore_clearance(&mut self, budget: &SolveBudget, elapsed: Duration) -> (usize, Duration) {
        let start = Instant::now();
        let s = self.settings;
        let Ok(remaining) = time_left(budget, elapsed) else {
            return (0, Duration::ZERO);
        };
        let c = s.restoration_penalty;
        self.restoration_z.copy_from_slice(&self.z);
        let mut iterations = 0;
        let retry = (s.restoration_retry_shift_m > 0.0).then_some(s.restoration_retry_shift_m);
        for shift_m in std::iter::once(s.restoration_shift_m).chain(retry) {
            for (r, y) in self.restoration_multipliers.iter_mut().zip(&self.warm_multipliers) {
                *r = (y + c * shift_m).min(s.max_multiplier);
            }
            let exit = self.inner_solve(
                c,
                InnerMultipliers::Restoration,
                s.restoration_iterations,
                remaining.map(|r| start + r),
            );
            iterations += exit.iterations;
            if exit.status == PanocStatus::NotFinite {
                break;
            }
            if !self.plan_inside_obstacle() {
                return (iterations, start.elapsed());
            }
            if exit.status == PanocStatus::Deadline {
                break;
            }
        }
        self.z.copy_from_slice(&self.restoration_z);
        (iterations, start.elapsed())
    }

    /// Our PANOC on `ψ(z; c, y)` over the box from and into `self.z`, with at most
    /// `max_iterations` iterations: the inner solve of an outer step and of the restoration
    /// phase, which differ in penalty, multipliers and budget only.
    fn inner_solve(
        &mut self,
        penalty: f64,
        multipliers: InnerMultipliers,
        max_iterations: usize,
        deadline: Option<Instant>,
    ) -> super::panoc::PanocExit {
        let mut ev = self.evaluator.borrow_mut();
        let multipliers: &[f64] = match multipliers {
            InnerMultipliers::None => &[],
            InnerMultipliers::Warm => &self.warm_multipliers,
            InnerMultipliers::Restoration => &self.restoration_multipliers,
        };
        let mut problem = AugmentedLagrangian { evaluator: &mut ev, penalty, multipliers };
        self.panoc.solve(
            &mut problem,
            &mut self.z,
            &self.lo,
            &self.hi,
            self.settings.cost_gap_tolerance_for(self.def.num_scenarios()),
            max_iterations,
            deadline,
        )
    }

    /// Sets the cycle's instance in the evaluator and scales the warm start for penalty `c`.
    fn start_instance(&mut self, x0: &[f64; 8], u_prev: &[f64; 3], weights: &[f64], c: f64) {
        let alm_multipliers = self.def.formulation == ObstacleFormulation::DistanceAlm;
        let mut ev = self.evaluator.borrow_mut();
        ev.set_instance(x0, u_prev, weights);
        let y: &[f64] = if alm_multipliers { &self.warm_multipliers } else { &[] };
        let slack = self.settings.penalty_preconditioner_slack_m;
        rescale(&mut ev, &self.def.bounds, slack, y, &self.warm, c, &mut self.z, &mut self.lo, &mut self.hi);
    }

    /// Each outer iteration restarts PANOC: rescale for the new active set, at the current
    /// iterate and penalty `c`.
    fn rescale_at_solution(&mut self, c: f64) {
        let alm_multipliers = self.def.formulation == ObstacleFormulation::DistanceAlm;
        let mut ev = self.evaluator.borrow_mut();
        ev.to_inputs(&self.z, &mut self.solution);
        let y: &[f64] = if alm_multipliers { &self.warm_multipliers } else { &[] };
        let slack = self.settings.penalty_preconditioner_slack_m;
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

    /// The inactive-set tolerances when the option is on and no constraint term is active at
    /// the start point (the constraint values come from the forward pass PANOC's first
    /// evaluation reuses).
    fn inactive_set_applies(&self, c: f64) -> Option<InactiveSetTolerances> {
        // Our PANOC's stopping test does not depend on the Lipschitz estimate: no second set.
        let t = self
            .settings
            .inactive_set
            .filter(|_| self.inactive_cache.is_some() && self.settings.solver == PanocSolver::OpEn)?;
        let alm_multipliers = self.def.formulation == ObstacleFormulation::DistanceAlm;
        let y: &[f64] = if alm_multipliers { &self.warm_multipliers } else { &[] };
        (!self.evaluator.borrow_mut().has_penalty_terms(&self.z, c, y)).then_some(t)
    }

    /// One OpEn outer step at penalty `c` from `self.z`, with at most `max_inner` PANOC
    /// iterations and `remaining` time. `Err` holds the status the solve ends with when the
    /// step did no work (time up before it started) or failed.
    fn outer_step(
        &mut self,
        c: f64,
        max_inner: usize,
        remaining: Option<Duration>,
    ) -> Result<OuterStep, SolveStatus> {
        if self.settings.solver == PanocSolver::Own {
            return self.own_outer_step(c, max_inner, remaining);
        }
        let s = self.settings;
        let (_, akkt_tolerance, _) = s.panoc_for(self.def.num_scenarios());
        let nc = self.def.num_constraints();
        let alm = self.def.formulation == ObstacleFormulation::DistanceAlm && nc > 0;
        let pm = self.def.formulation == ObstacleFormulation::PaperPenalty && nc > 0;
        let inactive = self.inactive_set_applies(c);
        if inactive.is_some() {
            self.multipliers_in.copy_from_slice(&self.warm_multipliers);
        }
        let report = self.call_open(c, max_inner, remaining, alm, pm, akkt_tolerance, inactive)?;
        if report.num_outer_iterations() == 0 {
            // The time was up before the first inner solve (a used cache does not panic):
            // nothing was solved, and the multipliers OpEn reports are an earlier solve's.
            return Err(SolveStatus::Deadline);
        }
        let violation = self.take_multipliers(&report, alm, c);
        // OpEn's ALM exit test needs a previous outer iteration, which a one-step call never
        // has; PANOC stops early only when it has converged, so an inner count below the cap
        // is inner convergence.
        let mut inner_converged = report.num_inner_iterations() < max_inner;
        let mut accepted = true;
        if let Some(t) = inactive
            && (inner_converged || report.exit_status() == ExitStatus::Converged)
        {
            accepted = self.inactive_result_accepted(c, t);
            inner_converged &= accepted;
        }
        Ok(OuterStep {
            inner_iterations: report.num_inner_iterations(),
            solve_time: report.solve_time(),
            exit_status: report.exit_status(),
            violation,
            inner_converged,
            accepted,
        })
    }

    /// One outer step with our PANOC ([`PanocSolver::Own`]): the inner problem at penalty `c`
    /// and the warm multipliers, then OpEn's multiplier update `y+ = P_Y(y + c g(z))` (the
    /// projection on the multiplier box `[0, max_multiplier]`) and its violation `|y+ - y| / c`,
    /// or the penalty method's `|F2|`: the same outer step as OpEn's, so that only the inner
    /// solver differs between the two.
    fn own_outer_step(
        &mut self,
        c: f64,
        max_inner: usize,
        remaining: Option<Duration>,
    ) -> Result<OuterStep, SolveStatus> {
        let start = Instant::now();
        let s = self.settings;
        let nc = self.def.num_constraints();
        let alm = self.def.formulation == ObstacleFormulation::DistanceAlm && nc > 0;
        let multipliers = if alm { InnerMultipliers::Warm } else { InnerMultipliers::None };
        let exit = self.inner_solve(c, multipliers, max_inner, remaining.map(|r| start + r));
        let mut ev = self.evaluator.borrow_mut();
        match exit.status {
            PanocStatus::NotFinite => return Err(SolveStatus::NumericalFailure),
            PanocStatus::Deadline if exit.iterations == 0 => return Err(SolveStatus::Deadline),
            _ => {}
        }
        ev.objective(&self.z);
        let g = ev.constraint_values();
        let violation = if alm {
            let mut dy2 = 0.0;
            for ((y, y_plus), g) in self.warm_multipliers.iter_mut().zip(self.multipliers.iter_mut()).zip(g) {
                let next = (*y + c * g).clamp(0.0, s.max_multiplier);
                dy2 += (next - *y) * (next - *y);
                *y = next;
                *y_plus = next;
            }
            dy2.sqrt() / c
        } else {
            g.iter().map(|v| v.max(0.0).powi(2)).sum::<f64>().sqrt()
        };
        let inner_converged = exit.status == PanocStatus::Converged;
        let exit_status = match exit.status {
            PanocStatus::Converged if violation <= s.constraint_tolerance => ExitStatus::Converged,
            PanocStatus::Deadline => ExitStatus::NotConvergedOutOfTime,
            _ => ExitStatus::NotConvergedIterations,
        };
        Ok(OuterStep {
            inner_iterations: exit.iterations,
            solve_time: start.elapsed(),
            exit_status,
            violation,
            inner_converged,
            accepted: true,
        })
    }

    /// One call of OpEn's ALM/PM limited to one outer iteration, on the cache of the
    /// inactive-set tolerances when they apply. `Err(Deadline)` when OpEn's time was up before
    /// its first inner solve, `Err(NumericalFailure)` when the call failed.
    #[allow(clippy::too_many_arguments)]
    fn call_open(
        &mut self,
        c: f64,
        max_inner: usize,
        remaining: Option<Duration>,
        alm: bool,
        pm: bool,
        akkt_tolerance: f64,
        inactive: Option<InactiveSetTolerances>,
    ) -> Result<AlmOptimizerStatus, SolveStatus> {
        let s = self.settings;
        let nc = self.def.num_constraints();
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
        let (cache, akkt_tolerance) = match (inactive, self.inactive_cache.as_mut()) {
            (Some(t), Some(cache)) => (cache, t.akkt_tolerance),
            _ => (&mut self.alm_cache, akkt_tolerance),
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
            // OpEn 0.12's ALM panics (an assertion on the inner residual it has not computed
            // yet) when its time is up before its first inner solve, which a preempted thread
            // can meet even with `MIN_CALL_DURATION` left: that is the deadline, not a crash of
            // the controller. Any other panic is a bug and goes on unwinding.
            match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| optimizer.solve(&mut self.z))) {
                Ok(solved) => solved,
                Err(payload) if is_open_time_up_before_first_solve(payload.as_ref()) => {
                    return Err(SolveStatus::Deadline);
                }
                Err(payload) => std::panic::resume_unwind(payload),
            }
        } else {
            optimizer.solve(&mut self.z)
        };
        solved.map_err(|_| SolveStatus::NumericalFailure)
    }

    /// Takes the multipliers of an ALM step into the warm start and the solution's, and returns
    /// the step's violation: OpEn's ALM infeasibility `|y+ - y| / c` (the violation in metres),
    /// or the penalty method's `|F2|`.
    fn take_multipliers(&mut self, report: &AlmOptimizerStatus, alm: bool, c: f64) -> f64 {
        if alm {
            let y_plus = report.lagrange_multipliers().as_deref().unwrap_or(&[]);
            let dy = y_plus.iter().zip(&self.warm_multipliers).map(|(a, b)| (a - b) * (a - b)).sum::<f64>();
            if y_plus.len() == self.warm_multipliers.len() {
                self.warm_multipliers.copy_from_slice(y_plus);
                self.multipliers.copy_from_slice(y_plus);
            }
            dy.sqrt() / c
        } else {
            report.f2_norm()
        }
    }

    /// The acceptance test of an inactive-set step: no constraint term active at its result,
    /// for the multipliers it started from, and a projected gradient below the tolerance.
    fn inactive_result_accepted(&mut self, c: f64, t: InactiveSetTolerances) -> bool {
        let alm_multipliers = self.def.formulation == ObstacleFormulation::DistanceAlm;
        let mut ev = self.evaluator.borrow_mut();
        let y: &[f64] = if alm_multipliers { &self.multipliers_in } else { &[] };
        !ev.has_penalty_terms(&self.z, c, y) && {
            ev.gradient(&self.z, c, y, &mut self.gradient);
            projected_gradient_norm(&self.z, &self.gradient, &self.lo, &self.hi) <= t.gradient_tolerance
        }
    }
}

/// The time OpEn's next call may take: `Ok(None)` without a deadline, `Err(Deadline)` when less
/// than [`MIN_CALL_DURATION`] is left.
fn time_left(budget: &SolveBudget, elapsed: Duration) -> Result<Option<Duration>, SolveStatus> {
    match budget.deadline {
        Some(d) => match d.checked_sub(elapsed) {
            Some(r) if r >= MIN_CALL_DURATION => Ok(Some(r)),
            _ => Err(SolveStatus::Deadline),
        },
        None => Ok(None),
    }
}

/// The panic of OpEn 0.12's ALM when its time is up before its first inner solve on a fresh cache
/// (`with_last_problem_norm_fpr` asserts on the residual it has not computed yet).
pub(super) fn is_open_time_up_before_first_solve(payload: &(dyn std::any::Any + Send)) -> bool {
    let message = payload
        .downcast_ref::<&str>()
        .copied()
        .or_else(|| payload.downcast_ref::<String>().map(String::as_str));
    message.is_some_and(|m| m.contains("last_problem_norm_fpr"))
}

/// `|z - P(z - grad)|` with `P` the projection on the box `[lo, hi]`: the fixed-point residual
/// of a unit projected-gradient step, zero exactly at a stationary point of the box-constrained
/// problem.
pub(super) fn projected_gradient_norm(z: &[f64], grad: &[f64], lo: &[f64], hi: &[f64]) -> f64 {
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
