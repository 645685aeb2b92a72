//! `controller`: serve the controller against a Plant API endpoint, or solve problems from
//! JSON lines (`controller solve`).

use std::io::BufReader;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Parser, Subcommand, ValueEnum};
use controller::ControllerConfig;
use controller::solve_lines::LineSolver;
use mav::TimeModeChoice;
use mpc::{
    ControllerMode, InactiveSetTolerances, MpcSettings, PanocSolver, QpSchedule, QpSettings, SafetySettings,
};

#[derive(Parser, Debug)]
#[command(name = "controller", version, about = "The multi-stage NMPC controller of hilbench")]
#[command(mut_arg("listen", |a| a.default_value("127.0.0.1:50053").value_name("HOST:PORT").required(false).help("Address of the Controller API, HOST:PORT.")))]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    server: hilbench_svc::ServerArgs,
    /// Plant API endpoint, HOST:PORT: a plant, netem, or a vehicle gateway (netem's `--plant`
    /// names the same kind of endpoint).
    #[arg(long, default_value = "127.0.0.1:50052")]
    plant: String,
    /// Scenario flown at start (problem, goal and limits): a built-in name (paper-1, paper-2,
    /// paper-3) or a scenario file (as `hilbench run` takes, its [run] options included);
    /// SetScenario flies another. The plant is reset to it when an episode starts (unless
    /// `--no-reset`), whatever scenario the plant was started with.
    #[arg(long, default_value = "paper-1", value_name = "NAME|FILE.toml")]
    scenario: String,
    /// Controller: the standard NMPC or the multi-stage NMPC.
    #[arg(long, value_parser = hilbench_svc::args::controller_mode(), default_value_t = ControllerMode::Multistage)]
    mode: ControllerMode,
    /// How time moves. `auto` (the default) asks the plant (or netem) with Describe and follows
    /// it, so that only the plant's `--time-mode` has to be chosen.
    #[arg(long, value_parser = hilbench_svc::args::time_mode_choice(), default_value_t = TimeModeChoice::Auto)]
    time_mode: TimeModeChoice,
    /// Do not reset the plant when an episode starts.
    #[arg(long)]
    no_reset: bool,
    /// Wait for SetScenario before flying.
    #[arg(long)]
    no_autostart: bool,
    /// Safety margin added to every cylinder radius, m (a scenario's own `obstacle_margin_m`
    /// takes precedence; `--margin-m` is an alias).
    #[arg(long, global = true, visible_alias = "margin-m", default_value_t = MpcSettings::default().obstacle_margin_m)]
    obstacle_margin_m: f64,
    /// Turn the safety layer off: send PANOC's input as it is (clipped to the bounds), with no
    /// QP cross-check and no fallback.
    #[arg(long)]
    no_safety: bool,
    /// When the QP fallback runs besides when PANOC's plan is rejected: every cycle, every
    /// n-th (`--qp-every`), or only when needed.
    #[arg(long, value_enum, default_value_t = Schedule::EveryNth)]
    qp_schedule: Schedule,
    /// n of `--qp-schedule every-nth`.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..))]
    qp_every: u32,
    /// Floor for both solvers and the safety checks: predicted altitudes stay at or above
    /// this, m, in every scenario flown (the key `min_altitude_m` of a scenario file, where
    /// `run.floor` turns the floor on). Default: each scenario's own (none in paper mode).
    #[arg(long)]
    min_altitude_m: Option<f64>,
    /// Make the QP fallback's rows that its nominal already violates elastic, at this cost
    /// per metre of remaining violation (e.g. 1e5), so that it returns a plan where the hard
    /// QP is infeasible (default: hard rows; BENCHMARKS.md, "The QP fallback", has the trade-off).
    #[arg(long)]
    qp_elastic_penalty: Option<f64>,
    /// Judge every candidate command with the fail-safe check: the command, then braking from
    /// the next cycle on, flown on the continuous model for sampled round-trip delays up to the
    /// scenario's largest sampling time. Off by default (the paper's controller checks its
    /// plan's predictions); see ARCHITECTURE.md.
    #[arg(long, conflicts_with = "no_safety")]
    fail_safe: bool,
    /// Multi-stage: a looser PANOC test in the outer iterations that start with no constraint
    /// active (`MpcSettings::inactive_set` at its measured values). About half the median solve
    /// time at a little lower accuracy, and it changes the closed loops; off by default (see
    /// docs/reproduction.md, "Options that change the result").
    #[arg(long, global = true)]
    inactive_set: bool,
    /// Whose PANOC solves the NMPC problems: `open` (OpEn 0.12's, the paper's toolchain) or
    /// `own` (mpc's, with the Lipschitz estimate carried across cycles and a scale-free
    /// stopping test; `MpcSettings::solver`, BENCHMARKS.md "The solver" compares them).
    #[arg(long, global = true, default_value = MpcSettings::default().solver.name(), value_parser = panoc_solver)]
    solver: PanocSolver,
    /// Longest wait for one plant RPC in real time, s (lockstep calls get at least 60 s): a
    /// link that stops answering without closing is then reported and retried like a closed
    /// one.
    #[arg(long, default_value_t = 5.0)]
    rpc_timeout_s: f64,
    /// Real time: no completed cycle for this long counts as a link outage (with its whole
    /// duration) even when no call failed, ms.
    #[arg(long, default_value_t = 500, value_parser = clap::value_parser!(u64).range(1..))]
    stall_timeout_ms: u64,
    /// StreamTelemetry streams served at once; one more is refused with RESOURCE_EXHAUSTED.
    #[arg(long, default_value_t = hilbench_svc::streams::DEFAULT_MAX_STREAMS, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..))]
    max_streams: usize,
    #[command(flatten)]
    trust: hilbench_svc::tls::TrustArgs,
}

impl Cli {
    /// The solver settings the flags ask for.
    fn mpc_settings(&self) -> MpcSettings {
        MpcSettings {
            obstacle_margin_m: self.obstacle_margin_m,
            inactive_set: self.inactive_set.then_some(InactiveSetTolerances::MEASURED),
            solver: self.solver,
            ..MpcSettings::default()
        }
    }
}

fn panoc_solver(value: &str) -> Result<PanocSolver, String> {
    PanocSolver::parse(value).ok_or_else(|| format!("`{value}`: open or own"))
}

#[derive(ValueEnum, Clone, Copy, Debug)]
enum Schedule {
    EveryCycle,
    EveryNth,
    WhenNeeded,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Solve problems given as JSON lines (from FILE, or stdin) and print one JSON line each
    /// (`--solver`, `--obstacle-margin-m` and `--inactive-set` may come before or after
    /// `solve`; a scenario's own solver wins over `--solver`, and the answer names the one used):
    /// the scenario (name, inline object or scenario_file), x0, u_prev, weights, and optionally
    /// mode, warm_start, multipliers, obstacle_margin_m, floor_m, delay_compensation,
    /// max_iterations (docs/api.md).
    Solve {
        /// Input file; stdin when absent or `-`.
        file: Option<PathBuf>,
    },
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let settings = cli.mpc_settings();
    settings.validate().context("--obstacle-margin-m")?;
    if let Some(Command::Solve { file }) = &cli.command {
        let mut solver = LineSolver::new(settings);
        let stdout = std::io::stdout().lock();
        match file {
            Some(path) if path.as_os_str() != "-" => {
                // A regular file (a device such as /dev/zero would never end; a stream of
                // problems comes on stdin), read a line at a time, each line capped.
                let meta =
                    std::fs::metadata(path).with_context(|| format!("cannot open {}", path.display()))?;
                hilbench_scenario_file::user_file::check_regular(&meta).map_err(|why| {
                    anyhow::anyhow!("{}: {why} (a stream of problems goes on stdin)", path.display())
                })?;
                let f =
                    std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
                solver.run(BufReader::new(f), stdout)?;
            }
            _ => {
                solver.run(std::io::stdin().lock(), stdout)?;
            }
        }
        return Ok(());
    }
    hilbench_svc::init_tracing();
    hilbench_svc::exit_on_panic();
    let scenario = hilbench_scenario_file::nmpc_scenario_arg(&cli.scenario)
        .map_err(|e| anyhow::anyhow!("--scenario: {e}"))?;
    let mut config = ControllerConfig::new(cli.plant.clone(), scenario, cli.mode);
    // The floor goes with every scenario flown, those set later by SetScenario included.
    config.min_altitude_m = cli.min_altitude_m;
    config.adapt(config.scenario.clone()).validate().context("--min-altitude-m")?;
    config.episode.mpc = settings;
    config.episode.safety = (!cli.no_safety).then(|| SafetySettings {
        qp_schedule: match cli.qp_schedule {
            Schedule::EveryCycle => QpSchedule::EveryCycle,
            Schedule::EveryNth => QpSchedule::EveryNth(cli.qp_every),
            Schedule::WhenNeeded => QpSchedule::WhenNeeded,
        },
        qp: QpSettings { elastic_penalty_per_m: cli.qp_elastic_penalty, ..QpSettings::default() },
        ..SafetySettings::default()
    });
    config.episode.fail_safe = cli.fail_safe;
    if let Some(safety) = &config.episode.safety {
        safety.validate().context("--qp-elastic-penalty")?;
    }
    config.rpc_timeout = std::time::Duration::try_from_secs_f64(cli.rpc_timeout_s)
        .ok()
        .filter(|d| !d.is_zero())
        .context("--rpc-timeout-s: must be a positive number of seconds")?;
    config.stall_timeout = std::time::Duration::from_millis(cli.stall_timeout_ms);
    config.max_streams = cli.max_streams;
    config.tls = hilbench_svc::tls::TlsFiles::server_and_client(&cli.server.tls, &cli.trust).load()?;
    config.connections = cli.server.connections.limits()?;
    config.reset_plant = !cli.no_reset;
    config.autostart = !cli.no_autostart;
    config.time_mode = cli.time_mode;
    let runtime = tokio::runtime::Runtime::new()?;
    runtime.block_on(async move {
        let listener = cli.server.bind().await?;
        controller::serve(listener, config, hilbench_svc::shutdown_signal()).await?;
        anyhow::Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solver_flags_reach_the_settings() {
        let cli = Cli::try_parse_from(["controller", "--obstacle-margin-m", "0.2"]).expect("valid flags");
        assert_eq!(cli.mpc_settings(), MpcSettings { obstacle_margin_m: 0.2, ..MpcSettings::default() });
        // The old name stays an alias, so that scripts written for it still work.
        let cli = Cli::try_parse_from(["controller", "--margin-m", "0.3"]).expect("valid flags");
        assert_eq!(cli.mpc_settings().obstacle_margin_m, 0.3);
        let cli = Cli::try_parse_from(["controller", "--inactive-set"]).expect("valid flags");
        assert_eq!(cli.mpc_settings().inactive_set, Some(InactiveSetTolerances::MEASURED));
        let cli = Cli::try_parse_from(["controller", "--solver", "own"]).expect("valid flags");
        assert_eq!(cli.mpc_settings().solver, PanocSolver::Own);
        let cli = Cli::try_parse_from(["controller"]).expect("valid flags");
        assert_eq!(cli.mpc_settings().solver, MpcSettings::default().solver);
        let e = Cli::try_parse_from(["controller", "--solver", "fast"]).expect_err("refused");
        assert!(e.to_string().contains("--solver") && e.to_string().contains("open or own"), "{e}");
    }

    #[test]
    fn the_solve_flags_are_taken_after_solve_as_before_it() {
        for args in [
            ["controller", "solve", "--solver", "own", "--inactive-set", "--obstacle-margin-m", "0.1"],
            ["controller", "--solver", "own", "--inactive-set", "--obstacle-margin-m", "0.1", "solve"],
        ] {
            let cli = Cli::try_parse_from(args).expect("valid flags");
            assert!(matches!(cli.command, Some(Command::Solve { file: None })), "{args:?}");
            let settings = cli.mpc_settings();
            assert_eq!(settings.solver, PanocSolver::Own, "{args:?}");
            assert_eq!(settings.inactive_set, Some(InactiveSetTolerances::MEASURED), "{args:?}");
            assert_eq!(settings.obstacle_margin_m, 0.1, "{args:?}");
        }
    }

    #[test]
    fn max_streams_takes_a_positive_count_and_refuses_zero_naming_the_flag() {
        let cli = Cli::try_parse_from(["controller", "--max-streams", "3"]).expect("valid flags");
        assert_eq!(cli.max_streams, 3);
        let default = Cli::try_parse_from(["controller"]).expect("valid flags");
        assert_eq!(default.max_streams, hilbench_svc::streams::DEFAULT_MAX_STREAMS);
        let e = Cli::try_parse_from(["controller", "--max-streams", "0"]).expect_err("refused");
        assert!(e.to_string().contains("--max-streams"), "{e}");
    }
}
