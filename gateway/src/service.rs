//! The gateway's services: `hilbench.v1.Plant` in real time and `hilbench.v1.VehicleControl`,
//! thin shells that decode (in `hilbench_proto::convert`), call the core
//! ([`mavbridge::Bridge`]) under one lock, send what it returns over the MAVLink link, and
//! encode. The service owns the clock and passes times into the core.

use crate::link::Link;
use hilbench_proto::convert::plant::{self as conv, Command, Reset, Step, StreamState};
use hilbench_proto::convert::vehicle as vconv;
use hilbench_proto::pb;
use hilbench_svc::streams::{Guarded, Pushed, StreamSlots, Writer, drop_oldest};
use mav::{PlantSample, Scenario, SimSettings};
use mavbridge::mavlink::dialects::common::{MavAutopilot, MavCmd, MavMessage, MavResult};
use mavbridge::mavlink::error::MessageWriteError;
use mavbridge::{Bridge, ModeRequest, Peer, Refusal, modes};
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};
use tokio::sync::oneshot;
use tokio_stream::StreamExt;
use tonic::{Request, Response, Status};

/// What the gateway calls itself in `PlantDescription.implementation`.
pub const IMPLEMENTATION: &str = concat!("hilbench-gateway ", env!("CARGO_PKG_VERSION"), " (MAVLink)");

/// At most one reboot warning this often, ns: a link that shows reboot after reboot (two
/// vehicles on one port, a flapping clock) says so without flooding the log.
const REBOOT_LOG_PERIOD_NS: u64 = 10_000_000_000;

/// How long a `COMMAND_LONG` waits for its `COMMAND_ACK` (a `PARAM_REQUEST_READ` for its
/// `PARAM_VALUE`) before it is sent again, and how many times it is sent.
const ACK_WAIT: Duration = Duration::from_millis(1_000);
const ACK_ATTEMPTS: u32 = 3;

/// What a request to the vehicle waits for.
#[derive(Debug, Clone, PartialEq)]
enum Awaited {
    /// The `COMMAND_ACK` of this command.
    Ack(MavCmd),
    /// The `PARAM_VALUE` of this parameter.
    Param(String),
}

/// The vehicle's answer to a request.
#[derive(Debug)]
enum Answer {
    Ack(MavResult),
    Param(f32),
}

struct Subscriber {
    period_ns: u64,
    last_slot: Option<u64>,
    tx: Writer<pb::StateSample>,
}

struct Inner {
    bridge: Bridge,
    subscribers: Subscribers,
    /// Requests waiting for their answer.
    pending: Vec<(Awaited, oneshot::Sender<Answer>)>,
    closed: bool,
    next_flight_id: u64,
    /// MAVLink messages that could not be sent to a vehicle there (`NotConnected` aside).
    send_errors: u64,
    /// Commands arrive while the vehicle does not fly them (armed, in its external mode), and
    /// that was logged.
    warned_not_flown: bool,
    /// Gateway time of the last Arm, Disarm or SetMode the vehicle accepted: its heartbeat says
    /// so up to a heartbeat period later, and until then "does not fly them" would be wrong.
    accepted_command_ns: Option<u64>,
    /// Gateway time of the last reboot warning, and the reboots not logged since.
    /// Times the link locked to a vehicle (a second lock is a vehicle that moved).
    locks: u64,
    reboot_logged_ns: Option<u64>,
    reboots_unlogged: u64,
    /// `--record-link`: the `TIMESYNC` exchanges, written as a delay trace.
    link_record: Option<LinkRecord>,
}

/// How long after an accepted Arm or SetMode the vehicle's heartbeat may still show the state
/// before it, ns: a heartbeat period (1 Hz) and its travel, with margin.
const HEARTBEAT_LAG_NS: u64 = 2_500_000_000;

/// How often `--record-link`'s file is written again while the gateway runs, ns.
const LINK_RECORD_EVERY_NS: u64 = 10_000_000_000;

/// `--record-link`: each `TIMESYNC` request the gateway sends is a probe, its answer from the
/// vehicle the reply (matched by the echoed `ts1`, which is the gateway's send time).
pub(crate) struct LinkRecord {
    ledger: linkfit::probe::Ledger,
    path: std::path::PathBuf,
    provenance: delay::Provenance,
    written_ns: u64,
}

impl LinkRecord {
    /// The trace of what is settled so far (`None`: nothing yet).
    fn text(
        exchanges: &[linkfit::probe::Exchange],
        provenance: &delay::Provenance,
        losses: u64,
    ) -> Option<String> {
        let mut p = provenance.clone();
        p.losses = Some(losses);
        delay::write_trace(&linkfit::probe::round_trips_s(exchanges), &p).ok()
    }
}

/// Writes `text` to `path`, logging a failure (the gateway goes on serving).
fn write_link_record(path: &std::path::Path, text: &str) {
    if let Err(e) = std::fs::write(path, text) {
        tracing::error!("--record-link {}: cannot write it: {e}", path.display());
    }
}

pub(crate) struct Shared {
    inner: Mutex<Inner>,
    origin: Instant,
    link: Link,
    slots: StreamSlots,
    stream_buffer: usize,
    /// The scenario given at start (what an empty `Reset.scenario` names at first).
    config_scenario: Scenario,
    /// The client certificates (common names) that may call VehicleControl (`--allow-client`;
    /// empty: any client the TLS set-up lets in).
    allow_clients: Vec<String>,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The gateway's clock, ns since start.
    pub(crate) fn now_ns(&self) -> u64 {
        u64::try_from(self.origin.elapsed().as_nanos()).unwrap_or(u64::MAX)
    }

    fn send(&self, msg: &MavMessage) {
        if let Err(e) = self.link.send(msg) {
            // No vehicle to send to (a serial device lost, which the link logged once; a udpin
            // link that has heard nobody yet, whose heartbeat timeout says so): not a failure
            // of the send, and not counted, so that a real one is logged at once.
            let no_vehicle =
                matches!(&e, MessageWriteError::Io(io) if io.kind() == std::io::ErrorKind::NotConnected);
            if !no_vehicle {
                let mut inner = self.lock();
                inner.send_errors += 1;
                if inner.send_errors.is_power_of_two() {
                    tracing::warn!(errors = inner.send_errors, "cannot send a MAVLink message: {e}");
                }
            }
        }
    }
}

/// Logs a dropped frame: the first of its kind, then each time the count of its kind reaches
/// a power of two (a flood says so a few times, not once a frame).
fn log_dropped(
    inner: &Inner,
    peer: Peer,
    why: Refusal,
    message: Option<(&mavbridge::mavlink::MavHeader, &MavMessage)>,
) {
    let dropped = inner.bridge.dropped();
    let count = match why {
        Refusal::NoVehicle => dropped.no_vehicle,
        Refusal::ForeignAddress => dropped.foreign_address,
        Refusal::ForeignSystem => dropped.foreign_system,
        Refusal::Undecodable => dropped.undecodable,
        Refusal::Unsigned => dropped.unsigned,
        Refusal::BadSignature => dropped.bad_signature,
        Refusal::Replayed => dropped.replayed,
    };
    if !count.is_power_of_two() {
        return;
    }
    let from = peer.map_or_else(|| "the serial device".to_string(), |a| a.to_string());
    let what = message.map_or_else(
        || "bytes".to_string(),
        |(h, m)| {
            use mavbridge::mavlink::Message;
            format!("{} of system {} component {}", m.message_name(), h.system_id, h.component_id)
        },
    );
    let vehicle = inner.bridge.vehicle().map_or_else(|| "none yet".to_string(), |v| v.to_string());
    if why == Refusal::NoVehicle {
        tracing::debug!(count, "dropped {what} from {from}: no vehicle heartbeat locked the link yet");
    } else {
        tracing::warn!(count, "dropped {what} from {from} ({why:?}); the vehicle is {vehicle}");
    }
}

/// The state streams of one gateway (either vehicle side): each subscriber at its period.
#[derive(Default)]
pub(crate) struct Subscribers {
    list: Vec<Subscriber>,
    /// Samples evicted from full subscriber buffers.
    pub(crate) overflow_dropped: u64,
}

impl Subscribers {
    /// Sends `sample` to every subscriber whose period it starts; closed ones are dropped.
    pub(crate) fn publish(&mut self, sample: &PlantSample) {
        let msg = pb::StateSample::from(sample);
        let Self { list, overflow_dropped } = self;
        list.retain_mut(|s| {
            let slot = msg.time_ns / s.period_ns;
            if s.last_slot.is_some_and(|l| slot <= l) {
                return true;
            }
            s.last_slot = Some(slot);
            match s.tx.push(msg.clone()) {
                Pushed::Queued => true,
                Pushed::Evicted(_) => {
                    *overflow_dropped += 1;
                    true
                }
                Pushed::Closed(_) => false,
            }
        });
    }

    /// After a reset: every subscriber takes the next sample.
    pub(crate) fn restart(&mut self) {
        for s in &mut self.list {
            s.last_slot = None;
        }
    }

    pub(crate) fn clear(&mut self) {
        self.list.clear();
    }

    /// A new stream at `period_ns`, starting with `first` (the newest sample, if any).
    pub(crate) fn open(&mut self, period_ns: u64, tx: Writer<pb::StateSample>, first: Option<&PlantSample>) {
        let period_ns = period_ns.max(1);
        let mut sub = Subscriber { period_ns, last_slot: None, tx };
        if let Some(first) = first {
            let first = pb::StateSample::from(first);
            sub.last_slot = Some(first.time_ns / period_ns);
            let _ = sub.tx.push(first);
        }
        self.list.push(sub);
    }
}

fn publish(inner: &mut Inner, sample: &PlantSample) {
    inner.subscribers.publish(sample);
}

/// The scenario a `Reset` names: its definition, else by name the one in force, the one given
/// at start, or a built-in one (both vehicle sides).
pub(crate) fn reset_scenario(req: &Reset, current: &Scenario, config: &Scenario) -> Result<Scenario, Status> {
    Ok(match (&req.definition, req.scenario.as_deref()) {
        (Some(definition), _) => definition.clone(),
        (None, None) => current.clone(),
        (None, Some(n)) if n == current.name => current.clone(),
        (None, Some(n)) if n == config.name => config.clone(),
        (None, Some(n)) => conv::scenario_by_name("scenario", n)?,
    })
}

/// Whether the client may call `VehicleControl/{call}`: any client when `allowed` (the
/// `--allow-client` names) is empty, else only those whose certificate's common name is listed.
pub(crate) fn authorize<T>(allowed: &[String], request: &Request<T>, call: &str) -> Result<(), Status> {
    if allowed.is_empty() {
        return Ok(());
    }
    let refused = |who: String| {
        tracing::warn!("VehicleControl/{call} refused to {who}");
        Status::permission_denied(format!(
            "VehicleControl/{call} is only for the client certificates {allowed:?} (--allow-client); \
             this client presented {who}"
        ))
    };
    match hilbench_svc::tls::client_common_name(request) {
        Ok(name) if allowed.contains(&name) => Ok(()),
        Ok(name) => Err(refused(format!("the certificate {name:?}"))),
        Err(why) => Err(refused(why.to_string())),
    }
}

/// Why the Plant API does not serve (health NOT_SERVING, calls `UNAVAILABLE`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NotServing {
    /// No vehicle heartbeat for the timeout (2 s).
    HeartbeatLost,
    /// The vehicle rebooted since the last `Reset` (its boot clock went back, or restarted
    /// during a silence).
    Rebooted,
}

/// The gateway: a small handle around the shared core and link (cheap to clone).
#[derive(Clone)]
pub struct GatewayService {
    pub(crate) shared: Arc<Shared>,
}

impl GatewayService {
    pub(crate) fn new(
        bridge: Bridge,
        link: Link,
        slots: StreamSlots,
        stream_buffer: usize,
        allow_clients: Vec<String>,
    ) -> Self {
        let first_flight_id = std::hash::BuildHasher::hash_one(
            &std::collections::hash_map::RandomState::new(),
            std::process::id(),
        )
        .max(1);
        let config_scenario = bridge.scenario().clone();
        Self {
            shared: Arc::new(Shared {
                inner: Mutex::new(Inner {
                    bridge,
                    subscribers: Subscribers::default(),
                    pending: Vec::new(),
                    closed: false,
                    next_flight_id: first_flight_id,
                    send_errors: 0,
                    warned_not_flown: false,
                    accepted_command_ns: None,
                    reboot_logged_ns: None,
                    locks: 0,
                    reboots_unlogged: 0,
                    link_record: None,
                }),
                origin: Instant::now(),
                link,
                slots,
                stream_buffer,
                config_scenario,
                allow_clients,
            }),
        }
    }

    /// Why the Plant API does not serve now (`None`: it does; health follows this): the
    /// heartbeat is lost, or the vehicle rebooted since the last `Reset`.
    pub fn not_serving(&self) -> Option<NotServing> {
        let now = self.shared.now_ns();
        let inner = self.shared.lock();
        if !inner.bridge.link_alive(now) {
            Some(NotServing::HeartbeatLost)
        } else {
            inner.bridge.awaiting_reset().map(|_| NotServing::Rebooted)
        }
    }

    /// Records the `TIMESYNC` round trips into `path` (`gateway --record-link`), an exchange
    /// unanswered within `timeout_ns` as lost; `source` names the link.
    pub fn record_link(&self, path: std::path::PathBuf, timeout_ns: u64, source: String) {
        let mut inner = self.shared.lock();
        let period_ns = inner.bridge.settings().timesync_period_ns;
        let unix_s =
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
        let provenance = delay::Provenance {
            source: Some(source),
            when: Some(linkfit::probe::iso8601_utc(unix_s)),
            rate_hz: Some(1e9 / period_ns as f64),
            // A MAVLink 2 TIMESYNC frame: 10 header, 16 payload, 2 checksum bytes.
            probe_bytes: Some(28),
            losses: Some(0),
            tool: Some(format!(
                "hilbench gateway {} --record-link (MAVLink TIMESYNC)",
                env!("CARGO_PKG_VERSION")
            )),
            other: vec![("timeout_s".into(), (timeout_ns as f64 * 1e-9).to_string())],
        };
        let now = self.shared.now_ns();
        inner.link_record = Some(LinkRecord {
            ledger: linkfit::probe::Ledger::new(timeout_ns),
            path,
            provenance,
            written_ns: now,
        });
    }

    /// Writes `--record-link`'s file with every exchange settled (at shutdown): the requests
    /// still waiting within their timeout are left out.
    pub fn finish_link_record(&self) {
        let now = self.shared.now_ns();
        let Some(record) = self.shared.lock().link_record.take() else { return };
        let (exchanges, counts, _) = record.ledger.finish(now);
        match LinkRecord::text(&exchanges, &record.provenance, counts.lost) {
            Some(text) => {
                write_link_record(&record.path, &text);
                tracing::info!(
                    exchanges = exchanges.len(),
                    lost = counts.lost,
                    "--record-link: TIMESYNC round trips written to {}",
                    record.path.display()
                );
            }
            None => tracing::warn!(
                "--record-link {}: no TIMESYNC exchange settled, nothing written",
                record.path.display()
            ),
        }
    }

    /// Ends every state stream and refuses new ones (at shutdown).
    pub fn close(&self) {
        let mut inner = self.shared.lock();
        inner.closed = true;
        inner.subscribers.clear();
    }

    /// The reading side: one frame of the link.
    pub(crate) fn on_frame(&self, frame: crate::link::Frame) {
        match frame {
            crate::link::Frame::Message(peer, header, msg) => self.on_message(peer, &header, &msg),
            crate::link::Frame::Refused(peer, why) => {
                let mut inner = self.shared.lock();
                let counted = inner.bridge.refuse(peer, why);
                log_dropped(&inner, peer, counted, None);
            }
        }
    }

    /// One message from `peer`: believed only from the vehicle locked to.
    pub(crate) fn on_message(&self, peer: Peer, header: &mavbridge::mavlink::MavHeader, msg: &MavMessage) {
        let now = self.shared.now_ns();
        let reply = {
            let mut inner = self.shared.lock();
            let event = inner.bridge.on_message(peer, header, msg, now);
            if let Some(why) = event.dropped {
                log_dropped(&inner, peer, why, Some((header, msg)));
                return;
            }
            if let Some(vehicle) = event.locked {
                // A lock after the first is a vehicle that moved: worth the operator's eye.
                if inner.locks > 0 {
                    tracing::warn!(
                        "locked again, to the vehicle {vehicle} (signed link): frames from any other address, system or component are dropped"
                    );
                } else {
                    tracing::info!(
                        "locked to the vehicle {vehicle}: frames from any other address, system or component are dropped"
                    );
                }
                inner.locks += 1;
                self.shared.link.answer(vehicle.peer);
            }
            if let Some(reboot) = &event.reboot {
                let due =
                    inner.reboot_logged_ns.is_none_or(|t| now.saturating_sub(t) >= REBOOT_LOG_PERIOD_NS);
                if due {
                    let unlogged = std::mem::take(&mut inner.reboots_unlogged);
                    let more = if unlogged > 0 {
                        format!(" ({unlogged} more since the last warning)")
                    } else {
                        String::new()
                    };
                    inner.reboot_logged_ns = Some(now);
                    tracing::warn!(
                        reboots = inner.bridge.counters().reboots,
                        "{reboot}{more}; until then the Plant API answers UNAVAILABLE and health is NOT_SERVING"
                    );
                } else {
                    inner.reboots_unlogged += 1;
                }
            }
            if let Some(sample) = &event.sample {
                publish(&mut inner, sample);
            }
            if let (Some((sent_ns, _)), Some(record)) = (event.timesync_answer, inner.link_record.as_mut())
                && let Some(seq) = record.ledger.waiting_sent_at(sent_ns)
            {
                record.ledger.answer(seq, now, None);
            }
            let answered = match (event.ack, event.param) {
                (Some((command, result)), _) => Some((Awaited::Ack(command), Answer::Ack(result))),
                (None, Some((name, value))) => Some((Awaited::Param(name), Answer::Param(value))),
                (None, None) => None,
            };
            if let Some((awaited, answer)) = answered {
                // A request whose caller went away (a cancelled call) must not take the answer
                // from the one waiting now.
                inner.pending.retain(|(_, tx)| !tx.is_closed());
                if let Some(i) = inner.pending.iter().position(|(a, _)| *a == awaited) {
                    let (_, tx) = inner.pending.remove(i);
                    let _ = tx.send(answer);
                }
            }
            event.reply
        };
        if let Some(reply) = reply {
            self.shared.send(&reply);
        }
    }

    /// The scheduling side: what is due now; returns when to call again.
    pub(crate) fn poll(&self) -> u64 {
        let now = self.shared.now_ns();
        let mut out = Vec::new();
        let (next, to_write) = {
            let mut inner = self.shared.lock();
            inner.bridge.poll(now, &mut out);
            let mut to_write = None;
            // Before a vehicle's heartbeat locked the link there is no link to measure: the
            // requests then go nowhere (udpin) and are not probes.
            let locked = inner.bridge.vehicle().is_some();
            if let Some(record) = inner.link_record.as_mut().filter(|_| locked) {
                for m in &out {
                    if let MavMessage::TIMESYNC(t) = m
                        && t.tc1 == 0
                    {
                        record.ledger.send(t.ts1 as u64);
                    }
                }
                record.ledger.settle(now);
                if now.saturating_sub(record.written_ns) >= LINK_RECORD_EVERY_NS {
                    record.written_ns = now;
                    let lost = record.ledger.counts().lost;
                    to_write = LinkRecord::text(record.ledger.settled(), &record.provenance, lost)
                        .map(|text| (record.path.clone(), text));
                }
            }
            (inner.bridge.next_due_ns(), to_write)
        };
        for m in &out {
            self.shared.send(m);
        }
        if let Some((path, text)) = to_write {
            write_link_record(&path, &text);
        }
        next
    }

    /// [`GatewayService::alive`], and the vehicle has not rebooted since the last `Reset`:
    /// what every Plant call but `Reset` and `Describe` needs.
    fn serving(&self, inner: &Inner, now: u64) -> Result<(), Status> {
        self.alive(inner, now)?;
        match inner.bridge.awaiting_reset() {
            Some(reboot) => Err(Status::unavailable(reboot.to_string())),
            None => Ok(()),
        }
    }

    fn alive(&self, inner: &Inner, now: u64) -> Result<(), Status> {
        if inner.bridge.link_alive(now) {
            Ok(())
        } else {
            let why = self.shared.link.status().down.map(|d| format!(" ({d})")).unwrap_or_default();
            Err(Status::unavailable(format!(
                "no heartbeat from the vehicle for {} s on {}: the vehicle link is lost{why}",
                mav::ns_to_s(inner.bridge.settings().heartbeat_timeout_ns),
                self.shared.link.address
            )))
        }
    }

    fn describe(&self, inner: &Inner) -> pb::PlantDescription {
        let settings = SimSettings {
            // time_boot_ms: the vehicle's clock counts milliseconds.
            step_ns: 1_000_000,
            watchdog_timeout_ns: Some(inner.bridge.settings().command_timeout_ns),
            // The gateway's own watchdog holds level hover (the vehicle's failsafe is PX4's).
            watchdog_action: mav::WatchdogAction::Hover,
        };
        let implementation = format!("{IMPLEMENTATION} {}", self.shared.link.address);
        conv::plant_description(inner.bridge.scenario(), &settings, mav::TimeMode::RealTime, &implementation)
    }

    /// Sends `msg` until the answer it awaits arrives, [`ACK_ATTEMPTS`] times [`ACK_WAIT`]
    /// apart (`None`: no answer).
    async fn request(&self, awaited: Awaited, msg: &MavMessage) -> Result<Option<Answer>, Status> {
        for _ in 0..ACK_ATTEMPTS {
            let (tx, rx) = oneshot::channel();
            {
                let mut inner = self.shared.lock();
                self.alive(&inner, self.shared.now_ns())?;
                inner.pending.push((awaited.clone(), tx));
            }
            self.shared.send(msg);
            match tokio::time::timeout(ACK_WAIT, rx).await {
                Ok(Ok(answer)) => return Ok(Some(answer)),
                _ => {
                    let mut inner = self.shared.lock();
                    inner.pending.retain(|(_, tx)| !tx.is_closed());
                }
            }
        }
        Ok(None)
    }

    /// Sends `msg` (a `COMMAND_LONG` for `command`) until its `COMMAND_ACK` arrives.
    async fn command(
        &self,
        command: MavCmd,
        msg: MavMessage,
    ) -> Result<Response<pb::VehicleCommandResponse>, Status> {
        match self.request(Awaited::Ack(command), &msg).await? {
            Some(Answer::Ack(MavResult::MAV_RESULT_ACCEPTED)) => {
                self.shared.lock().accepted_command_ns = Some(self.shared.now_ns());
                Ok(Response::new(pb::VehicleCommandResponse {
                    result: format!("{:?}", MavResult::MAV_RESULT_ACCEPTED),
                }))
            }
            Some(Answer::Ack(result)) => {
                Err(Status::failed_precondition(format!("the vehicle refused {command:?}: {result:?}")))
            }
            _ => Err(Status::deadline_exceeded(format!(
                "no COMMAND_ACK for {command:?} after {ACK_ATTEMPTS} attempts {} ms apart",
                ACK_WAIT.as_millis()
            ))),
        }
    }

    fn authorize<T>(&self, request: &Request<T>, call: &str) -> Result<(), Status> {
        authorize(&self.shared.allow_clients, request, call)
    }

    /// The vehicle's parameter `name` (`PARAM_REQUEST_READ` until its `PARAM_VALUE` arrives).
    async fn read_param(&self, name: &str) -> Result<f32, Status> {
        let msg = self.shared.lock().bridge.param_request(name);
        match self.request(Awaited::Param(name.into()), &msg).await? {
            Some(Answer::Param(value)) => Ok(value),
            _ => Err(Status::deadline_exceeded(format!(
                "no PARAM_VALUE for {name} after {ACK_ATTEMPTS} attempts {} ms apart",
                ACK_WAIT.as_millis()
            ))),
        }
    }
}

pub(crate) type SampleStream =
    Pin<Box<dyn tokio_stream::Stream<Item = Result<pb::StateSample, Status>> + Send + 'static>>;

pub(crate) fn refuse_real_time(what: &str) -> Status {
    Status::failed_precondition(format!(
        "the gateway flies a vehicle in real time: {what} with a duration > 0 is only served by a lockstep plant"
    ))
}

#[tonic::async_trait]
impl pb::plant_server::Plant for GatewayService {
    async fn reset(&self, request: Request<pb::ResetRequest>) -> Result<Response<pb::ResetResponse>, Status> {
        let req = Reset::try_from(request.get_ref())?;
        let now = self.shared.now_ns();
        let mut inner = self.shared.lock();
        self.alive(&inner, now)?;
        let scenario = reset_scenario(&req, inner.bridge.scenario(), &self.shared.config_scenario)?;
        let flight_id = inner.next_flight_id;
        let sample = inner
            .bridge
            .reset(scenario, req.initial_state, now, flight_id)
            .map_err(|e| Status::failed_precondition(e.to_string()))?;
        inner.next_flight_id = flight_id.wrapping_add(1).max(1);
        tracing::info!(scenario = %inner.bridge.scenario().name, flight_id, "reset (the vehicle stays where it is)");
        inner.subscribers.restart();
        publish(&mut inner, &sample);
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
                "the vehicle has reported no state yet (LOCAL_POSITION_NED and ATTITUDE)",
            )),
        }
    }

    async fn apply_command(
        &self,
        request: Request<pb::Command>,
    ) -> Result<Response<pb::ApplyCommandResponse>, Status> {
        let command = Command::try_from(request.get_ref())?;
        let now = self.shared.now_ns();
        let (applied, msg) = {
            let mut inner = self.shared.lock();
            self.serving(&inner, now)?;
            // Said once per spell: a controller flying a vehicle that ignores it would otherwise
            // only see the states not follow.
            // Right after an accepted Arm or SetMode the last heartbeat is older than the
            // change: the vehicle is given a heartbeat's lag before it is said not to fly them.
            let lagging = inner.accepted_command_ns.is_some_and(|t| now.saturating_sub(t) < HEARTBEAT_LAG_NS);
            let flies = inner.bridge.flies_setpoints() || lagging;
            if !flies && !inner.warned_not_flown {
                let status = inner.bridge.status(now);
                tracing::warn!(
                    mode = %status.mode,
                    armed = status.armed,
                    "commands arrive but the vehicle does not fly them: arm it and set OFFBOARD (PX4) or \
                     GUIDED_NOGPS (ArduCopter), e.g. `vehiclectl arm-offboard`"
                );
            }
            inner.warned_not_flown = !flies;
            inner.bridge.apply(command.input, command.meta, now)
        };
        if let Some(msg) = msg {
            self.shared.send(&msg);
        }
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

#[tonic::async_trait]
impl pb::vehicle_control_server::VehicleControl for GatewayService {
    async fn arm(
        &self,
        request: Request<pb::ArmRequest>,
    ) -> Result<Response<pb::VehicleCommandResponse>, Status> {
        self.authorize(&request, "Arm")?;
        let msg = self.shared.lock().bridge.arm_message(true);
        tracing::info!("arming the vehicle (asked)");
        self.command(MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, msg).await
    }

    async fn disarm(
        &self,
        request: Request<pb::DisarmRequest>,
    ) -> Result<Response<pb::VehicleCommandResponse>, Status> {
        self.authorize(&request, "Disarm")?;
        let msg = self.shared.lock().bridge.arm_message(false);
        tracing::info!("disarming the vehicle (asked)");
        self.command(MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, msg).await
    }

    async fn set_mode(
        &self,
        request: Request<pb::SetModeRequest>,
    ) -> Result<Response<pb::VehicleCommandResponse>, Status> {
        self.authorize(&request, "SetMode")?;
        let mode: ModeRequest = vconv::mode_request(request.get_ref()).map_err(Status::from)?;
        let (msg, autopilot) = {
            let inner = self.shared.lock();
            (inner.bridge.mode_message(mode), inner.bridge.autopilot())
        };
        // ArduCopter reads the setpoints' thrust as a climb rate unless told otherwise: a mode
        // in which the controller's thrust would not be flown is refused before it is asked for.
        if mode == ModeRequest::ArduGuidedNoGps
            && autopilot == Some(MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA)
        {
            let guid_options = self.read_param(modes::ARDU_GUID_OPTIONS).await?;
            if !modes::ardu_thrust_as_thrust(guid_options) {
                return Err(Status::failed_precondition(format!(
                    "ArduCopter's {} is {guid_options}: without bit 3 (8, \"SetAttitudeTarget interprets \
                     Thrust As Thrust\") it flies SET_ATTITUDE_TARGET's thrust as a climb rate, not the \
                     controller's thrust; set it to include 8 and ask again (the mode is unchanged)",
                    modes::ARDU_GUID_OPTIONS
                )));
            }
        }
        tracing::info!(?mode, "setting the vehicle's mode (asked)");
        self.command(MavCmd::MAV_CMD_DO_SET_MODE, msg).await
    }

    async fn get_status(
        &self,
        request: Request<pb::GetVehicleStatusRequest>,
    ) -> Result<Response<pb::VehicleStatus>, Status> {
        self.authorize(&request, "GetStatus")?;
        let now = self.shared.now_ns();
        let inner = self.shared.lock();
        let status = inner.bridge.status(now);
        let mut status = vconv::vehicle_status(&status, inner.bridge.settings().hover_thrust);
        // The transport's part is the shell's: the core knows messages, not devices.
        let link = self.shared.link.status();
        status.link_losses = link.losses;
        status.link_reopens = link.reopens;
        status.link_error = link.down.unwrap_or_default();
        status.link_read_errors = link.read_errors;
        status.mavlink_signed = self.shared.link.signs();
        Ok(Response::new(status))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavbridge::mavlink::MavHeader;
    use mavbridge::mavlink::dialects::common::{COMMAND_ACK_DATA, PARAM_VALUE_DATA};

    fn service() -> GatewayService {
        let bridge =
            Bridge::new(Scenario::paper_2(), mavbridge::BridgeSettings::default(), 0, 1).expect("valid");
        let link = Link::open("udpin:127.0.0.1:0", 255, 191).expect("a loopback UDP port");
        GatewayService::new(bridge, link, StreamSlots::new("gateway", 4, 4), 16, Vec::new())
    }

    #[test]
    fn an_answer_goes_to_the_live_request_not_to_one_whose_caller_went_away() {
        let service = service();
        let arm = Awaited::Ack(MavCmd::MAV_CMD_COMPONENT_ARM_DISARM);
        let guid = Awaited::Param(modes::ARDU_GUID_OPTIONS.into());
        let (cancelled_arm, _) = oneshot::channel();
        let (cancelled_guid, _) = oneshot::channel();
        let (live_arm, mut arm_answer) = oneshot::channel();
        let (live_guid, mut guid_answer) = oneshot::channel();
        {
            let mut inner = service.shared.lock();
            inner.pending.push((arm.clone(), cancelled_arm));
            inner.pending.push((guid.clone(), cancelled_guid));
            inner.pending.push((arm, live_arm));
            inner.pending.push((guid, live_guid));
        }
        let header = MavHeader { system_id: 1, component_id: 1, sequence: 0 };
        let px4 = mavbridge::mavlink::dialects::common::HEARTBEAT_DATA {
            autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
            ..Default::default()
        };
        service.on_message(None, &header, &MavMessage::HEARTBEAT(px4));
        service.on_message(
            None,
            &header,
            &MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
                command: MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
                result: MavResult::MAV_RESULT_ACCEPTED,
            }),
        );
        service.on_message(
            None,
            &header,
            &MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
                param_value: 8.0,
                param_id: modes::ARDU_GUID_OPTIONS.into(),
                ..Default::default()
            }),
        );
        assert!(matches!(arm_answer.try_recv(), Ok(Answer::Ack(MavResult::MAV_RESULT_ACCEPTED))));
        assert!(matches!(guid_answer.try_recv(), Ok(Answer::Param(v)) if v == 8.0));
        assert!(service.shared.lock().pending.is_empty(), "the cancelled requests are dropped");
    }

    #[test]
    fn reboot_after_reboot_is_logged_once_in_ten_seconds_and_the_rest_are_counted_for_the_next_warning() {
        let service = service();
        let header = MavHeader { system_id: 1, component_id: 1, sequence: 0 };
        let px4 = mavbridge::mavlink::dialects::common::HEARTBEAT_DATA {
            autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
            ..Default::default()
        };
        service.on_message(None, &header, &MavMessage::HEARTBEAT(px4));
        let start = Scenario::paper_2().start_state();
        let state = |ms: u64| {
            let (a, p) = mavbridge::messages::state_messages(&start, 0.0, ms * 1_000_000);
            [MavMessage::ATTITUDE(a), MavMessage::LOCAL_POSITION_NED(p)]
        };
        // Two vehicles on one link (one up for ten minutes, one just booted), in turns: each
        // turn of the young one is a reboot of the old one's clock, confirmed.
        for turn in 0..5u64 {
            for k in 0..3 {
                for m in state(600_000 + turn * 10 + k) {
                    service.on_message(None, &header, &m);
                }
            }
            for k in 0..3 {
                for m in state(turn * 10 + k) {
                    service.on_message(None, &header, &m);
                }
            }
        }
        let inner = service.shared.lock();
        let reboots = inner.bridge.counters().reboots;
        assert_eq!(reboots, 5, "{:?}", inner.bridge.counters());
        assert!(inner.reboot_logged_ns.is_some());
        assert_eq!(inner.reboots_unlogged, reboots - 1, "one warning, the rest counted for the next");
    }
}
