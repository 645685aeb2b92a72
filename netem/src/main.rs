//! `netem`: the delay emulator between a controller and its plant. Glue only: flags, logging,
//! signals; the service is the `netem` library.

use anyhow::Context;
use clap::Parser;
use netem::{Config, TimeModeSetting};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum TimeModeArg {
    /// Follow the plant behind (asked with Describe).
    Auto,
    /// Release every message on netem's clock.
    RealTime,
    /// Advance the plant's virtual clock to each release (deterministic).
    Lockstep,
}

/// hilbench netem: serves the Plant API (and NetemControl, health, reflection), forwarding
/// every message to the plant behind it after a delay drawn per message and direction.
#[derive(Debug, Parser)]
#[command(name = "netem", version)]
struct Args {
    /// Address to listen on, HOST:PORT.
    #[arg(long, default_value = "127.0.0.1:50052")]
    listen: String,
    /// The Plant API behind netem, HOST:PORT: a plant or a vehicle gateway (the controller's
    /// `--plant` names the same kind of endpoint; `--upstream` is an alias).
    #[arg(long, visible_alias = "upstream", default_value = "127.0.0.1:50051")]
    plant: String,
    /// Named profile of both directions: paper (Gamma(12, 0.015) round trip on commands, as in
    /// docs/spec.md), paper-split (Gamma(6, 0.015) each way), none.
    #[arg(long, default_value = "paper")]
    profile: String,
    /// Seed of the delay generators.
    #[arg(long, default_value_t = 42)]
    seed: u64,
    /// How time moves. `auto` (the default) asks the plant behind with Describe and follows
    /// it, so that only the plant's `--time-mode` has to be chosen.
    #[arg(long, value_enum, default_value_t = TimeModeArg::Auto)]
    time_mode: TimeModeArg,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    hilbench_svc::init_tracing();
    let args = Args::parse();
    let mut config = Config::new(&args.plant)
        .with_preset(&args.profile, args.seed)
        .with_context(|| format!("--profile {}", args.profile))?;
    config.time_mode = match args.time_mode {
        TimeModeArg::Auto => TimeModeSetting::Auto,
        TimeModeArg::RealTime => TimeModeSetting::RealTime,
        TimeModeArg::Lockstep => TimeModeSetting::Lockstep,
    };
    let listener = tokio::net::TcpListener::bind(&args.listen)
        .await
        .with_context(|| format!("cannot listen on {}", args.listen))?;
    netem::serve(listener, config, hilbench_svc::shutdown_signal()).await?;
    Ok(())
}
