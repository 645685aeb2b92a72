//! bfsim against the real firmware (Betaflight 4.6.0 SITL): the binary started as a user
//! starts it, the firmware spoken to over MSP on TCP 5761 as the gateway will, the pose stream
//! read as a motion-capture consumer would (pymavlink, an independent implementation, and the
//! `mavlink` crate).
//!
//! Needs the SITL binary cached by `scripts/betaflight-sitl.sh`; without it each test says so
//! and passes, unless `HILBENCH_REQUIRE_SITL=1` (then a missing binary fails it). The SITL's
//! ports are fixed, so one runs per machine: the tests take [`SITL`] in turn.

use msp::messages::FcVariant;
use msp::{Decoder, DecoderSettings, Frame, command};
use std::io::{BufRead, BufReader};
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
    assert!(got > 200, "the firmware answers state packets with motor packets: {end}");
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
