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
use hilbench::grpc::{EndpointArgs, Endpoints, TimeMode, TlsArgs};
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
    /// Do not write the runs' MCAP files (OUT/<scenario>-<controller>.mcap, for Foxglove).
    #[arg(long, global = true)]
    no_mcap: bool,
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
        #[command(flatten)]
        tls: TlsArgs,
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
        /// Fly run I of the file's [sweep] again, bit for bit (its delays drawn from the sweep's
        /// seed, which --seed sets, and I alone).
        #[arg(long, value_name = "I", conflicts_with_all = ["delay_trace", "keep_netem_profile"])]
        sweep_run: Option<u64>,
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
        #[command(flatten)]
        tls: TlsArgs,
        /// Serve the run live to Foxglove over its WebSocket protocol (the channels of the
        /// MCAP files) while it flies in real time; ADDR defaults to 127.0.0.1:8765.
        #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
        foxglove_ws: Option<std::net::SocketAddr>,
    },
    /// N lockstep runs of a scenario file, each under a delay process drawn from the file's
    /// [sweep] table; outcomes as distributions (sweep.json, runs.csv, report.md, plots).
    Sweep(SweepArgs),
    /// Make a CA and a certificate for each service (plant, netem, controller, gateway) and
    /// for hilbench, for mutual TLS (docs/tls.md); keys are written readable by their owner.
    Certs {
        /// Directory to write ca.pem, ca-key.pem, <name>.pem and <name>-key.pem into (files
        /// already there are never overwritten).
        #[arg(long)]
        out: PathBuf,
        /// A host name or IP address every certificate also names (repeat the flag); each names
        /// its service (plant, netem, ...), localhost, 127.0.0.1 and ::1 anyway.
        #[arg(long, value_name = "NAME")]
        san: Vec<String>,
    },
    /// Merge the output directories of a sweep's shards into the sweep.json of the whole.
    SweepMerge {
        /// The shards' output directories.
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
        /// Output directory of the merged sweep.
        #[arg(long)]
        out: PathBuf,
        /// Print sweep.json on stdout.
        #[arg(long)]
        json: bool,
    },
}

#[derive(clap::Args, Debug)]
struct SweepArgs {
    /// The scenario file, with a [sweep] table.
    file: PathBuf,
    /// Runs of the sweep (default: the file's `sweep.runs`).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    runs: Option<u64>,
    /// Runs flown at once (default: every core).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=1024))]
    jobs: Option<u64>,
    /// Seed of the draws (default: the file's `sweep.seed`, else `scenario.seed`).
    #[arg(long)]
    seed: Option<u64>,
    /// Output directory (default: runs/sweep-<unix time>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Controllers to fly each run with (default: the file's `run.modes`).
    #[arg(long, value_enum)]
    mode: Option<ModeArg>,
    /// Fly only the I-th of K disjoint slices of the runs (I from 0); merge the shards'
    /// directories with `hilbench sweep-merge`.
    #[arg(long, value_name = "I/K", value_parser = parse_shard)]
    shard: Option<(u64, u64)>,
    /// Fly each run over the services (plant, netem, controller on loopback) instead of in
    /// process: the same numbers, slower.
    #[arg(long, conflicts_with = "controller_cmd")]
    grpc: bool,
    /// With --grpc: the services' links over mutual TLS (as `hilbench run`'s).
    #[command(flatten)]
    tls: TlsArgs,
    /// Sweep your own controller instead of the bench's: a command line that speaks the Plant
    /// API as a client at $HILBENCH_PLANT_ADDR (as `hilbench run --controller-cmd`), started
    /// for each run, judged from the plant's truth (docs/external-controller.md).
    #[arg(long, value_name = "CMD", value_parser = command_line, conflicts_with = "mode")]
    controller_cmd: Option<String>,
    /// Shrink each failing run's delay trace to a smaller one that still fails
    /// (failures/<run>.csv).
    #[arg(long)]
    shrink: bool,
    /// A run that takes longer than this (wall clock) is a failure, and the sweep goes on
    /// (default: the file's `sweep.run_timeout_s`, else 300).
    #[arg(long, value_name = "S", value_parser = parse_timeout)]
    run_timeout_s: Option<f64>,
    /// Print sweep.json on stdout instead of the table.
    #[arg(long)]
    json: bool,
}

/// `--shard I/K`.
fn parse_shard(text: &str) -> Result<(u64, u64), String> {
    let (i, k) = text.split_once('/').ok_or("expected I/K, e.g. 0/4")?;
    let i: u64 = i.trim().parse().map_err(|_| format!("{i:?} is not a shard number"))?;
    let k: u64 = k.trim().parse().map_err(|_| format!("{k:?} is not a number of shards"))?;
    if k == 0 || i >= k {
        return Err(format!("shard {i} of {k}: I must be below K (shards 0 to K-1)"));
    }
    Ok((i, k))
}

/// `--run-timeout-s`.
fn parse_timeout(text: &str) -> Result<f64, String> {
    let s: f64 = text.parse().map_err(|_| format!("{text:?} is not a number of seconds"))?;
    if !(s.is_finite() && s > 0.0 && s <= 86_400.0) {
        return Err("must be in (0, 86400] s".into());
    }
    Ok(s)
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
    let opts = Options { quiet: cli.quiet, plots: !cli.no_plots, mcap: !cli.no_mcap, started };
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
            tls,
        } => {
            let transport = if in_process {
                anyhow::ensure!(!tls.given(), "--in-process has no links: the TLS flags need the services");
                Transport::InProcess
            } else {
                Transport::Grpc(Endpoints {
                    plant,
                    netem,
                    controller,
                    tls: tls.load()?.into(),
                    ..Endpoints::default()
                })
            };
            let overrides = Overrides {
                seed,
                delay_trace: None,
                continue_after_collision,
                sweep_run: None,
                foxglove_ws: None,
            };
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
            sweep_run,
            controller_cmd,
            stall_timeout_s,
            services,
            tls,
            foxglove_ws,
        } => {
            anyhow::ensure!(
                !tls.given() || (controller_cmd.is_none() && !in_process),
                "the TLS flags need the bench's services (not --in-process or --controller-cmd, whose links stay plaintext on loopback)"
            );
            let transport = match controller_cmd {
                Some(command) => RunTransport::External { command, time_mode, stall_timeout_s },
                None if in_process => RunTransport::InProcess,
                None => RunTransport::Services { endpoints: services, tls: tls.load()?.into(), time_mode },
            };
            let overrides = Overrides { seed, delay_trace, continue_after_collision, sweep_run, foxglove_ws };
            run(&file, mode, out, json, &opts, &overrides, transport)?
        }
        Command::Sweep(args) => sweep(args, &opts)?,
        Command::Certs { out, san } => {
            for path in hilbench::certs::write_dir(&out, &san)? {
                if !opts.quiet {
                    println!("{}", path.display());
                }
            }
            return Ok(());
        }
        Command::SweepMerge { dirs, out, json } => {
            let summary = hilbench::sweep::output::merge(&dirs, &out, opts.plots)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&summary)?);
            } else if !opts.quiet {
                print_sweep(&summary, &out);
            }
            return Ok(());
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
    /// Write each run's MCAP file.
    mcap: bool,
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
    // Timed for the summary (BENCHMARKS.md: its share of the wall time).
    let mcap_s = if opts.mcap {
        let writing = Instant::now();
        hilbench::foxglove_out::write_outcome(&dir, jobs, &outcome)?;
        Some(writing.elapsed().as_secs_f64())
    } else {
        None
    };
    if outcome.interrupted {
        let mut summary = outcome.summary_json();
        summary["timing"]["mcap_s"] = serde_json::json!(mcap_s);
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
        summary["timing"]["mcap_s"] = serde_json::json!(mcap_s);
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
    summary["timing"]["mcap_s"] = serde_json::json!(mcap_s);
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
    /// `--sweep-run`.
    sweep_run: Option<u64>,
    /// `--foxglove-ws`.
    foxglove_ws: Option<std::net::SocketAddr>,
}

/// How `hilbench run` flies the file (`time_mode` `None`: the file's).
enum RunTransport {
    InProcess,
    Services {
        endpoints: EndpointArgs,
        tls: std::sync::Arc<hilbench::grpc::BenchTls>,
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
    if let Some(index) = overrides.sweep_run {
        // The run as the sweep flies it: the scenario's own seed, delays drawn from the
        // sweep's seed (which --seed sets there) and the index.
        let table = spec
            .sweep
            .as_ref()
            .with_context(|| format!("--sweep-run: {} has no [sweep] table", file.display()))?;
        let seed = overrides.seed.or(table.seed).unwrap_or(spec.scenario.seed);
        let plan = hilbench::sweep::draw::plan(table, &spec.scenario, seed, index)
            .map_err(|e| anyhow::anyhow!("--sweep-run {index}: {e}"))?;
        spec.scenario = plan.scenario(&spec.scenario);
    } else if let Some(seed) = overrides.seed {
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
    if overrides.foxglove_ws.is_some() && !matches!(transport, RunTransport::Services { .. }) {
        anyhow::bail!(
            "--foxglove-ws needs the bench's services in real time (not --in-process or --controller-cmd)"
        );
    }
    let transport = &match transport {
        RunTransport::Services { endpoints: args, tls, time_mode } => {
            let mut endpoints = args.endpoints(time_mode.unwrap_or(spec.run.time_mode));
            endpoints.tls = tls;
            if let Some(addr) = overrides.foxglove_ws {
                if endpoints.time_mode != TimeMode::RealTime {
                    anyhow::bail!(
                        "--foxglove-ws needs --time-mode real-time (a lockstep run is over before a viewer connects; open its .mcap file instead)"
                    );
                }
                let live = hilbench::foxglove_out::Live::start(addr)?;
                if !opts.quiet {
                    eprintln!("Foxglove: serving the run live on ws://{}", live.addr());
                }
                endpoints.live = Some(live);
            }
            Transport::Grpc(endpoints)
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
    let mcap = if opts.mcap { format!(", MCAP files {}", secs("mcap_s")) } else { String::new() };
    println!("Time: {:.2} s wall in all; {runs}{plots}{mcap}", opts.started.elapsed().as_secs_f64());
}

/// The files a command wrote.
fn print_outputs(dir: &std::path::Path) {
    println!("Report: {}", dir.join("report.md").display());
    println!("Summary: {}", dir.join("summary.json").display());
}

/// `hilbench sweep`.
fn sweep(args: SweepArgs, opts: &Options) -> anyhow::Result<Outcome> {
    use hilbench::sweep::{Sweep, execute, output};
    let spec = ScenarioFile::load(&args.file)?;
    let table = spec.sweep.clone().with_context(|| {
        format!(
            "{}: no [sweep] table (the delay families to draw from; see docs/sweep.md)",
            args.file.display()
        )
    })?;
    let runs = args.runs.or(table.runs).with_context(|| {
        format!(
            "--runs: how many runs? (give --runs N, or `runs` in the [sweep] table of {})",
            args.file.display()
        )
    })?;
    let modes = match args.mode {
        // One flight per run for an external controller (the mode names no controller then).
        None if args.controller_cmd.is_some() => vec![mpc::ControllerMode::Multistage],
        None => spec.run.modes.iter().map(|m| hilbench::bench::controller_mode(*m)).collect(),
        Some(ModeArg::Nmpc) => vec![mpc::ControllerMode::Nmpc],
        Some(ModeArg::Multistage) => vec![mpc::ControllerMode::Multistage],
        Some(ModeArg::Both) => vec![mpc::ControllerMode::Nmpc, mpc::ControllerMode::Multistage],
    };
    anyhow::ensure!(
        spec.run.time_mode == TimeMode::Lockstep,
        "{}: a sweep flies in lockstep (run.time_mode is real-time)",
        args.file.display()
    );
    let jobs =
        args.jobs.map_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()), |j| j as usize);
    let sweep = Sweep {
        file: args.file.clone(),
        seed: args.seed.or(table.seed).unwrap_or(spec.scenario.seed),
        runs,
        modes,
        shard: args.shard,
        jobs,
        transport: match args.controller_cmd {
            Some(command) => Transport::External(hilbench::external::ExternalController {
                command,
                time_mode: TimeMode::Lockstep,
                settings: hilbench::external::ExternalSettings::default(),
            }),
            None if args.tls.given() && !args.grpc => {
                anyhow::bail!("the TLS flags need --grpc (a sweep flies in process otherwise)")
            }
            None if args.grpc => {
                Transport::Grpc(Endpoints { tls: args.tls.load()?.into(), ..Endpoints::default() })
            }
            None => Transport::InProcess,
        },
        run_timeout: std::time::Duration::from_secs_f64(
            args.run_timeout_s
                .or(table.run_timeout_s)
                .unwrap_or(hilbench_svc::sweep_table::DEFAULT_RUN_TIMEOUT_S),
        ),
        shrink: args.shrink,
        shrink_runs: table.shrink_runs.unwrap_or(hilbench_svc::sweep_table::DEFAULT_SHRINK_RUNS),
        scenario: spec.scenario,
        table,
    };
    let dir = args.out.unwrap_or_else(|| {
        let secs = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0);
        PathBuf::from("runs").join(format!("sweep-{secs}"))
    });
    // The output directory before the first run: a sweep that cannot write loses nothing.
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let show = !args.json && !opts.quiet;
    let items = (sweep.indices().end - sweep.indices().start) * sweep.modes.len() as u64;
    let bar = hilbench::progress::bar_with_eta(items, "runs", show);
    let result = execute(&sweep, &bar, show);
    bar.finish_and_clear();
    let summary = output::write(&dir, &sweep, &result, opts.plots)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else if show {
        print_sweep(&summary, &dir);
    }
    if result.interrupted {
        eprintln!(
            "interrupted: {} run(s) had finished; they are in {}",
            result.done.len(),
            dir.join("sweep.json").display()
        );
        std::process::exit(EXIT_INTERRUPTED);
    }
    std::process::exit(0);
}

/// The sweep's counts and distributions, per family, on stdout.
fn print_sweep(v: &serde_json::Value, dir: &std::path::Path) {
    let f = |x: &serde_json::Value| x.as_f64().map_or_else(|| "-".to_string(), |x| format!("{x:.3}"));
    println!();
    println!(
        "{} runs of {} ({}), seed {}: {} reached, {} collided ({} with the ground), {} missed, {} errors",
        v["runs"],
        v["scenario"].as_str().unwrap_or(""),
        v["file"].as_str().unwrap_or(""),
        v["seed"],
        v["reached"],
        v["collided"],
        v["collided_ground"],
        v["missed"],
        v["errors"]
    );
    println!();
    println!(
        "{:<16} {:>6} {:>8} {:>9} {:>7} {:>7} {:>22} {:>16}",
        "family",
        "runs",
        "reached",
        "collided",
        "missed",
        "errors",
        "clearance p1/p5/p50 m",
        "path p50/p95 m"
    );
    let families = v["family_order"].as_array().cloned().unwrap_or_default();
    for name in families.iter().filter_map(|n| n.as_str()) {
        let a = &v["families"][name];
        println!(
            "{:<16} {:>6} {:>8} {:>9} {:>7} {:>7} {:>22} {:>16}",
            name,
            a["runs"].to_string(),
            a["reached"].to_string(),
            a["collided"].to_string(),
            a["missed"].to_string(),
            a["errors"].to_string(),
            format!(
                "{}/{}/{}",
                f(&a["min_clearance_m"]["p1"]),
                f(&a["min_clearance_m"]["p5"]),
                f(&a["min_clearance_m"]["p50"])
            ),
            format!("{}/{}", f(&a["path_length_m"]["p50"]), f(&a["path_length_m"]["p95"])),
        );
    }
    let t = &v["timing"];
    if let (Some(wall), Some(rate)) = (t["wall_time_s"].as_f64(), t["runs_per_s"].as_f64()) {
        println!();
        println!(
            "Time: {wall:.1} s wall, {rate:.1} runs/s with {} jobs (solver {:.1} s of {:.1} s in runs)",
            t["jobs"],
            t["solver_s"].as_f64().unwrap_or(0.0),
            t["run_wall_s"].as_f64().unwrap_or(0.0)
        );
    }
    println!("Report: {}", dir.join("report.md").display());
    println!("Summary: {}", dir.join("sweep.json").display());
}
