//! The firmware as a child process: where the cached SITL binary is, its working directory
//! (its `eeprom.bin`), the configuration applied through the CLI on TCP 5761 when that
//! directory lacks it, and what the firmware says about itself over MSP.
//!
//! The child is started through `setpriv --pdeathsig KILL` when util-linux's `setpriv` is
//! there: the kernel then kills the SITL when the thread that started it ends, whatever ends
//! it (a panic that aborts, SIGKILL), so no firmware outlives its vehicle. [`Sitl`]'s `Drop`
//! kills it too. Start it from a thread that lives as long as the vehicle (the binary's main
//! thread).

use msp::messages::{ApiVersion, FcVariant, FcVersion, ModeRange, boxes};
use msp::{Decoder, DecoderSettings, Frame, Version, cli, command, reply_payload};
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The SITL's MSP and CLI port (its UART1).
pub const MSP_PORT: u16 = 5761;
/// Where the SITL listens for state packets.
pub const FDM_PORT: u16 = 9003;
/// Where the SITL sends motor packets.
pub const SERVO_PORT: u16 = 9002;
/// The script that builds and caches the binary.
pub const SCRIPT: &str = "scripts/betaflight-sitl.sh";
/// The project's configuration of the firmware (`firmware/betaflight/hilbench.cli`).
pub const HILBENCH_CLI: &str = include_str!("../../firmware/betaflight/hilbench.cli");
/// Next to `eeprom.bin`: the CLI text that was saved into it.
pub const STAMP: &str = "hilbench.cli.applied";

#[derive(Debug, thiserror::Error)]
pub enum FirmwareError {
    #[error("no Betaflight SITL binary at {0}: build it with {SCRIPT} (or name one with --sitl)")]
    Missing(PathBuf),
    #[error("{what}: port {port} is taken (another SITL running? one SITL runs per machine)")]
    PortTaken { what: &'static str, port: u16 },
    #[error("cannot start {binary}: {source}")]
    Spawn { binary: PathBuf, source: std::io::Error },
    #[error("the SITL exited ({status}); its log: {log}")]
    Exited { status: std::process::ExitStatus, log: PathBuf },
    #[error("the SITL never listened on TCP {MSP_PORT} within {0:?}")]
    NoListener(Duration),
    #[error("the CLI: {0}")]
    Cli(String),
    #[error("MSP: {0}")]
    Msp(String),
    #[error("the working directory {dir}: {source}")]
    Workdir { dir: PathBuf, source: std::io::Error },
    #[error("io: {0}")]
    Io(#[from] std::io::Error),
}

/// Where `scripts/betaflight-sitl.sh --check` finds the cached binary:
/// `${HILBENCH_CACHE:-$HOME/.cache/hilbench}/betaflight-4.6.0/betaflight_4.6.0_SITL`
/// (`lockstep/` before the file name for the lockstep build).
pub fn default_binary(lockstep: bool) -> PathBuf {
    let cache = std::env::var_os("HILBENCH_CACHE").map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(std::env::var_os("HOME").unwrap_or_else(|| "/root".into())).join(".cache/hilbench")
    });
    let dir = cache.join("betaflight-4.6.0");
    let dir = if lockstep { dir.join("lockstep") } else { dir };
    dir.join("betaflight_4.6.0_SITL")
}

/// The machine-wide lock of the SITL's fixed ports:
/// `${HILBENCH_CACHE:-$HOME/.cache/hilbench}/betaflight-4.6.0/sitl.lock`, held (`flock`,
/// exclusive) by whoever runs a SITL, released when the holder ends however it ends.
pub fn lock_path() -> PathBuf {
    default_binary(false).with_file_name("sitl.lock")
}

/// The lock of [`lock_path`], held while this lives.
#[derive(Debug)]
pub struct SitlLock {
    _file: std::fs::File,
}

impl SitlLock {
    /// Takes the lock, waiting up to `within` for another holder to end.
    pub fn acquire(within: Duration) -> Result<Self, FirmwareError> {
        let path = lock_path();
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)?;
        }
        let file = std::fs::OpenOptions::new().create(true).truncate(false).write(true).open(&path)?;
        let started = Instant::now();
        loop {
            match rustix::fs::flock(&file, rustix::fs::FlockOperation::NonBlockingLockExclusive) {
                Ok(()) => return Ok(Self { _file: file }),
                Err(_) if started.elapsed() < within => std::thread::sleep(Duration::from_millis(100)),
                Err(_) => {
                    return Err(FirmwareError::PortTaken {
                        what: "the SITL lock (another bfsim?)",
                        port: MSP_PORT,
                    });
                }
            }
        }
    }
}

/// Checks that the binary is there, else names the script.
pub fn check_binary(binary: &Path) -> Result<(), FirmwareError> {
    if binary.is_file() { Ok(()) } else { Err(FirmwareError::Missing(binary.to_path_buf())) }
}

/// Checks that the SITL's fixed ports are free (one SITL per machine).
pub fn check_ports() -> Result<(), FirmwareError> {
    TcpListener::bind(("0.0.0.0", MSP_PORT))
        .map_err(|_| FirmwareError::PortTaken { what: "MSP", port: MSP_PORT })?;
    UdpSocket::bind(("0.0.0.0", FDM_PORT))
        .map_err(|_| FirmwareError::PortTaken { what: "state packets", port: FDM_PORT })?;
    Ok(())
}

/// A SITL process in its working directory; killed (and reaped) on drop.
#[derive(Debug)]
pub struct Sitl {
    child: Child,
    dir: PathBuf,
}

fn setpriv() -> Option<PathBuf> {
    ["/usr/bin/setpriv", "/bin/setpriv"].iter().map(PathBuf::from).find(|p| p.is_file())
}

impl Sitl {
    /// Starts `binary` in `dir`, its output appended to `dir/sitl.log`.
    pub fn start(binary: &Path, dir: &Path) -> Result<Self, FirmwareError> {
        check_binary(binary)?;
        let log = std::fs::OpenOptions::new().create(true).append(true).open(dir.join("sitl.log"))?;
        let mut cmd = match setpriv() {
            Some(setpriv) => {
                let mut c = Command::new(setpriv);
                c.args(["--pdeathsig", "KILL", "--"]).arg(binary);
                c
            }
            None => Command::new(binary),
        };
        let child = cmd
            .current_dir(dir)
            .stdin(Stdio::null())
            .stdout(log.try_clone()?)
            .stderr(log)
            .spawn()
            .map_err(|source| FirmwareError::Spawn { binary: binary.to_path_buf(), source })?;
        Ok(Self { child, dir: dir.to_path_buf() })
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    pub fn log(&self) -> PathBuf {
        self.dir.join("sitl.log")
    }

    /// `Some(status)` once the process has ended.
    pub fn exited(&mut self) -> Option<std::process::ExitStatus> {
        self.child.try_wait().ok().flatten()
    }

    fn fail_if_exited(&mut self) -> Result<(), FirmwareError> {
        match self.exited() {
            Some(status) => Err(FirmwareError::Exited { status, log: self.log() }),
            None => Ok(()),
        }
    }

    /// Connects to TCP 5761 once the firmware listens.
    pub fn connect(&mut self, within: Duration) -> Result<TcpStream, FirmwareError> {
        let started = Instant::now();
        loop {
            self.fail_if_exited()?;
            if let Ok(s) = TcpStream::connect(("127.0.0.1", MSP_PORT)) {
                s.set_read_timeout(Some(Duration::from_millis(50)))?;
                s.set_nodelay(true)?;
                return Ok(s);
            }
            if started.elapsed() > within {
                return Err(FirmwareError::NoListener(within));
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Waits for the process to end by itself (after `save`).
    fn wait_exit(&mut self, within: Duration) -> Result<std::process::ExitStatus, FirmwareError> {
        let started = Instant::now();
        loop {
            if let Some(status) = self.exited() {
                return Ok(status);
            }
            if started.elapsed() > within {
                return Err(FirmwareError::Cli(format!(
                    "the SITL did not exit within {within:?} after `save`"
                )));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Kills the process and reaps it.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Sitl {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Whether `dir`'s `eeprom.bin` holds `cli_text` (saved by [`configure`]).
pub fn is_configured(dir: &Path, cli_text: &str) -> bool {
    dir.join("eeprom.bin").is_file() && std::fs::read_to_string(dir.join(STAMP)).is_ok_and(|s| s == cli_text)
}

/// Applies `cli_text` to the firmware in `dir` unless its `eeprom.bin` already holds it: starts
/// the SITL there, enters the CLI, sends each command, `save` (the SITL writes `eeprom.bin` and
/// exits), and records the text beside `eeprom.bin`. Returns whether it applied anything.
pub fn configure(binary: &Path, dir: &Path, cli_text: &str) -> Result<bool, FirmwareError> {
    if is_configured(dir, cli_text) {
        return Ok(false);
    }
    let _ = std::fs::remove_file(dir.join(STAMP));
    let mut sitl = Sitl::start(binary, dir)?;
    let mut s = sitl.connect(Duration::from_secs(10))?;
    enter_cli(&mut s)?;
    for cmd in cli::commands(cli_text) {
        s.write_all(format!("{cmd}\r\n").as_bytes())?;
        let out = read_to_prompt(&mut s, Duration::from_secs(5))?
            .ok_or_else(|| FirmwareError::Cli(format!("no prompt after `{cmd}`")))?;
        if let Some(err) = cli::error_in(&out) {
            return Err(FirmwareError::Cli(format!("the firmware refused `{cmd}`: {err}")));
        }
    }
    s.write_all(b"save\r\n")?;
    let status = sitl.wait_exit(Duration::from_secs(10))?;
    if !status.success() || !dir.join("eeprom.bin").is_file() {
        return Err(FirmwareError::Cli(format!("`save` ended the SITL with {status} and no eeprom.bin")));
    }
    std::fs::write(dir.join(STAMP), cli_text)?;
    Ok(true)
}

/// Reads CLI output until the prompt, within `within` (`None`: no prompt).
fn read_to_prompt(s: &mut TcpStream, within: Duration) -> Result<Option<String>, FirmwareError> {
    let started = Instant::now();
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    while started.elapsed() < within {
        match s.read(&mut buf) {
            Ok(0) => return Err(FirmwareError::Cli("the SITL closed the connection".into())),
            Ok(n) => out.extend_from_slice(&buf[..n]),
            Err(e) if is_timeout(&e) => {}
            Err(e) => return Err(e.into()),
        }
        let text = String::from_utf8_lossy(&out);
        if cli::at_prompt(&text) {
            return Ok(Some(text.into_owned()));
        }
    }
    Ok(None)
}

fn is_timeout(e: &std::io::Error) -> bool {
    matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut)
}

/// Opens the CLI: `#` alone, again until the prompt answers (docs/betaflight.md).
fn enter_cli(s: &mut TcpStream) -> Result<(), FirmwareError> {
    for _ in 0..20 {
        s.write_all(&[cli::ENTER])?;
        if read_to_prompt(s, Duration::from_millis(500))?.is_some() {
            return Ok(());
        }
    }
    Err(FirmwareError::Cli("the CLI never answered `#`".into()))
}

/// What the firmware says about itself over MSP.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FirmwareInfo {
    /// MSP_FC_VARIANT: `BTFL`.
    pub variant: String,
    /// MSP_FC_VERSION: `4.6.0`.
    pub version: String,
    /// MSP_API_VERSION, `major.minor`.
    pub api: String,
    /// The configuration's AUX ranges are in force (ARM on AUX1, ANGLE on AUX2).
    pub configured: bool,
}

impl std::fmt::Display for FirmwareInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "variant={} version={} msp_api={} configured={}",
            self.variant, self.version, self.api, self.configured
        )
    }
}

/// One MSP exchange on `s`: the request, then frames until the reply to its command.
pub fn exchange(
    s: &mut TcpStream,
    d: &mut Decoder,
    command: u16,
    payload: &[u8],
    within: Duration,
) -> Result<Frame, FirmwareError> {
    let bytes = Frame::request(Version::V1, command, payload.to_vec())
        .to_bytes()
        .map_err(|e| FirmwareError::Msp(format!("encode {command}: {e}")))?;
    s.write_all(&bytes)?;
    let started = Instant::now();
    let mut buf = [0u8; 1024];
    while started.elapsed() < within {
        match s.read(&mut buf) {
            Ok(0) => return Err(FirmwareError::Msp("the SITL closed the connection".into())),
            Ok(n) => {
                if let Some(f) = d.feed(&buf[..n]).find(|f| f.command == command) {
                    return Ok(f);
                }
            }
            Err(e) if is_timeout(&e) => {}
            Err(e) => return Err(e.into()),
        }
    }
    Err(FirmwareError::Msp(format!("no reply to command {command} within {within:?}")))
}

/// Asks the firmware on 5761 for its variant, version, API version and AUX ranges, then
/// closes the connection (the port takes one client: the gateway's).
pub fn query_info(s: &mut TcpStream) -> Result<FirmwareInfo, FirmwareError> {
    let mut d = Decoder::new(DecoderSettings::default()).map_err(|e| FirmwareError::Msp(e.to_string()))?;
    let within = Duration::from_secs(3);
    let msp_err = |e: msp::DecodeError| FirmwareError::Msp(e.to_string());
    // The first request may come before the firmware's serial task runs (a loaded machine
    // boots it slowly): asked again until it answers.
    let mut first = None;
    for _ in 0..5 {
        match exchange(s, &mut d, command::FC_VARIANT, &[], within) {
            Ok(f) => {
                first = Some(f);
                break;
            }
            Err(FirmwareError::Msp(_)) => continue,
            Err(e) => return Err(e),
        }
    }
    let f = first
        .ok_or_else(|| FirmwareError::Msp(format!("no answer to MSP_FC_VARIANT in 5 tries of {within:?}")))?;
    let variant =
        FcVariant::decode(reply_payload(&f, command::FC_VARIANT).map_err(msp_err)?).map_err(msp_err)?;
    let f = exchange(s, &mut d, command::FC_VERSION, &[], within)?;
    let version =
        FcVersion::decode(reply_payload(&f, command::FC_VERSION).map_err(msp_err)?).map_err(msp_err)?;
    let f = exchange(s, &mut d, command::API_VERSION, &[], within)?;
    let api =
        ApiVersion::decode(reply_payload(&f, command::API_VERSION).map_err(msp_err)?).map_err(msp_err)?;
    let f = exchange(s, &mut d, command::MODE_RANGES, &[], within)?;
    let ranges =
        ModeRange::decode_all(reply_payload(&f, command::MODE_RANGES).map_err(msp_err)?).map_err(msp_err)?;
    let has = |id, aux| ranges.iter().any(|r| r.is_used() && r.permanent_id == id && r.aux_index == aux);
    Ok(FirmwareInfo {
        variant: variant.as_str().to_string(),
        version: version.to_string(),
        api: format!("{}.{}", api.major, api.minor),
        configured: has(boxes::ARM, 0) && has(boxes::ANGLE, 1),
    })
}

/// A working directory: the one named (kept), or a fresh one under the temp dir (removed on
/// drop).
#[derive(Debug)]
pub struct Workdir {
    path: PathBuf,
    remove: bool,
}

impl Workdir {
    pub fn new(named: Option<&Path>) -> Result<Self, FirmwareError> {
        let (path, remove) = match named {
            Some(p) => (p.to_path_buf(), false),
            None => {
                let nanos = std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0, |d| d.subsec_nanos());
                (std::env::temp_dir().join(format!("bfsim-{}-{nanos}", std::process::id())), true)
            }
        };
        std::fs::create_dir_all(&path)
            .map_err(|source| FirmwareError::Workdir { dir: path.clone(), source })?;
        Ok(Self { path, remove })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for Workdir {
    fn drop(&mut self) {
        if self.remove {
            let _ = std::fs::remove_dir_all(&self.path);
        }
    }
}
