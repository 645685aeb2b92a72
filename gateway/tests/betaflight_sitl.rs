//! The gateway against the real firmware: Betaflight 4.6.0 SITL, configured with
//! `firmware/betaflight/hilbench.cli` through its CLI (docs/betaflight.md, section 2), fed
//! level state packets by a loop of this test (no vehicle model: the attitude is what the
//! test says it is), and a pose stream (MAVLink ODOMETRY) from the test. The gateway
//! (`gateway --msp`, in process) is then asked, over gRPC as the bench asks it, to Describe
//! itself, Arm, report the status and the attitude, and is left without commands until its
//! watchdog disarms.
//!
//! Needs the SITL binary cached by `scripts/betaflight-sitl.sh`; without it the test says so
//! and passes, unless `HILBENCH_REQUIRE_SITL=1`. One SITL per machine (fixed ports): the test
//! takes the lock directory `$TMPDIR/hilbench-sitl.lock` first, and waits for TCP 5761 to be
//! free before each start (a SITL of a test that does not take the lock).

use hilbench_proto::pb;
use hilbench_proto::pb::plant_client::PlantClient;
use hilbench_proto::pb::vehicle_control_client::VehicleControlClient;
use mavbridge::mavlink::dialects::common::{MavFrame, MavMessage, ODOMETRY_DATA};
use mavbridge::mavlink::{MavHeader, MavlinkVersion};
use std::io::{Read, Write};
use std::net::{TcpStream, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the workspace").to_path_buf()
}

fn sitl_binary() -> Option<PathBuf> {
    if let Some(path) = std::env::var_os("HILBENCH_BETAFLIGHT_SITL") {
        return Some(PathBuf::from(path));
    }
    let out = Command::new("bash")
        .arg(repo().join("scripts/betaflight-sitl.sh"))
        .arg("--check")
        .stderr(Stdio::inherit())
        .output()
        .expect("run scripts/betaflight-sitl.sh --check");
    out.status.success().then(|| PathBuf::from(String::from_utf8_lossy(&out.stdout).trim()))
}

/// The machine's one SITL slot: a directory created exclusively, holding the owner's pid; a
/// dead owner's is taken over.
struct SitlLock(PathBuf);

impl SitlLock {
    fn take() -> Self {
        let dir = std::env::temp_dir().join("hilbench-sitl.lock");
        let started = Instant::now();
        loop {
            match std::fs::create_dir(&dir) {
                Ok(()) => {
                    std::fs::write(dir.join("pid"), std::process::id().to_string()).expect("pid");
                    let lock = Self(dir);
                    // A SITL started by a test that does not take the lock: wait for its end.
                    while std::net::TcpListener::bind("0.0.0.0:5761").is_err() {
                        assert!(
                            started.elapsed() < Duration::from_secs(300),
                            "TCP 5761 stays taken (another SITL?)"
                        );
                        std::thread::sleep(Duration::from_millis(500));
                    }
                    return lock;
                }
                Err(_) => {
                    let owner = std::fs::read_to_string(dir.join("pid")).unwrap_or_default();
                    let alive =
                        owner.trim().parse::<u32>().is_ok_and(|p| Path::new(&format!("/proc/{p}")).exists());
                    if !alive && started.elapsed() > Duration::from_secs(1) {
                        let _ = std::fs::remove_dir_all(&dir);
                        continue;
                    }
                    assert!(
                        started.elapsed() < Duration::from_secs(300),
                        "the SITL lock {} is held",
                        dir.display()
                    );
                    std::thread::sleep(Duration::from_millis(200));
                }
            }
        }
    }
}

impl Drop for SitlLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Whether a SITL process runs on this machine (any `betaflight_*_SITL` command line).
fn sitl_running() -> bool {
    let Ok(procs) = std::fs::read_dir("/proc") else { return false };
    procs.flatten().any(|p| {
        std::fs::read(p.path().join("cmdline")).is_ok_and(|c| {
            String::from_utf8_lossy(&c)
                .split('\0')
                .next()
                .is_some_and(|a| a.contains("betaflight_") && a.ends_with("_SITL"))
        })
    })
}

/// Waits until no SITL runs and TCP 5761 is free: a SITL of a test that does not take the
/// lock ends first.
fn wait_for_port() {
    let started = Instant::now();
    while sitl_running() || std::net::TcpListener::bind("0.0.0.0:5761").is_err() {
        assert!(started.elapsed() < Duration::from_secs(300), "TCP 5761 stays taken (another SITL?)");
        std::thread::sleep(Duration::from_millis(500));
    }
}

/// Removes the SITL's directory, whatever the test's outcome.
struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

struct Sitl(Child);

impl Sitl {
    fn start(binary: &Path, dir: &Path) -> Self {
        wait_for_port();
        let log =
            std::fs::OpenOptions::new().create(true).append(true).open(dir.join("sitl.log")).expect("log");
        let child = Command::new(binary)
            .current_dir(dir)
            .stdin(Stdio::null())
            .stdout(log.try_clone().expect("log"))
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", binary.display()));
        Self(child)
    }
}

impl Drop for Sitl {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn connect() -> TcpStream {
    let started = Instant::now();
    loop {
        if let Ok(s) = TcpStream::connect(("127.0.0.1", 5761)) {
            s.set_read_timeout(Some(Duration::from_millis(100))).expect("timeout");
            return s;
        }
        assert!(started.elapsed() < Duration::from_secs(10), "the SITL never opened TCP 5761");
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn read_to_prompt(s: &mut TcpStream, within: Duration) -> Option<String> {
    let started = Instant::now();
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    while started.elapsed() < within {
        match s.read(&mut buf) {
            Ok(0) => return None,
            Ok(n) => out.extend_from_slice(&buf[..n]),
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            Err(e) => panic!("CLI read: {e}"),
        }
        let text = String::from_utf8_lossy(&out);
        if msp::cli::at_prompt(&text) {
            return Some(text.into_owned());
        }
    }
    None
}

/// Applies `firmware/betaflight/hilbench.cli` as docs/betaflight.md says; `save` ends the
/// process.
fn configure(sitl: &mut Sitl) {
    let mut s = connect();
    let mut entered = false;
    for _ in 0..20 {
        s.write_all(&[msp::cli::ENTER]).expect("write");
        if read_to_prompt(&mut s, Duration::from_millis(500)).is_some() {
            entered = true;
            break;
        }
    }
    assert!(entered, "the CLI never answered `#`");
    let file =
        std::fs::read_to_string(repo().join("firmware/betaflight/hilbench.cli")).expect("the CLI file");
    for cmd in msp::cli::commands(&file) {
        s.write_all(format!("{cmd}\r\n").as_bytes()).expect("write");
        let out = read_to_prompt(&mut s, Duration::from_secs(5))
            .unwrap_or_else(|| panic!("no prompt after `{cmd}`"));
        assert!(msp::cli::error_in(&out).is_none(), "the firmware refused `{cmd}`: {out}");
    }
    s.write_all(b"save\r\n").expect("write");
    let started = Instant::now();
    loop {
        if let Some(status) = sitl.0.try_wait().expect("wait") {
            assert!(status.success(), "the SITL ended with {status} after save");
            return;
        }
        assert!(started.elapsed() < Duration::from_secs(10), "the SITL did not restart after save");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The attitude the state packets and poses carry: NED roll and pitch, rad (yaw 0).
type Tilt = Arc<Mutex<(f64, f64)>>;

fn quaternion(roll: f64, pitch: f64) -> [f64; 4] {
    mavbridge::frame::quaternion_from_euler(roll, pitch, 0.0)
}

/// State packets to UDP 9003 at 1 kHz, stamped with real time, at rest with the attitude
/// `tilt` (docs/betaflight.md, section 3).
fn feed_state(stop: Arc<AtomicBool>, tilt: Tilt) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let socket = UdpSocket::bind("127.0.0.1:0").expect("a socket");
        let started = Instant::now();
        while !stop.load(Ordering::Relaxed) {
            let (roll, pitch) = *tilt.lock().expect("not poisoned");
            let q = quaternion(roll, pitch);
            // Specific force at rest: -g along the world's down, in the body FRD frame.
            let g = 9.80665;
            let f_body = [g * pitch.sin(), -g * pitch.cos() * roll.sin(), -g * pitch.cos() * roll.cos()];
            let mut packet = Vec::with_capacity(144);
            let mut put = |v: f64| packet.extend_from_slice(&v.to_le_bytes());
            put(started.elapsed().as_secs_f64());
            for v in [0.0; 3] {
                put(v);
            }
            for v in f_body {
                put(v);
            }
            for v in q {
                put(v);
            }
            for v in [0.0; 6] {
                put(v);
            }
            put(101_325.0);
            let _ = socket.send_to(&packet, "127.0.0.1:9003");
            std::thread::sleep(Duration::from_millis(1));
        }
    })
}

/// ODOMETRY at 50 Hz to the gateway's `--pose-in`, at the scenario's start.
fn feed_pose(
    stop: Arc<AtomicBool>,
    to: std::net::SocketAddr,
    start: [f64; 3],
    tilt: Tilt,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let socket = UdpSocket::bind("127.0.0.1:0").expect("a socket");
        let started = Instant::now();
        let header = MavHeader { system_id: 1, component_id: 197, sequence: 0 };
        while !stop.load(Ordering::Relaxed) {
            let (roll, pitch) = *tilt.lock().expect("not poisoned");
            let q = quaternion(roll, pitch).map(|c| c as f32);
            let msg = MavMessage::ODOMETRY(ODOMETRY_DATA {
                time_usec: started.elapsed().as_micros() as u64,
                x: start[0] as f32,
                y: -start[1] as f32,
                z: -start[2] as f32,
                q,
                frame_id: MavFrame::MAV_FRAME_LOCAL_NED,
                child_frame_id: MavFrame::MAV_FRAME_BODY_FRD,
                ..Default::default()
            });
            let mut buf = Vec::new();
            mavbridge::mavlink::write_versioned_msg(&mut buf, MavlinkVersion::V2, header, &msg)
                .expect("encodes");
            let _ = socket.send_to(&buf, to);
            std::thread::sleep(Duration::from_millis(20));
        }
    })
}

async fn status(control: &mut VehicleControlClient<tonic::transport::Channel>) -> pb::VehicleStatus {
    control.get_status(pb::GetVehicleStatusRequest {}).await.expect("GetStatus").into_inner()
}

#[test]
fn the_gateway_flies_the_real_betaflight_over_msp_arms_on_request_reports_attitude_and_its_watchdog_disarms()
{
    if std::env::var_os("HILBENCH_SITL").is_none() && std::env::var_os("HILBENCH_REQUIRE_SITL").is_none() {
        eprintln!(
            "skipped: the firmware-in-the-loop tests run with HILBENCH_SITL=1 (scripts/betaflight-check.sh): \
             on a loaded 2-core machine the firmware misses its RC and MSP deadlines (docs/betaflight.md)"
        );
        return;
    }
    let Some(binary) = sitl_binary() else {
        assert!(
            std::env::var_os("HILBENCH_REQUIRE_SITL").is_none(),
            "HILBENCH_REQUIRE_SITL is set and no SITL binary is cached: run scripts/betaflight-sitl.sh"
        );
        eprintln!("skipped: no Betaflight SITL binary cached; build it with scripts/betaflight-sitl.sh");
        return;
    };
    let _lock = SitlLock::take();
    let dir = std::env::temp_dir().join(format!("gateway-sitl-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("a directory");
    let _dir = TempDir(dir.clone());
    let mut first = Sitl::start(&binary, &dir);
    configure(&mut first);
    drop(first);
    let _sitl = Sitl::start(&binary, &dir);

    let stop = Arc::new(AtomicBool::new(false));
    let tilt: Tilt = Arc::new(Mutex::new((0.0, 0.0)));
    let state = feed_state(stop.clone(), tilt.clone());
    let scenario = mav::Scenario::paper_2();
    let pose_in = {
        let probe = UdpSocket::bind("127.0.0.1:0").expect("a port");
        probe.local_addr().expect("bound")
    };
    let pose = feed_pose(
        stop.clone(),
        pose_in,
        [scenario.start[0], scenario.start[1], scenario.start[2]],
        tilt.clone(),
    );

    hilbench_svc::init_tracing();
    let runtime = tokio::runtime::Runtime::new().expect("a runtime");
    runtime.block_on(async {
        let mut config = gateway::betaflight::MspConfig::new(
            gateway::betaflight::MspAddress::Tcp("127.0.0.1:5761".into()),
            pose_in,
            scenario.clone(),
        );
        config.settings.calibration.hover_throttle_us = 1400.0;
        config.settings.disarm_timeout_ns = 1_500_000_000;
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("a port");
        let addr = listener.local_addr().expect("bound");
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let server = tokio::spawn(gateway::betaflight::serve(listener, config, async {
            let _ = stop_rx.await;
        }));
        let url = format!("http://{addr}");
        let channel = loop {
            if let Ok(c) = tonic::transport::Channel::from_shared(url.clone()).expect("url").connect().await {
                break c;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        };
        let mut plant = PlantClient::new(channel.clone());
        let mut control = VehicleControlClient::new(channel);

        // Describe names the firmware once the gateway asked it.
        let started = Instant::now();
        let description = loop {
            let d = plant.describe(pb::DescribeRequest {}).await.expect("Describe").into_inner();
            if d.implementation.contains("BTFL 4.6.0") {
                break d;
            }
            if started.elapsed() > Duration::from_secs(10) {
                let log = std::fs::read_to_string(dir.join("sitl.log")).unwrap_or_default();
                let tail: String =
                    log.lines().filter(|l| !l.starts_with("[FLASH")).take(40).collect::<Vec<_>>().join("\n");
                panic!(
                    "Describe: {}; {:?}; the SITL's log:\n{tail}",
                    d.implementation,
                    status(&mut control).await
                );
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        };
        eprintln!("Describe: {}", description.implementation);
        assert!(
            description.implementation.contains("MSP")
                && description.implementation.contains("tcp:127.0.0.1:5761")
        );

        // Never armed unasked: seconds of RC and no arming.
        tokio::time::sleep(Duration::from_secs(2)).await;
        let s = status(&mut control).await;
        assert!(s.link_alive && !s.armed, "{s:?}");
        assert!(s.setpoints_sent > 50, "RC frames flow at 50 Hz: {s:?}");

        // The attitude flows: tilt the state packets and the samples follow (NED roll 5 deg,
        // nose up 3 deg, yaw 0: the model's phi = roll, theta = -pitch).
        *tilt.lock().expect("not poisoned") = (5f64.to_radians(), 3f64.to_radians());
        let started = Instant::now();
        let mut last_time = 0;
        let sample = loop {
            let s = match plant.get_state(pb::GetStateRequest {}).await {
                Ok(s) => s.into_inner(),
                // The first MSP_ATTITUDE may still be on its way.
                Err(e)
                    if e.code() == tonic::Code::Unavailable && started.elapsed() < Duration::from_secs(2) =>
                {
                    tokio::time::sleep(Duration::from_millis(20)).await;
                    continue;
                }
                Err(e) => panic!("GetState: {e:?}"),
            };
            let x = s.state.as_ref().expect("a state").x.clone();
            assert!(s.time_ns >= last_time);
            last_time = s.time_ns;
            if (x[6] - 5f64.to_radians()).abs() < 0.3f64.to_radians()
                && (x[7] + 3f64.to_radians()).abs() < 0.3f64.to_radians()
            {
                break s;
            }
            assert!(
                started.elapsed() < Duration::from_secs(3),
                "the attitude did not follow: phi {} theta {} rad",
                x[6],
                x[7]
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        };
        eprintln!("attitude followed in {:?} (sample {})", started.elapsed(), sample.seq);
        // Level again before arming (tilted, the armed firmware's PID loop saturates against a
        // vehicle that cannot move, and its runaway-takeoff check disarms).
        *tilt.lock().expect("not poisoned") = (0.0, 0.0);
        tokio::time::sleep(Duration::from_millis(300)).await;

        // Arm (boot grace and gyro calibration may still refuse the first asks).
        let mut armed = false;
        for attempt in 0..5 {
            match control.arm(pb::ArmRequest {}).await {
                Ok(r) => {
                    eprintln!("Arm: {}", r.into_inner().result);
                    armed = true;
                    break;
                }
                Err(e) => eprintln!("Arm attempt {attempt}: {}", e.message()),
            }
        }
        assert!(armed, "the firmware never armed");
        // Commands at 50 Hz while we look: level hover.
        let hover = pb::Command {
            input: Some(pb::ControlInput { thrust_mps2: 9.81, roll_rad: 0.0, pitch_rad: 0.0 }),
            ..Default::default()
        };
        let s = status(&mut control).await;
        assert!(s.armed && s.mode == "ANGLE" && s.flies_setpoints, "{s:?}");
        assert_eq!(s.autopilot, "BTFL 4.6.0");
        let mode = control.set_mode(pb::SetModeRequest { mode: pb::FlightMode::Px4Offboard as i32 }).await;
        assert!(mode.is_ok(), "{mode:?}");

        // Silence: level hover after 0.5 s, still armed; disarmed by the watchdog 1.5 s after
        // the last command.
        // Commands at 50 Hz for a second: still armed.
        let flying = Instant::now();
        while flying.elapsed() < Duration::from_secs(1) {
            plant.apply_command(hover).await.expect("ApplyCommand");
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        let s = status(&mut control).await;
        assert!(s.armed, "still armed under commands: {s:?}");
        let holds_before = s.watchdog_holds;
        let silent = Instant::now();
        tokio::time::sleep(Duration::from_millis(1_000)).await;
        let s = status(&mut control).await;
        assert!(s.armed && s.watchdog_holds == holds_before + 1, "hovering, armed: {s:?}");
        let sample = plant.get_state(pb::GetStateRequest {}).await.expect("GetState").into_inner();
        assert!(sample.watchdog_hover, "the samples say watchdog_hover");
        loop {
            let s = status(&mut control).await;
            if !s.armed {
                eprintln!("disarmed {:?} after the last command", silent.elapsed());
                assert!(silent.elapsed() >= Duration::from_millis(1_400), "{:?}", silent.elapsed());
                break;
            }
            assert!(silent.elapsed() < Duration::from_secs(4), "the watchdog never disarmed: {s:?}");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let s = status(&mut control).await;
        assert_eq!(s.dropped_undecodable, 0, "no bad frame from the firmware: {s:?}");
        let _ = stop_tx.send(());
        server.await.expect("joined").expect("served");
    });
    stop.store(true, Ordering::Relaxed);
    let _ = state.join();
    let _ = pose.join();
}
