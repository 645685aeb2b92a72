//! Profiling target: the in-process closed loop of paper-2 (run under callgrind, e.g. with
//! `--toggle-collect='*Mpc::solve*'` for the solver's instructions alone). Prints the cycles,
//! solves, PANOC iterations and the evaluator's passes, to divide the instruction count by.
use mpc::{ClosedLoopSettings, ControllerMode, run_closed_loop};

use crate::settings::MpcFlags;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// `nmpc` or `multistage`.
    #[arg(default_value = "multistage", value_parser = crate::mode)]
    mode: ControllerMode,
    /// A built-in scenario.
    #[arg(long, default_value = "paper-2", value_parser = crate::scenario)]
    scenario: mav::Scenario,
    #[command(flatten)]
    mpc: MpcFlags,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let mut settings = ClosedLoopSettings::paper(args.mode);
    settings.episode.mpc = args.mpc.settings();
    let (s, records) = run_closed_loop(&args.scenario, &settings)?;
    let iterations: usize = records.iter().map(|r| r.report.iterations).sum();
    let forward: u64 = records.iter().map(|r| r.report.passes.forward).sum();
    let adjoint: u64 = records.iter().map(|r| r.report.passes.adjoint).sum();
    println!(
        "{} cycles, {} solves, {iterations} PANOC iterations, {forward} forward and {adjoint} adjoint passes",
        s.cycles,
        records.len()
    );
    Ok(())
}
