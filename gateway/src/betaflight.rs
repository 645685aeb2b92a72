//! The gateway for a Betaflight flight controller over MSP (`gateway --msp`): the same
//! `hilbench.v1.Plant` and `VehicleControl` as the MAVLink side, around
//! [`mavbridge::betaflight::MspBridge`]. The shell moves bytes: one thread reads the flight
//! controller (TCP to SITL's 5761, or a serial device: the same bytes), one sends what the core
//! schedules (RC at 50 Hz, the requests), one reads the pose stream (MAVLink `ODOMETRY` on
//! UDP); the gRPC services decode, call the core under one lock and encode. The stream
//! subscribers, the Reset's scenario choice, `--allow-client` and the refusal of lockstep calls
//! are the MAVLink side's ([`crate::service`]).

use crate::service::{SampleStream, Subscribers, authorize, refuse_real_time, reset_scenario};
use hilbench_proto::convert::plant::{self as conv, Command, Reset, Step, StreamState};
use hilbench_proto::pb;
use hilbench_svc::streams::{Guarded, StreamSlots, drop_oldest};
use mav::{Scenario, SimSettings};
use mavbridge::betaflight::{MspBridge, MspSettings};
use mavbridge::mavlink::dialects::common::MavMessage;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};
use tokio_stream::StreamExt;
use tonic::{Request, Response, Status};

/// What the gateway calls itself in `PlantDescription.implementation`.
pub const IMPLEMENTATION: &str = concat!("hilbench-gateway ", env!("CARGO_PKG_VERSION"), " (MSP)");

/// How long `Arm` waits for the firmware to say it armed (boot grace and gyro calibration are
/// over by then on a started SITL; the switch edge is seen within a status period).
const ARM_WAIT: Duration = Duration::from_millis(3_000);
/// How long `Disarm` waits for the firmware to say it disarmed.
const DISARM_WAIT: Duration = Duration::from_millis(1_500);

/// Where the flight controller is: `tcp:HOST:PORT` or `serial:DEVICE:BAUD`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum MspAddress {
    Tcp(String),
    Serial { device: String, baud: u32 },
}

impl MspAddress {
    pub fn parse(s: &str) -> Result<Self, String> {
        if let Some(rest) = s.strip_prefix("tcp:") {
            if rest.rsplit_once(':').is_none_or(|(h, p)| h.is_empty() || p.parse::<u16>().is_err()) {
                return Err(format!("--msp {s}: expected tcp:HOST:PORT (SITL: tcp:127.0.0.1:5761)"));
            }
            return Ok(Self::Tcp(rest.to_string()));
        }
        if let Some(rest) = s.strip_prefix("serial:") {
            let (device, baud) = rest.rsplit_once(':').ok_or_else(|| {
                format!("--msp {s}: expected serial:DEVICE:BAUD (e.g. serial:/dev/ttyACM0:115200)")
            })?;
            let baud =
                baud.parse().map_err(|_| format!("--msp {s}: the baud rate `{baud}` is not a number"))?;
            return Ok(Self::Serial { device: device.to_string(), baud });
        }
        Err(format!("--msp {s}: expected tcp:HOST:PORT or serial:DEVICE:BAUD"))
    }
}

impl std::fmt::Display for MspAddress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Tcp(a) => write!(f, "tcp:{a}"),
            Self::Serial { device, baud } => write!(f, "serial:{device}:{baud}"),
        }
    }
}

/// Settings of the MSP gateway.
#[derive(Debug, Clone)]
pub struct MspConfig {
    pub msp: MspAddress,
    /// Where the pose stream (MAVLink `ODOMETRY`) arrives (`--pose-in`, 127.0.0.1:14560).
    pub pose_in: SocketAddr,
    pub scenario: Scenario,
    pub settings: MspSettings,
    pub max_streams: usize,
    pub stream_buffer: usize,
    pub tls: hilbench_svc::tls::Tls,
    pub connections: hilbench_svc::connections::ConnectionLimits,
    pub allow_clients: Vec<String>,
}

impl MspConfig {
    pub fn new(msp: MspAddress, pose_in: SocketAddr, scenario: Scenario) -> Self {
        Self {
            msp,
            pose_in,
            scenario,
            settings: MspSettings::default(),
            max_streams: hilbench_svc::streams::DEFAULT_MAX_STREAMS,
            stream_buffer: 256,
            tls: hilbench_svc::tls::Tls::plaintext(),
            connections: hilbench_svc::connections::ConnectionLimits::default(),
            allow_clients: Vec::new(),
        }
    }
}

/// The byte stream to the flight controller, reopened when lost.
trait Port: Read + Write + Send {}
impl<T: Read + Write + Send> Port for T {}

fn open(address: &MspAddress) -> std::io::Result<(Box<dyn Port>, Box<dyn Port>)> {
    match address {
        MspAddress::Tcp(a) => {
            let s = TcpStream::connect(a)?;
            s.set_nodelay(true)?;
            s.set_read_timeout(Some(Duration::from_millis(100)))?;
            Ok((Box::new(s.try_clone()?), Box::new(s)))
        }
        MspAddress::Serial { device, baud } => {
            let p = serialport::new(device, *baud)
                .timeout(Duration::from_millis(100))
                .open()
                .map_err(std::io::Error::other)?;
            let w = p.try_clone().map_err(std::io::Error::other)?;
            Ok((Box::new(p), Box::new(w)))
        }
    }
}

struct Inner {
    bridge: MspBridge,
    subscribers: Subscribers,
    closed: bool,
    next_flight_id: u64,
    /// Link losses (the TCP peer closed, the serial device lost) and write errors.
    link_losses: u64,
    link_error: Option<String>,
}

struct Shared {
    inner: Mutex<Inner>,
    origin: Instant,
    writer: Mutex<Option<Box<dyn Port>>>,
    slots: StreamSlots,
    stream_buffer: usize,
    config_scenario: Scenario,
    allow_clients: Vec<String>,
    address: MspAddress,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn now_ns(&self) -> u64 {
        u64::try_from(self.origin.elapsed().as_nanos()).unwrap_or(u64::MAX)
    }
}

/// The MSP gateway's services (cheap to clone).
#[derive(Clone)]
pub struct MspService {
    shared: Arc<Shared>,
}

impl MspService {
    fn new(bridge: MspBridge, config: &MspConfig) -> Self {
        let first_flight_id = std::hash::BuildHasher::hash_one(
            &std::collections::hash_map::RandomState::new(),
            std::process::id(),
        )
        .max(1);
        Self {
            shared: Arc::new(Shared {
                inner: Mutex::new(Inner {
                    bridge,
                    subscribers: Subscribers::default(),
                    closed: false,
                    next_flight_id: first_flight_id,
                    link_losses: 0,
                    link_error: None,
                }),
                origin: Instant::now(),
                writer: Mutex::new(None),
                slots: StreamSlots::new(
                    "gateway",
                    config.max_streams,
                    config.connections.max_streams_per_client,
                ),
                stream_buffer: config.stream_buffer,
                config_scenario: config.scenario.clone(),
                allow_clients: config.allow_clients.clone(),
                address: config.msp.clone(),
            }),
        }
    }

    /// Why the Plant API does not serve now (`None`: it does).
    pub fn not_serving(&self) -> Option<String> {
        let now = self.shared.now_ns();
        self.serving(&self.shared.lock(), now).err().map(|s| s.message().to_string())
    }

    fn serving(&self, inner: &Inner, now: u64) -> Result<(), Status> {
        let s = inner.bridge.settings();
        if !inner.bridge.link_alive(now) {
            let why = inner.link_error.as_deref().map(|e| format!(" ({e})")).unwrap_or_default();
            return Err(Status::unavailable(format!(
                "no MSP frame from the flight controller on {} for {} s: the vehicle link is lost{why}",
                self.shared.address,
                mav::ns_to_s(s.link_timeout_ns)
            )));
        }
        if !inner.bridge.pose_alive(now) {
            return Err(Status::unavailable(format!(
                "no pose (MAVLink ODOMETRY on --pose-in) for {} s: position and velocity are unknown",
                mav::ns_to_s(s.pose_timeout_ns)
            )));
        }
        Ok(())
    }

    fn send(&self, bytes: &[u8]) {
        let mut writer = self.shared.writer.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(w) = writer.as_mut()
            && let Err(e) = w.write_all(bytes)
        {
            *writer = None;
            let mut inner = self.shared.lock();
            inner.link_losses += 1;
            inner.link_error = Some(format!("write: {e}"));
            tracing::warn!("MSP link {}: {e}; reopening", self.shared.address);
        }
    }

    /// The scheduling side: what is due now; returns when to call again.
    fn poll(&self) -> u64 {
        let now = self.shared.now_ns();
        let mut out = Vec::new();
        let next = {
            let mut inner = self.shared.lock();
            inner.bridge.poll(now, &mut out);
            inner.bridge.next_due_ns()
        };
        if !out.is_empty() {
            self.send(&out);
        }
        next
    }

    /// Reads the flight controller until `stop`, reopening a lost link every half second.
    fn read_loop(&self, stop: &AtomicBool) {
        let mut buf = [0u8; 1024];
        let mut logged_down = false;
        while !stop.load(Ordering::Relaxed) {
            let (mut reader, writer) = match open(&self.shared.address) {
                Ok(p) => p,
                Err(e) => {
                    if !logged_down {
                        tracing::warn!("MSP link {}: {e}; retrying every 0.5 s", self.shared.address);
                        logged_down = true;
                    }
                    self.shared.lock().link_error = Some(e.to_string());
                    std::thread::sleep(Duration::from_millis(500));
                    continue;
                }
            };
            logged_down = false;
            tracing::info!("MSP link {} open", self.shared.address);
            self.shared.lock().link_error = None;
            *self.shared.writer.lock().unwrap_or_else(PoisonError::into_inner) = Some(writer);
            while !stop.load(Ordering::Relaxed) {
                match reader.read(&mut buf) {
                    Ok(0) => {
                        self.lost("the flight controller closed the connection".into());
                        break;
                    }
                    Ok(n) => {
                        let now = self.shared.now_ns();
                        self.shared.lock().bridge.on_bytes(&buf[..n], now);
                    }
                    Err(e)
                        if matches!(
                            e.kind(),
                            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                        ) => {}
                    Err(e) => {
                        self.lost(format!("read: {e}"));
                        break;
                    }
                }
            }
        }
    }

    fn lost(&self, why: String) {
        tracing::warn!("MSP link {}: {why}; reopening", self.shared.address);
        *self.shared.writer.lock().unwrap_or_else(PoisonError::into_inner) = None;
        let mut inner = self.shared.lock();
        inner.link_losses += 1;
        inner.link_error = Some(why);
        std::thread::sleep(Duration::from_millis(200));
    }

    /// Reads the pose stream until `stop`: MAVLink 2 (or 1) `ODOMETRY`, any other message
    /// ignored, undecodable datagrams counted.
    fn pose_loop(&self, socket: &UdpSocket, stop: &AtomicBool) {
        let mut buf = [0u8; 2048];
        let mut warned_refused = false;
        while !stop.load(Ordering::Relaxed) {
            let Ok((n, peer)) = socket.recv_from(&mut buf) else { continue };
            let mut reader = mavbridge::mavlink::MavlinkReader::new(&buf[..n]);
            let Ok((_, msg)) = reader.read_any_message::<MavMessage>() else {
                self.shared.lock().bridge.count_bad_pose_datagram();
                continue;
            };
            let MavMessage::ODOMETRY(odometry) = msg else { continue };
            let now = self.shared.now_ns();
            let mut inner = self.shared.lock();
            match inner.bridge.on_pose(peer, &odometry, now) {
                Ok(Some(sample)) => inner.subscribers.publish(&sample),
                Ok(None) => {}
                Err(why) if !warned_refused => {
                    warned_refused = true;
                    tracing::warn!(
                        "pose from {peer} refused ({why:?}): ODOMETRY must have frame_id MAV_FRAME_LOCAL_NED, child_frame_id MAV_FRAME_BODY_FRD, finite values and a unit quaternion (counted; said once)"
                    );
                }
                Err(_) => {}
            }
        }
    }

    fn describe(&self, inner: &Inner) -> pb::PlantDescription {
        let settings = SimSettings {
            // ODOMETRY.time_usec: the vehicle's clock counts microseconds.
            step_ns: 1_000,
            watchdog_timeout_ns: Some(inner.bridge.settings().command_timeout_ns),
            watchdog_action: mav::WatchdogAction::Hover,
        };
        let firmware = inner.bridge.firmware().unwrap_or_else(|| "firmware not heard yet".into());
        let implementation =
            format!("{IMPLEMENTATION} Betaflight flight controller {firmware} on {}", self.shared.address);
        conv::plant_description(inner.bridge.scenario(), &settings, mav::TimeMode::RealTime, &implementation)
    }
}

#[tonic::async_trait]
impl pb::plant_server::Plant for MspService {
    async fn reset(&self, request: Request<pb::ResetRequest>) -> Result<Response<pb::ResetResponse>, Status> {
        let req = Reset::try_from(request.get_ref())?;
        let now = self.shared.now_ns();
        let mut inner = self.shared.lock();
        self.serving(&inner, now)?;
        let scenario = reset_scenario(&req, inner.bridge.scenario(), &self.shared.config_scenario)?;
        let flight_id = inner.next_flight_id;
        let sample = inner
            .bridge
            .reset(scenario, req.initial_state, now, flight_id)
            .map_err(|e| Status::failed_precondition(e.to_string()))?;
        inner.next_flight_id = flight_id.wrapping_add(1).max(1);
        tracing::info!(scenario = %inner.bridge.scenario().name, flight_id, "reset (the vehicle stays where it is)");
        inner.subscribers.restart();
        inner.subscribers.publish(&sample);
        let description = self.describe(&inner);
        Ok(Response::new(pb::ResetResponse {
            description: Some(description),
            sample: Some((&sample).into()),
        }))
    }

    type StreamStateStream = SampleStream;

    async fn stream_state(
        &self,
        request: Request<pb::StreamStateRequest>,
    ) -> Result<Response<Self::StreamStateStream>, Status> {
        let req = StreamState::try_from(request.get_ref())?;
        let slot = self.shared.slots.acquire(&request, "StreamState")?;
        let (tx, rx) = drop_oldest(self.shared.stream_buffer);
        let now = self.shared.now_ns();
        let mut inner = self.shared.lock();
        if inner.closed {
            return Err(Status::unavailable("the gateway is shutting down"));
        }
        self.serving(&inner, now)?;
        let first = inner.bridge.sample().cloned();
        inner.subscribers.open(req.period_ns, tx, first.as_ref());
        Ok(Response::new(Box::pin(Guarded::new(rx.map(Ok), slot))))
    }

    async fn get_state(
        &self,
        _request: Request<pb::GetStateRequest>,
    ) -> Result<Response<pb::StateSample>, Status> {
        let now = self.shared.now_ns();
        let inner = self.shared.lock();
        self.serving(&inner, now)?;
        match inner.bridge.sample() {
            Some(s) => Ok(Response::new(s.into())),
            None => Err(Status::unavailable(
                "the vehicle has reported no state yet (a pose on --pose-in and MSP_ATTITUDE)",
            )),
        }
    }

    async fn apply_command(
        &self,
        request: Request<pb::Command>,
    ) -> Result<Response<pb::ApplyCommandResponse>, Status> {
        let command = Command::try_from(request.get_ref())?;
        let now = self.shared.now_ns();
        let mut inner = self.shared.lock();
        self.serving(&inner, now)?;
        // Flown from the next RC frame (at most 20 ms away): the steady rate is the firmware's
        // limit, so a command never adds a frame of its own.
        let applied = inner.bridge.apply(command.input, command.meta, now);
        Ok(Response::new(pb::ApplyCommandResponse { applied: Some((&applied).into()) }))
    }

    async fn advance(
        &self,
        request: Request<pb::AdvanceRequest>,
    ) -> Result<Response<pb::AdvanceResponse>, Status> {
        conv::advance_duration_ns(request.get_ref())?;
        Err(refuse_real_time("Advance"))
    }

    async fn step(&self, request: Request<pb::StepRequest>) -> Result<Response<pb::AdvanceResponse>, Status> {
        let step = Step::try_from(request.get_ref())?;
        if step.duration_ns > 0 {
            return Err(refuse_real_time("Step"));
        }
        if let Some(c) = step.command {
            self.apply_command(Request::new(pb::Command::from(&c))).await?;
        }
        let sample = self.get_state(Request::new(pb::GetStateRequest {})).await?.into_inner();
        Ok(Response::new(pb::AdvanceResponse { sample: Some(sample) }))
    }

    async fn describe(
        &self,
        _request: Request<pb::DescribeRequest>,
    ) -> Result<Response<pb::PlantDescription>, Status> {
        let inner = self.shared.lock();
        Ok(Response::new(self.describe(&inner)))
    }
}

impl MspService {
    /// Waits until the firmware's armed state is `armed`, within `wait`.
    async fn wait_armed(&self, armed: bool, wait: Duration) -> bool {
        let started = Instant::now();
        while started.elapsed() < wait {
            if self.shared.lock().bridge.armed() == armed {
                return true;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        false
    }
}

#[tonic::async_trait]
impl pb::vehicle_control_server::VehicleControl for MspService {
    async fn arm(
        &self,
        request: Request<pb::ArmRequest>,
    ) -> Result<Response<pb::VehicleCommandResponse>, Status> {
        authorize(&self.shared.allow_clients, &request, "Arm")?;
        {
            let now = self.shared.now_ns();
            let mut inner = self.shared.lock();
            if !inner.bridge.link_alive(now) {
                return Err(Status::unavailable(format!(
                    "no MSP link to the flight controller on {}",
                    self.shared.address
                )));
            }
            tracing::info!("arming the vehicle (asked): AUX1 high, throttle low");
            inner.bridge.request_arm(now);
        }
        if self.wait_armed(true, ARM_WAIT).await {
            return Ok(Response::new(pb::VehicleCommandResponse { result: "ARMED".into() }));
        }
        let now = self.shared.now_ns();
        let mut inner = self.shared.lock();
        inner.bridge.request_disarm(now);
        let flags = inner.bridge.arming_disabled().unwrap_or_default();
        Err(Status::failed_precondition(format!(
            "the firmware did not arm within {} s (arming disabled by {flags:?}); the arm switch is low again",
            ARM_WAIT.as_secs_f64()
        )))
    }

    async fn disarm(
        &self,
        request: Request<pb::DisarmRequest>,
    ) -> Result<Response<pb::VehicleCommandResponse>, Status> {
        authorize(&self.shared.allow_clients, &request, "Disarm")?;
        tracing::info!("disarming the vehicle (asked): AUX1 low");
        let now = self.shared.now_ns();
        self.shared.lock().bridge.request_disarm(now);
        if self.wait_armed(false, DISARM_WAIT).await {
            Ok(Response::new(pb::VehicleCommandResponse { result: "DISARMED".into() }))
        } else {
            Err(Status::deadline_exceeded(format!(
                "the firmware still says armed {} s after the switch went low",
                DISARM_WAIT.as_secs_f64()
            )))
        }
    }

    async fn set_mode(
        &self,
        request: Request<pb::SetModeRequest>,
    ) -> Result<Response<pb::VehicleCommandResponse>, Status> {
        authorize(&self.shared.allow_clients, &request, "SetMode")?;
        // Betaflight flies the gateway's sticks in ANGLE mode, held on by AUX2 in every RC
        // frame: the mode that flies the controller's tilts whatever was asked for.
        let angle = self.shared.lock().bridge.angle_mode();
        if angle {
            Ok(Response::new(pb::VehicleCommandResponse { result: "ANGLE (AUX2, always on)".into() }))
        } else {
            Err(Status::failed_precondition(
                "the firmware does not report ANGLE mode although AUX2 is high: check the mode ranges (firmware/betaflight/hilbench.cli) and that it has an attitude (state packets)",
            ))
        }
    }

    async fn get_status(
        &self,
        request: Request<pb::GetVehicleStatusRequest>,
    ) -> Result<Response<pb::VehicleStatus>, Status> {
        authorize(&self.shared.allow_clients, &request, "GetStatus")?;
        let now = self.shared.now_ns();
        let inner = self.shared.lock();
        let s = inner.bridge.status(now);
        let c = s.counters;
        let d = s.decoder;
        Ok(Response::new(pb::VehicleStatus {
            heartbeat_seen: s.last_frame_age_ns.is_some(),
            heartbeat_age_ns: s.last_frame_age_ns.unwrap_or(0),
            link_alive: s.link_alive,
            autopilot: s.firmware.clone().unwrap_or_default(),
            armed: s.armed,
            mode: if s.angle_mode { "ANGLE".into() } else { "ACRO".into() },
            flies_setpoints: s.armed && s.angle_mode,
            setpoints_sent: c.rc_sent,
            thrust_clamped: c.throttle_clamped,
            watchdog_holds: c.watchdog_holds,
            stale_messages: c.poses_stale,
            bad_messages: c.poses_invalid + c.poses_bad_frame + c.bad_replies,
            hover_thrust: inner.bridge.stick_map().throttle_curve().hover_output(),
            link_losses: inner.link_losses,
            link_error: inner.link_error.clone().unwrap_or_default(),
            vehicle_locked: s.link_alive,
            vehicle_address: self.shared.address.to_string(),
            dropped_foreign_address: c.poses_foreign,
            dropped_undecodable: d.dropped.frames() + d.dropped.garbage_bytes,
            implausible_states: c.poses_implausible,
            ..Default::default()
        }))
    }
}

/// Serves the MSP gateway on `listener` until `shutdown` resolves.
pub async fn serve(
    listener: tokio::net::TcpListener,
    config: MspConfig,
    shutdown: impl std::future::Future<Output = ()> + Send,
) -> Result<(), crate::GatewayError> {
    use hilbench_proto::pb::plant_server::PlantServer;
    use hilbench_proto::pb::vehicle_control_server::VehicleControlServer;
    use tonic::server::NamedService;
    let bridge = MspBridge::new(config.scenario.clone(), config.settings, 0, 1)
        .map_err(|e| crate::GatewayError::Msp(e.to_string()))?;
    let pose = UdpSocket::bind(config.pose_in)
        .map_err(|e| crate::GatewayError::Msp(format!("--pose-in {}: {e}", config.pose_in)))?;
    pose.set_read_timeout(Some(Duration::from_millis(100))).map_err(hilbench_svc::ServeError::Io)?;
    let service = MspService::new(bridge, &config);
    const NAMES: [&str; 2] = [PlantServer::<MspService>::NAME, VehicleControlServer::<MspService>::NAME];
    let server =
        hilbench_svc::GrpcServer::new("gateway", listener, true, &config.tls, &config.connections, &NAMES)
            .await?;
    let (addr, health) = (server.addr, server.health.clone());
    crate::set_health(&health, &NAMES, false).await;
    let stop = Arc::new(AtomicBool::new(false));
    let spawn =
        |name: &str, f: Box<dyn FnOnce() + Send>| std::thread::Builder::new().name(name.into()).spawn(f);
    let threads = [
        {
            let (service, stop) = (service.clone(), stop.clone());
            spawn("msp-recv", Box::new(move || service.read_loop(&stop)))
        },
        {
            let (service, stop) = (service.clone(), stop.clone());
            spawn(
                "msp-send",
                Box::new(move || {
                    while !stop.load(Ordering::Relaxed) {
                        let next = service.poll();
                        let wait = next.saturating_sub(service.shared.now_ns()).min(5_000_000);
                        std::thread::sleep(Duration::from_nanos(wait));
                    }
                }),
            )
        },
        {
            let (service, stop) = (service.clone(), stop.clone());
            spawn("pose-recv", Box::new(move || service.pose_loop(&pose, &stop)))
        },
    ];
    let mut joins = Vec::new();
    for t in threads {
        joins.push(t.map_err(hilbench_svc::ServeError::Io)?);
    }
    let health_task = {
        let (service, health) = (service.clone(), health.clone());
        tokio::spawn(async move {
            let mut serving = false;
            loop {
                let why = service.not_serving();
                if why.is_none() != serving {
                    serving = why.is_none();
                    crate::set_health(&health, &NAMES, serving).await;
                    match why {
                        None => tracing::info!("MSP link and pose stream alive: serving"),
                        Some(why) => tracing::warn!("NOT_SERVING: {why}"),
                    }
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        })
    };
    let signal = {
        let service = service.clone();
        async move {
            shutdown.await;
            tracing::info!("gateway shutting down");
            health_task.abort();
            crate::set_health(&health, &NAMES, false).await;
            let mut inner = service.shared.lock();
            inner.closed = true;
            inner.subscribers.clear();
        }
    };
    tracing::info!(%addr, msp = %config.msp, pose_in = %config.pose_in, scenario = %config.scenario.name, "gateway serving (MSP)");
    let result = server
        .serve(
            |router| {
                router
                    .add_service(PlantServer::new(service.clone()))
                    .add_service(VehicleControlServer::new(service.clone()))
            },
            signal,
        )
        .await;
    stop.store(true, Ordering::Relaxed);
    for j in joins {
        let _ = j.join();
    }
    {
        let inner = service.shared.lock();
        let (c, d) = (inner.bridge.counters(), inner.bridge.decoder_counters());
        tracing::info!(counters = ?c, decoder = ?d, "MSP link counters");
        // The gateway's hop of a command's path to the motors (docs/betaflight.md, section 9).
        let hold = inner.bridge.command_to_rc();
        let ms = |ns: Option<u64>| ns.map_or_else(|| "-".to_string(), |v| format!("{:.3}", v as f64 / 1e6));
        tracing::info!(
            "command to RC frame: commands={} superseded={} hold_ms_min={} hold_ms_median={} hold_ms_p99={} hold_ms_max={} hold_ms_mean={}",
            hold.count(),
            c.commands_superseded,
            ms(hold.min_ns()),
            ms(hold.quantile_ns(0.5)),
            ms(hold.quantile_ns(0.99)),
            ms(hold.max_ns()),
            ms(hold.mean_ns()),
        );
    }
    result?;
    tracing::info!("gateway stopped");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_are_tcp_or_serial_and_a_bad_one_names_the_flag() {
        assert_eq!(MspAddress::parse("tcp:127.0.0.1:5761"), Ok(MspAddress::Tcp("127.0.0.1:5761".into())));
        assert_eq!(
            MspAddress::parse("serial:/dev/ttyACM0:115200"),
            Ok(MspAddress::Serial { device: "/dev/ttyACM0".into(), baud: 115_200 })
        );
        for bad in ["tcp:5761", "udp:1.2.3.4:5", "serial:/dev/ttyACM0", "serial:/dev/x:fast"] {
            assert!(MspAddress::parse(bad).expect_err(bad).starts_with("--msp"), "{bad}");
        }
    }
}
