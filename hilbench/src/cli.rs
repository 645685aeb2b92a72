//! The command line: clap's types, parsed and checked here, and nothing else (the work is in
//! `commands`). Every command that reaches services takes the same [`EndpointArgs`] and
//! [`TlsArgs`].

use std::path::PathBuf;

use clap::builder::PossibleValuesParser;
use clap::{Parser, Subcommand, ValueEnum};
use mav::{ControllerMode, Scenario, TimeMode};

#[derive(Parser, Debug)]
#[command(
    name = "hilbench",
    version,
    about = "Hardware-in-the-loop bench for MAV control over delayed networks"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
    /// Print nothing but errors (every file is written as without it, and the exit code is
    /// the same).
    #[arg(long, global = true)]
    pub quiet: bool,
    /// Do not draw the plots (PNG and SVG under OUT/plots/).
    #[arg(long, global = true)]
    pub no_plots: bool,
}

impl Cli {
    /// Whether the command writes its runs' MCAP files (only `reproduce` and `run` write any).
    pub fn mcap(&self) -> bool {
        match &self.command {
            Command::Reproduce(a) => !a.no_mcap,
            Command::Run(a) => !a.no_mcap,
            _ => false,
        }
    }
}

/// `--mode`: the bench's controllers to fly.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ModeArg {
    Nmpc,
    Multistage,
    Both,
}

impl ModeArg {
    /// The controllers, in the order they fly.
    pub fn modes(self) -> Vec<ControllerMode> {
        match self {
            ModeArg::Nmpc => vec![ControllerMode::Nmpc],
            ModeArg::Multistage => vec![ControllerMode::Multistage],
            ModeArg::Both => vec![ControllerMode::Nmpc, ControllerMode::Multistage],
        }
    }
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Reproduce the paper: paper-1..3 with NMPC and multi-stage NMPC, tables side by side.
    Reproduce(ReproduceArgs),
    /// Run one scenario file (TOML, see scenarios/) over gRPC, in lockstep or real time.
    Run(RunArgs),
    /// N lockstep runs of a scenario file, each under a delay process drawn from the file's
    /// [sweep] table; outcomes as distributions (sweep.json, runs.csv, report.md, plots).
    Sweep(SweepArgs),
    /// Make a CA and a certificate for each service (plant, netem, controller, gateway) and
    /// for hilbench, for mutual TLS (docs/tls.md); keys are written readable by their owner.
    Certs(CertsArgs),
    /// Merge the output directories of a sweep's shards into the sweep.json of the whole.
    SweepMerge(SweepMergeArgs),
    /// A real link's delays: import them (ping, irtt, a CSV column), look at them, fit them
    /// (docs/links.md).
    Trace(TraceArgs),
    /// Search the delays of a scenario file's [falsify] spaces for a run that fails its
    /// property (a collision, a missed goal, a clearance below X) with CMA-ES, or random
    /// search as the baseline; the worst run's trace shrunk and replayable (docs/falsify.md).
    Falsify(FalsifyArgs),
}

/// `--method`: how a search picks its runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// CMA-ES with restarts.
    Cmaes,
    /// Uniform random points of the same space: the baseline.
    Random,
}

impl MethodArg {
    pub fn method(self) -> falsify::Method {
        match self {
            MethodArg::Cmaes => falsify::Method::Cmaes,
            MethodArg::Random => falsify::Method::Random,
        }
    }
}

// The flags of `hilbench falsify`.
#[derive(clap::Args, Debug)]
pub struct FalsifyArgs {
    /// The scenario file, with a [falsify] table (and the [sweep] families it names).
    pub file: PathBuf,
    /// Runs per search (default: the file's `falsify.budget`, else 300).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=falsify::table::MAX_BUDGET))]
    pub budget: Option<u64>,
    /// Methods, each a search of every space with the same budget and seed (comma-separated;
    /// `cmaes,random` draws the optimiser beside its baseline; default: the file's
    /// `falsify.method`).
    #[arg(long, value_enum, value_delimiter = ',')]
    pub method: Vec<MethodArg>,
    /// Search only these spaces: a [sweep] family's name, or `signal` (repeat or
    /// comma-separate; default: every space of the [falsify] table).
    #[arg(long, value_name = "NAME", value_delimiter = ',')]
    pub space: Vec<String>,
    /// Seed of the searches and of the families' delay processes (default: the file's
    /// `falsify.seed`, else `scenario.seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Runs flown at once (default: every core).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=1024))]
    pub jobs: Option<u64>,
    /// The bench's controller to fly (default: the first of the file's `run.modes`).
    #[arg(long, value_enum)]
    pub mode: Option<ModeArg>,
    /// Search for your own controller's failures: a command line that speaks the Plant API as
    /// a client at $HILBENCH_PLANT_ADDR (as `hilbench run --controller-cmd`), started for each
    /// run (docs/external-controller.md).
    #[arg(long, value_name = "CMD", value_parser = command_line, conflicts_with_all = ["mode", "grpc"])]
    pub controller_cmd: Option<String>,
    /// Fly each run over the services (plant, netem, controller on loopback) instead of in
    /// process: the same numbers, slower.
    #[arg(long)]
    pub grpc: bool,
    /// With --grpc: the services' links over mutual TLS.
    #[command(flatten)]
    pub tls: TlsArgs,
    /// CMA-ES first flies N random points (random search's first N, for the same seed) and
    /// starts at the best of them (default: the file's `falsify.warmup`, else 0).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(0..=1_000_000))]
    pub warmup: Option<u64>,
    /// Search on after the first failure, to the budget (a lower score, a worse failure).
    #[arg(long)]
    pub whole_budget: bool,
    /// Reruns to shrink the worst failing run's trace (default: the file's
    /// `sweep.shrink_runs`, else 150).
    #[arg(long, value_name = "N", conflicts_with = "no_shrink")]
    pub shrink_runs: Option<u64>,
    /// Write the worst run's trace as it flew, unshrunk.
    #[arg(long)]
    pub no_shrink: bool,
    /// A run that takes longer than this (wall clock) is scored as the worst, and the search
    /// goes on (default: the file's `sweep.run_timeout_s`, else 300).
    #[arg(long, value_name = "S", value_parser = seconds)]
    pub run_timeout_s: Option<f64>,
    /// Output directory (default: runs/falsify-<unix time>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// When --out holds this falsification, killed before it finished, fly only the runs it
    /// lacks (the same file and flags; refused, naming what differs, when they are not);
    /// otherwise start it as without --resume.
    #[arg(long, requires = "out")]
    pub resume: bool,
    /// Print falsify.json on stdout instead of the table.
    #[arg(long)]
    pub json: bool,
}

// The flags of `hilbench reproduce`.
#[derive(clap::Args, Debug)]
pub struct ReproduceArgs {
    /// Output directory for summary.json (default: runs/<unix time>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print the summary as JSON on stdout instead of the tables.
    #[arg(long)]
    pub json: bool,
    /// Do not write the runs' MCAP files (OUT/<scenario>-<controller>.mcap, for Foxglove).
    #[arg(long)]
    pub no_mcap: bool,
    /// Only this scenario (repeat the flag for more; default: all three).
    #[arg(long, value_parser = PossibleValuesParser::new(Scenario::BUILT_IN))]
    pub scenario: Vec<String>,
    /// Seed of the delay process instead of the scenarios' own (42).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Go on flying after the vehicle's first collision (lockstep); by default a run ends
    /// there, as a real flight does, and summary.json's `end_reason` is "collided".
    #[arg(long)]
    pub continue_after_collision: bool,
    /// Run the closed loop in process (`mpc::run_closed_loop`) instead of over gRPC.
    #[arg(long, conflicts_with_all = ["plant", "netem", "controller"])]
    pub in_process: bool,
    #[command(flatten)]
    pub services: EndpointArgs,
    #[command(flatten)]
    pub tls: TlsArgs,
}

// The flags of `hilbench run`.
#[derive(clap::Args, Debug)]
pub struct RunArgs {
    /// The scenario file.
    pub file: PathBuf,
    /// Controllers to run (default: the file's `run.modes`).
    #[arg(long, value_enum)]
    pub mode: Option<ModeArg>,
    /// Output directory for summary.json (default: runs/<unix time>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print the summary as JSON on stdout instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Do not write the runs' MCAP files (OUT/<scenario>-<controller>.mcap, for Foxglove).
    #[arg(long)]
    pub no_mcap: bool,
    /// Run the closed loop in process (`mpc::run_closed_loop`) instead of over gRPC.
    #[arg(long, conflicts_with_all = ["plant", "netem", "controller", "time_mode"])]
    pub in_process: bool,
    /// How plant time moves (default: the file's `run.time_mode`, lockstep unless the file
    /// says otherwise: a bench run should be deterministic; real time exercises the
    /// services on the wall clock, as a vehicle would).
    #[arg(long, value_parser = hilbench_svc::args::time_mode())]
    pub time_mode: Option<TimeMode>,
    /// Seed of the delay process instead of the file's `scenario.seed`.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Replay this delay trace as the round trip instead of the file's [scenario.delays]:
    /// one delay in s per line (optional first line `delay_s`), cycle k's command takes
    /// line k, and a run that outlasts it stops with an error.
    #[arg(long, value_name = "TRACE.csv", conflicts_with = "keep_netem_profile")]
    pub delay_trace: Option<PathBuf>,
    /// Go on flying after the vehicle's first collision (lockstep); by default a run ends
    /// there, as a real flight does, and summary.json's `end_reason` is "collided".
    #[arg(long)]
    pub continue_after_collision: bool,
    /// Fly run I of the file's [sweep] again, bit for bit (its delays drawn from the sweep's
    /// seed, which --seed sets, and I alone).
    #[arg(long, value_name = "I", conflicts_with_all = ["delay_trace", "keep_netem_profile"])]
    pub sweep_run: Option<u64>,
    /// Fly your own controller instead of the bench's: a command line (run with `sh -c`)
    /// that speaks the Plant API as a client at $HILBENCH_PLANT_ADDR (netem, in front of a
    /// plant started here, or of --plant: a running plant or a vehicle's gateway), with
    /// $HILBENCH_SCENARIO and $HILBENCH_TIME_MODE; judged from the plant's truth (what the
    /// gateway reports, for a vehicle) (docs/external-controller.md).
    #[arg(
        long,
        value_name = "CMD",
        value_parser = command_line,
        conflicts_with_all = ["in_process", "mode", "netem", "controller"]
    )]
    pub controller_cmd: Option<String>,
    /// With --controller-cmd: fail the run when plant time has not moved for this long
    /// (wall time, s; in lockstep a controller that stopped calling Step, or is slow to
    /// start).
    #[arg(long, value_name = "S", requires = "controller_cmd", value_parser = seconds)]
    pub stall_timeout_s: Option<f64>,
    #[command(flatten)]
    pub services: EndpointArgs,
    #[command(flatten)]
    pub tls: TlsArgs,
    /// Serve the run live to Foxglove over its WebSocket protocol (the channels of the
    /// MCAP files) while it flies in real time; ADDR defaults to 127.0.0.1:8765.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
    pub foxglove_ws: Option<std::net::SocketAddr>,
}

// The flags of `hilbench trace`.
#[derive(clap::Args, Debug)]
pub struct TraceArgs {
    #[command(subcommand)]
    pub command: TraceCommand,
}

#[derive(Subcommand, Debug)]
pub enum TraceCommand {
    /// Read a measurement of a link into a trace file: one delay in s per line, `lost` for a
    /// lost probe, the provenance in comment lines.
    Import {
        /// The measurement: ping's output, irtt's JSON (`irtt client -o`), or a CSV.
        file: PathBuf,
        /// What FILE is.
        #[arg(long, value_parser = ["ping", "irtt", "csv"])]
        format: String,
        /// The trace file to write.
        #[arg(long)]
        out: PathBuf,
        /// csv: the column, by its header name (default: the only column).
        #[arg(long)]
        column: Option<String>,
        /// csv: the values' unit (default: the column name's suffix, e.g. rtt_ms, else s).
        #[arg(long, value_parser = ["s", "ms", "us"])]
        unit: Option<String>,
        /// Skip a bad line and count it, instead of stopping there with its number.
        #[arg(long)]
        skip_bad: bool,
        /// Probes per second, written in the trace's provenance (ping -D's stamps and irtt give
        /// it; a CSV or a plain ping log does not).
        #[arg(long, value_name = "HZ", value_parser = rate_hz)]
        rate_hz: Option<f64>,
    },
    /// Record a live link: probes at a rate to an echo on the far side (`hilbench trace echo`,
    /// or any UDP echo), the round trip of each into a trace file, a probe without a reply as
    /// `lost`, the provenance in comment lines; a progress line every 5 s; Ctrl-C writes what
    /// was recorded. Against `trace echo`, --out-directions writes the two one-way delays too.
    Record {
        /// The echo, HOST:PORT (UDP).
        #[arg(long, value_name = "HOST:PORT")]
        target: String,
        /// Probes per second (the controller's rate or more: 20 for the paper's 50 ms).
        #[arg(long, value_name = "HZ", default_value_t = 50.0, value_parser = rate_hz)]
        rate_hz: f64,
        /// How long to record, s.
        #[arg(long, value_name = "S", default_value_t = 300.0, value_parser = seconds)]
        duration_s: f64,
        /// The trace file to write: one round trip in s per probe, `lost` for a lost one.
        #[arg(long)]
        out: PathBuf,
        /// Also write the one-way delays as PREFIX-up.csv (here to the echo) and
        /// PREFIX-down.csv (back), the clocks' offset estimated from the probes with the
        /// shortest round trips (the far side must be `hilbench trace echo`).
        #[arg(long, value_name = "PREFIX")]
        out_directions: Option<PathBuf>,
        /// Bytes of each probe (the UDP payload; the echo answers with as many).
        #[arg(long, value_name = "N", default_value_t = 64,
              value_parser = clap::value_parser!(u64).range(40..=1472))]
        probe_bytes: u64,
        /// A probe with no reply within this long is lost, s.
        #[arg(long, value_name = "S", default_value_t = 2.0, value_parser = seconds)]
        timeout_s: f64,
    },
    /// Answer `trace record`'s probes until Ctrl-C: the far side of a recording (e.g. on the
    /// vehicle's companion computer). It answers only probes, each with as many bytes, and
    /// stamps its receive and send times so that the recorder can split the round trip.
    Echo {
        /// Address to listen on, HOST:PORT (UDP; 0.0.0.0:PORT for every interface).
        #[arg(long, value_name = "HOST:PORT")]
        listen: String,
    },
    /// Count, losses, percentiles, the share above a threshold, autocorrelation, spike runs.
    Stats {
        /// A trace file.
        file: PathBuf,
        /// The share of delays above this, s (e.g. the scenario tree's largest sampling time).
        #[arg(long, value_name = "S", value_parser = seconds)]
        threshold_s: Option<f64>,
        /// Print the statistics as JSON.
        #[arg(long)]
        json: bool,
        /// Draw the time series, the histogram and the ECDF into DIR (PNG and SVG).
        #[arg(long, value_name = "DIR")]
        plot: Option<PathBuf>,
    },
    /// Fit Gamma, lognormal, Pareto, Weibull and a two-state regime by maximum likelihood,
    /// ranked by AIC and KS distance, with 95 % intervals; prints the best law's
    /// [scenario.delays] table and a [[sweep.families]] table around it.
    Fit {
        /// A trace file.
        file: PathBuf,
        /// Seed of the bootstrap (the same file and seed give the same numbers).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Print the fits as JSON (every candidate's parameters with their intervals, AIC and KS
        /// distance, best first; the ranking by KS; the loss share) instead of the tables.
        #[arg(long)]
        json: bool,
        /// Draw the data with the fitted densities into DIR (PNG and SVG).
        #[arg(long, value_name = "DIR")]
        plot: Option<PathBuf>,
        /// Widen the [[sweep.families]] ranges to hold at least a factor F either side of each
        /// estimate (a lognormal's level e^mu too), for links like this one on a worse or
        /// better day: the 95 % intervals alone are tiny on a long recording. 1 to 100.
        #[arg(long, value_name = "F", value_parser = widening)]
        widen: Option<f64>,
    },
}

// The flags of `hilbench certs`.
#[derive(clap::Args, Debug)]
pub struct CertsArgs {
    /// Directory to write ca.pem, ca-key.pem, <name>.pem and <name>-key.pem into (files
    /// already there are never overwritten).
    #[arg(long)]
    pub out: PathBuf,
    /// A host name or IP address every certificate also names (repeat the flag); each names
    /// its service (plant, netem, ...), localhost, 127.0.0.1 and ::1 anyway.
    #[arg(long, value_name = "NAME", value_parser = san_name)]
    pub san: Vec<String>,
    /// How long the CA and the certificates are valid, days from now (they are valid from an
    /// hour ago).
    #[arg(long, value_name = "N", default_value_t = DEFAULT_DAYS,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(MAX_DAYS)))]
    pub days: u32,
}

// The flags of `hilbench sweep-merge`.
#[derive(clap::Args, Debug)]
pub struct SweepMergeArgs {
    /// The shards' output directories.
    #[arg(required = true)]
    pub dirs: Vec<PathBuf>,
    /// Output directory of the merged sweep.
    #[arg(long)]
    pub out: PathBuf,
    /// Print sweep.json on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args, Debug)]
pub struct SweepArgs {
    /// The scenario file, with a [sweep] table.
    pub file: PathBuf,
    /// Runs of the sweep (default: the file's `sweep.runs`).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub runs: Option<u64>,
    /// Runs flown at once (default: every core).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=1024))]
    pub jobs: Option<u64>,
    /// Seed of the draws (default: the file's `sweep.seed`, else `scenario.seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Output directory, new or empty (default: runs/sweep-<unix time>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// When --out holds this sweep, killed before it finished, fly only the runs it lacks (the
    /// same file and flags; refused, naming what differs, when they are not); otherwise start
    /// it as without --resume (a scheduler's retry of a task is the same command line).
    #[arg(long, requires = "out")]
    pub resume: bool,
    /// Controllers to fly each run with (default: the file's `run.modes`).
    #[arg(long, value_enum)]
    pub mode: Option<ModeArg>,
    /// Fly only the I-th of K disjoint slices of the runs (I from 0); merge the shards'
    /// directories with `hilbench sweep-merge`. `auto`: the shard of a Slurm array task
    /// (SLURM_ARRAY_TASK_ID, SLURM_ARRAY_TASK_COUNT or _MIN/_MAX) or of a Kubernetes Indexed
    /// Job's pod (JOB_COMPLETION_INDEX, with HILBENCH_SHARD_COUNT or `auto/K`).
    #[arg(long, value_name = "I/K|auto|auto/K", value_parser = shard_arg)]
    pub shard: Option<ShardArg>,
    /// Fly each run over the services (plant, netem, controller on loopback) instead of in
    /// process: the same numbers, slower.
    #[arg(long, conflicts_with = "controller_cmd")]
    pub grpc: bool,
    /// With --grpc: the services' links over mutual TLS (as `hilbench run`'s).
    #[command(flatten)]
    pub tls: TlsArgs,
    /// Sweep your own controller instead of the bench's: a command line that speaks the Plant
    /// API as a client at $HILBENCH_PLANT_ADDR (as `hilbench run --controller-cmd`), started
    /// for each run, judged from the plant's truth (docs/external-controller.md).
    #[arg(long, value_name = "CMD", value_parser = command_line, conflicts_with = "mode")]
    pub controller_cmd: Option<String>,
    /// After the runs, shrink each failing run's delay trace to a smaller one that still fails
    /// (failures/<run>.csv); says first what it may cost.
    #[arg(long)]
    pub shrink: bool,
    /// Reruns one failure's shrinking may spend (default: the file's `sweep.shrink_runs`,
    /// else 150).
    #[arg(long, value_name = "N", requires = "shrink")]
    pub shrink_runs: Option<u64>,
    /// Reruns the shrinking of all the failures may spend, shared out evenly in run order
    /// (default: the file's `sweep.shrink_total_runs`, else 1500).
    #[arg(long, value_name = "N", requires = "shrink")]
    pub shrink_total_runs: Option<u64>,
    /// Wall time the shrinking of all the failures may take, s: no rerun starts after it, and
    /// each failure keeps what it had shrunk (default: no limit but the reruns').
    #[arg(long, value_name = "S", requires = "shrink", value_parser = seconds)]
    pub shrink_wall_s: Option<f64>,
    /// A run that takes longer than this (wall clock) is a failure, and the sweep goes on
    /// (default: the file's `sweep.run_timeout_s`, else 300).
    #[arg(long, value_name = "S", value_parser = seconds)]
    pub run_timeout_s: Option<f64>,
    /// Keep drawing runs (0, 1, 2, ...: run i is still run i) until the 95 % Clopper-Pearson
    /// upper bound on the failure probability (a collision or a missed goal) is below P for
    /// every controller, or a run fails, or --runs runs have flown (default 100000, not the
    /// file's sweep.runs); sweep.json's until_bound says which and how many runs it took.
    #[arg(long, value_name = "P", value_parser = probability, conflicts_with = "shard")]
    pub until_bound: Option<f64>,
    /// With --until-bound: the bound must fall below P for each family the sweep draws, on
    /// its own runs (every controller too), not for the families pooled: "my link".
    #[arg(long, requires = "until_bound")]
    pub per_family: bool,
    /// Print sweep.json on stdout instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// Default validity of the certificates, days (`--days`).
pub const DEFAULT_DAYS: u32 = 365;
/// Longest validity `--days` may ask for, days (ten years).
pub const MAX_DAYS: u32 = 3650;

/// A name `--san` may add: an IP address, or a DNS name (labels of letters, digits and `-`,
/// separated by dots, a leading `*.` allowed, at most 253 characters). An empty name, or one
/// with a space, would be written into every certificate and match nothing.
pub fn san_name(name: &str) -> Result<String, String> {
    if name.parse::<std::net::IpAddr>().is_ok() {
        return Ok(name.to_string());
    }
    let host = name.strip_prefix("*.").unwrap_or(name);
    let label_ok = |l: &str| {
        (1..=63).contains(&l.len())
            && l.chars().all(|c| c.is_ascii_alphanumeric() || c == '-')
            && !l.starts_with('-')
            && !l.ends_with('-')
    };
    // A last label of digits only is no host name (RFC 1123, 2.1): `1.2.3.4.5` is a mistyped
    // address, not a name.
    let numeric_tld = host.rsplit('.').next().is_some_and(|l| l.chars().all(|c| c.is_ascii_digit()));
    if name.len() > 253 || host.is_empty() || !host.split('.').all(label_ok) || numeric_tld {
        return Err(format!(
            "{name:?} is neither an IP address nor a DNS name (letters, digits and `-` between dots, \
             not all digits at the end; `*.` may lead)"
        ));
    }
    Ok(name.to_string())
}

/// `--controller-cmd`: a command line with something to run.
fn command_line(s: &str) -> Result<String, String> {
    if s.trim().is_empty() {
        return Err("is empty: give the command that starts your controller".to_string());
    }
    Ok(s.to_string())
}

/// A duration flag (`--run-timeout-s`, `--stall-timeout-s`): finite, above 0 and at most a day.
fn seconds(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("{s:?} is not a number of seconds"))?;
    if !(v.is_finite() && v > 0.0 && v <= 86_400.0) {
        return Err(format!("must be in (0, 86400] s, got {s}"));
    }
    Ok(v)
}

/// `--until-bound`: a probability in (0, 1).
fn probability(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("{s:?} is not a probability"))?;
    if !(v > 0.0 && v < 1.0) {
        return Err(format!("must be in (0, 1), e.g. 0.01 for 1 %, got {s}"));
    }
    Ok(v)
}

/// `--widen`: a factor in [1, 100].
fn widening(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("{s:?} is not a factor"))?;
    if !(v.is_finite() && (1.0..=linkfit::fit::MAX_WIDEN).contains(&v)) {
        return Err(format!("must be a factor in [1, {}], got {s}", linkfit::fit::MAX_WIDEN));
    }
    Ok(v)
}

/// `--rate-hz`: probes per second, in (0, 10000].
fn rate_hz(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("{s:?} is not a number of probes per second"))?;
    if !(v.is_finite() && v > 0.0 && v <= 10_000.0) {
        return Err(format!("must be in (0, 10000] Hz, got {s}"));
    }
    Ok(v)
}

/// What `--shard` says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShardArg {
    /// `I/K`: the I-th (from 0) of K slices.
    Slice { index: u64, count: u64 },
    /// `auto`, or `auto/K` (K shards expected, or given where the environment has no count).
    Auto { count: Option<u64> },
}

/// `--shard I/K`, `--shard auto` or `--shard auto/K`.
pub fn shard_arg(text: &str) -> Result<ShardArg, String> {
    let (i, k) = match text.split_once('/') {
        Some((i, k)) => (i.trim(), Some(k.trim())),
        None => (text.trim(), None),
    };
    let count = |k: &str| -> Result<u64, String> {
        match k.parse::<u64>() {
            Ok(0) => Err("K must be at least 1".to_string()),
            Ok(k) => Ok(k),
            Err(_) => Err(format!("{k:?} is not a number of shards")),
        }
    };
    if i == "auto" {
        return Ok(ShardArg::Auto { count: k.map(count).transpose()? });
    }
    let k = k.ok_or("expected I/K (e.g. 0/4), auto or auto/K")?;
    let i: u64 = i.parse().map_err(|_| format!("{i:?} is not a shard number"))?;
    let k = count(k)?;
    if i >= k {
        return Err(format!("shard {i} of {k}: I must be below K (shards 0 to K-1)"));
    }
    Ok(ShardArg::Slice { index: i, count: k })
}

/// `hilbench`'s TLS flags: a directory made by `hilbench certs`, or the files one by one.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct TlsArgs {
    /// Run every link over mutual TLS with the certificates in DIR (`hilbench certs --out
    /// DIR`): ca.pem, and <service>.pem / <service>-key.pem for plant, netem, controller and
    /// hilbench itself (docs/tls.md).
    #[arg(long, value_name = "DIR", conflicts_with_all = ["tls_ca", "tls_cert", "tls_key"])]
    pub tls_dir: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub identity: hilbench_svc::tls::IdentityArgs,
    #[command(flatten)]
    pub trust: hilbench_svc::tls::TrustArgs,
}

impl TlsArgs {
    /// Whether any TLS flag was given.
    pub fn given(&self) -> bool {
        self.tls_dir.is_some()
            || self.identity.tls_cert.is_some()
            || self.identity.tls_key.is_some()
            || self.trust.tls_ca.is_some()
    }
}

/// `--plant`, `--netem`, `--controller` of the CLI: services already running.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct EndpointArgs {
    /// A running plant (HOST:PORT) instead of one started here.
    #[arg(long)]
    pub plant: Option<String>,
    /// A running netem (HOST:PORT) instead of one started here; it gets each scenario's
    /// delay profiles through NetemControl.
    #[arg(long)]
    pub netem: Option<String>,
    /// A running controller (HOST:PORT), already pointed at the netem (or plant) it should
    /// fly; needs --plant or --netem to read the final state.
    #[arg(long)]
    pub controller: Option<String>,
    /// Leave the profile of the netem at --netem as it is (the file's [scenario.delays] is
    /// then not used); a file without [scenario.delays] leaves it alone anyway. summary.json's
    /// `delay_profile` says what was in force.
    #[arg(long, requires = "netem")]
    pub keep_netem_profile: bool,
    /// Start each run where the vehicle (or plant) at --plant is now: its state becomes the
    /// scenario's start, so that a gateway, which never moves its vehicle to a start, takes
    /// the run's reset (a second run after the first ended away from the start, a vehicle
    /// placed by hand). The goal and the obstacles stay the file's.
    #[arg(long, requires = "plant")]
    pub start_from_vehicle: bool,
}

impl EndpointArgs {
    /// Whether any service was given.
    pub fn given(&self) -> bool {
        self.plant.is_some() || self.netem.is_some() || self.controller.is_some()
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    use super::Cli;

    /// The long help of `hilbench <command>`.
    fn help(command: &str) -> String {
        let mut cli = Cli::command();
        cli.build();
        cli.find_subcommand_mut(command).expect("the command").render_long_help().to_string()
    }

    #[test]
    fn only_the_commands_that_write_mcap_files_offer_no_mcap() {
        for command in ["reproduce", "run"] {
            assert!(help(command).contains("--no-mcap"), "{command}");
        }
        for command in ["sweep", "falsify", "sweep-merge", "trace", "certs"] {
            assert!(!help(command).contains("--no-mcap"), "{command} offers --no-mcap:\n{}", help(command));
        }
    }

    #[test]
    fn the_users_controller_takes_a_vehicle_and_start_from_vehicle_needs_one() {
        use clap::Parser;
        let run = |args: &[&str]| Cli::try_parse_from([&["hilbench", "run", "f.toml"], args].concat());
        let cli =
            run(&["--controller-cmd", "python c.py", "--plant", "127.0.0.1:50054", "--start-from-vehicle"])
                .expect("a user's controller on a vehicle");
        let super::Command::Run(a) = cli.command else { panic!("run") };
        assert_eq!(a.services.plant.as_deref(), Some("127.0.0.1:50054"));
        assert!(a.services.start_from_vehicle);
        let e = run(&["--start-from-vehicle"]).expect_err("without --plant");
        assert!(e.to_string().contains("--plant"), "{e}");
        for other in ["--netem", "--controller"] {
            let e = run(&["--controller-cmd", "python c.py", other, "127.0.0.1:1"]).expect_err(other);
            assert!(e.to_string().contains(other), "{e}");
        }
    }

    #[test]
    fn quiet_promises_no_exit_code_that_a_sweep_does_not_give() {
        // A sweep exits 0 whatever its runs did: --quiet's help must not say the exit code
        // tells a collision.
        let sweep = help("sweep");
        assert!(sweep.contains("--quiet"), "{sweep}");
        assert!(!sweep.contains("whether a run collided"), "{sweep}");
    }
}
