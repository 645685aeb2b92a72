//! `mavsim`: the hilbench MAV model in real time playing a PX4 (or ArduCopter) autopilot's side of MAVLink, so
//! that the whole chain controller -> netem -> gateway -> MAVLink -> vehicle runs on one
//! machine. Glue only: flags, logging, signals; the simulator is `gateway::mavsim`.

use clap::Parser;
use gateway::mavsim::{Mavsim, MavsimConfig};
use mavbridge::{AutopilotSettings, Firmware};

/// A simulated PX4 vehicle over MAVLink 2: HEARTBEAT (armed, custom mode), ATTITUDE,
/// LOCAL_POSITION_NED, SYS_STATUS, TIMESYNC answers, COMMAND_LONG arming and modes with
/// COMMAND_ACK, and SET_ATTITUDE_TARGET. OFFBOARD is refused without a setpoint stream; when the
/// stream stops the vehicle fails safe to a hold (level, hover thrust). With `--autopilot
/// arducopter`, an ArduCopter: GUIDED_NOGPS, GUID_OPTIONS (answered to PARAM_REQUEST_READ) and
/// its reading of the thrust.
#[derive(Debug, Parser)]
#[command(name = "mavsim", version)]
struct Args {
    /// Where the gateway listens: udpout:HOST:PORT (or udpin:HOST:PORT, serial:DEVICE:BAUD).
    #[arg(long, default_value = "udpout:127.0.0.1:14540")]
    mavlink: String,
    /// The model's parameters, limits and start: a built-in name or a scenario file.
    #[arg(long, default_value = "paper-1", value_name = "NAME|FILE.toml")]
    scenario: String,
    /// Normalised thrust that hovers this vehicle (the gateway's --hover-thrust must match).
    #[arg(long, default_value_t = 0.5)]
    hover_thrust: f64,
    /// ATTITUDE and LOCAL_POSITION_NED rate, Hz.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..=1000))]
    state_rate_hz: u64,
    /// The vehicle's heading, degrees (the model has no yaw; the MAVLink frames carry it).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    yaw_deg: f64,
    /// Setpoints older than this end OFFBOARD (failsafe to a hold; ArduCopter levels in
    /// GUIDED_NOGPS), ms [default: 500, PX4's COM_OF_LOSS_T; 3000 for ArduCopter, its GUID_TIMEOUT].
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=60_000))]
    offboard_loss_ms: Option<u64>,
    /// Whose side of MAVLink to play.
    #[arg(long, value_enum, default_value_t = AutopilotArg::Px4)]
    autopilot: AutopilotArg,
    /// ArduCopter's GUID_OPTIONS: with bit 3 (8) the setpoints' thrust is thrust, without it a
    /// climb rate (0.5 holds the height), as with ArduCopter's default, 0 [default: 0].
    #[arg(long, value_name = "N")]
    guid_options: Option<u32>,
    /// Reboot once, this long after start, s: the boot clock restarts at 0, disarmed in POSCTL (LOITER)
    /// (to try the gateway's reboot handling; see also --reboot-silence-s).
    #[arg(long, value_name = "S")]
    reboot_after_s: Option<f64>,
    /// With --reboot-after-s: say nothing and hear nothing for this long from the reboot, s, as
    /// an autopilot booting (its clock then comes back ahead of the last stamp, by less than the
    /// silence lasted).
    #[arg(long, default_value_t = 0.0, value_name = "S", requires = "reboot_after_s")]
    reboot_silence_s: f64,
    /// MAVLink 2 signing with the key in FILE (as the gateway's --mavlink-signing-key): frames
    /// sent are signed, unsigned or otherwise signed ones dropped.
    #[arg(long, value_name = "FILE")]
    mavlink_signing_key: Option<std::path::PathBuf>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum AutopilotArg {
    Px4,
    Arducopter,
}

/// A duration flag in seconds: finite and not negative.
fn seconds(flag: &str, s: f64) -> anyhow::Result<std::time::Duration> {
    std::time::Duration::try_from_secs_f64(s)
        .map_err(|_| anyhow::anyhow!("{flag}: must be a finite number of seconds >= 0, got {s}"))
}

fn main() -> anyhow::Result<()> {
    hilbench_svc::init_tracing();
    hilbench_svc::exit_on_panic();
    let args = Args::parse();
    let scenario = hilbench_scenario_file::scenario_arg(&args.scenario)
        .map_err(|e| anyhow::anyhow!("--scenario: {e}"))?;
    if !args.yaw_deg.is_finite() || args.yaw_deg.abs() > 360.0 {
        anyhow::bail!("--yaw-deg: must be in [-360, 360], got {}", args.yaw_deg);
    }
    let autopilot = AutopilotSettings {
        hover_thrust: args.hover_thrust,
        offboard_loss_ns: args.offboard_loss_ms.unwrap_or(match args.autopilot {
            AutopilotArg::Px4 => 500,
            AutopilotArg::Arducopter => 3_000,
        }) * 1_000_000,
        state_period_ns: 1_000_000_000 / args.state_rate_hz,
        yaw_rad: args.yaw_deg.to_radians(),
        firmware: match (args.autopilot, args.guid_options) {
            (AutopilotArg::Px4, None) => Firmware::Px4,
            (AutopilotArg::Px4, Some(_)) => {
                anyhow::bail!("--guid-options: an ArduCopter parameter, only with --autopilot arducopter")
            }
            (AutopilotArg::Arducopter, guid_options) => {
                Firmware::ArduCopter { guid_options: guid_options.unwrap_or(0) }
            }
        },
        ..AutopilotSettings::default()
    };
    mavbridge::ThrustMap::new(args.hover_thrust, scenario.model.gravity_mps2)
        .map_err(|e| anyhow::anyhow!("--hover-thrust: {e}"))?;
    let reboot = match args.reboot_after_s {
        Some(after) => {
            Some((seconds("--reboot-after-s", after)?, seconds("--reboot-silence-s", args.reboot_silence_s)?))
        }
        None => None,
    };
    let signing_key = args.mavlink_signing_key.as_deref().map(gateway::signing_key_file).transpose()?;
    let sim = Mavsim::start(&MavsimConfig { mavlink: args.mavlink, scenario, autopilot, signing_key })?;
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    runtime.block_on(async {
        let shutdown = hilbench_svc::shutdown_signal();
        tokio::pin!(shutdown);
        if let Some((after, silence)) = reboot {
            tokio::select! {
                () = &mut shutdown => return Ok(()),
                () = tokio::time::sleep(after) => {}
            }
            // As a real autopilot: the clock restarts when it goes quiet, and it talks once booted.
            sim.set_silent(true);
            sim.reboot()?;
            tokio::select! {
                () = &mut shutdown => return Ok(()),
                () = tokio::time::sleep(silence) => {}
            }
            sim.set_silent(false);
        }
        shutdown.await;
        anyhow::Ok(())
    })?;
    sim.stop();
    Ok(())
}
