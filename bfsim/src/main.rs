//! `bfsim`: Betaflight SITL flying the rigid-body quadrotor, with a motion-capture pose stream.
//! Glue only: flags, signals, the order of things; the parts are the library's.

use anyhow::{Context, bail};
use bfsim::firmware::{self, FirmwareInfo, Sitl, Workdir};
use bfsim::vehicle::{MonotonicClock, TimeMode, Vehicle, VehicleSettings};
use clap::Parser;
use nix::sys::signal::{SigSet, Signal};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// The Betaflight vehicle: starts the real firmware (Betaflight SITL) as a child process,
/// configures it with firmware/betaflight/hilbench.cli when its eeprom.bin lacks it, flies
/// the rigid-body quadrotor with its motor outputs in real time (state packets on UDP 9003,
/// motor packets on UDP 9002) and publishes the body's pose as MAVLink 2 ODOMETRY (a
/// motion-capture stream). The firmware's MSP port (TCP 5761) is left to the gateway.
#[derive(Debug, Parser)]
#[command(name = "bfsim", version)]
struct Args {
    /// The SITL binary [default: the one scripts/betaflight-sitl.sh caches:
    /// ${HILBENCH_CACHE:-$HOME/.cache/hilbench}/betaflight-4.6.0/betaflight_4.6.0_SITL, with
    /// --lockstep its lockstep/ build].
    #[arg(long, value_name = "PATH")]
    sitl: Option<PathBuf>,
    /// The firmware's working directory (its eeprom.bin), kept [default: a fresh temporary
    /// directory, removed on exit].
    #[arg(long, value_name = "DIR")]
    workdir: Option<PathBuf>,
    /// The CLI file applied to the firmware [default: firmware/betaflight/hilbench.cli, built in].
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Start position in the bench's world (x north, y west, z up; ground at 0), m
    /// [default: 0,0,0].
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_xyz, allow_hyphen_values = true, conflicts_with = "scenario")]
    start_m: Option<[f64; 3]>,
    /// Start where a scenario starts (its start state's position; the body starts at rest,
    /// level, nose north): a built-in name or a scenario file.
    #[arg(long, value_name = "NAME|FILE.toml")]
    scenario: Option<String>,
    /// Where the pose stream (MAVLink 2 ODOMETRY over UDP) goes.
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:14560")]
    pose_out: SocketAddr,
    /// Pose frames per second (of plant time).
    #[arg(long, value_name = "HZ", default_value_t = 100.0)]
    pose_rate_hz: f64,
    /// Plant time between state packets, ms (1 or 2).
    #[arg(long, value_name = "MS", default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=2))]
    fdm_period_ms: u64,
    /// Lockstep: plant time advances one state period per state/motor exchange, as fast as the
    /// firmware answers (needs the SIMULATOR_GYROPID_SYNC build: scripts/betaflight-sitl.sh
    /// --lockstep). See docs/betaflight.md for what it does and does not make repeatable.
    #[arg(long)]
    lockstep: bool,
    /// In lockstep, how long a state packet waits for its motor packet before plant time moves
    /// on with the motors held, ms.
    #[arg(long, value_name = "MS", default_value_t = 20, requires = "lockstep")]
    lockstep_timeout_ms: u64,
    /// Write every motor packet applied to FILE (plant time ns and the four floats' bits).
    #[arg(long, value_name = "FILE")]
    motor_log: Option<PathBuf>,
    /// Wait this long for the machine's SITL lock (docs/betaflight.md) when another process
    /// holds it, s.
    #[arg(long, value_name = "S", default_value_t = 300)]
    wait_lock_s: u64,
    /// Stop after this long, s (wall clock) [default: until SIGINT or SIGTERM].
    #[arg(long, value_name = "S")]
    duration_s: Option<f64>,
}

fn parse_xyz(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|e| format!("`{p}`: {e}")))
        .collect::<Result<_, _>>()?;
    <[f64; 3]>::try_from(v).map_err(|_| "three numbers, X,Y,Z".to_string())
}

fn main() {
    if let Err(e) = run() {
        eprintln!("bfsim: error: {e:#}");
        std::process::exit(1);
    }
}

fn run() -> anyhow::Result<()> {
    let args = Args::parse();
    // SIGINT and SIGTERM are taken by one thread (sigwait), so the firmware is stopped and the
    // counters printed; blocked here, before any thread starts, for every thread. Children get
    // the default mask back (std resets it in the child).
    let mut signals = SigSet::empty();
    signals.add(Signal::SIGINT);
    signals.add(Signal::SIGTERM);
    signals.thread_block().context("block SIGINT and SIGTERM")?;
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        std::thread::Builder::new().name("bfsim-signals".into()).spawn(move || {
            if let Ok(sig) = signals.wait() {
                eprintln!("bfsim: {sig:?}: stopping");
                stop.store(true, Ordering::Relaxed);
            }
        })?;
    }

    let binary = args.sitl.clone().unwrap_or_else(|| firmware::default_binary(args.lockstep));
    firmware::check_binary(&binary)?;
    let cli_text = match &args.config {
        Some(p) => std::fs::read_to_string(p).with_context(|| format!("read {}", p.display()))?,
        None => firmware::HILBENCH_CLI.to_string(),
    };
    let start_m = match (&args.scenario, args.start_m) {
        (Some(name), _) => {
            let scenario =
                hilbench_scenario_file::scenario_arg(name).map_err(|e| anyhow::anyhow!("--scenario: {e}"))?;
            [scenario.start[0], scenario.start[1], scenario.start[2]]
        }
        (None, Some(p)) => p,
        (None, None) => [0.0; 3],
    };
    let settings = VehicleSettings {
        start_m,
        fdm_period_ns: args.fdm_period_ms * 1_000_000,
        time_mode: if args.lockstep {
            TimeMode::Lockstep { reply_timeout: Duration::from_millis(args.lockstep_timeout_ms) }
        } else {
            TimeMode::RealTime
        },
        pose_out: args.pose_out,
        pose_rate_hz: args.pose_rate_hz,
        motor_log: args.motor_log.clone(),
        ..VehicleSettings::default()
    };
    settings.validate()?;
    // One SITL per machine: the lock first (waiting for another holder), then the ports.
    let _lock = firmware::SitlLock::acquire(Duration::from_secs(args.wait_lock_s))?;
    firmware::check_ports()?;
    let workdir = Workdir::new(args.workdir.as_deref())?;
    let started = Instant::now();
    if firmware::configure(&binary, workdir.path(), &cli_text)? {
        eprintln!(
            "bfsim: configured the firmware in {} ({:.1} s)",
            workdir.path().display(),
            started.elapsed().as_secs_f64()
        );
    }
    let mut sitl = Sitl::start(&binary, workdir.path())?;
    // State packets only once the firmware answers MSP: its UDP thread starts before the
    // sensors exist, and a state packet then crashes it (sitl.c's updateState writes to the
    // virtual gyro before `gyroInit`).
    // A connection reset (the port takes one client; another may have tried it) is retried.
    let mut info = None;
    for attempt in 1..=5 {
        let mut s = sitl.connect(Duration::from_secs(10))?;
        match firmware::query_info(&mut s) {
            Ok(i) => {
                info = Some(i);
                break;
            }
            Err(e) if attempt < 5 => {
                eprintln!("bfsim: MSP query {attempt}: {e}; again");
                std::thread::sleep(Duration::from_millis(300));
            }
            Err(e) => return Err(e.into()),
        }
    }
    let info = info.context("the firmware's MSP answers")?;
    let vehicle = Vehicle::start(&settings, MonotonicClock::new())?;
    // The firmware is up once its motor packets answer the state packets (ten of them: the
    // first may be the answer to a stale state, section 3 of docs/betaflight.md).
    let waited = Instant::now();
    while vehicle.stats().servo_received < 10 {
        if let Some(status) = sitl.exited() {
            bail!(
                "the SITL exited ({status}) before it sent a motor packet; its log: {}",
                sitl.log().display()
            );
        }
        if waited.elapsed() > Duration::from_secs(10) {
            bail!("no motor packet from the firmware within 10 s: {}", vehicle.stats());
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    print_line("up", &info, &sitl, &binary, &vehicle.stats(), settings.start_m);

    let outcome = loop {
        if stop.load(Ordering::Relaxed) {
            break Ok(());
        }
        if let Some(status) = sitl.exited() {
            break Err(anyhow::anyhow!("the firmware exited ({status}); its log: {}", sitl.log().display()));
        }
        if vehicle.is_finished() {
            break Err(anyhow::anyhow!("the vehicle's loop ended"));
        }
        if args.duration_s.is_some_and(|d| started.elapsed().as_secs_f64() >= d) {
            break Ok(());
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let (loop_result, stats) = vehicle.stop();
    sitl.kill();
    let end = vehicle_end(&stats);
    eprintln!("bfsim: shutdown {info} sitl_pid={} {stats}{end}", sitl.pid());
    drop(workdir);
    loop_result?;
    outcome
}

fn vehicle_end(_stats: &bfsim::stats::LinkStats) -> String {
    String::new()
}

fn print_line(
    what: &str,
    info: &FirmwareInfo,
    sitl: &Sitl,
    binary: &std::path::Path,
    stats: &bfsim::stats::LinkStats,
    start: [f64; 3],
) {
    eprintln!(
        "bfsim: {what} {info} sitl_pid={} sitl={} start_m={},{},{} {stats}",
        sitl.pid(),
        binary.display(),
        start[0],
        start[1],
        start[2]
    );
}
