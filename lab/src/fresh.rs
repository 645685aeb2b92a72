//! Cold solves of logged states (issues 20 and 39): states logged along closed loops, each
//! solved from scratch from the warm start logged with it, as `controller solve` does (a reset
//! workspace: zero multipliers, the initial penalty, no carried Lipschitz estimate), by both
//! PANOCs in the same run, against the best known cost of a clear plan.
//!
//! We have no other implementation's logs, so the states come from the bench's own paper loops
//! (paper-1/2/3) flown with `--log-solver` (OpEn, the paper's toolchain, by default): every
//! `stride`-th cycle's state, last command, weights and warm start (the previous plan shifted
//! by one step). The loops fly paper mode (its 0.1 m margin); the cold solves solve the problem
//! `--obstacle-margin-m` sets (0: the paper's exact problem). `--lines FILE` writes the sample as
//! `controller solve` JSON lines (with that margin), so that the same sample can be solved
//! through the controller (`controller --solver own solve FILE`).
//!
//! The best known cost of a state is the least cost of a clear plan (no predicted point inside
//! a cylinder, [`mpc::INSIDE_TOLERANCE_M`]) among both answers and the careful reference
//! (`mpc::accuracy`) started from the warm start and from each answer (`--answers-only`: the
//! two answers alone). Where any of those ends inside a cylinder, a careful solve of the
//! constraints alone from the same starts looks for clear plans too, which count as they are
//! and as the starts of careful solves of the true problem: a state with no clear plan known
//! has none that these found, not merely none the careful references kept. Times are one
//! solve's each, or with `--repeat K` the least of K solves (the solvers alternating): the
//! medians and totals compared with OpEn's then hold under load.
use std::io::Write;

use mpc::{
    ControllerMode, INSIDE_TOLERANCE_M, Mpc, OcpDefinition, PanocSolver, SolveBudget, SolveStatus, accuracy,
    record::percentile,
};

use crate::settings::MpcFlags;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Take every `stride`-th cycle of each loop.
    #[arg(default_value_t = 4)]
    stride: usize,
    /// That controller alone (`nmpc` or `multistage`; default both).
    #[arg(long, env = "MPC_MODE", value_parser = crate::mode)]
    mode: Option<ControllerMode>,
    /// The solver of the logged loops.
    #[arg(long, default_value = "open", value_parser = solver)]
    log_solver: PanocSolver,
    /// The margin of the cold solves' problem, m (the loops fly paper mode's); default: the
    /// settings' (0.1 m). 0 is the paper's exact problem.
    #[arg(long, env = "MPC_MARGIN")]
    obstacle_margin_m: Option<f64>,
    /// That built-in scenario alone (default: the three paper scenarios).
    #[arg(long)]
    scenario: Option<String>,
    /// Print every answer (scenario, cycle, status, iterations, gap, clearance).
    #[arg(long)]
    verbose: bool,
    /// Write the sample as `controller solve` JSON lines to this file.
    #[arg(long)]
    lines: Option<std::path::PathBuf>,
    /// Solve each state this many times with each solver, alternating the solvers, and take the
    /// least time of each: a time that other processes on the machine lengthen less (the answers
    /// of the repeats must be identical, or the command fails).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=1000))]
    repeat: u32,
    /// The best known cost from the two answers alone, no careful reference: quick, for timing
    /// and profiling (the gaps are then to the better answer, not to the best known cost).
    #[arg(long)]
    answers_only: bool,
    /// The settings of the cold solves (`--solver` is ignored: both solvers run).
    #[command(flatten)]
    mpc: MpcFlags,
}

/// One solver's sample.
#[derive(Default)]
struct Stats {
    /// Relative gap to the best known clear cost; `None` when the answer's plan is not clear
    /// (or no clear plan is known).
    gaps: Vec<Option<f64>>,
    times: Vec<f64>,
    iterations: Vec<f64>,
    /// Forward and adjoint passes, summed over the sample.
    forward_passes: u64,
    adjoint_passes: u64,
    /// Answers at the iteration limit whose plan is clear.
    limits_clear: usize,
    /// Depths of the answers whose plan is predicted inside a cylinder, by status name.
    inside: Vec<(&'static str, f64)>,
}

fn solver(value: &str) -> Result<PanocSolver, String> {
    PanocSolver::parse(value).ok_or_else(|| format!("`{value}`: open or own"))
}

/// The predicted points of the last solve inside a cylinder: `scenario:step depth` each.
fn inside_points(m: &Mpc) -> String {
    let obstacles = &m.definition().obstacles;
    let mut out = Vec::new();
    for (i, p) in m.predictions().iter().enumerate() {
        for (j, x) in p.iter().enumerate().skip(1) {
            let (c, _) = mav::geometry::min_clearance(obstacles, x[0], x[1], x[2]);
            if c < -INSIDE_TOLERANCE_M {
                out.push(format!("{i}:{j} {:.3}", -c));
            }
        }
    }
    out.join(", ")
}

/// A careful solve's (clearance, cost) from `start`.
fn reference_solve(
    def: &OcpDefinition,
    settings: &mpc::MpcSettings,
    i: &accuracy::Instance,
    start: &[f64],
) -> anyhow::Result<(f64, f64)> {
    let mut r = Mpc::new(def.clone(), accuracy::reference_settings(settings))?;
    r.set_warm_start(start)?;
    let rep = r.solve(&i.x0, &i.u_prev, &i.weights, &SolveBudget::default())?;
    Ok((rep.min_clearance_m, rep.cost))
}

/// The weight of the objective in a feasibility solve: small enough that the careful solve
/// minimises the constraint violation (in metres) first, large enough to keep the problem
/// regular. Measured on paper-1 cycle 12, where the careful references from the warm start and
/// from both answers all end inside a cylinder: at 1e-10 the feasibility solves come out
/// 3-195 mm clear (at 1e-6 the objective still wins: 0.02 mm inside).
const FEASIBILITY_OBJECTIVE_SCALE: f64 = 1e-10;

/// Clear plans for a state where an answer or a careful reference ended inside: a careful solve
/// of the constraints alone (the objective scaled by [`FEASIBILITY_OBJECTIVE_SCALE`]) from each
/// of `starts`, and each clear plan it finds, both as it is and as the start of a careful
/// solve of the true problem. Returns (clearance, cost) pairs under the true objective.
fn feasibility_candidates(
    def: &OcpDefinition,
    settings: &mpc::MpcSettings,
    i: &accuracy::Instance,
    starts: &[&[f64]],
) -> anyhow::Result<Vec<(f64, f64)>> {
    let mut constraints_only = def.clone();
    for q in
        constraints_only.q_x.iter_mut().chain(&mut constraints_only.q_u).chain(&mut constraints_only.q_du)
    {
        *q *= FEASIBILITY_OBJECTIVE_SCALE;
    }
    let mut candidates = Vec::new();
    for start in starts {
        let mut f = Mpc::new(constraints_only.clone(), accuracy::reference_settings(settings))?;
        f.set_warm_start(start)?;
        let r = f.solve(&i.x0, &i.u_prev, &i.weights, &SolveBudget::default())?;
        if r.min_clearance_m < -INSIDE_TOLERANCE_M {
            continue;
        }
        let plan = f.solution().to_vec();
        // The plan's own cost: a budget of zero returns the warm start, evaluated.
        let mut e = Mpc::new(def.clone(), *settings)?;
        e.set_warm_start(&plan)?;
        let zero = SolveBudget { max_inner_iterations: Some(0), ..SolveBudget::default() };
        let as_is = e.solve(&i.x0, &i.u_prev, &i.weights, &zero)?;
        candidates.push((as_is.min_clearance_m, as_is.cost));
        candidates.push(reference_solve(def, settings, i, &plan)?);
    }
    Ok(candidates)
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let stride = args.stride.max(1);
    let base = args.mpc.settings();
    let margin = args.obstacle_margin_m.unwrap_or(base.obstacle_margin_m);
    let cold = mpc::MpcSettings { obstacle_margin_m: margin, ..base };
    let mut lines = args.lines.as_ref().map(std::fs::File::create).transpose()?;
    println!(
        "cold solves: margin {margin} m; states from {} loops, every {stride}th",
        args.log_solver.name()
    );
    for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
        if args.mode.is_some_and(|m| m != mode) {
            continue;
        }
        let solvers = [PanocSolver::OpEn, PanocSolver::Own];
        let mut stats: Vec<Stats> = solvers.iter().map(|_| Stats::default()).collect();
        let mut no_clear_known = 0;
        for name in mav::Scenario::BUILT_IN {
            if args.scenario.as_deref().is_some_and(|s| s != name) {
                continue;
            }
            let scenario = mav::Scenario::by_name(name)?;
            let mut cold_scenario = scenario.clone();
            cold_scenario.obstacle_margin_m = Some(margin);
            let def = OcpDefinition::from_scenario(&cold_scenario, mode, margin, cold.formulation);
            // The loops fly paper mode: the default settings but for the solver.
            let logged = mpc::MpcSettings { solver: args.log_solver, ..mpc::MpcSettings::default() };
            let solves = accuracy::loop_solves(&scenario, mode, &logged)?;
            for (k, ls) in solves.iter().enumerate().step_by(stride) {
                let i = &ls.instance;
                if let Some(f) = lines.as_mut() {
                    let rows: Vec<&[f64]> = i.warm_start.chunks(3).collect();
                    let line = serde_json::json!({
                        "scenario": name, "mode": mode.name(), "x0": i.x0, "u_prev": i.u_prev,
                        "weights": i.weights, "warm_start": rows, "obstacle_margin_m": margin,
                    });
                    writeln!(f, "{line}")?;
                }
                let mut answers: Vec<(mpc::SolveReport, Vec<f64>)> = Vec::new();
                for repeat in 0..args.repeat {
                    for (si, &solver) in solvers.iter().enumerate() {
                        let settings = mpc::MpcSettings { solver, ..cold };
                        let mut m = Mpc::new(def.clone(), settings)?;
                        m.reset_warm_start();
                        m.set_warm_start(&i.warm_start)?;
                        let r = m.solve(&i.x0, &i.u_prev, &i.weights, &SolveBudget::default())?;
                        if repeat == 0 {
                            if args.verbose && r.min_clearance_m < -INSIDE_TOLERANCE_M {
                                println!("    {} inside: {}", solver.name(), inside_points(&m));
                            }
                            answers.push((r, m.solution().to_vec()));
                            continue;
                        }
                        let (first, plan) = &mut answers[si];
                        anyhow::ensure!(
                            plan.as_slice() == m.solution() && first.iterations == r.iterations,
                            "{name} cycle {k}: {} answered differently on repeat {repeat}",
                            solver.name()
                        );
                        first.solve_time = first.solve_time.min(r.solve_time);
                    }
                }
                let mut candidates: Vec<(f64, f64)> =
                    answers.iter().map(|(r, _)| (r.min_clearance_m, r.cost)).collect();
                if !args.answers_only {
                    candidates.push(reference_solve(&def, &cold, i, &i.warm_start)?);
                    for (_, plan) in &answers {
                        candidates.push(reference_solve(&def, &cold, i, plan)?);
                    }
                }
                let best_clear = |candidates: &[(f64, f64)]| {
                    candidates
                        .iter()
                        .filter(|(clearance, _)| *clearance >= -INSIDE_TOLERANCE_M)
                        .map(|(_, cost)| *cost)
                        .fold(f64::INFINITY, f64::min)
                };
                let mut best = best_clear(&candidates);
                // A state where an answer or a careful reference ends inside a cylinder is one
                // where clear plans are hard to find: there the feasibility solves look too.
                let hard = candidates.iter().any(|(clearance, _)| *clearance < -INSIDE_TOLERANCE_M);
                if hard && !args.answers_only {
                    let mut starts: Vec<&[f64]> = vec![&i.warm_start];
                    starts.extend(answers.iter().map(|(_, plan)| plan.as_slice()));
                    candidates.extend(feasibility_candidates(&def, &cold, i, &starts)?);
                    best = best_clear(&candidates);
                }
                if !best.is_finite() {
                    no_clear_known += 1;
                    if args.verbose {
                        println!(
                            "  {name} {} cycle {k}: no clear plan known; (clearance, cost) {candidates:.4?}",
                            mode.name()
                        );
                    }
                }
                for (si, (r, _)) in answers.iter().enumerate() {
                    let s = &mut stats[si];
                    s.times.push(r.solve_time.as_secs_f64() * 1e3);
                    s.iterations.push(r.iterations as f64);
                    s.forward_passes += r.passes.forward;
                    s.adjoint_passes += r.passes.adjoint;
                    let clear = r.min_clearance_m >= -INSIDE_TOLERANCE_M;
                    if !clear {
                        s.inside.push((r.status.name(), -r.min_clearance_m));
                    } else if r.status == SolveStatus::IterationLimit {
                        s.limits_clear += 1;
                    }
                    let gap = (clear && best.is_finite()).then(|| (r.cost - best) / best.abs().max(1e-12));
                    s.gaps.push(gap);
                    let miss = gap.is_none_or(|g| g > 0.01);
                    if args.verbose || miss {
                        println!(
                            "  {name} {} cycle {k} {}: {} {} it. {:.3} ms, cost {:.4} (best {best:.4}), gap {}, clearance {:+.4} m",
                            mode.name(),
                            solvers[si].name(),
                            r.status.name(),
                            r.iterations,
                            r.solve_time.as_secs_f64() * 1e3,
                            r.cost,
                            gap.map_or("-".to_string(), |g| format!("{g:.4}")),
                            r.min_clearance_m,
                        );
                    }
                }
            }
        }
        let n = stats[0].gaps.len();
        println!("{} cold, {n} states ({no_clear_known} with no clear plan known):", mode.name());
        for (si, s) in stats.iter().enumerate() {
            let within = s.gaps.iter().filter(|g| g.is_some_and(|g| g <= 0.01)).count();
            let mut depths: Vec<f64> = s.inside.iter().map(|(_, d)| *d).collect();
            let statuses: std::collections::BTreeMap<&str, usize> =
                s.inside.iter().fold(Default::default(), |mut m, (st, _)| {
                    *m.entry(*st).or_default() += 1;
                    m
                });
            println!(
                "  {:4}: {within}/{n} within 1% with a clear plan ({:.1} % of the {} states with a clear plan known); ms median {:.3} total {:.1}; iterations median {} total {} (forward / adjoint passes {} / {}); at the limit and clear {}; inside a cylinder {} {:?} (depth max {:.4} m, median {:.4} m)",
                solvers[si].name(),
                100.0 * within as f64 / (n - no_clear_known).max(1) as f64,
                n - no_clear_known,
                percentile(&mut s.times.clone(), 50.0),
                s.times.iter().sum::<f64>(),
                percentile(&mut s.iterations.clone(), 50.0),
                s.iterations.iter().sum::<f64>(),
                s.forward_passes,
                s.adjoint_passes,
                s.limits_clear,
                s.inside.len(),
                statuses,
                percentile(&mut depths.clone(), 100.0),
                percentile(&mut depths, 50.0),
            );
        }
        let ratio = |f: &dyn Fn(&Stats) -> f64| f(&stats[1]) / f(&stats[0]);
        println!(
            "  own / open: median time {:.2}, total time {:.2}, total iterations {:.2}",
            ratio(&|s| percentile(&mut s.times.clone(), 50.0)),
            ratio(&|s| s.times.iter().sum::<f64>()),
            ratio(&|s| s.iterations.iter().sum::<f64>()),
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_feasibility_solve_finds_a_clear_plan_where_the_careful_reference_ends_inside() {
        // Cycle 12 of OpEn's paper-1 multi-stage loop at no margin: the careful reference from
        // the warm start ends 8 cm inside a cylinder, yet clear plans exist.
        let scenario = mav::Scenario::by_name("paper-1").expect("built in");
        let mode = ControllerMode::Multistage;
        let logged = mpc::MpcSettings::default();
        let solves = accuracy::loop_solves(&scenario, mode, &logged).expect("the loop flies");
        let i = &solves[12].instance;
        let settings = mpc::MpcSettings { obstacle_margin_m: 0.0, ..logged };
        let mut cold_scenario = scenario.clone();
        cold_scenario.obstacle_margin_m = Some(0.0);
        let def = OcpDefinition::from_scenario(&cold_scenario, mode, 0.0, settings.formulation);
        let (clearance, _) = reference_solve(&def, &settings, i, &i.warm_start).expect("solves");
        assert!(clearance < -0.01, "the careful reference came out clear: {clearance} m");
        let found = feasibility_candidates(&def, &settings, i, &[&i.warm_start]).expect("solves");
        let clear: Vec<_> = found.iter().filter(|(c, _)| *c >= -INSIDE_TOLERANCE_M).collect();
        assert!(!clear.is_empty(), "no clear plan among {found:?}");
        assert!(clear.iter().all(|(_, cost)| cost.is_finite() && *cost > 0.0), "{clear:?}");
    }
}
