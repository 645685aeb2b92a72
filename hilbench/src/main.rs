//! `hilbench`: the bench's command line. `hilbench reproduce` runs the paper's three scenarios
//! with the standard and the multi-stage NMPC in paper mode and prints the paper's tables
//! beside what this bench measures.

mod report;

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::{Parser, Subcommand};
use mpc::closed_loop::RunSummary;
use mpc::{ClosedLoopSettings, ControllerMode, run_closed_loop};

#[derive(Parser, Debug)]
#[command(
    name = "hilbench",
    version,
    about = "Hardware-in-the-loop bench for MAV control over delayed networks"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Reproduce the paper: paper-1..3 with NMPC and multi-stage NMPC, tables side by side.
    Reproduce {
        /// Output directory for summary.json (default: runs/<unix time>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Print the summary as JSON on stdout instead of the tables.
        #[arg(long)]
        json: bool,
        /// Only these scenarios (default: all three).
        #[arg(long)]
        scenario: Vec<String>,
    },
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Reproduce { out, json, scenario } => reproduce(out, json, &scenario),
    }
}

fn reproduce(out: Option<PathBuf>, json: bool, only: &[String]) -> anyhow::Result<()> {
    let started = Instant::now();
    let mut runs: Vec<RunSummary> = Vec::new();
    for name in mav::Scenario::BUILT_IN {
        if !only.is_empty() && !only.iter().any(|o| o == name) {
            continue;
        }
        let scenario = mav::Scenario::by_name(name)?;
        for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
            let (summary, _records) = run_closed_loop(&scenario, &ClosedLoopSettings::paper(mode))
                .with_context(|| format!("{name} with {}", mode.name()))?;
            if !json {
                eprintln!("  {name} {:<11} done ({} cycles)", mode.name(), summary.cycles);
            }
            runs.push(summary);
        }
    }
    let dir = out.unwrap_or_else(|| {
        let secs = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0);
        PathBuf::from("runs").join(secs.to_string())
    });
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let summary = serde_json::json!({
        "runs": runs.iter().map(run_json).collect::<Vec<_>>(),
        "verdicts": report::verdicts(&runs),
        "wall_time_s": started.elapsed().as_secs_f64(),
    });
    let path = dir.join("summary.json");
    std::fs::write(&path, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    if json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!();
        println!(
            "Paper reproduction: SPEC.md paper mode (RK4 plant at 1 ms, Gamma(12, 0.015) round-trip delays, seed 42), lockstep, in process"
        );
        println!();
        print!("{}", report::tables(&runs));
        println!();
        println!("What reproduces");
        for v in report::verdicts(&runs) {
            println!("  - {v}");
        }
        println!();
        println!("Summary: {} ({:.1} s)", path.display(), started.elapsed().as_secs_f64());
    }
    if runs.iter().any(|r| r.collided) {
        // A collision is a result worth reporting, and scripts must see it.
        std::process::exit(2);
    }
    Ok(())
}

/// One entry of `summary.json` (names are stable; see README).
fn run_json(r: &RunSummary) -> serde_json::Value {
    serde_json::json!({
        "scenario": r.scenario,
        "controller": r.controller,
        "reached": r.reached,
        "collided": r.collided,
        "time_to_goal_s": r.time_to_goal_s,
        "path_length_m": r.path_length_m,
        "min_clearance_m": r.min_clearance_m,
        "cycles": r.cycles,
        "solve_ms": { "mean": r.solve_ms_mean, "median": r.solve_ms_median, "p95": r.solve_ms_p95, "max": r.solve_ms_max },
        "iterations_median": r.iterations_median,
        "fallbacks": r.fallbacks,
        "collisions": r.collisions,
        "final_position_m": r.final_position_m,
    })
}
