//! Solver settings compared on the *same* problems. The instances (state, last input,
//! weights, warm start) are those of the in-process paper closed loops with the default
//! settings; the flags' settings solve them in order on one `Mpc` (so multipliers and penalty
//! carry over as in the controller). Unlike `accuracy`, the settings cannot change which
//! states are visited, so iteration and pass counts compare like with like.
use mpc::{ControllerMode, Mpc, MpcSettings, OcpDefinition, SolveBudget, SolveStatus, accuracy};

use crate::settings::MpcFlags;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub(crate) mpc: MpcFlags,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let s = args.mpc.settings();
    for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
        let (mut iters, mut limits, mut cost, mut times) = (Vec::new(), 0, 0.0, Vec::new());
        let mut passes = mpc::PassCounts::default();
        for name in mav::Scenario::BUILT_IN {
            let scenario = mav::Scenario::by_name(name)?;
            let def = OcpDefinition::from_scenario(&scenario, mode, s.obstacle_margin_m, s.formulation);
            let solves = accuracy::loop_solves(&scenario, mode, &MpcSettings::default())?;
            let mut mpc = Mpc::new(def, s)?;
            for ls in &solves[1..] {
                let i = &ls.instance;
                mpc.set_warm_start(&i.warm_start)?;
                let r = mpc.solve(&i.x0, &i.u_prev, &i.weights, &SolveBudget::default())?;
                iters.push(r.iterations as f64);
                passes.forward += r.passes.forward;
                passes.adjoint += r.passes.adjoint;
                times.push(r.solve_time.as_secs_f64() * 1e3);
                limits += usize::from(r.status == SolveStatus::IterationLimit);
                // Relative to the closed loop's own solve of the same instance.
                cost += (r.cost - ls.report.cost) / ls.report.cost.abs().max(1e-12);
            }
        }
        let n = iters.len() as f64;
        println!(
            "{}: {} instances; iterations total {} median {} p99 {}; at the limit {limits}; mean cost change {:+.3} %; ms median {:.3} p99 {:.3}; passes fwd {} adj {}",
            mode.name(),
            iters.len(),
            iters.iter().sum::<f64>(),
            mpc::record::percentile(&mut iters.clone(), 50.0),
            mpc::record::percentile(&mut iters, 99.0),
            cost / n * 100.0,
            mpc::record::percentile(&mut times.clone(), 50.0),
            mpc::record::percentile(&mut times, 99.0),
            passes.forward,
            passes.adjoint,
        );
    }
    Ok(())
}
