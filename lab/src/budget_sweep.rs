//! How cost, violation and clearance of chosen loop solves evolve with PANOC's iteration
//! budget: the instances come from the closed loop with the default settings, the solves use
//! the flags' settings.
use mpc::{MpcSettings, OcpDefinition, accuracy};

use crate::settings::{LoopArgs, MpcFlags};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    run: LoopArgs,
    /// The loop's cycles to sweep.
    #[arg(required = true)]
    cycles: Vec<usize>,
    #[command(flatten)]
    mpc: MpcFlags,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let (scenario, mode) = (&args.run.scenario, args.run.mode);
    let s = args.mpc.settings();
    let loop_settings = MpcSettings::default();
    let solves = accuracy::loop_solves(scenario, mode, &loop_settings)?;
    let def = OcpDefinition::from_scenario(scenario, mode, s.obstacle_margin_m, s.formulation);
    for &k in &args.cycles {
        let ls = solves.get(k).ok_or_else(|| anyhow::anyhow!("cycle {k}: the loop has {}", solves.len()))?;
        let reference =
            accuracy::reference_cost(&def, &s, &ls.instance, &[&ls.instance.warm_start, &ls.plan])?;
        println!("cycle {k}: reference {reference:.4}");
        for budget in [5, 10, 20, 40, 80, 160, 320, 640, 2000] {
            let budgeted =
                MpcSettings { max_inner_iterations: budget, own_max_inner_iterations: budget, ..s };
            let (r, _) = accuracy::fast_solve(&def, &budgeted, &ls.instance)?;
            println!(
                "  budget {budget:5}: it={:4} outer={} c={:.0e} cost={:.4} gap={:+.4} viol={:.2e} clear={:.3} {:?}",
                r.iterations,
                r.outer_iterations,
                r.penalty_parameter,
                r.cost,
                (r.cost - reference) / reference,
                r.constraint_violation,
                r.min_clearance_m,
                r.status
            );
        }
    }
    Ok(())
}
