//! `hilbench`: the bench's command line. `hilbench reproduce` runs the paper's three scenarios
//! with the standard and the multi-stage NMPC in paper mode, over real gRPC (plant, netem and
//! controller on loopback) or in process, and prints the paper's tables beside what this bench
//! measures.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::{Parser, Subcommand};
use hilbench::grpc::{Endpoints, GrpcSettings, RunTiming, run_against};
use hilbench::report;
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
        /// Run the closed loop in process (`mpc::run_closed_loop`) instead of over gRPC.
        #[arg(long, conflicts_with_all = ["plant", "netem", "controller"])]
        in_process: bool,
        /// A running plant (HOST:PORT, lockstep) instead of one started here.
        #[arg(long)]
        plant: Option<String>,
        /// A running netem (HOST:PORT) instead of one started here; it gets each scenario's
        /// delay profiles through NetemControl.
        #[arg(long)]
        netem: Option<String>,
        /// A running controller (HOST:PORT), already pointed at the netem (or plant) it should
        /// fly; needs --plant or --netem to read the final state.
        #[arg(long)]
        controller: Option<String>,
    },
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Reproduce { out, json, scenario, in_process, plant, netem, controller } => {
            let endpoints = Endpoints { plant, netem, controller };
            reproduce(out, json, &scenario, in_process, &endpoints)
        }
    }
}

/// Where the time of a run went (gRPC runs only).
#[derive(Debug, Clone, serde::Serialize)]
struct TimedRun {
    scenario: String,
    controller: String,
    #[serde(flatten)]
    timing: RunTiming,
    loop_overhead_s: f64,
}

fn reproduce(
    out: Option<PathBuf>,
    json: bool,
    only: &[String],
    in_process: bool,
    endpoints: &Endpoints,
) -> anyhow::Result<()> {
    let started = Instant::now();
    for o in only {
        if !mav::Scenario::BUILT_IN.contains(&o.as_str()) {
            anyhow::bail!("--scenario {o:?}: unknown (known: {})", mav::Scenario::BUILT_IN.join(", "));
        }
    }
    let runtime = if in_process {
        None
    } else {
        Some(
            tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .enable_all()
                .build()
                .context("cannot start the tokio runtime")?,
        )
    };
    let mut runs: Vec<RunSummary> = Vec::new();
    let mut timings: Vec<TimedRun> = Vec::new();
    for name in mav::Scenario::BUILT_IN {
        if !only.is_empty() && !only.iter().any(|o| o == name) {
            continue;
        }
        let scenario = mav::Scenario::by_name(name)?;
        for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
            let run_started = Instant::now();
            let summary = match &runtime {
                None => {
                    run_closed_loop(&scenario, &ClosedLoopSettings::paper(mode))
                        .with_context(|| format!("{name} with {}", mode.name()))?
                        .0
                }
                Some(rt) => {
                    let run = rt
                        .block_on(run_against(&scenario, mode, &GrpcSettings::default(), endpoints))
                        .with_context(|| format!("{name} with {} over gRPC", mode.name()))?;
                    timings.push(TimedRun {
                        scenario: name.to_string(),
                        controller: mode.name().to_string(),
                        timing: run.timing,
                        loop_overhead_s: run.timing.loop_overhead_s(),
                    });
                    run.summary
                }
            };
            if !json {
                eprintln!(
                    "  {name} {:<11} done ({} cycles, {:.2} s)",
                    mode.name(),
                    summary.cycles,
                    run_started.elapsed().as_secs_f64()
                );
            }
            runs.push(summary);
        }
    }
    let wall_time_s = started.elapsed().as_secs_f64();
    let transport = if in_process { "in-process" } else { "grpc" };
    let solver_s: f64 = runs.iter().map(|r| r.solve_ms_mean * r.cycles as f64 * 1e-3).sum();
    let timing = serde_json::json!({
        "wall_time_s": wall_time_s,
        "solver_s": solver_s,
        "setup_s": timings.iter().map(|t| t.timing.setup_s).sum::<f64>(),
        "loop_overhead_s": timings.iter().map(|t| t.loop_overhead_s).sum::<f64>(),
        "teardown_s": timings.iter().map(|t| t.timing.teardown_s).sum::<f64>(),
        "runs": timings,
    });
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
        "transport": transport,
        "wall_time_s": wall_time_s,
        "timing": timing,
    });
    let path = dir.join("summary.json");
    std::fs::write(&path, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    if json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!();
        println!(
            "Paper reproduction: SPEC.md paper mode (RK4 plant at 1 ms, Gamma(12, 0.015) round-trip delays, seed 42), lockstep, {}",
            if in_process {
                "in process"
            } else if endpoints.is_local() {
                "over gRPC (plant, netem, controller on loopback)"
            } else {
                "over gRPC (given services)"
            }
        );
        println!();
        print!("{}", report::tables(&runs));
        println!();
        println!("What reproduces");
        for v in report::verdicts(&runs) {
            println!("  - {v}");
        }
        println!();
        println!();
        if in_process {
            println!("Time: {wall_time_s:.2} s wall, of which {solver_s:.2} s in the solver");
        } else {
            println!(
                "Time: {wall_time_s:.2} s wall; solver {solver_s:.2} s, gRPC loop (round trips, netem, plant RK4, telemetry) {:.2} s, service start {:.2} s, stop {:.2} s",
                timing["loop_overhead_s"].as_f64().unwrap_or(f64::NAN),
                timing["setup_s"].as_f64().unwrap_or(f64::NAN),
                timing["teardown_s"].as_f64().unwrap_or(f64::NAN),
            );
        }
        println!("Summary: {}", path.display());
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
