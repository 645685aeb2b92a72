//! The closed loops' own warm-started solves (paper-1/2/3) against the careful reference
//! (`mpc::accuracy`): the share within 1 % of its cost, solve times, iterations, passes.
use mpc::{ControllerMode, OcpDefinition, accuracy, record::percentile};

use crate::settings::MpcFlags;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Compare every `stride`-th solve with the reference (1000 or more: none).
    #[arg(default_value_t = 5)]
    stride: usize,
    /// That controller alone (`nmpc` or `multistage`; default both).
    #[arg(long, env = "MPC_MODE", value_parser = crate::mode)]
    mode: Option<ControllerMode>,
    #[command(flatten)]
    mpc: MpcFlags,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let stride = args.stride.max(1);
    let s = args.mpc.settings();
    println!("{s:?}");
    for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
        if args.mode.is_some_and(|m| m != mode) {
            continue;
        }
        let (mut times, mut iters, mut gaps, mut unsafe_count) = (Vec::new(), Vec::new(), Vec::new(), 0);
        let (mut passes, mut limits, mut outers) = ((0u64, 0u64), 0, 0);
        // Forward plus adjoint passes per solve: the work that sets a solve's time, counted.
        let mut work = Vec::new();
        for name in mav::Scenario::BUILT_IN {
            let scenario = mav::Scenario::by_name(name)?;
            let def = OcpDefinition::from_scenario(&scenario, mode, s.obstacle_margin_m, s.formulation);
            let solves = accuracy::loop_solves(&scenario, mode, &s)?;
            passes.0 += solves.iter().map(|l| l.report.passes.forward).sum::<u64>();
            passes.1 += solves.iter().map(|l| l.report.passes.adjoint).sum::<u64>();
            limits += solves.iter().filter(|l| l.report.status == mpc::SolveStatus::IterationLimit).count();
            outers += solves.iter().map(|l| l.report.outer_iterations).sum::<usize>();
            for (k, ls) in solves.iter().enumerate() {
                times.push(ls.report.solve_time.as_secs_f64() * 1e3);
                work.push((ls.report.passes.forward + ls.report.passes.adjoint) as f64);
                iters.push(ls.report.iterations as f64);
                if ls.report.min_clearance_m < 0.0 {
                    unsafe_count += 1;
                }
                if k % stride == 0 && stride < 1000 {
                    let gap = accuracy::loop_solve_gap(&def, &s, ls)?;
                    gaps.push(gap);
                    if gap > 0.01 {
                        println!(
                            "  {name} {} cycle {k} gap={gap:.3} it={} outer={} {:?} viol={:.1e}",
                            mode.name(),
                            ls.report.iterations,
                            ls.report.outer_iterations,
                            ls.report.status,
                            ls.report.constraint_violation
                        );
                    }
                }
            }
        }
        let within = gaps.iter().filter(|g| **g <= 0.01).count();
        println!(
            "{}: {}/{} within 1%; {} solves, ms median {:.3} p99 {:.3} max {:.3}; iterations median {} p99 {}; predicted clearance < 0 in {}",
            mode.name(),
            within,
            gaps.len(),
            times.len(),
            percentile(&mut times.clone(), 50.0),
            percentile(&mut times.clone(), 99.0),
            percentile(&mut times, 100.0),
            percentile(&mut iters.clone(), 50.0),
            percentile(&mut iters, 99.0),
            unsafe_count
        );
        let solves = times.len() as f64;
        println!(
            "  iterations total {}; at the iteration limit {limits}; outer per solve {:.2}; per solve (whole loop) forward {:.1} adjoint {:.1}",
            iters.iter().sum::<f64>(),
            outers as f64 / solves,
            passes.0 as f64 / solves,
            passes.1 as f64 / solves
        );
        println!(
            "  forward + adjoint passes per solve: median {} p99 {} max {}",
            percentile(&mut work.clone(), 50.0),
            percentile(&mut work.clone(), 99.0),
            percentile(&mut work, 100.0)
        );
    }
    Ok(())
}
