//! Accuracy of the fast path against a slow, careful reference solve of the same problem.
//!
//! The reference shares the problem definition and the (finite-difference-checked) cost and
//! gradient, and nothing of the fast path's budget: tolerances six orders tighter, thousands
//! of iterations, a larger L-BFGS memory, exact-feasibility ALM, and two starting points (the
//! warm start and the fast solution), keeping the better feasible one. It is a *local* optimum
//! in the same basin, which is what "within 1 % of a tight local optimum" asks for.

use crate::error::MpcError;
use crate::problem::{ControllerMode, OcpDefinition};
use crate::solver::{Mpc, MpcSettings, SolveBudget, SolveReport};

/// One problem instance as the controller saw it in a closed loop.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Instance {
    pub x0: [f64; 8],
    pub u_prev: [f64; 3],
    pub weights: Vec<f64>,
    /// The warm start the controller used (the previous plan shifted by one step, or by the
    /// elapsed steps with `MpcSettings::warm_start_by_elapsed_time`).
    pub warm_start: Vec<f64>,
}

/// Settings of the reference solve: OpEn's PANOC whichever solver the fast path uses, so that
/// both solvers are measured against the same reference.
pub fn reference_settings(fast: &MpcSettings) -> MpcSettings {
    MpcSettings {
        solver: crate::solver::PanocSolver::OpEn,
        cost_gap_tolerance: 1e-12,
        single_scenario_cost_gap_tolerance: 1e-12,
        tolerance: 1e-9,
        akkt_tolerance: 1e-7,
        single_scenario_tolerance: 1e-9,
        single_scenario_akkt_tolerance: 1e-7,
        constraint_tolerance: 1e-6,
        max_outer_iterations: 30,
        max_inner_iterations: 100_000,
        own_max_inner_iterations: 100_000,
        max_penalty: 1e9,
        lbfgs_memory: 30,
        single_scenario_lbfgs_memory: 30,
        max_multiplier: crate::solver::MAX_MULTIPLIER,
        penalty_preconditioner_slack_m: None,
        max_inner_iterations_per_outer: None,
        // The reference's own tolerances throughout, whatever the fast path uses.
        inactive_set: None,
        ..*fast
    }
}

/// Result of comparing one fast solve with its reference.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Comparison {
    pub fast: SolveReport,
    pub reference_cost: f64,
    /// `(fast - reference) / reference`.
    pub relative_gap: f64,
}

/// Solves `instance` with `fast` settings, as the controller does.
pub fn fast_solve(
    def: &OcpDefinition,
    fast: &MpcSettings,
    instance: &Instance,
) -> Result<(SolveReport, Vec<f64>), MpcError> {
    let mut mpc = Mpc::new(def.clone(), *fast)?;
    mpc.set_warm_start(&instance.warm_start)?;
    let report = mpc.solve(&instance.x0, &instance.u_prev, &instance.weights, &SolveBudget::default())?;
    Ok((report, mpc.solution().to_vec()))
}

/// The reference cost of `instance`: the best of careful solves from each of `starts`.
/// Feasible solutions (violation <= 1e-5) win; if none is feasible (the state is already
/// inside an inflated cylinder), the least violating one.
pub fn reference_cost(
    def: &OcpDefinition,
    fast: &MpcSettings,
    instance: &Instance,
    starts: &[&[f64]],
) -> Result<f64, MpcError> {
    let reference = reference_settings(fast);
    let mut best = (f64::INFINITY, f64::INFINITY);
    for start in starts {
        let mut r = Mpc::new(def.clone(), reference)?;
        r.set_warm_start(start)?;
        let rep = r.solve(&instance.x0, &instance.u_prev, &instance.weights, &SolveBudget::default())?;
        let key = (if rep.constraint_violation <= 1e-5 { 0.0 } else { rep.constraint_violation }, rep.cost);
        if key < best {
            best = key;
        }
    }
    Ok(best.1)
}

/// Solves `instance` with `fast` settings (as the controller does) and with the reference.
pub fn compare(def: &OcpDefinition, fast: &MpcSettings, instance: &Instance) -> Result<Comparison, MpcError> {
    let (report, fast_solution) = fast_solve(def, fast, instance)?;
    let best = reference_cost(def, fast, instance, &[&instance.warm_start, &fast_solution])?;
    Ok(Comparison {
        fast: report,
        reference_cost: best,
        relative_gap: (report.cost - best) / best.abs().max(1e-12),
    })
}

/// One solve of a closed loop: the instance as the controller saw it, and what its warm-started
/// solver returned.
#[derive(Debug, Clone)]
pub struct LoopSolve {
    pub instance: Instance,
    pub report: SolveReport,
    pub plan: Vec<f64>,
}

/// Every solve of the in-process paper closed loop of `scenario` with `settings`: the
/// controller's own warm-started solves (previous plan shifted, multipliers and penalty carried
/// over), which is what the accuracy and timing targets are about.
pub fn loop_solves(
    scenario: &mav::Scenario,
    mode: ControllerMode,
    settings: &MpcSettings,
) -> Result<Vec<LoopSolve>, MpcError> {
    let mut loop_settings = crate::ClosedLoopSettings::paper(mode);
    loop_settings.episode.mpc = *settings;
    let (_, records) = crate::run_closed_loop(scenario, &loop_settings)?;
    let g = scenario.model.gravity_mps2;
    let mut out = Vec::with_capacity(records.len());
    for k in 0..records.len() {
        let (warm, u_prev) = if k == 0 {
            let hover: Vec<f64> = (0..scenario.horizon).flat_map(|_| [g, 0.0, 0.0]).collect();
            (hover, [g, 0.0, 0.0])
        } else {
            let prev = &records[k - 1];
            let mut warm = crate::solver::shifted_plan(&prev.plan);
            if settings.warm_start_by_elapsed_time && mode == ControllerMode::Nmpc {
                // As `CycleController::step` does, from the records' times.
                let steps =
                    ((records[k].record.t_s() - prev.record.t_s()) / scenario.sampling_times_s[0]).round();
                for _ in 1..(steps as usize) {
                    warm = crate::solver::shifted_plan(&warm);
                }
            }
            (warm, prev.record.command)
        };
        out.push(LoopSolve {
            instance: Instance {
                x0: records[k].record.state,
                u_prev,
                weights: records[k].record.weights.clone(),
                warm_start: warm,
            },
            report: records[k].report,
            plan: records[k].plan.clone(),
        });
    }
    Ok(out)
}

/// Relative gap of a loop solve to its reference.
pub fn loop_solve_gap(def: &OcpDefinition, settings: &MpcSettings, s: &LoopSolve) -> Result<f64, MpcError> {
    let reference = reference_cost(def, settings, &s.instance, &[&s.instance.warm_start, &s.plan])?;
    Ok((s.report.cost - reference) / reference.abs().max(1e-12))
}
