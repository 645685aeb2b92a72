//! `hilbench`: the bench's command line. `hilbench reproduce` runs the paper's three scenarios
//! with the standard and the multi-stage NMPC in paper mode, over real gRPC (plant, netem and
//! controller on loopback) or in process, and prints the paper's tables beside what this bench
//! measures. `hilbench run SCENARIO.toml` does the same for one scenario file.

use std::path::PathBuf;

use clap::{Parser, Subcommand, ValueEnum};
use hilbench::bench::{
    Outcome, Transport, default_out_dir, file_jobs, paper_jobs, run_all, run_table, write_cycle_logs,
    write_summary,
};
use hilbench::grpc::{EndpointArgs, Endpoints, TimeMode};
use hilbench::report;
use hilbench::scenario_file::{Mode, ScenarioFile};

#[derive(Parser, Debug)]
#[command(
    name = "hilbench",
    version,
    about = "Hardware-in-the-loop bench for MAV control over delayed networks"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Print nothing but errors (the summary and logs are still written; the exit code says
    /// whether a run collided).
    #[arg(long, global = true)]
    quiet: bool,
}

/// `--mode` of `hilbench run`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum ModeArg {
    Nmpc,
    Multistage,
    Both,
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
    /// Run one scenario file (TOML, see scenarios/) over gRPC, in lockstep or real time.
    Run {
        /// The scenario file.
        file: PathBuf,
        /// Controllers to run (default: the file's `run.modes`).
        #[arg(long, value_enum)]
        mode: Option<ModeArg>,
        /// Output directory for summary.json (default: runs/<unix time>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Print the summary as JSON on stdout instead of the table.
        #[arg(long)]
        json: bool,
        /// Run the closed loop in process (`mpc::run_closed_loop`) instead of over gRPC.
        #[arg(long, conflicts_with_all = ["plant", "netem", "controller", "time_mode"])]
        in_process: bool,
        /// How plant time moves (default: the file's `run.time_mode`).
        #[arg(long, value_enum)]
        time_mode: Option<TimeMode>,
        #[command(flatten)]
        services: EndpointArgs,
    },
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let outcome = match cli.command {
        Command::Reproduce { out, json, scenario, in_process, plant, netem, controller } => {
            let transport = if in_process {
                Transport::InProcess
            } else {
                Transport::Grpc(Endpoints { plant, netem, controller, ..Endpoints::default() })
            };
            reproduce(out, json, cli.quiet, &scenario, &transport)?
        }
        Command::Run { file, mode, out, json, in_process, time_mode, services } => {
            let transport = (!in_process).then_some((services, time_mode));
            run(&file, mode, out, json, cli.quiet, transport)?
        }
    };
    if outcome.any_collided() {
        // A collision is a result worth reporting, and scripts must see it.
        std::process::exit(2);
    }
    Ok(())
}

/// What both commands do the same way: run the jobs, write `summary.json` and the per-cycle
/// logs, and print the JSON summary when asked.
struct Executed {
    outcome: Outcome,
    summary: serde_json::Value,
    path: PathBuf,
    /// Print the human-readable report (neither `--json` nor `--quiet`).
    show: bool,
}

fn execute(
    jobs: &[hilbench::bench::Job],
    out: Option<PathBuf>,
    json: bool,
    quiet: bool,
    transport: &Transport,
) -> anyhow::Result<Executed> {
    let outcome = run_all(jobs, transport, !json && !quiet)?;
    let summary = outcome.summary_json();
    let dir = out.unwrap_or_else(default_out_dir);
    let path = write_summary(&dir, &summary)?;
    write_cycle_logs(&dir, &outcome)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    }
    Ok(Executed { outcome, summary, path, show: !json && !quiet })
}

fn reproduce(
    out: Option<PathBuf>,
    json: bool,
    quiet: bool,
    only: &[String],
    transport: &Transport,
) -> anyhow::Result<Outcome> {
    let jobs = paper_jobs(only)?;
    let Executed { outcome, summary, path, show } = execute(&jobs, out, json, quiet, transport)?;
    if !show {
        return Ok(outcome);
    }
    println!();
    println!(
        "Paper reproduction: SPEC.md paper mode (RK4 plant at 1 ms, Gamma(12, 0.015) round-trip delays, seed 42), lockstep, {}",
        transport.describe()
    );
    println!();
    print!("{}", report::tables(&outcome.runs));
    println!();
    println!("What reproduces");
    for v in report::verdicts(&outcome.runs) {
        println!("  - {v}");
    }
    println!();
    println!();
    print_time(&outcome, &summary);
    println!("Summary: {}", path.display());
    Ok(outcome)
}

fn run(
    file: &std::path::Path,
    mode: Option<ModeArg>,
    out: Option<PathBuf>,
    json: bool,
    quiet: bool,
    services: Option<(EndpointArgs, Option<TimeMode>)>,
) -> anyhow::Result<Outcome> {
    let spec = ScenarioFile::load(file)?;
    let transport = &match services {
        Some((args, time_mode)) => Transport::Grpc(args.endpoints(time_mode.unwrap_or(spec.run.time_mode))),
        None if spec.run.time_mode == TimeMode::RealTime => {
            anyhow::bail!("{}: real time needs the services (not --in-process)", file.display())
        }
        None => Transport::InProcess,
    };
    let modes = match mode {
        None => None,
        Some(ModeArg::Nmpc) => Some(vec![Mode::Nmpc]),
        Some(ModeArg::Multistage) => Some(vec![Mode::Multistage]),
        Some(ModeArg::Both) => Some(vec![Mode::Nmpc, Mode::Multistage]),
    };
    let jobs = file_jobs(&spec, modes.as_deref());
    let Executed { outcome, summary, path, show } = execute(&jobs, out, json, quiet, transport)?;
    if !show {
        return Ok(outcome);
    }
    println!();
    println!("{} ({}): {}, {}", spec.scenario.name, file.display(), outcome.time_mode, transport.describe());
    println!();
    print!("{}", run_table(&outcome.runs));
    println!();
    print_time(&outcome, &summary);
    println!("Summary: {}", path.display());
    Ok(outcome)
}

fn print_time(outcome: &Outcome, summary: &serde_json::Value) {
    let timing = &summary["timing"];
    let wall = outcome.wall_time_s;
    let solver = outcome.solver_s();
    if outcome.transport == "in-process" {
        println!("Time: {wall:.2} s wall, of which {solver:.2} s in the solver");
    } else {
        println!(
            "Time: {wall:.2} s wall; solver {solver:.2} s, gRPC loop (round trips, netem, plant RK4, telemetry) {:.2} s, service start {:.2} s, stop {:.2} s",
            timing["loop_overhead_s"].as_f64().unwrap_or(f64::NAN),
            timing["setup_s"].as_f64().unwrap_or(f64::NAN),
            timing["teardown_s"].as_f64().unwrap_or(f64::NAN),
        );
    }
}
