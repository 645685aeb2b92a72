//! `gateway`: the Plant API for a MAVLink vehicle. Glue only: flags, logging, signals; the
//! service is the `gateway` library.

use clap::Parser;
use gateway::GatewayConfig;

/// The hilbench vehicle gateway: serves hilbench.v1.Plant (real time) and
/// hilbench.v1.VehicleControl for a PX4 or ArduPilot vehicle over MAVLink 2. It never arms or
/// changes the vehicle's mode on its own: VehicleControl's Arm, Disarm and SetMode do.
#[derive(Debug, Parser)]
#[command(name = "gateway", version)]
#[command(mut_arg("listen", |a| a.default_value("127.0.0.1:50054").value_name("HOST:PORT").required(false).help("Address of the Plant and VehicleControl APIs, HOST:PORT.")))]
struct Args {
    #[command(flatten)]
    server: hilbench_svc::ServerArgs,
    /// The vehicle's link: udpin:HOST:PORT (listen; PX4 SITL's offboard link is
    /// udpin:0.0.0.0:14540), udpout:HOST:PORT, or serial:DEVICE:BAUD.
    #[arg(long, default_value = "udpin:0.0.0.0:14540")]
    mavlink: String,
    /// Fly a Betaflight flight controller over MSP instead of a MAVLink autopilot:
    /// tcp:HOST:PORT (SITL's UART1: tcp:127.0.0.1:5761) or serial:DEVICE:BAUD
    /// (docs/gateway.md, "A Betaflight flight controller over MSP").
    #[arg(long, value_name = "ADDRESS", conflicts_with_all = ["mavlink", "mavlink_signing_key", "record_link", "hover_thrust"])]
    msp: Option<String>,
    /// With --msp: where the motion-capture pose stream arrives, MAVLink 2 ODOMETRY over UDP
    /// (frame_id MAV_FRAME_LOCAL_NED, child_frame_id MAV_FRAME_BODY_FRD), HOST:PORT.
    #[arg(long, default_value = "127.0.0.1:14560", value_name = "HOST:PORT")]
    pose_in: std::net::SocketAddr,
    /// With --msp: the throttle that hovers the vehicle in ANGLE mode, us (1000..2000,
    /// measured on the vehicle): T = g maps to it.
    #[arg(long, default_value_t = 1500.0, value_name = "US")]
    hover_throttle_us: f64,
    /// With --msp: the firmware's min_check, us: the throttle stick below which it reads zero
    /// throttle.
    #[arg(long, default_value_t = 1050.0, value_name = "US")]
    min_check_us: f64,
    /// With --msp: the firmware's motor_idle, percent of full output (its setting / 100): what
    /// the motors give at zero throttle while armed.
    #[arg(long, default_value_t = 5.5, value_name = "PERCENT")]
    motor_idle_percent: f64,
    /// With --msp: where the samples' roll, pitch and heading come from: `firmware`
    /// (MSP_ATTITUDE, 10 Hz, what the firmware flies) or `pose` (the pose stream's quaternion,
    /// at its rate).
    #[arg(long, value_enum, default_value_t = AttitudeFrom::Firmware, value_name = "SOURCE")]
    attitude_from: AttitudeFrom,
    /// With --msp: the firmware's angle_limit, degrees (full stick in ANGLE mode); the value
    /// the firmware reports over MSP_PID_ADVANCED replaces it once heard.
    #[arg(long, default_value_t = 20.0, value_name = "DEG")]
    angle_limit_deg: f64,
    /// With --msp: no command for this long while armed, ms: the arm switch goes low (after
    /// --command-timeout-ms of level hover).
    #[arg(long, default_value_t = 2_000, value_parser = clap::value_parser!(u64).range(1..=600_000))]
    disarm_timeout_ms: u64,
    /// Scenario in force until a Reset brings one (obstacles, goal, limits): a built-in name or
    /// a scenario file.
    #[arg(long, default_value = "paper-1", value_name = "NAME|FILE.toml")]
    scenario: String,
    /// Normalised thrust (0..1) that makes the vehicle hover: T = g maps to it (clamped to
    /// [0, 1]). Measure it first (PX4: MPC_THR_HOVER).
    #[arg(long, default_value_t = 0.5)]
    hover_thrust: f64,
    /// No command from the controller for this long, ms: hold level attitude at hover thrust
    /// and say so in the samples (watchdog_hover).
    #[arg(long, default_value_t = 500, value_parser = clap::value_parser!(u64).range(1..=60_000))]
    command_timeout_ms: u64,
    /// Rate at which the last setpoint is resent, Hz (PX4 leaves OFFBOARD below 2 Hz).
    #[arg(long, default_value_t = 50, value_parser = clap::value_parser!(u64).range(20..=1000))]
    setpoint_rate_hz: u64,
    /// A Reset whose start is farther than this from the vehicle is refused, m.
    #[arg(long, default_value_t = 0.5)]
    start_tolerance_m: f64,
    /// The gateway's MAVLink system id.
    #[arg(long, default_value_t = 255)]
    system_id: u8,
    /// The gateway's MAVLink component id (191: onboard computer).
    #[arg(long, default_value_t = 191)]
    component_id: u8,
    /// Lock to the vehicle of this MAVLink system id (default: the first autopilot heartbeat
    /// heard); frames from any other system, component or address are dropped and counted.
    #[arg(long, value_name = "ID")]
    vehicle_sysid: Option<u8>,
    /// Lock to the vehicle's component of this id (default: the first autopilot heartbeat's).
    #[arg(long, value_name = "ID")]
    vehicle_compid: Option<u8>,
    /// MAVLink 2 signing: a file of the 32-byte key shared with the vehicle (32 bytes, or 64 hex
    /// digits; not readable by other users). Frames sent are signed; unsigned, badly signed
    /// and replayed frames are dropped and counted.
    #[arg(long, value_name = "FILE")]
    mavlink_signing_key: Option<std::path::PathBuf>,
    /// A LOCAL_POSITION_NED farther than this outside the scenario's box (start, goal,
    /// obstacles) is refused and counted, m.
    #[arg(long, default_value_t = 100.0)]
    envelope_margin_m: f64,
    /// A LOCAL_POSITION_NED faster than this is refused and counted, m/s.
    #[arg(long, default_value_t = 50.0)]
    max_speed_mps: f64,
    /// Only the client certificate with this common name may call VehicleControl (Arm,
    /// Disarm, SetMode, GetStatus); repeatable. Needs --tls-client-ca. Default: any client
    /// the TLS set-up lets in.
    #[arg(long, value_name = "NAME")]
    allow_client: Vec<String>,
    /// Record the vehicle link's round trips (MAVLink TIMESYNC, sent at 10 Hz while
    /// recording) into FILE as a delay trace (docs/links.md): one round trip in s per request,
    /// `lost` for one unanswered within 0.8 s; written every 10 s and at shutdown.
    #[arg(long, value_name = "FILE")]
    record_link: Option<std::path::PathBuf>,
    /// StreamState streams served at once; one more is refused with RESOURCE_EXHAUSTED.
    #[arg(long, default_value_t = hilbench_svc::streams::DEFAULT_MAX_STREAMS, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..))]
    max_streams: usize,
}

fn config(args: &Args) -> anyhow::Result<GatewayConfig> {
    let scenario = hilbench_scenario_file::scenario_arg(&args.scenario)
        .map_err(|e| anyhow::anyhow!("--scenario: {e}"))?;
    gateway::link::check_address(&args.mavlink)?;
    let mut config = GatewayConfig::new(args.mavlink.clone(), scenario);
    config.bridge.hover_thrust = args.hover_thrust;
    config.bridge.command_timeout_ns = args.command_timeout_ms * 1_000_000;
    config.bridge.setpoint_period_ns = 1_000_000_000 / args.setpoint_rate_hz;
    config.bridge.start_tolerance_m = args.start_tolerance_m;
    config.system_id = args.system_id;
    config.component_id = args.component_id;
    config.max_streams = args.max_streams;
    config.tls = hilbench_svc::tls::TlsFiles::server(&args.server.tls).load()?;
    config.connections = args.server.connections.limits()?;
    config.bridge.vehicle = mavbridge::VehicleFilter {
        system_id: args.vehicle_sysid,
        component_id: args.vehicle_compid,
        may_move: args.mavlink_signing_key.is_some(),
    };
    config.bridge.envelope_margin_m = args.envelope_margin_m;
    config.bridge.max_speed_mps = args.max_speed_mps;
    config.signing_key = args.mavlink_signing_key.as_deref().map(gateway::signing_key_file).transpose()?;
    if !args.allow_client.is_empty() && !config.tls.requires_client_certificates() {
        anyhow::bail!(
            "--allow-client needs client certificates: give --tls-cert, --tls-key and --tls-client-ca"
        );
    }
    config.allow_clients = args.allow_client.clone();
    config.record_link = args.record_link.clone();
    config.bridge.validate().map_err(|e| match e {
        mavbridge::BridgeError::Thrust(t) => anyhow::anyhow!("--hover-thrust: {t}"),
        mavbridge::BridgeError::Setting("start_tolerance_m", r) => {
            anyhow::anyhow!("--start-tolerance-m: {r}")
        }
        mavbridge::BridgeError::Setting("envelope_margin_m", r) => {
            anyhow::anyhow!("--envelope-margin-m: {r}")
        }
        mavbridge::BridgeError::Setting("max_speed_mps", r) => anyhow::anyhow!("--max-speed-mps: {r}"),
        other => anyhow::anyhow!("{other}"),
    })?;
    Ok(config)
}

/// `--attitude-from`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum AttitudeFrom {
    Firmware,
    Pose,
}

fn msp_config(args: &Args, msp: &str) -> anyhow::Result<gateway::betaflight::MspConfig> {
    let scenario = hilbench_scenario_file::scenario_arg(&args.scenario)
        .map_err(|e| anyhow::anyhow!("--scenario: {e}"))?;
    let address = gateway::betaflight::MspAddress::parse(msp).map_err(anyhow::Error::msg)?;
    let mut config = gateway::betaflight::MspConfig::new(address, args.pose_in, scenario);
    let s = &mut config.settings;
    s.calibration.hover_throttle_us = args.hover_throttle_us;
    s.calibration.angle_limit_deg = args.angle_limit_deg;
    s.attitude_source = match args.attitude_from {
        AttitudeFrom::Firmware => mavbridge::betaflight::AttitudeSource::Firmware,
        AttitudeFrom::Pose => mavbridge::betaflight::AttitudeSource::Pose,
    };
    s.calibration.min_check_us = args.min_check_us;
    s.calibration.motor_idle = args.motor_idle_percent / 100.0;
    s.command_timeout_ns = args.command_timeout_ms * 1_000_000;
    s.disarm_timeout_ns = args.disarm_timeout_ms * 1_000_000;
    s.start_tolerance_m = args.start_tolerance_m;
    s.envelope_margin_m = args.envelope_margin_m;
    s.max_speed_mps = args.max_speed_mps;
    config.settings.validate().map_err(|e| {
        let flag = match &e {
            mavbridge::betaflight::MspError::Setting(name, _) => match *name {
                "hover_throttle_us" => "--hover-throttle-us",
                "angle_limit_deg" => "--angle-limit-deg",
                "min_check_us" => "--min-check-us",
                "motor_idle" => "--motor-idle-percent",
                "disarm_timeout_ns" => "--disarm-timeout-ms",
                "start_tolerance_m" => "--start-tolerance-m",
                "envelope_margin_m" => "--envelope-margin-m",
                "max_speed_mps" => "--max-speed-mps",
                _ => "--msp",
            },
        };
        anyhow::anyhow!("{flag}: {e}")
    })?;
    config.max_streams = args.max_streams;
    config.tls = hilbench_svc::tls::TlsFiles::server(&args.server.tls).load()?;
    config.connections = args.server.connections.limits()?;
    if !args.allow_client.is_empty() && !config.tls.requires_client_certificates() {
        anyhow::bail!(
            "--allow-client needs client certificates: give --tls-cert, --tls-key and --tls-client-ca"
        );
    }
    config.allow_clients = args.allow_client.clone();
    Ok(config)
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    hilbench_svc::init_tracing();
    hilbench_svc::exit_on_panic();
    let args = Args::parse();
    if let Some(msp) = &args.msp {
        let config = msp_config(&args, msp)?;
        let listener = args.server.bind().await?;
        gateway::betaflight::serve(listener, config, hilbench_svc::shutdown_signal()).await?;
        return Ok(());
    }
    let config = config(&args)?;
    let listener = args.server.bind().await?;
    gateway::serve(listener, config, hilbench_svc::shutdown_signal()).await?;
    Ok(())
}
