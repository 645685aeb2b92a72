//! The vehicle gateway (see ARCHITECTURE.md): the `hilbench.v1.Plant` API served in real time
//! for a MAVLink autopilot, and `hilbench.v1.VehicleControl` to arm it and set its mode; and
//! [`mavsim`], the MAV model playing the autopilot's side of the same MAVLink subset.
//!
//! The decisions are [`mavbridge`]'s (frames, thrust, setpoints, the command timeout, resets);
//! this crate is the shell: the runtime reads a UDP link as its datagrams arrive (a thread reads
//! a serial one) and feeds the core, a thread sends what the core schedules (setpoints at 50 Hz,
//! heartbeats, `TIMESYNC`), the gRPC services decode, call the core, send and encode, and health
//! follows the vehicle's heartbeat (and goes NOT_SERVING from a reboot of the vehicle until the
//! next `Reset`).

pub mod betaflight;
pub mod link;
pub mod mavsim;
pub mod service;

pub use link::{Frame, Link, LinkError, TryRecv};
pub use service::{GatewayService, NotServing};

use hilbench_proto::pb::plant_server::PlantServer;
use hilbench_proto::pb::vehicle_control_server::VehicleControlServer;
use hilbench_svc::{GrpcServer, ServeError};
use mav::Scenario;
use mavbridge::{Bridge, BridgeError, BridgeSettings};
use std::future::Future;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;
use tokio::io::Interest;
use tonic::server::NamedService;

/// Settings of one gateway.
#[derive(Debug, Clone, PartialEq)]
pub struct GatewayConfig {
    /// `udpin:HOST:PORT`, `udpout:HOST:PORT` or `serial:DEVICE:BAUD`.
    pub mavlink: String,
    /// The scenario in force until a `Reset` brings another (obstacles, goal, limits).
    pub scenario: Scenario,
    pub bridge: BridgeSettings,
    /// The gateway's MAVLink system and component ids.
    pub system_id: u8,
    pub component_id: u8,
    pub max_streams: usize,
    pub stream_buffer: usize,
    /// TLS of the Plant and VehicleControl APIs (default: plaintext).
    pub tls: hilbench_svc::tls::Tls,
    /// Limits on the server's connections and on the streams one client holds
    /// (`--max-connections`, `--handshake-timeout-s`, `--idle-timeout-s`,
    /// `--max-streams-per-client`).
    pub connections: hilbench_svc::connections::ConnectionLimits,
    /// MAVLink 2 signing of the vehicle link (`--mavlink-signing-key`; `None`: unsigned).
    pub signing_key: Option<mavbridge::SigningKey>,
    /// The client certificates (common names) that may call VehicleControl (`--allow-client`;
    /// empty: any client the TLS set-up lets in).
    pub allow_clients: Vec<String>,
    /// `--record-link FILE`: the `TIMESYNC` round trips of the vehicle link as a delay trace
    /// (the requests then go at [`RECORD_LINK_TIMESYNC_PERIOD_NS`]).
    pub record_link: Option<std::path::PathBuf>,
}

/// The `TIMESYNC` request period while `--record-link` records, ns (10 Hz).
pub const RECORD_LINK_TIMESYNC_PERIOD_NS: u64 = 100_000_000;

/// Requests `mavbridge`'s `TimeSync` keeps waiting for their answer: an answer later than this
/// many request periods is not taken, so `--record-link` counts it lost.
const TIMESYNC_OUTSTANDING: u64 = 8;

impl GatewayConfig {
    /// Listening on `mavlink`, paper-1, the defaults of [`BridgeSettings`].
    pub fn new(mavlink: impl Into<String>, scenario: Scenario) -> Self {
        Self {
            mavlink: mavlink.into(),
            scenario,
            bridge: BridgeSettings::default(),
            system_id: 255,
            component_id: 191,
            max_streams: hilbench_svc::streams::DEFAULT_MAX_STREAMS,
            stream_buffer: 256,
            tls: hilbench_svc::tls::Tls::plaintext(),
            connections: hilbench_svc::connections::ConnectionLimits::default(),
            signing_key: None,
            allow_clients: Vec::new(),
            record_link: None,
        }
    }
}

/// Why the gateway could not serve.
#[derive(Debug, thiserror::Error)]
pub enum GatewayError {
    #[error(transparent)]
    Config(#[from] BridgeError),
    #[error(transparent)]
    Link(#[from] LinkError),
    #[error(transparent)]
    Serve(#[from] ServeError),
    #[error("invalid gateway setting `{0}`: must be at least 1")]
    Count(&'static str),
    #[error("{0}")]
    Msp(String),
}

/// Why a signing key file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum KeyFileError {
    #[error("--mavlink-signing-key {}: cannot read it: {source}", path.display())]
    Read { path: std::path::PathBuf, source: std::io::Error },
    #[error("--mavlink-signing-key {}: {source}", path.display())]
    Key { path: std::path::PathBuf, source: mavbridge::KeyError },
    #[error(
        "--mavlink-signing-key {}: readable or writable by every user (mode {mode:o}); the key signs commands to the vehicle: chmod 600 it",
        path.display()
    )]
    WorldReadable { path: std::path::PathBuf, mode: u32 },
}

/// Largest MAVLink signing key file, bytes.
const MAX_KEY_FILE_BYTES: u64 = 1024;

/// Reads a MAVLink signing key file (32 bytes, or 64 hex digits) that other users cannot read.
pub fn signing_key_file(path: &std::path::Path) -> Result<mavbridge::SigningKey, KeyFileError> {
    use std::os::unix::fs::PermissionsExt;
    let read = |source| KeyFileError::Read { path: path.into(), source };
    let mode = std::fs::metadata(path).map_err(read)?.permissions().mode();
    if mode & 0o006 != 0 {
        return Err(KeyFileError::WorldReadable { path: path.into(), mode: mode & 0o777 });
    }
    // A regular file of at most a few bytes (a key is 32 bytes, or 64 hex digits and a newline).
    let contents =
        hilbench_scenario_file::user_file::read_bytes(path, MAX_KEY_FILE_BYTES, "a MAVLink signing key")
            .map_err(|e| read(std::io::Error::other(e.reason)))?;
    mavbridge::SigningKey::parse(&contents).map_err(|source| KeyFileError::Key { path: path.into(), source })
}

/// Reports every one of `names` SERVING or NOT_SERVING.
async fn set_health(health: &tonic_health::server::HealthReporter, names: &[&str], serving: bool) {
    use tonic_health::ServingStatus;
    let status = if serving { ServingStatus::Serving } else { ServingStatus::NotServing };
    for name in names {
        health.set_service_status(*name, status).await;
    }
}

/// Serves the gateway on `listener` until `shutdown` resolves.
pub async fn serve(
    listener: tokio::net::TcpListener,
    config: GatewayConfig,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), GatewayError> {
    let link = Link::open_signed(
        &config.mavlink,
        config.system_id,
        config.component_id,
        config.signing_key.clone(),
    )?;
    serve_with_link(listener, config, link, shutdown).await
}

/// As [`serve`], on a link already open (`config.mavlink` only names it, and the link's own
/// signing key is used, not `config.signing_key`); tests open a `udpin:127.0.0.1:0` link to
/// learn its port first.
pub async fn serve_with_link(
    listener: tokio::net::TcpListener,
    config: GatewayConfig,
    link: Link,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), GatewayError> {
    if config.max_streams == 0 {
        return Err(GatewayError::Count("max_streams"));
    }
    if config.stream_buffer == 0 {
        return Err(GatewayError::Count("stream_buffer"));
    }
    let mut settings = config.bridge;
    if config.record_link.is_some() {
        settings.timesync_period_ns = settings.timesync_period_ns.min(RECORD_LINK_TIMESYNC_PERIOD_NS);
    }
    let bridge = Bridge::new(config.scenario.clone(), settings, 0, 1)?;
    let service = GatewayService::new(
        bridge,
        link.clone(),
        hilbench_svc::streams::StreamSlots::new(
            "gateway",
            config.max_streams,
            config.connections.max_streams_per_client,
        ),
        config.stream_buffer,
        config.allow_clients.clone(),
    );
    if let Some(path) = &config.record_link {
        let timeout_ns = TIMESYNC_OUTSTANDING * settings.timesync_period_ns;
        service.record_link(
            path.clone(),
            timeout_ns,
            format!("MAVLink {} (the vehicle link)", config.mavlink),
        );
    }
    const NAMES: [&str; 2] =
        [PlantServer::<GatewayService>::NAME, VehicleControlServer::<GatewayService>::NAME];
    let server = GrpcServer::new("gateway", listener, true, &config.tls, &config.connections, &NAMES).await?;
    let (addr, health) = (server.addr, server.health.clone());
    // Not serving until the vehicle's heartbeat arrives.
    set_health(&health, &NAMES, false).await;

    let stop = Arc::new(AtomicBool::new(false));
    let reader = match link.udp_socket().map_err(ServeError::Io)? {
        Some(socket) => {
            // Registered with the runtime for readiness only: the link reads it.
            let ready = tokio::net::UdpSocket::from_std(socket).map_err(ServeError::Io)?;
            Ok(Reader::Task(tokio::spawn(read_udp(ready, link.clone(), service.clone()))))
        }
        None => {
            let (service, stop, link) = (service.clone(), stop.clone(), link.clone());
            std::thread::Builder::new()
                .name("mavlink-recv".into())
                .spawn(move || {
                    while !stop.load(Ordering::Relaxed) {
                        if let Some(frame) = link.recv() {
                            service.on_frame(frame);
                        }
                    }
                })
                .map(Reader::Thread)
        }
    };
    let scheduler = {
        let (service, stop) = (service.clone(), stop.clone());
        std::thread::Builder::new().name("mavlink-send".into()).spawn(move || {
            while !stop.load(Ordering::Relaxed) {
                let next = service.poll();
                let wait = next.saturating_sub(service.shared.now_ns()).min(10_000_000);
                std::thread::sleep(Duration::from_nanos(wait));
            }
        })
    };
    let (reader, scheduler) = match (reader, scheduler) {
        (Ok(r), Ok(s)) => (r, s),
        (Err(e), _) | (_, Err(e)) => return Err(GatewayError::Serve(ServeError::Io(e))),
    };
    let health_task = {
        let (service, health, link) = (service.clone(), health.clone(), link.clone());
        tokio::spawn(async move {
            let mut serving = false;
            loop {
                let not_serving = service.not_serving();
                if not_serving.is_none() != serving {
                    serving = not_serving.is_none();
                    set_health(&health, &NAMES, serving).await;
                    match not_serving {
                        None => tracing::info!("vehicle heartbeat, no reboot since the last reset: serving"),
                        Some(NotServing::HeartbeatLost) => {
                            let why = link.status().down.map(|d| format!(" ({d})")).unwrap_or_default();
                            tracing::warn!(
                                "vehicle heartbeat lost for 2 s{why}: NOT_SERVING, calls answer UNAVAILABLE"
                            );
                        }
                        // The reader logged the reboot once, naming the Reset it needs.
                        Some(NotServing::Rebooted) => {}
                    }
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        })
    };

    let service_for_record = service.clone();
    let signal = {
        let service = service.clone();
        async move {
            shutdown.await;
            tracing::info!("gateway shutting down");
            // NOT_SERVING first, and for good: the task that follows the heartbeat stops.
            health_task.abort();
            set_health(&health, &NAMES, false).await;
            service.close();
        }
    };
    tracing::info!(
        %addr,
        mavlink = %config.mavlink,
        signed = link.signs(),
        scenario = %config.scenario.name,
        "gateway serving"
    );
    let result = server
        .serve(
            |router| {
                router
                    .add_service(PlantServer::new(service.clone()))
                    .add_service(VehicleControlServer::new(service))
            },
            signal,
        )
        .await;
    stop.store(true, Ordering::Relaxed);
    match reader {
        Reader::Task(task) => {
            // Gone before this returns: the link's socket is closed when `serve` is.
            task.abort();
            let _ = task.await;
        }
        Reader::Thread(thread) => {
            let _ = thread.join();
        }
    }
    let _ = scheduler.join();
    service_for_record.finish_link_record();
    result?;
    tracing::info!("gateway stopped");
    Ok(())
}

/// Who reads the link.
enum Reader {
    /// A UDP link: a task on the runtime.
    Task(tokio::task::JoinHandle<()>),
    /// A serial link: a thread of its own (blocking reads, reopening a lost device).
    Thread(std::thread::JoinHandle<()>),
}

/// Reads a UDP link on the runtime, the frames of each datagram as it arrives. A sample made of
/// one is then served by the same worker: one thread woken per state, where a reading thread of
/// its own would wake and then wake a worker (BENCHMARKS.md, the gateway's overhead).
async fn read_udp(ready: tokio::net::UdpSocket, link: Link, service: GatewayService) {
    let would_block = || std::io::Error::from(std::io::ErrorKind::WouldBlock);
    loop {
        if ready.readable().await.is_err() {
            // Only a runtime shutting down fails here.
            return;
        }
        // Until the socket is drained; `try_io` then clears its readiness.
        loop {
            let received = ready.try_io(Interest::READABLE, || match link.try_recv() {
                TryRecv::Empty => Err(would_block()),
                other => Ok(other),
            });
            match received {
                Ok(TryRecv::Frame(frame)) => service.on_frame(frame),
                Ok(TryRecv::Empty) => {}
                Ok(TryRecv::Failed) => tokio::time::sleep(link::UDP_ERROR_PAUSE).await,
                Err(_) => break,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    #[test]
    fn a_signing_key_file_is_refused_naming_the_flag_when_missing_short_huge_not_a_file_or_readable_by_everyone()
     {
        let dir = std::env::temp_dir().join(format!("gateway-key-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("a directory");
        let write = |name: &str, contents: &[u8], mode: u32| {
            let path = dir.join(name);
            std::fs::write(&path, contents).expect("written");
            std::fs::set_permissions(&path, std::fs::Permissions::from_mode(mode)).expect("chmod");
            path
        };
        let good = write("good", &[1; 32], 0o600);
        assert_eq!(signing_key_file(&good).expect("a key"), mavbridge::SigningKey::new([1; 32]));
        let hex = write("hex", format!("{}\n", "ab".repeat(32)).as_bytes(), 0o640);
        assert_eq!(signing_key_file(&hex).expect("a key"), mavbridge::SigningKey::new([0xab; 32]));
        let missing = dir.join("missing");
        let short = write("short", &[1; 31], 0o600);
        let open = write("open", &[1; 32], 0o644);
        let huge = write("huge", &[b'a'; 4096], 0o600);
        let folder = dir.join("folder");
        std::fs::create_dir_all(&folder).expect("a folder");
        std::fs::set_permissions(&folder, std::fs::Permissions::from_mode(0o700)).expect("chmod");
        for (path, says) in [
            (&missing, "cannot read"),
            (&short, "31 bytes"),
            (&open, "chmod 600"),
            (&huge, "more than the 1024 bytes"),
            (&folder, "a directory"),
        ] {
            let e = signing_key_file(path).expect_err("refused").to_string();
            assert!(e.starts_with("--mavlink-signing-key") && e.contains(says), "{e}");
            assert!(e.contains(&path.display().to_string()), "{e}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
