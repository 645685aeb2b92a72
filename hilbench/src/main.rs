//! `hilbench`: the bench's command line. `hilbench reproduce` runs the paper's three scenarios
//! with the standard and the multi-stage NMPC in paper mode, over real gRPC (plant, netem and
//! controller on loopback) or in process, and prints the paper's tables beside what this bench
//! measures. `hilbench run SCENARIO.toml` does the same for one scenario file.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::builder::PossibleValuesParser;
use clap::{Parser, Subcommand, ValueEnum};
use hilbench::bench::{
    Outcome, Transport, default_out_dir, file_jobs, paper_jobs, run_all, run_table, write_cycle_logs,
    write_summary,
};
use hilbench::grpc::{EndpointArgs, Endpoints, TimeMode};
use hilbench::report;
use hilbench::report_md::{self, ReportText};
use hilbench::scenario_file::{Mode, ScenarioFile};
use mav::Scenario;

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
    /// Do not draw the plots (PNG and SVG under OUT/plots/).
    #[arg(long, global = true)]
    no_plots: bool,
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
        /// Only this scenario (repeat the flag for more; default: all three).
        #[arg(long, value_parser = PossibleValuesParser::new(Scenario::BUILT_IN))]
        scenario: Vec<String>,
        /// Seed of the delay process instead of the scenarios' own (42).
        #[arg(long)]
        seed: Option<u64>,
        /// Go on flying after the vehicle's first collision (lockstep); by default a run ends
        /// there, as a real flight does, and summary.json's `end_reason` is "collided".
        #[arg(long)]
        continue_after_collision: bool,
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
        /// How plant time moves (default: the file's `run.time_mode`, lockstep unless the file
        /// says otherwise: a bench run should be deterministic; real time exercises the
        /// services on the wall clock, as a vehicle would).
        #[arg(long, value_enum)]
        time_mode: Option<TimeMode>,
        /// Seed of the delay process instead of the file's `scenario.seed`.
        #[arg(long)]
        seed: Option<u64>,
        /// Replay this delay trace as the round trip instead of the file's [scenario.delays]:
        /// one delay in s per line (optional first line `delay_s`), cycle k's command takes
        /// line k, and a run that outlasts it stops with an error.
        #[arg(long, value_name = "TRACE.csv", conflicts_with = "keep_netem_profile")]
        delay_trace: Option<PathBuf>,
        /// Go on flying after the vehicle's first collision (lockstep); by default a run ends
        /// there, as a real flight does, and summary.json's `end_reason` is "collided".
        #[arg(long)]
        continue_after_collision: bool,
        /// Fly your own controller instead of the bench's: a command line (run with `sh -c`)
        /// that speaks the Plant API as a client at $HILBENCH_PLANT_ADDR (netem, in front of a
        /// plant started here), with $HILBENCH_SCENARIO and $HILBENCH_TIME_MODE; judged from the
        /// plant's truth (docs/external-controller.md).
        #[arg(
            long,
            value_name = "CMD",
            value_parser = command_line,
            conflicts_with_all = ["in_process", "mode", "plant", "netem", "controller"]
        )]
        controller_cmd: Option<String>,
        /// With --controller-cmd: fail the run when plant time has not moved for this long
        /// (wall time, s; in lockstep a controller that stopped calling Step, or is slow to
        /// start).
        #[arg(long, value_name = "S", requires = "controller_cmd", value_parser = positive_seconds)]
        stall_timeout_s: Option<f64>,
        #[command(flatten)]
        services: EndpointArgs,
    },
}

/// `--controller-cmd`: a command line with something to run.
fn command_line(s: &str) -> Result<String, String> {
    if s.trim().is_empty() {
        return Err("is empty: give the command that starts your controller".to_string());
    }
    Ok(s.to_string())
}

/// `--stall-timeout-s`: a finite duration above 0 and at most a day.
fn positive_seconds(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|e| format!("{s:?} is not a number of seconds: {e}"))?;
    if !(v > 0.0 && v <= 86_400.0) {
        return Err(format!("must be > 0 and at most 86400 s, got {s}"));
    }
    Ok(v)
}

/// Exit codes: 0 every run ended without a collision, 1 an error (anyhow's), 2 a usage error
/// (clap's), [`EXIT_COLLISION`] a run collided (a result scripts must be able to tell from both).
const EXIT_COLLISION: i32 = 3;
/// Ctrl-C (SIGINT), after what had finished was written (the shells' 128 + 2).
const EXIT_INTERRUPTED: i32 = 130;

fn main() -> anyhow::Result<()> {
    let started = Instant::now();
    let cli = Cli::parse();
    let opts = Options { quiet: cli.quiet, plots: !cli.no_plots, started };
    let outcome = match cli.command {
        Command::Reproduce {
            out,
            json,
            scenario,
            seed,
            continue_after_collision,
            in_process,
            plant,
            netem,
            controller,
        } => {
            let transport = if in_process {
                Transport::InProcess
            } else {
                Transport::Grpc(Endpoints { plant, netem, controller, ..Endpoints::default() })
            };
            let overrides = Overrides { seed, delay_trace: None, continue_after_collision };
            reproduce(out, json, &opts, &scenario, &overrides, &transport)?
        }
        Command::Run {
            file,
            mode,
            out,
            json,
            in_process,
            time_mode,
            seed,
            delay_trace,
            continue_after_collision,
            controller_cmd,
            stall_timeout_s,
            services,
        } => {
            let transport = match controller_cmd {
                Some(command) => RunTransport::External { command, time_mode, stall_timeout_s },
                None if in_process => RunTransport::InProcess,
                None => RunTransport::Services { endpoints: services, time_mode },
            };
            let overrides = Overrides { seed, delay_trace, continue_after_collision };
            run(&file, mode, out, json, &opts, &overrides, transport)?
        }
    };
    if outcome.any_collided() {
        // A collision is a result worth reporting, and scripts must see it.
        std::process::exit(EXIT_COLLISION);
    }
    Ok(())
}

/// Flags both commands share.
struct Options {
    quiet: bool,
    plots: bool,
    /// When the command started (for the total wall time).
    started: Instant,
}

/// What `report.md` says besides the runs (owned; see `ReportText`).
struct ReportParts {
    title: String,
    header: String,
    tables: Option<String>,
    verdicts: Vec<String>,
}

/// What both commands do the same way: run the jobs, draw the plots, write `summary.json`, the
/// per-cycle logs and `report.md`, and print the JSON summary when asked.
struct Executed {
    outcome: Outcome,
    summary: serde_json::Value,
    dir: PathBuf,
    /// Print the human-readable report (neither `--json` nor `--quiet`).
    show: bool,
}

fn execute(
    jobs: &[hilbench::bench::Job],
    out: Option<PathBuf>,
    json: bool,
    opts: &Options,
    transport: &Transport,
    report: impl Fn(&Outcome) -> ReportParts,
) -> anyhow::Result<Executed> {
    let show = !json && !opts.quiet;
    let outcome = run_all(jobs, transport, show)?;
    let dir = out.unwrap_or_else(default_out_dir);
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut plotting_s = None;
    hilbench::bench::write_scenarios(&dir, jobs)?;
    if outcome.interrupted {
        let summary = outcome.summary_json();
        write_summary(&dir, &summary)?;
        write_cycle_logs(&dir, &outcome)?;
        eprintln!(
            "interrupted: {} run(s) had finished; they are in {}",
            outcome.runs.len(),
            dir.join("summary.json").display()
        );
        std::process::exit(EXIT_INTERRUPTED);
    }
    if let Some(error) = &outcome.error {
        // What finished is kept: summary.json (with the error) and the per-cycle logs.
        let mut summary = outcome.summary_json();
        summary["timing"]["plotting_s"] = serde_json::json!(plotting_s);
        write_summary(&dir, &summary)?;
        write_cycle_logs(&dir, &outcome)?;
        if json {
            println!("{}", serde_json::to_string_pretty(&summary)?);
        }
        let failed = if outcome.failed_run_kept { ", and the failed run's cycles so far" } else { "" };
        anyhow::bail!(
            "{error}\n({} run(s) finished before it; they{failed} and the error are in {})",
            outcome.runs.len() - usize::from(outcome.failed_run_kept),
            dir.join("summary.json").display()
        );
    }
    if opts.plots {
        let plotting = Instant::now();
        let bar = hilbench::progress::bar(1, "plot sets", show);
        bar.set_message("drawing the plots");
        hilbench::plots::write_outcome(&dir, jobs, &outcome)?;
        bar.finish_and_clear();
        plotting_s = Some(plotting.elapsed().as_secs_f64());
    }
    let mut summary = outcome.summary_json();
    summary["timing"]["plotting_s"] = serde_json::json!(plotting_s);
    write_summary(&dir, &summary)?;
    write_cycle_logs(&dir, &outcome)?;
    let parts = report(&outcome);
    let text = ReportText {
        title: &parts.title,
        header: &parts.header,
        tables: parts.tables.as_deref(),
        verdicts: &parts.verdicts,
    };
    let facts: Vec<_> = outcome.runs.iter().map(hilbench::plots::RunFacts::from).collect();
    report_md::write(&dir, &text, &facts, outcome.transport, &summary)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    }
    Ok(Executed { outcome, summary, dir, show })
}

fn reproduce(
    out: Option<PathBuf>,
    json: bool,
    opts: &Options,
    only: &[String],
    overrides: &Overrides,
    transport: &Transport,
) -> anyhow::Result<Outcome> {
    let seed = overrides.seed;
    let mut jobs = paper_jobs(only)?;
    for (scenario, _) in &mut jobs {
        scenario.seed = seed.unwrap_or(scenario.seed);
        scenario.continue_after_collision = overrides.continue_after_collision;
    }
    let header = format!(
        "Paper reproduction: docs/spec.md paper mode (RK4 plant at 1 ms, Gamma(12, 0.015) round-trip delays, seed {}), lockstep, {}",
        seed.unwrap_or(Scenario::paper_1().seed),
        transport.describe()
    );
    let Executed { outcome, summary, dir, show } =
        execute(&jobs, out, json, opts, transport, |o| ReportParts {
            title: "Paper reproduction".to_string(),
            header: header.clone(),
            tables: Some(report::tables(&o.runs)),
            verdicts: report::verdicts(&o.runs),
        })?;
    if !show {
        return Ok(outcome);
    }
    println!();
    println!("{header}");
    println!();
    print!("{}", report::tables(&outcome.runs));
    println!();
    println!("What reproduces");
    for v in report::verdicts(&outcome.runs) {
        println!("  - {v}");
    }
    println!();
    println!();
    print_time(&summary, opts);
    print_outputs(&dir);
    Ok(outcome)
}

/// What `hilbench run`'s flags change in the file's scenario.
struct Overrides {
    /// `--seed`.
    seed: Option<u64>,
    /// `--delay-trace`.
    delay_trace: Option<PathBuf>,
    /// `--continue-after-collision`.
    continue_after_collision: bool,
}

/// How `hilbench run` flies the file (`time_mode` `None`: the file's).
enum RunTransport {
    InProcess,
    Services {
        endpoints: EndpointArgs,
        time_mode: Option<TimeMode>,
    },
    /// `--controller-cmd` (and `--stall-timeout-s`).
    External {
        command: String,
        time_mode: Option<TimeMode>,
        stall_timeout_s: Option<f64>,
    },
}

fn run(
    file: &std::path::Path,
    mode: Option<ModeArg>,
    out: Option<PathBuf>,
    json: bool,
    opts: &Options,
    overrides: &Overrides,
    transport: RunTransport,
) -> anyhow::Result<Outcome> {
    let mut spec = ScenarioFile::load(file)?;
    if let Some(seed) = overrides.seed {
        spec.scenario.seed = seed;
    }
    spec.scenario.continue_after_collision |= overrides.continue_after_collision;
    if let Some(trace) = &overrides.delay_trace {
        let delays =
            hilbench::scenario_file::read_trace(trace).map_err(|e| anyhow::anyhow!("--delay-trace: {e}"))?;
        let name = trace.display().to_string();
        spec.scenario.delays = Some(delay::DelaysTable::trace(&name, delays, false));
        spec.scenario.validate().map_err(|e| anyhow::anyhow!("--delay-trace {name}: {e}"))?;
    }
    let transport = &match transport {
        RunTransport::Services { endpoints, time_mode } => {
            Transport::Grpc(endpoints.endpoints(time_mode.unwrap_or(spec.run.time_mode)))
        }
        RunTransport::External { command, time_mode, stall_timeout_s } => {
            let mut settings = hilbench::external::ExternalSettings::default();
            if let Some(s) = stall_timeout_s {
                settings.stall_timeout = std::time::Duration::from_secs_f64(s);
            }
            Transport::External(hilbench::external::ExternalController {
                command,
                time_mode: time_mode.unwrap_or(spec.run.time_mode),
                settings,
            })
        }
        RunTransport::InProcess if spec.run.time_mode == TimeMode::RealTime => {
            anyhow::bail!("{}: real time needs the services (not --in-process)", file.display())
        }
        RunTransport::InProcess => Transport::InProcess,
    };
    let modes = match mode {
        None => None,
        Some(ModeArg::Nmpc) => Some(vec![Mode::Nmpc]),
        Some(ModeArg::Multistage) => Some(vec![Mode::Multistage]),
        Some(ModeArg::Both) => Some(vec![Mode::Nmpc, Mode::Multistage]),
    };
    let jobs = match transport {
        // One run of the file's scenario; the mode of the job is not used.
        Transport::External(_) => vec![(spec.scenario.clone(), mpc::ControllerMode::Multistage)],
        _ => file_jobs(&spec, modes.as_deref()),
    };
    let header = |o: &Outcome| {
        format!("{} ({}): {}, {}", spec.scenario.name, file.display(), o.time_mode, transport.describe())
    };
    let Executed { outcome, summary, dir, show } =
        execute(&jobs, out, json, opts, transport, |o| ReportParts {
            title: format!("hilbench run {}", file.display()),
            header: header(o),
            tables: None,
            verdicts: Vec::new(),
        })?;
    if !show {
        return Ok(outcome);
    }
    println!();
    println!("{}", header(&outcome));
    println!();
    print!("{}", run_table(&outcome.runs));
    println!();
    print_time(&summary, opts);
    print_outputs(&dir);
    Ok(outcome)
}

/// Where the wall time went: the runs (solver, gRPC, services), the plots, and the command.
fn print_time(summary: &serde_json::Value, opts: &Options) {
    let timing = &summary["timing"];
    let secs = |key: &str| timing[key].as_f64().map_or_else(|| "-".to_string(), |s| format!("{s:.2} s"));
    let runs = if summary["transport"] == "grpc" {
        format!(
            "runs {} (solver {}, gRPC loop: round trips, netem, plant RK4, telemetry {}, service start {}, stop {})",
            secs("wall_time_s"),
            secs("solver_s"),
            secs("loop_overhead_s"),
            secs("setup_s"),
            secs("teardown_s"),
        )
    } else {
        format!("runs {} (solver {})", secs("wall_time_s"), secs("solver_s"))
    };
    let plots = if opts.plots { format!(", plotting {}", secs("plotting_s")) } else { String::new() };
    println!("Time: {:.2} s wall in all; {runs}{plots}", opts.started.elapsed().as_secs_f64());
}

/// The files a command wrote.
fn print_outputs(dir: &std::path::Path) {
    println!("Report: {}", dir.join("report.md").display());
    println!("Summary: {}", dir.join("summary.json").display());
}
