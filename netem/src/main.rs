//! `netem`: the delay emulator between a controller and its plant. Glue only: flags, logging,
//! signals; the service is the `netem` library.

use anyhow::Context;
use clap::Parser;
use mav::{TimeMode, TimeModeChoice};
use netem::Config;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum SideArg {
    /// The plant sends first, to --udp-listen (PX4 SITL to 14540, a radio's UDP bridge).
    Listen,
    /// The plant is at --udp-forward.
    Forward,
}

/// hilbench netem: serves the Plant API (and NetemControl, health, reflection), forwarding
/// every message to the plant behind it after a delay drawn per message and direction; with
/// --udp-listen and --udp-forward, a UDP proxy under the same delays instead (NetemControl on
/// --listen).
#[derive(Debug, Parser)]
#[command(name = "netem", version)]
#[command(mut_arg("listen", |a| a.default_value("127.0.0.1:50052").value_name("HOST:PORT").required(false).help("Address to listen on, HOST:PORT.")))]
struct Args {
    #[command(flatten)]
    server: hilbench_svc::ServerArgs,
    /// The Plant API behind netem, HOST:PORT: a plant or a vehicle gateway (the controller's
    /// `--plant` names the same kind of endpoint; `--upstream` is an alias).
    #[arg(long, visible_alias = "upstream", default_value = "127.0.0.1:50051")]
    plant: String,
    /// Named profile of both directions: paper (Gamma(12, 0.015) round trip on commands, as in
    /// docs/spec.md), paper-split (Gamma(6, 0.015) each way), none.
    #[arg(long, default_value = "paper")]
    profile: String,
    /// Both directions from a TOML file instead: a scenario file's [scenario.delays] table
    /// alone (every kind: constant, uniform, normal, gamma, lognormal, pareto, trace, regime;
    /// `to_plant` and `to_controller` tables for each direction; see docs/scenario-file.md).
    /// A trace's `file` is relative to this file.
    #[arg(long, value_name = "FILE.toml", conflicts_with = "profile")]
    profile_file: Option<std::path::PathBuf>,
    /// Seed of the delay generators.
    #[arg(long, default_value_t = 42)]
    seed: u64,
    /// How time moves. `auto` (the default) asks the plant behind with Describe and follows
    /// it, so that only the plant's `--time-mode` has to be chosen. In real time every message
    /// is released on netem's clock; in lockstep netem advances the plant's virtual clock to
    /// each release (deterministic).
    #[arg(long, value_parser = hilbench_svc::args::time_mode_choice(), default_value_t = TimeModeChoice::Auto)]
    time_mode: TimeModeChoice,
    /// Server streams served at once (StreamState and StreamDeliveries together); one more is
    /// refused with RESOURCE_EXHAUSTED.
    #[arg(long, default_value_t = hilbench_svc::streams::DEFAULT_MAX_STREAMS, value_parser = at_least_one())]
    max_streams: usize,
    #[command(flatten)]
    trust: hilbench_svc::tls::TrustArgs,
    /// UDP mode: the address the client's datagrams arrive at, HOST:PORT. The first datagram's
    /// sender becomes the client; datagrams from anyone else are refused and counted. Needs
    /// --udp-forward; the Plant API is not served (no --plant).
    #[arg(long, value_name = "HOST:PORT", conflicts_with = "plant")]
    udp_listen: Option<String>,
    /// UDP mode: where the client's datagrams go, HOST:PORT; its answers go back to the client.
    #[arg(long, value_name = "HOST:PORT", conflicts_with = "plant")]
    udp_forward: Option<String>,
    /// UDP mode: which side the plant (the vehicle) is on, so which datagrams are commands
    /// (to_plant) and which samples (to_controller).
    #[arg(long, value_enum, default_value_t = SideArg::Listen, requires = "udp_listen")]
    udp_plant_side: SideArg,
    /// UDP mode: most bytes of delayed datagrams held at once (default 64 MiB); a datagram
    /// past it is dropped and counted (`dropped_held_cap` in GetStats).
    #[arg(long, value_name = "BYTES", requires = "udp_listen", value_parser = clap::value_parser!(u64).range(1..=(16u64 << 30)))]
    udp_max_held_bytes: Option<u64>,
}

impl Args {
    /// The UDP proxy's addresses (`None` in gRPC mode), or a usage error naming the flag.
    fn udp(&self) -> Result<Option<netem::udp::UdpConfig>, String> {
        let side = match self.udp_plant_side {
            SideArg::Listen => netem::udp::Side::Listen,
            SideArg::Forward => netem::udp::Side::Forward,
        };
        let udp =
            netem::udp::UdpConfig::from_flags(self.udp_listen.as_deref(), self.udp_forward.as_deref(), side)
                .map_err(|e| e.to_string())?
                .map(|mut u| {
                    u.max_held_bytes = self.udp_max_held_bytes.unwrap_or(netem::udp::DEFAULT_MAX_HELD_BYTES);
                    u
                });
        if udp.is_some() && self.time_mode == TimeModeChoice::Fixed(TimeMode::Lockstep) {
            return Err("--time-mode lockstep: the UDP proxy runs in real time (lockstep needs a plant whose time netem moves)".into());
        }
        Ok(udp)
    }
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    hilbench_svc::init_tracing();
    hilbench_svc::exit_on_panic();
    let args = Args::parse();
    let udp = args.udp().unwrap_or_else(|e| {
        <Args as clap::CommandFactory>::command().error(clap::error::ErrorKind::ArgumentConflict, e).exit()
    });
    let mut config = match &args.profile_file {
        Some(path) => Config::new(&args.plant).with_network(load_profile_file(path, args.seed)?),
        None => Config::new(&args.plant)
            .with_preset(&args.profile, args.seed)
            .with_context(|| format!("--profile {}", args.profile))?,
    };
    config.time_mode = args.time_mode;
    config.max_streams = args.max_streams;
    config.tls = hilbench_svc::tls::TlsFiles::server_and_client(&args.server.tls, &args.trust).load()?;
    config.connections = args.server.connections.limits()?;
    let listener = args.server.bind().await?;
    match udp {
        Some(udp) => netem::serve_udp(listener, config, udp, hilbench_svc::shutdown_signal()).await?,
        None => netem::serve(listener, config, hilbench_svc::shutdown_signal()).await?,
    }
    Ok(())
}

/// The network of a `--profile-file`, seeded with `seed`; errors name the file and the key
/// (serde's with their line).
fn load_profile_file(path: &std::path::Path, seed: u64) -> anyhow::Result<delay::NetworkProfile> {
    let shown = path.display();
    let text = hilbench_scenario_file::user_file::read_text(
        path,
        hilbench_scenario_file::user_file::MAX_SCENARIO_FILE_BYTES,
        "a profile",
    )
    .map_err(|e| anyhow::anyhow!("--profile-file {e}"))?;
    let table: delay::DelaysTable =
        toml::from_str(&text).map_err(|e| anyhow::anyhow!("--profile-file {shown}: {e}"))?;
    let dir = path.parent().unwrap_or(std::path::Path::new("."));
    let mut read_trace = |name: &str| hilbench_scenario_file::read_trace(&dir.join(name));
    table
        .to_network(seed, &mut read_trace)
        .map_err(|e| anyhow::anyhow!("--profile-file {shown}: field `{}`: {}", e.field, e.reason))
}

/// A count of at least 1 (clap names the flag when it is not).
fn at_least_one() -> clap::builder::RangedU64ValueParser<usize> {
    clap::builder::RangedU64ValueParser::new().range(1..)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn udp_of(args: &[&str]) -> Result<Option<netem::udp::UdpConfig>, String> {
        let args = Args::try_parse_from(std::iter::once("netem").chain(args.iter().copied()))
            .map_err(|e| e.to_string())?;
        args.udp()
    }

    #[test]
    fn udp_flags_give_both_addresses_and_the_plant_side() {
        let udp = udp_of(&["--udp-listen", "127.0.0.1:14540", "--udp-forward", "127.0.0.1:14541"])
            .expect("valid")
            .expect("UDP mode");
        assert_eq!(udp.listen, "127.0.0.1:14540".parse().expect("address"));
        assert_eq!(udp.forward, "127.0.0.1:14541".parse().expect("address"));
        assert_eq!(udp.plant_side, netem::udp::Side::Listen);
        let udp = udp_of(&[
            "--udp-listen",
            "127.0.0.1:0",
            "--udp-forward",
            "localhost:14580",
            "--udp-plant-side",
            "forward",
        ])
        .expect("valid")
        .expect("UDP mode");
        assert_eq!(udp.plant_side, netem::udp::Side::Forward);
        assert_eq!(udp_of(&[]), Ok(None), "gRPC mode without the flags");
    }

    #[test]
    fn udp_flags_alone_a_bad_address_a_plant_or_lockstep_are_usage_errors_naming_the_flag() {
        let err = |args: &[&str]| udp_of(args).expect_err("refused");
        let e = err(&["--udp-listen", "127.0.0.1:14540"]);
        assert!(e.contains("--udp-listen") && e.contains("needs --udp-forward"), "{e}");
        let e = err(&["--udp-forward", "127.0.0.1:14540"]);
        assert!(e.contains("--udp-forward") && e.contains("needs --udp-listen"), "{e}");
        let e = err(&["--udp-listen", "14540", "--udp-forward", "127.0.0.1:14541"]);
        assert!(e.contains("--udp-listen") && e.contains("HOST:PORT"), "{e}");
        let e = err(&["--udp-listen", "127.0.0.1:14540", "--udp-forward", "127.0.0.1:port"]);
        assert!(e.contains("--udp-forward") && e.contains("not an address"), "{e}");
        let e = err(&["--udp-listen", "127.0.0.1:14540", "--udp-forward", "127.0.0.1:14540"]);
        assert!(e.contains("--udp-forward") && e.contains("itself"), "{e}");
        let e = err(&["--udp-listen", "127.0.0.1:14540", "--udp-forward", "0.0.0.0:14541"]);
        assert!(e.contains("--udp-forward") && e.contains("unspecified"), "{e}");
        let e = err(&["--udp-listen", "127.0.0.1:14540", "--udp-forward", "127.0.0.1:0"]);
        assert!(e.contains("--udp-forward") && e.contains("port 0"), "{e}");
        let e =
            err(&["--udp-listen", "127.0.0.1:1", "--udp-forward", "127.0.0.1:2", "--plant", "127.0.0.1:3"]);
        assert!(e.contains("--plant") && e.contains("cannot be used"), "{e}");
        let e =
            err(&["--udp-listen", "127.0.0.1:1", "--udp-forward", "127.0.0.1:2", "--time-mode", "lockstep"]);
        assert!(e.contains("--time-mode lockstep") && e.contains("real time"), "{e}");
        let e = err(&["--udp-plant-side", "forward"]);
        assert!(e.contains("--udp-listen"), "{e}");
    }
}
