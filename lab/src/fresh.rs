//! The "fresh from a logged warm start" sample of issue 20: states logged along closed loops,
//! each solved from scratch from the warm start logged with it, as `controller solve` does
//! (a reset workspace: zero multipliers, the initial penalty, no carried Lipschitz estimate),
//! by both PANOCs, against the careful reference (`mpc::accuracy`).
//!
//! We have no other implementation's logs, so the states come from the bench's own paper loops
//! (paper-1/2/3) flown with `--log-solver` (OpEn by default): every `stride`-th cycle's state,
//! last command, weights and warm start (the previous plan shifted by one step). `--lines FILE`
//! writes them as `controller solve` JSON lines, so that the same sample can be solved through
//! the controller (`controller --solver own solve FILE`).
use std::io::Write;

use mpc::{
    ControllerMode, Mpc, OcpDefinition, PanocSolver, SolveBudget, SolveStatus, accuracy, record::percentile,
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
    /// Write the sample as `controller solve` JSON lines to this file.
    #[arg(long)]
    lines: Option<std::path::PathBuf>,
    /// The settings of the fresh solves (`--solver` is ignored: both solvers run).
    #[command(flatten)]
    mpc: MpcFlags,
}

/// One solver's sample: relative gaps to the reference, solve times (ms), iterations, and the
/// solves at the iteration limit.
#[derive(Default)]
struct Stats {
    gaps: Vec<f64>,
    times: Vec<f64>,
    iterations: Vec<f64>,
    limits: usize,
}

fn solver(value: &str) -> Result<PanocSolver, String> {
    PanocSolver::parse(value).ok_or_else(|| format!("`{value}`: open or own"))
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let stride = args.stride.max(1);
    let base = args.mpc.settings();
    let mut lines = args.lines.as_ref().map(std::fs::File::create).transpose()?;
    for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
        if args.mode.is_some_and(|m| m != mode) {
            continue;
        }
        // Per solver: gaps, times (ms), iterations, solves at the iteration limit.
        let solvers = [PanocSolver::OpEn, PanocSolver::Own];
        let mut stats: Vec<Stats> = solvers.iter().map(|_| Stats::default()).collect();
        for name in mav::Scenario::BUILT_IN {
            let scenario = mav::Scenario::by_name(name)?;
            let def = OcpDefinition::from_scenario(&scenario, mode, base.obstacle_margin_m, base.formulation);
            let logged = mpc::MpcSettings { solver: args.log_solver, ..base };
            let solves = accuracy::loop_solves(&scenario, mode, &logged)?;
            for (k, ls) in solves.iter().enumerate().step_by(stride) {
                let i = &ls.instance;
                if let Some(f) = lines.as_mut() {
                    let rows: Vec<&[f64]> = i.warm_start.chunks(3).collect();
                    let line = serde_json::json!({
                        "scenario": name, "mode": mode.name(), "x0": i.x0, "u_prev": i.u_prev,
                        "weights": i.weights, "warm_start": rows,
                    });
                    writeln!(f, "{line}")?;
                }
                let mut plans = Vec::new();
                let mut costs = Vec::new();
                for (si, &solver) in solvers.iter().enumerate() {
                    let settings = mpc::MpcSettings { solver, ..base };
                    let mut m = Mpc::new(def.clone(), settings)?;
                    m.reset_warm_start();
                    m.set_warm_start(&i.warm_start)?;
                    let r = m.solve(&i.x0, &i.u_prev, &i.weights, &SolveBudget::default())?;
                    stats[si].times.push(r.solve_time.as_secs_f64() * 1e3);
                    stats[si].iterations.push(r.iterations as f64);
                    if r.status == SolveStatus::IterationLimit {
                        stats[si].limits += 1;
                    }
                    costs.push(r.cost);
                    plans.push(m.solution().to_vec());
                }
                let mut starts: Vec<&[f64]> = vec![&i.warm_start];
                starts.extend(plans.iter().map(Vec::as_slice));
                let reference = accuracy::reference_cost(&def, &base, i, &starts)?;
                for (si, cost) in costs.iter().enumerate() {
                    let gap = (cost - reference) / reference.abs().max(1e-12);
                    stats[si].gaps.push(gap);
                    if gap > 0.01 {
                        println!("  {name} {} cycle {k} {}: gap {gap:.3}", mode.name(), solvers[si].name());
                    }
                }
            }
        }
        for (si, Stats { gaps, times, iterations: iters, limits }) in stats.iter_mut().enumerate() {
            let within = gaps.iter().filter(|g| **g <= 0.01).count();
            println!(
                "{} fresh, {}: {within}/{} within 1%; ms median {:.3} p99 {:.3} max {:.3}; iterations median {} p99 {} total {}; at the iteration limit {limits}",
                mode.name(),
                solvers[si].name(),
                gaps.len(),
                percentile(&mut times.clone(), 50.0),
                percentile(&mut times.clone(), 99.0),
                percentile(times, 100.0),
                percentile(&mut iters.clone(), 50.0),
                percentile(&mut iters.clone(), 99.0),
                iters.iter().sum::<f64>(),
            );
        }
    }
    Ok(())
}
