//! `plant`: the MAV plant service. Glue only: flags, logging, signals; the service is the
//! `plant` library.

use anyhow::Context;
use clap::Parser;
use mav::TimeMode;
use plant::PlantConfig;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum WatchdogArg {
    Brake,
    Hover,
}

/// The hilbench plant: the MAV truth simulation served over gRPC (hilbench.v1.Plant, with
/// health checking and server reflection).
#[derive(Debug, Parser)]
#[command(name = "plant", version)]
#[command(mut_arg("listen", |a| a.default_value("127.0.0.1:50051").value_name("HOST:PORT").required(false).help("Address of the Plant API, HOST:PORT.")))]
struct Args {
    #[command(flatten)]
    server: hilbench_svc::ServerArgs,
    /// Scenario loaded at start: a built-in name (paper-1, paper-2, paper-3) or a scenario file
    /// (as `hilbench run` takes). A controller resets the plant to its own scenario when an
    /// episode starts (unless it runs with `--no-reset`).
    #[arg(long, default_value = "paper-1", value_name = "NAME|FILE.toml")]
    scenario: String,
    /// How plant time moves. The plant decides for the whole bench: netem and the controller
    /// follow it (their `--time-mode auto`). Real time by default, as a vehicle runs; the bench
    /// (`hilbench`) starts its plants in lockstep, which is deterministic. In real time
    /// Advance/Step with a duration are refused.
    #[arg(long, value_parser = hilbench_svc::args::time_mode(), default_value_t = TimeMode::RealTime)]
    time_mode: TimeMode,
    /// RK4 integration rate, Hz (the step is 1/rate).
    #[arg(long, default_value_t = 1000.0)]
    rate_hz: f64,
    /// The watchdog fires after this long without a command, ms; 0 = off (default 500).
    #[arg(long)]
    watchdog_ms: Option<u64>,
    /// What the watchdog does until the next command: brake to a standstill on board (as
    /// PX4's Hold failsafe; what the controller's fail-safe check assumes), or hold level
    /// hover (the vehicle coasts on).
    #[arg(long, value_enum, default_value_t = WatchdogArg::Brake)]
    watchdog_action: WatchdogArg,
    /// StreamState streams served at once; one more is refused with RESOURCE_EXHAUSTED.
    #[arg(long, default_value_t = hilbench_svc::streams::DEFAULT_MAX_STREAMS, value_parser = at_least_one())]
    max_streams: usize,
}

fn config(args: &Args) -> anyhow::Result<PlantConfig> {
    let scenario = hilbench_scenario_file::scenario_arg(&args.scenario)
        .map_err(|e| anyhow::anyhow!("--scenario: {e}"))?;
    let mut config = PlantConfig { time_mode: args.time_mode, ..PlantConfig::lockstep(scenario) };
    config.rate_hz = args.rate_hz;
    config.max_streams = args.max_streams;
    config.watchdog_action = match args.watchdog_action {
        WatchdogArg::Brake => mav::WatchdogAction::Brake,
        WatchdogArg::Hover => mav::WatchdogAction::Hover,
    };
    config.tls = hilbench_svc::tls::TlsFiles::server(&args.server.tls).load()?;
    config.connections = args.server.connections.limits()?;
    if let Some(ms) = args.watchdog_ms {
        config.watchdog_timeout_ns = match ms {
            0 => None,
            ms => Some(ms.checked_mul(1_000_000).context("--watchdog-ms is too large")?),
        };
    }
    config.validate()?;
    Ok(config)
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    hilbench_svc::init_tracing();
    hilbench_svc::exit_on_panic();
    let args = Args::parse();
    let config = config(&args)?;
    let listener = args.server.bind().await?;
    plant::serve(listener, config, hilbench_svc::shutdown_signal()).await?;
    Ok(())
}

/// A count of at least 1 (clap names the flag when it is not).
fn at_least_one() -> clap::builder::RangedU64ValueParser<usize> {
    clap::builder::RangedU64ValueParser::new().range(1..)
}
