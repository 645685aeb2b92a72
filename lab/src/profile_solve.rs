//! Profiling target: the in-process closed loop of paper-2 (run under callgrind).
use mpc::{ClosedLoopSettings, ControllerMode, run_closed_loop};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// `nmpc` or `multistage`.
    #[arg(default_value = "multistage", value_parser = crate::mode)]
    mode: ControllerMode,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let scenario = mav::Scenario::paper_2();
    let (s, _) = run_closed_loop(&scenario, &ClosedLoopSettings::paper(args.mode))?;
    println!("{} cycles", s.cycles);
    Ok(())
}
