//! `hilbench`: the bench's command line. `hilbench reproduce` runs the paper's three scenarios
//! with the standard and the multi-stage NMPC in paper mode, over real gRPC (plant, netem and
//! controller on loopback) or in process, and prints the paper's tables beside what this bench
//! measures; `run`, `sweep`, `sweep-merge`, `falsify`, `trace` and `certs` are the rest (see
//! `--help`).
//!
//! This file parses the command line, dispatches to `hilbench::commands`, and is the only
//! place that ends the process: exit 0 (every run without a collision), 1 (an error, anyhow's),
//! 2 (a usage error, clap's), 3 (a run collided; `falsify`: a run failed the property), 130
//! (Ctrl-C, after what finished was written).

use std::time::Instant;

use clap::Parser;
use hilbench::cli::{Cli, Command};
use hilbench::commands::{self, Exit, Options};

fn main() {
    // The error and its causes on one line, without the backtrace anyhow's Debug adds when
    // RUST_BACKTRACE is set: a refusal is a message, not a crash.
    if let Err(e) = run() {
        eprintln!("Error: {e:#}");
        std::process::exit(1);
    }
}

fn run() -> anyhow::Result<()> {
    let started = Instant::now();
    let cli = Cli::parse();
    let opts = Options { quiet: cli.quiet, plots: !cli.no_plots, mcap: cli.mcap(), started };
    let exit = match cli.command {
        Command::Reproduce(args) => commands::reproduce::reproduce(args, &opts)?,
        Command::Run(args) => commands::run::run(args, &opts)?,
        Command::Sweep(args) => commands::sweep::sweep(args, &opts)?,
        Command::SweepMerge(args) => commands::sweep_merge::sweep_merge(args, &opts)?,
        Command::Certs(args) => commands::certs::certs(args, &opts)?,
        Command::Trace(args) => commands::trace::trace(args, &opts)?,
        Command::Falsify(args) => commands::falsify::falsify(args, &opts)?,
    };
    if exit != Exit::Success {
        std::process::exit(exit.code());
    }
    Ok(())
}
