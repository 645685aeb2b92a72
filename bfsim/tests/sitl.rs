//! bfsim against the real firmware (Betaflight 4.6.0 SITL): the binary started as a user
//! starts it, the firmware spoken to over MSP on TCP 5761 as the gateway will, the pose stream
//! read as a motion-capture consumer would (pymavlink, an independent implementation, and the
//! `mavlink` crate).
//!
//! Needs the SITL binary cached by `scripts/betaflight-sitl.sh`; without it each test says so
//! and passes, unless `HILBENCH_REQUIRE_SITL=1` (then a missing binary fails it). The SITL's
//! ports are fixed, so one runs per machine: the tests take [`SITL`] in turn.

use mavlink::dialects::common::MavMessage;
use msp::messages::{ArmingDisabled, BoxIds, FcVariant, RawRc, Status, Sticks, boxes};
use msp::{Decoder, DecoderSettings, Frame, Version, command};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream, UdpSocket};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::sync::mpsc::{Receiver, channel};
use std::time::{Duration, Instant};

/// One SITL at a time in this test binary.
static SITL: Mutex<()> = Mutex::new(());

mod python {
    //! The same venv as `tests/src/python.rs` (same directory, stamp and lock), so whichever
    //! test makes it first makes it for both.
    use std::path::PathBuf;
    use std::process::Command;
    use std::time::{Duration, Instant};

    const REQUIREMENTS: &str = include_str!("../../tests/python/requirements.txt");

    pub fn python() -> PathBuf {
        if let Some(python) = std::env::var_os("HILBENCH_PYTHON") {
            return PathBuf::from(python);
        }
        let target = std::env::current_exe().expect("exe").ancestors().nth(3).expect("target").to_path_buf();
        let venv = target.join("python-venv");
        let python = venv.join("bin").join("python");
        let stamp = venv.join("requirements.txt");
        let fresh = || std::fs::read_to_string(&stamp).is_ok_and(|s| s == REQUIREMENTS);
        if fresh() {
            return python;
        }
        let lock = target.join("python-venv.lock");
        let started = Instant::now();
        loop {
            match std::fs::create_dir(&lock) {
                Ok(()) => break,
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    assert!(
                        started.elapsed() < Duration::from_secs(900),
                        "{} held for 15 min",
                        lock.display()
                    );
                    std::thread::sleep(Duration::from_millis(200));
                }
                Err(e) => panic!("cannot create {}: {e}", lock.display()),
            }
        }
        let _unlock = Unlock(lock);
        if fresh() {
            return python;
        }
        run(
            Command::new("python3").args(["-m", "venv", "--clear"]).arg(&venv),
            "python3 -m venv (python3-venv)",
        );
        let requirements = venv.join("requirements.in");
        std::fs::write(&requirements, REQUIREMENTS).expect("write requirements");
        run(
            Command::new(&python)
                .args(["-m", "pip", "install", "--quiet", "--disable-pip-version-check", "-r"])
                .arg(&requirements),
            "pip install -r tests/python/requirements.txt (needs PyPI)",
        );
        std::fs::write(&stamp, REQUIREMENTS).expect("write stamp");
        python
    }

    fn run(command: &mut Command, what: &str) {
        let status = command.status().unwrap_or_else(|e| panic!("cannot run {what}: {e}"));
        assert!(status.success(), "{what} failed ({status})");
    }

    struct Unlock(PathBuf);

    impl Drop for Unlock {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir(&self.0);
        }
    }
}

/// Whether the SITL binary is cached (or the test must fail: HILBENCH_REQUIRE_SITL).
fn sitl_available() -> bool {
    if std::env::var_os("HILBENCH_SITL").is_none() && std::env::var_os("HILBENCH_REQUIRE_SITL").is_none() {
        eprintln!(
            "skipped: the firmware-in-the-loop tests run with HILBENCH_SITL=1 (scripts/betaflight-check.sh): \
             on a loaded 2-core machine the firmware misses its RC and MSP deadlines (docs/betaflight.md)"
        );
        return false;
    }
    if bfsim::firmware::default_binary(false).is_file() {
        return true;
    }
    assert!(
        std::env::var_os("HILBENCH_REQUIRE_SITL").is_none(),
        "HILBENCH_REQUIRE_SITL is set and no SITL binary is cached: run scripts/betaflight-sitl.sh"
    );
    eprintln!("skipped: no Betaflight SITL binary cached; build it with scripts/betaflight-sitl.sh");
    false
}

/// `key=value` of a bfsim status line.
fn field<'a>(line: &'a str, key: &str) -> Option<&'a str> {
    line.split_whitespace().find_map(|kv| kv.strip_prefix(key).and_then(|r| r.strip_prefix('=')))
}

fn num(line: &str, key: &str) -> u64 {
    field(line, key).and_then(|v| v.parse().ok()).unwrap_or_else(|| panic!("no {key} in {line}"))
}

/// The bfsim binary, running; killed on drop.
struct Bfsim {
    child: Child,
    lines: Receiver<String>,
    up: String,
}

impl Bfsim {
    fn start(args: &[&str]) -> Self {
        // Another test binary (msp's, the gateway's) may be flying its own SITL: wait for it.
        assert!(
            wait_until(Duration::from_secs(300), || TcpListener::bind(("0.0.0.0", 5761)).is_ok()
                && UdpSocket::bind(("0.0.0.0", 9002)).is_ok()
                && UdpSocket::bind(("0.0.0.0", 9003)).is_ok()),
            "TCP 5761 or UDP 9002/9003 taken for 5 min (another SITL?)"
        );
        let mut child = Command::new(env!("CARGO_BIN_EXE_bfsim"))
            .args(args)
            .stdin(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start bfsim");
        let stderr = child.stderr.take().expect("stderr");
        let (tx, lines) = channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                eprintln!("[bfsim] {line}");
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let mut me = Self { child, lines, up: String::new() };
        me.up = me.wait_line("bfsim: up", Duration::from_secs(40));
        me
    }

    fn wait_line(&mut self, prefix: &str, within: Duration) -> String {
        let started = Instant::now();
        while started.elapsed() < within {
            match self.lines.recv_timeout(Duration::from_millis(100)) {
                Ok(line) if line.starts_with(prefix) => return line,
                Ok(_) => {}
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                    if let Ok(Some(status)) = self.child.try_wait() {
                        panic!("bfsim exited ({status}) before `{prefix}`");
                    }
                }
                Err(_) => panic!("bfsim's stderr closed before `{prefix}`"),
            }
        }
        panic!("no `{prefix}` line from bfsim within {within:?}");
    }

    fn signal(&self, sig: nix::sys::signal::Signal) {
        let pid = nix::unistd::Pid::from_raw(i32::try_from(self.child.id()).expect("pid"));
        nix::sys::signal::kill(pid, sig).expect("signal bfsim");
    }

    fn sitl_pid(&self) -> u32 {
        u32::try_from(num(&self.up, "sitl_pid")).expect("pid")
    }
}

impl Drop for Bfsim {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Whether process `pid` is gone (or a zombie nobody will run again).
fn process_gone(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        Err(_) => true,
        Ok(stat) => stat.rsplit(')').next().is_some_and(|rest| rest.trim_start().starts_with('Z')),
    }
}

fn wait_until(within: Duration, mut f: impl FnMut() -> bool) -> bool {
    let started = Instant::now();
    while started.elapsed() < within {
        if f() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    f()
}

fn msp_connect() -> TcpStream {
    let s = TcpStream::connect(("127.0.0.1", 5761)).expect("connect to the SITL's MSP port");
    s.set_read_timeout(Some(Duration::from_millis(20))).expect("timeout");
    s.set_nodelay(true).expect("nodelay");
    s
}

fn exchange(s: &mut TcpStream, d: &mut Decoder, cmd: u16) -> Frame {
    bfsim::firmware::exchange(s, d, cmd, &[], Duration::from_secs(3)).expect("an MSP reply")
}

#[test]
fn bfsim_starts_the_firmware_which_answers_msp_and_flies_the_state_packets() {
    let _one = SITL.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if !sitl_available() {
        return;
    }
    let mut b = Bfsim::start(&["--pose-rate-hz", "0"]);
    assert_eq!(field(&b.up, "variant"), Some("BTFL"), "{}", b.up);
    assert_eq!(field(&b.up, "version"), Some("4.6.0"), "{}", b.up);
    assert_eq!(field(&b.up, "configured"), Some("true"), "{}", b.up);
    // The test's own MSP: the firmware answers the variant.
    let mut s = msp_connect();
    let mut d = Decoder::new(DecoderSettings::default()).expect("valid");
    let f = exchange(&mut s, &mut d, command::FC_VARIANT);
    assert_eq!(FcVariant::decode(&f.payload).expect("decodes").as_str(), "BTFL");
    drop(s);
    std::thread::sleep(Duration::from_secs(2));
    let sitl = b.sitl_pid();
    b.signal(nix::sys::signal::Signal::SIGTERM);
    let end = b.wait_line("bfsim: shutdown", Duration::from_secs(10));
    let (sent, got) = (num(&end, "fdm_sent"), num(&end, "servo_received"));
    assert!(sent > 1500, "state packets at 1 kHz for 2 s and more: {end}");
    // On the wall clock the SITL's loop answered 0.09 to 0.19 of the state packets here (182 of
    // 2,110 in this test's first 2 s, during its gyro calibration; 3,189 of 17,184 over a flight):
    // 50 a second is the floor of a firmware that flies.
    assert!(got > 100, "the firmware answers state packets with motor packets: {end}");
    assert!(got <= sent + 1, "one motor packet per state packet at most: {end}");
    assert_eq!(num(&end, "bad_packets"), 0, "{end}");
    assert!(b.child.wait().expect("wait").success());
    assert!(wait_until(Duration::from_secs(3), || process_gone(sitl)), "SIGTERM: the SITL {sitl} is left");
}

#[test]
fn killing_bfsim_kills_the_firmware() {
    let _one = SITL.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if !sitl_available() {
        return;
    }
    let b = Bfsim::start(&["--pose-rate-hz", "0"]);
    let sitl = b.sitl_pid();
    assert!(!process_gone(sitl));
    // SIGKILL: no handler runs, the kernel's parent-death signal ends the firmware.
    b.signal(nix::sys::signal::Signal::SIGKILL);
    assert!(wait_until(Duration::from_secs(5), || process_gone(sitl)), "the SITL {sitl} outlived bfsim");
    assert!(
        wait_until(Duration::from_secs(5), || TcpListener::bind(("0.0.0.0", 5761)).is_ok()),
        "TCP 5761 still taken after bfsim was killed"
    );
    drop(b);
}

/// Datagrams of the pose stream received on `sock` within `within`.
fn pose_datagrams(sock: &UdpSocket, count: usize, within: Duration) -> Vec<Vec<u8>> {
    let started = Instant::now();
    let mut out = Vec::new();
    let mut buf = [0u8; 512];
    sock.set_read_timeout(Some(Duration::from_millis(100))).expect("timeout");
    while out.len() < count && started.elapsed() < within {
        if let Ok(n) = sock.recv(&mut buf) {
            out.push(buf[..n].to_vec());
        }
    }
    out
}

#[test]
fn the_pose_stream_is_odometry_that_pymavlink_reads() {
    let _one = SITL.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if !sitl_available() {
        return;
    }
    let sock = UdpSocket::bind("127.0.0.1:0").expect("bind");
    let addr = sock.local_addr().expect("addr").to_string();
    let b = Bfsim::start(&["--pose-out", &addr, "--pose-rate-hz", "100", "--start-m", "1.5,-2,0"]);
    let started = Instant::now();
    let frames = pose_datagrams(&sock, 100, Duration::from_secs(5));
    let elapsed = started.elapsed().as_secs_f64();
    drop(b);
    assert_eq!(frames.len(), 100, "100 frames at 100 Hz within 5 s");
    let rate = 100.0 / elapsed;
    assert!(rate > 70.0, "about 100 Hz: {rate:.1} Hz");
    let dir = std::env::temp_dir().join(format!("bfsim-pose-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let file = dir.join("pose.bin");
    std::fs::write(&file, frames.concat()).expect("write");
    let out = Command::new(python::python())
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/pose.py"))
        .arg(&file)
        .output()
        .expect("run pose.py");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "pose.py: {stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    let _ = std::fs::remove_dir_all(&dir);
    let v: Vec<&str> = stdout.lines().collect();
    // pose.py prints: count, then the last frame's fields.
    assert_eq!(field(v[0], "count"), Some("100"), "{stdout}");
    let last = v[1];
    for (k, want) in [
        ("frame_id", "1"),        // MAV_FRAME_LOCAL_NED
        ("child_frame_id", "12"), // MAV_FRAME_BODY_FRD
        ("estimator_type", "6"),  // MAV_ESTIMATOR_TYPE_MOCAP
        ("x", "1.5"),             // north
        ("y", "2.0"),             // east: the bench's y is west
        ("z", "0.0"),             // on the ground
        ("q", "1.0,0.0,0.0,0.0"), // level, nose north
        ("cov0_nan", "True"),
        ("sysid", "1"),
        ("compid", "197"),
    ] {
        assert_eq!(field(last, k), Some(want), "{k} in {last}");
    }
    let t: Vec<u64> = v[2].split(',').map(|x| x.parse().expect("time_usec")).collect();
    assert!(t.windows(2).all(|w| w[1] > w[0]), "time_usec increases: {t:?}");
    let dt = (t[t.len() - 1] - t[0]) as f64 / (t.len() - 1) as f64;
    assert!((dt - 10_000.0).abs() < 500.0, "10 ms of plant time apart: {dt}");
}

/// The latest pose from the stream: (time s, NED position, roll, pitch rad, down velocity in
/// the body).
#[derive(Debug, Clone, Copy, Default)]
struct Pose {
    t_s: f64,
    ned: [f32; 3],
    roll: f64,
    pitch: f64,
    vz_body: f32,
}

fn read_poses(sock: &UdpSocket, latest: &mut Option<Pose>) {
    let mut buf = [0u8; 512];
    while let Ok(n) = sock.recv(&mut buf) {
        let mut r = mavlink::MavlinkReader::new(&buf[..n]);
        if let Ok((_, MavMessage::ODOMETRY(o))) = r.read_message::<MavMessage>(mavlink::MavlinkVersion::V2) {
            let [w, x, y, z] = o.q.map(f64::from);
            let roll = (2.0 * (w * x + y * z)).atan2(1.0 - 2.0 * (x * x + y * y));
            let pitch = (2.0 * (w * y - z * x)).clamp(-1.0, 1.0).asin();
            *latest = Some(Pose {
                t_s: o.time_usec as f64 * 1e-6,
                ned: [o.x, o.y, o.z],
                roll,
                pitch,
                vz_body: o.vz,
            });
        }
    }
}

/// MSP_SET_RAW_RC sent without waiting (the firmware answers each with an empty frame,
/// drained here), MSP_STATUS_EX asked now and then: what a gateway does at 50 Hz.
struct Rc {
    s: TcpStream,
    d: Decoder,
    status: Option<Status>,
}

impl Rc {
    fn send(&mut self, sticks: Sticks, aux: &[u16]) {
        let raw = RawRc::aetr(sticks, aux).expect("channels");
        let bytes = raw.to_frame(Version::V1).to_bytes().expect("encodes");
        self.s.write_all(&bytes).expect("write");
    }

    fn ask_status(&mut self) {
        let bytes = Frame::request(Version::V1, command::STATUS_EX, vec![]).to_bytes().expect("encodes");
        self.s.write_all(&bytes).expect("write");
    }

    fn drain(&mut self) {
        let mut buf = [0u8; 2048];
        self.s.set_nonblocking(true).expect("nonblocking");
        while let Ok(n) = self.s.read(&mut buf) {
            if n == 0 {
                break;
            }
            for f in self.d.feed(&buf[..n]) {
                if f.command == command::STATUS_EX
                    && let Ok(st) = Status::decode(&f.payload, true)
                {
                    self.status = Some(st);
                }
            }
        }
        self.s.set_nonblocking(false).expect("blocking");
    }
}

#[test]
fn armed_over_msp_in_angle_mode_the_firmware_flies_the_rigid_body_at_a_steady_height() {
    let _one = SITL.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if !sitl_available() {
        return;
    }
    // On a loaded machine the firmware's serial task can fall behind the RC stream: RXLOSS,
    // then its failsafe drops the vehicle (docs/betaflight.md, section 4). Such a flight says
    // nothing about the loop; it is flown again, at most three times.
    for attempt in 1..=3 {
        if hover_flight() {
            return;
        }
        eprintln!("flight {attempt}: the firmware lost the RC stream (RXLOSS); flying again");
    }
    panic!("three flights in a row ended in the firmware's RXLOSS failsafe");
}

/// The firmware lost the RC stream: RXLOSS, or disarmed by its failsafe (nothing else disarms
/// with the switch high and `auto_disarm_delay` 0).
fn lost_rc(st: &Status, ids: &BoxIds) -> bool {
    st.arming_disabled.contains(ArmingDisabled::RX_LOSS) || st.is_on(ids, boxes::ARM) == Some(false)
}

/// One hover flight with its checks; false when the firmware lost the RC stream (RXLOSS).
fn hover_flight() -> bool {
    let pose_sock = UdpSocket::bind("127.0.0.1:0").expect("bind");
    pose_sock.set_nonblocking(true).expect("nonblocking");
    let addr = pose_sock.local_addr().expect("addr").to_string();
    let b = Bfsim::start(&["--pose-out", &addr, "--pose-rate-hz", "100"]);
    let mut s = msp_connect();
    let mut d = Decoder::new(DecoderSettings::default()).expect("valid");
    let f = exchange(&mut s, &mut d, command::BOXIDS);
    let ids = BoxIds::decode(&f.payload);
    let mut rc = Rc { s, d, status: None };

    // The hover command: quad's hover motor output (0.58 of full speed by default) through
    // the firmware's throttle-to-motor map (idle 1055 us at zero throttle, 2000 us at full),
    // rounded; the height loop below trims it, as the gateway's calibration will.
    let params = quad::QuadParams::default();
    let hover_us = 1000.0 + 1000.0 * (params.hover_command() * 1000.0 - 55.0) / 945.0;
    let target_up_m = 1.0;
    let (low, high, angle_on) = (1000u16, 1800u16, 1800u16);
    let started = Instant::now();
    let mut latest = None::<Pose>;
    let mut armed_at = None::<Instant>;
    let mut integral = 0.0f64;
    let mut heights = Vec::new();
    let mut max_tilt = 0.0f64;
    let mut tick = 0u64;
    let mut switch_high = false;
    let (mut roll_at_stick, mut pitch_at_stick) = (Vec::new(), Vec::new());
    let period = Duration::from_millis(20);
    let mut next = Instant::now();
    loop {
        let t = started.elapsed().as_secs_f64();
        read_poses(&pose_sock, &mut latest);
        rc.drain();
        let armed = rc.status.as_ref().and_then(|st| st.is_on(&ids, boxes::ARM)) == Some(true);
        if armed && armed_at.is_none() {
            armed_at = Some(Instant::now());
            eprintln!("armed at {t:.2} s");
        }
        // 3 s with the switch low (boot grace, gyro calibration), throttle low; then the
        // switch high; once armed, the height loop.
        // (The calibration's length depends on the machine's load: the switch goes high once
        // nothing refuses arming, and back low if the firmware latched ARM_SWITCH.)
        let ready = rc.status.as_ref().is_some_and(|st| st.arming_disabled.none());
        let latched =
            rc.status.as_ref().is_some_and(|st| st.arming_disabled.contains(ArmingDisabled::ARM_SWITCH));
        if t > 1.0 && ready {
            switch_high = true;
        }
        if latched && armed_at.is_none() {
            switch_high = false;
        }
        let arm_switch = if switch_high { high } else { low };
        // After arming: level, then 1.5 s of roll stick right, 1.5 s of pitch stick forward,
        // then level again. The tilt each gives proves the motor order: with motors swapped
        // the firmware's corrections would tip the body over.
        let since_armed = armed_at.map_or(0.0, |a| a.elapsed().as_secs_f64());
        let (roll_us, pitch_us) = if (5.0..6.5).contains(&since_armed) {
            (1600, 1500)
        } else if (6.5..8.0).contains(&since_armed) {
            (1500, 1600)
        } else {
            (1500, 1500)
        };
        let throttle_us = match (armed_at, latest) {
            (Some(_), Some(p)) => {
                let up = -f64::from(p.ned[2]);
                let climb = -f64::from(p.vz_body);
                // The target climbs to its height over 2 s (no step, no overshoot); the
                // integral starts off the ground (no wind-up while the motors spin up).
                let since = armed_at.map_or(0.0, |a| a.elapsed().as_secs_f64());
                let err = target_up_m * (since / 2.0).min(1.0) - up;
                if up > 0.1 {
                    integral = (integral + err * 0.02).clamp(-3.0, 3.0);
                }
                (hover_us + 50.0 * err - 60.0 * climb + 10.0 * integral).clamp(1300.0, 1800.0)
            }
            _ => 1000.0,
        };
        rc.send(
            Sticks { roll_us, pitch_us, throttle_us: throttle_us as u16, yaw_us: 1500 },
            &[arm_switch, angle_on, low, low],
        );
        // MSP_STATUS_EX 4 times a second until armed, then once a second: the firmware's
        // serial task takes one frame per run, and RC frames must not queue behind requests.
        if tick.is_multiple_of(if armed_at.is_some() { 50 } else { 12 }) {
            rc.ask_status();
        }
        if armed_at.is_none() && tick.is_multiple_of(25) {
            eprintln!(
                "t={t:.2} {:?}",
                rc.status.as_ref().map(|s| (s.is_on(&ids, boxes::ARM), s.arming_disabled.names()))
            );
        }
        if let (Some(at), Some(p)) = (armed_at, latest) {
            let since = at.elapsed().as_secs_f64();
            if tick.is_multiple_of(25) {
                eprintln!(
                    "t={t:.2} plant={:.2} up={:.3} roll={:.1} pitch={:.1} deg throttle={throttle_us:.0} {:?}",
                    p.t_s,
                    -p.ned[2],
                    p.roll.to_degrees(),
                    p.pitch.to_degrees(),
                    rc.status.as_ref().map(|s| (s.is_on(&ids, boxes::ARM), s.arming_disabled.names()))
                );
            }
            if since > 4.0 {
                heights.push(-f64::from(p.ned[2]));
            }
            if (4.0..5.0).contains(&since) {
                max_tilt = max_tilt.max(p.roll.abs().max(p.pitch.abs()));
            }
            if (6.0..6.5).contains(&since) {
                roll_at_stick.push(p.roll.to_degrees());
            }
            if (7.5..8.0).contains(&since) {
                pitch_at_stick.push(p.pitch.to_degrees());
            }
            if since > 9.0 {
                break;
            }
        }
        assert!(t < 30.0, "never armed: {:?}", rc.status.as_ref().map(|s| s.arming_disabled.names()));
        if armed_at.is_some() && rc.status.as_ref().is_some_and(|st| lost_rc(st, &ids)) {
            eprintln!(
                "t={t:.2}: lost: {:?}",
                rc.status.as_ref().map(|st| (st.is_on(&ids, boxes::ARM), st.arming_disabled.names()))
            );
            return false;
        }
        tick += 1;
        next += period;
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
    }
    // The last status, fresh: a failsafe in the last second would otherwise go unseen.
    rc.ask_status();
    std::thread::sleep(Duration::from_millis(300));
    rc.drain();
    if rc.status.as_ref().is_some_and(|st| lost_rc(st, &ids)) {
        return false;
    }
    drop(b);
    let (lo, hi) = heights.iter().fold((f64::MAX, f64::MIN), |(a, b), h| (a.min(*h), b.max(*h)));
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let (roll, pitch) = (mean(&roll_at_stick), mean(&pitch_at_stick));
    eprintln!(
        "from 4 s to 9 s after arming: height {lo:.3} to {hi:.3} m; level: tilt up to {:.2} deg; \
         roll stick +100 us: roll {roll:.2} deg; pitch stick +100 us: pitch {pitch:.2} deg",
        max_tilt.to_degrees()
    );
    // Right side down (NED roll > 0) and nose down (NED pitch < 0), the same angle for both.
    // hilbench.cli makes ANGLE mode's rates curve a line (centre rate = full rate), so the tilt
    // is angle_limit * deflection: 20 deg * 100 / 500 = 4 deg (the firmware's defaults gave 1.1).
    assert!((3.0..5.0).contains(&roll), "roll stick right: {roll:.2} deg, 4 expected");
    assert!((3.0..5.0).contains(&-pitch), "pitch stick forward: {pitch:.2} deg, 4 expected");
    assert!((roll + pitch).abs() < 0.5, "roll and pitch alike: {roll:.2} and {pitch:.2} deg");
    assert!(heights.len() > 200, "poses (at the loop's 50 Hz) through the hover: {}", heights.len());
    assert!(lo > 0.5 && hi < 1.5, "a steady height about 1 m: {lo:.3} to {hi:.3} m");
    assert!(
        max_tilt.to_degrees() < 1.0,
        "level in ANGLE mode with the sticks centred: {:.1} deg",
        max_tilt.to_degrees()
    );
    true
}
