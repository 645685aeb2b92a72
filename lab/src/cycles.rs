//! Per-cycle solver statistics of one in-process paper run and what the safety layer chose.
use mpc::{ClosedLoopSettings, run_closed_loop};

use crate::fmt::fixed;
use crate::settings::{LoopArgs, MpcFlags};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    run: LoopArgs,
    #[command(flatten)]
    mpc: MpcFlags,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let mut settings = ClosedLoopSettings::paper(args.run.mode);
    settings.episode.mpc = args.mpc.settings();
    let (s, records) = run_closed_loop(&args.run.scenario, &settings)?;
    for r in &records {
        println!(
            "{:3} t={:6.2} p=[{}] v=[{}] u=[{:6.2} {:6.3} {:6.3}] d={:.3} {:?} it={} outer={} c={:.0e} viol={:.2e} clr={:.3} ms={:.2} cost={:.1} w={:.2?} {}",
            r.record.cycle,
            r.record.t_s(),
            fixed(&r.record.state[..3], 6, " "),
            fixed(&r.record.state[3..6], 5, " "),
            r.record.command[0],
            r.record.command[1],
            r.record.command[2],
            r.delay_s,
            r.report.status,
            r.report.iterations,
            r.report.outer_iterations,
            r.report.penalty_parameter,
            r.report.constraint_violation,
            r.report.min_clearance_m,
            r.report.solve_time.as_secs_f64() * 1e3,
            r.report.cost,
            r.record.weights,
            r.selection.as_ref().map_or(String::new(), |sel| sel.reason())
        );
    }
    println!("{s:?}");
    Ok(())
}
