//! The state netem's services share. [`Net`] is what every face of netem has: the delay lines
//! and statistics (under one short lock that is never held across an await), the clock and the
//! real-time release thread, the stream cap and the shutdown signal; `NetemControl` serves it.
//! [`Shared`] adds the gRPC proxy's upstream plant client and lockstep machinery on top (it
//! dereferences to its [`Net`]); the UDP proxy (`crate::udp`) uses a [`Net`] alone.

use std::sync::{Arc, Mutex, MutexGuard};

use delay::{Decision, DelayLine, Direction, DirectionProfile, DirectionStats, Fate, Record, ReleaseQueue};
use hilbench_proto::pb;
use hilbench_proto::pb::plant_client::PlantClient;
use hilbench_svc::streams::StreamSlots;
use mav::{TimeMode, TimeModeChoice};
use tokio::sync::{broadcast, mpsc, oneshot};
use tonic::transport::Channel;
use tonic::{Response, Status};

use crate::clock::Clock;
use crate::release::Releaser;

/// Largest number of records a trace recording keeps; later ones are counted but not kept.
pub const MAX_TRACE_RECORDS: usize = 5_000_000;

/// The drop reason of a sample evicted from a state stream's full buffer.
pub const STREAM_OVERFLOW_REASON: &str = "subscriber too slow";

/// Items a relayed stream (lockstep `StreamState`, `StreamDeliveries`) holds between its
/// source and gRPC. Small: it only decouples the two; a reader that stops reading leaves the
/// rest where it is bounded already (the plant's own buffer, the deliveries channel).
pub const RELAY_BUFFER: usize = 16;

/// One copy of one message on its way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Msg {
    pub dir: Direction,
    pub seq: u64,
    pub payload_seq: u64,
    pub send_ns: u64,
    pub release_ns: u64,
    pub duplicate: bool,
}

impl Msg {
    /// The copies a decision delivers.
    pub fn copies(d: &Decision, dir: Direction, payload_seq: u64) -> impl Iterator<Item = Msg> + '_ {
        d.releases().map(move |r| Msg {
            dir,
            seq: d.seq,
            payload_seq,
            send_ns: d.send_time_ns,
            release_ns: r.release_time_ns,
            duplicate: r.duplicate,
        })
    }
}

/// A command held in lockstep until plant time reaches its release.
pub struct PendingCommand {
    pub msg: Msg,
    pub command: pb::Command,
}

/// A command handed to the real-time forwarder at its release.
pub struct Forward {
    pub msg: Msg,
    pub command: pb::Command,
    pub epoch: u64,
    pub release_error_ns: i64,
    pub reply: Option<oneshot::Sender<Result<pb::ApplyCommandResponse, Status>>>,
}

pub struct Inner {
    pub lines: [DelayLine; 2],
    pub stats: [DirectionStats; 2],
    pub in_flight: [u64; 2],
    pub recording: Option<Vec<Record>>,
    pub deliveries: broadcast::Sender<pb::TraceRecord>,
    pub mode: Option<TimeMode>,
    /// Lockstep: plant time as of the last upstream answer; `None` until known again.
    pub plant_time_ns: Option<u64>,
    pub pending: ReleaseQueue<PendingCommand>,
    /// The newest sample delivered to the controller (what a lost sample leaves it with).
    pub last_sample: Option<pb::StateSample>,
    pub upstream_connected: bool,
    pub upstream_failures: u64,
    /// Bumped when the upstream goes away or the plant is reset: real-time copies of an older
    /// epoch are dropped with `epoch_reason` instead of being delivered.
    pub epoch: u64,
    pub epoch_reason: String,
    /// Per direction: copies evicted from a state stream's full buffer (also in `stats`'s
    /// `dropped`).
    pub stream_overflow_dropped: [u64; 2],
    /// Commands refused to their sender as invalid (`INVALID_ARGUMENT`), never delayed.
    pub refused_invalid: u64,
    /// Records `StreamDeliveries` readers missed because they fell behind, summed over readers.
    pub deliveries_lagged: u64,
    /// The UDP proxy's peers and refusals (`None` in gRPC mode).
    pub udp: Option<crate::peers::Peers>,
    /// Lockstep: the plant time each command was drawn at, since the plant's last reset
    /// through netem (`NetemControl.CommandsSentBefore`).
    pub command_times: crate::command_times::CommandTimes,
}

impl Inner {
    fn record(&mut self, r: Record) {
        if self.deliveries.receiver_count() > 0 {
            let _ = self.deliveries.send(pb::TraceRecord::from(&r));
        }
        if let Some(rec) = &mut self.recording
            && rec.len() < MAX_TRACE_RECORDS
        {
            rec.push(r);
        }
    }

    /// The end of a trace that stops there, when the next message of `dir` has no delay left:
    /// such a message is refused to its sender (the run must stop), not dropped.
    pub fn trace_ended(&self, dir: Direction) -> Option<delay::TraceEnded> {
        self.lines[dir.index()].check_next().err()
    }

    /// Runs message `payload_seq`, sent at `send_ns`, through the line of `dir`.
    pub fn decide(&mut self, dir: Direction, send_ns: u64, payload_seq: u64) -> Decision {
        // Asked before the decision, after which the line can no longer say what the trace
        // was. Commands and lockstep samples never get here past a trace's end (they are
        // refused to their sender): real-time samples do, and are dropped with this reason.
        let ended = self.trace_ended(dir);
        let d = self.lines[dir.index()].send(send_ns);
        self.stats[dir.index()].record_decision(&d);
        if dir == Direction::ControllerToPlant && self.mode == Some(TimeMode::Lockstep) {
            // In lockstep a command's send time is the plant time netem knows.
            self.command_times.push(send_ns);
        }
        if let Some(ended) = ended.as_ref().filter(|_| d.trace_ended) {
            tracing::warn!(direction = ?dir, message = d.seq, "{ended}");
        }
        match d.fate {
            Fate::Dropped => self.record(Record {
                direction: dir,
                message_seq: d.seq,
                payload_seq,
                send_time_ns: send_ns,
                release_time_ns: send_ns.saturating_add(delay::delay_ns(d.sampled_delay_s)),
                injected_delay_s: d.sampled_delay_s,
                dropped: true,
                duplicate: false,
                drop_reason: ended.map_or_else(|| "loss".into(), |e| e.to_string()),
                release_error_ns: 0,
            }),
            Fate::Delivered { .. } => self.in_flight[dir.index()] += d.releases().count() as u64,
        }
        d
    }

    /// A copy reached its destination `release_error_ns` after its scheduled release.
    pub fn delivered(&mut self, m: &Msg, release_error_ns: i64) {
        let i = m.dir.index();
        self.in_flight[i] = self.in_flight[i].saturating_sub(1);
        let actual = (m.release_ns as i64 + release_error_ns).max(m.send_ns as i64) as u64;
        let delay_ns = actual - m.send_ns;
        self.stats[i].record_delivered(delay_ns);
        if release_error_ns != 0 || self.mode == Some(TimeMode::RealTime) {
            self.stats[i].record_release_error(release_error_ns);
        }
        self.record(Record {
            direction: m.dir,
            message_seq: m.seq,
            payload_seq: m.payload_seq,
            send_time_ns: m.send_ns,
            release_time_ns: m.release_ns,
            injected_delay_s: delay::ns_to_s(delay_ns),
            dropped: false,
            duplicate: m.duplicate,
            drop_reason: String::new(),
            release_error_ns,
        });
    }

    /// A copy held by netem was dropped (the upstream went away, the plant was reset, ...).
    pub fn dropped(&mut self, m: &Msg, reason: &str) {
        let i = m.dir.index();
        self.in_flight[i] = self.in_flight[i].saturating_sub(1);
        self.stats[i].record_dropped();
        self.record(Record {
            direction: m.dir,
            message_seq: m.seq,
            payload_seq: m.payload_seq,
            send_time_ns: m.send_ns,
            release_time_ns: m.release_ns,
            injected_delay_s: delay::ns_to_s(m.release_ns - m.send_ns),
            dropped: true,
            duplicate: m.duplicate,
            drop_reason: reason.to_string(),
            release_error_ns: 0,
        });
    }

    /// A released copy was evicted from a state stream's full buffer for a newer one: a drop
    /// like the others (reason [`STREAM_OVERFLOW_REASON`]), counted apart as well, and logged
    /// at every power of two so that a reader that never reads does not flood the log.
    pub fn overflowed(&mut self, m: &Msg) {
        self.dropped(m, STREAM_OVERFLOW_REASON);
        let n = &mut self.stream_overflow_dropped[m.dir.index()];
        *n += 1;
        if n.is_power_of_two() {
            tracing::warn!(
                dropped = *n,
                direction = ?m.dir,
                "a StreamState reader is too slow: netem discards the oldest samples of its buffer"
            );
        }
    }

    /// A `StreamDeliveries` reader fell behind and missed `n` records.
    pub fn deliveries_lagged(&mut self, n: u64) {
        self.deliveries_lagged += n;
        tracing::warn!(missed = n, total = self.deliveries_lagged, "a StreamDeliveries reader is too slow");
    }

    /// Draws a lockstep sample arriving at `time_ns` from the plant-to-controller line.
    pub fn draw_sample(&mut self, time_ns: u64) -> delay::Draw {
        self.lines[Direction::PlantToController.index()].draw(time_ns)
    }

    /// A lockstep sample: drawn from the plant-to-controller line without FIFO scheduling,
    /// delivered (or lost) at once; see `proxy::Proxy::lockstep_advance`, which refuses a
    /// sample past the end of a trace before drawing it.
    pub fn lockstep_sample(
        &mut self,
        send_ns: u64,
        release_ns: u64,
        draw: &delay::Draw,
        payload_seq: u64,
    ) -> Msg {
        let dir = Direction::PlantToController;
        let i = dir.index();
        self.stats[i].sent += 1;
        let m = Msg { dir, seq: draw.seq, payload_seq, send_ns, release_ns, duplicate: false };
        if draw.lost {
            self.in_flight[i] += 1;
            self.dropped(&m, "loss");
            return m;
        }
        let copies = 1 + u64::from(draw.duplicated);
        self.stats[i].duplicated += u64::from(draw.duplicated);
        self.in_flight[i] += copies;
        self.delivered(&m, 0);
        if draw.duplicated {
            self.delivered(&Msg { duplicate: true, ..m }, 0);
        }
        m
    }

    /// Everything held is dropped with `reason`, and copies still in the real-time release
    /// thread will be when their time comes.
    pub fn new_epoch(&mut self, reason: &str) {
        self.epoch += 1;
        self.epoch_reason = reason.to_string();
        for (_, p) in self.pending.drain() {
            self.dropped(&p.msg, reason);
        }
    }
}

/// Whether an upstream status means that the plant is gone (as opposed to refusing a request).
pub fn is_gone(s: &Status) -> bool {
    matches!(s.code(), tonic::Code::Unavailable | tonic::Code::Cancelled | tonic::Code::Unknown)
}

/// What every face of netem shares (see the module's documentation).
pub struct Net {
    inner: Mutex<Inner>,
    pub clock: Clock,
    pub releaser: Releaser,
    /// Seed given to presets set at run time.
    pub seed: u64,
    /// Set to true when netem shuts down: open streams end, so the graceful shutdown is not
    /// kept waiting by a controller that never hangs up.
    pub closing: tokio::sync::watch::Sender<bool>,
    /// The cap on open server streams, of every service.
    pub slots: StreamSlots,
}

impl Net {
    /// The delay lines of `config` (validated) and a release thread on a new clock; `mode` is
    /// the time mode in force (`None`: not known yet).
    pub fn new(config: &crate::Config, mode: Option<TimeMode>) -> Result<Arc<Self>, crate::NetemError> {
        let line =
            |dir, p: &DirectionProfile| DelayLine::new(dir, p.clone()).map_err(crate::NetemError::Profile);
        let lines = [
            line(Direction::PlantToController, &config.plant_to_controller)?,
            line(Direction::ControllerToPlant, &config.controller_to_plant)?,
        ];
        let clock = Clock::new();
        let releaser = Releaser::start(clock).map_err(crate::NetemError::Io)?;
        let inner = Inner {
            lines,
            stats: Default::default(),
            in_flight: [0; 2],
            recording: None,
            deliveries: broadcast::channel(config.deliveries_buffer).0,
            mode,
            plant_time_ns: None,
            pending: ReleaseQueue::new(),
            last_sample: None,
            upstream_connected: true,
            upstream_failures: 0,
            epoch: 0,
            epoch_reason: String::new(),
            stream_overflow_dropped: [0; 2],
            refused_invalid: 0,
            deliveries_lagged: 0,
            udp: None,
            command_times: Default::default(),
        };
        Ok(Arc::new(Self {
            inner: Mutex::new(inner),
            clock,
            releaser,
            seed: config.seed,
            closing: tokio::sync::watch::channel(false).0,
            slots: StreamSlots::new("netem", config.max_streams, config.connections.max_streams_per_client),
        }))
    }

    /// Resolves when netem starts shutting down.
    pub fn closed(&self) -> impl std::future::Future<Output = ()> + Send + 'static {
        let mut rx = self.closing.subscribe();
        async move {
            let _ = rx.wait_for(|c| *c).await;
        }
    }

    pub fn lock(&self) -> MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// The gRPC proxy's state: a [`Net`] (which it dereferences to) and the upstream plant.
pub struct Shared {
    pub net: Arc<Net>,
    pub upstream: PlantClient<Channel>,
    pub upstream_addr: String,
    /// Serialises lockstep operations so that their order, and so the run, is deterministic.
    pub lockstep: tokio::sync::Mutex<()>,
    pub setting: TimeModeChoice,
    pub forward_tx: mpsc::UnboundedSender<Forward>,
    /// Samples a real-time state stream's buffer holds (`Config::stream_buffer`).
    pub stream_buffer: usize,
}

impl std::ops::Deref for Shared {
    type Target = Net;

    fn deref(&self) -> &Net {
        &self.net
    }
}

impl Shared {
    /// The state of a netem on `config` (validated) with `upstream` as its client.
    pub fn new(
        upstream: PlantClient<Channel>,
        config: &crate::Config,
    ) -> Result<(Arc<Self>, mpsc::UnboundedReceiver<Forward>), crate::NetemError> {
        let setting = config.time_mode;
        let net = Net::new(config, setting.fixed())?;
        let (forward_tx, forward_rx) = mpsc::unbounded_channel();
        let shared = Arc::new(Self {
            net,
            upstream,
            upstream_addr: config.upstream.clone(),
            lockstep: tokio::sync::Mutex::new(()),
            setting,
            forward_tx,
            stream_buffer: config.stream_buffer,
        });
        Ok((shared, forward_rx))
    }

    pub fn client(&self) -> PlantClient<Channel> {
        self.upstream.clone()
    }

    /// Awaits an upstream call, keeping track of whether the upstream is there. A gone
    /// upstream drops everything in flight and becomes `UNAVAILABLE` for the controller.
    pub async fn up<T>(
        &self,
        call: impl std::future::Future<Output = Result<Response<T>, Status>>,
    ) -> Result<Response<T>, Status> {
        match call.await {
            Ok(r) => {
                self.upstream_ok();
                Ok(r)
            }
            Err(s) if is_gone(&s) => Err(self.upstream_lost(&s)),
            Err(s) => Err(s),
        }
    }

    pub fn upstream_ok(&self) {
        let mut inner = self.lock();
        if !inner.upstream_connected {
            tracing::info!(upstream = %self.upstream_addr, "upstream plant is back");
            inner.upstream_connected = true;
        }
    }

    /// Records the loss of the upstream and returns the status the controller gets.
    pub fn upstream_lost(&self, s: &Status) -> Status {
        let reason = format!("upstream unavailable: {}", s.message());
        let mut inner = self.lock();
        if inner.upstream_connected {
            tracing::warn!(upstream = %self.upstream_addr, status = %s, "upstream plant is gone");
            inner.upstream_connected = false;
            inner.upstream_failures += 1;
        }
        inner.new_epoch(&reason);
        inner.plant_time_ns = None;
        Status::unavailable(format!(
            "netem: the upstream plant at {} is unavailable: {}",
            self.upstream_addr,
            s.message()
        ))
    }

    /// The time mode: fixed by configuration, or asked from the upstream once.
    pub async fn mode(&self) -> Result<TimeMode, Status> {
        if let Some(m) = self.lock().mode {
            return Ok(m);
        }
        let d = self.up(self.client().describe(pb::DescribeRequest {})).await?.into_inner();
        let m = self.learn_mode(d.time_mode);
        Ok(m)
    }

    /// Takes the upstream's time mode into account (only when configured `auto`).
    pub fn learn_mode(&self, time_mode: i32) -> TimeMode {
        let mut inner = self.lock();
        if self.setting == TimeModeChoice::Auto {
            inner.mode = Some(hilbench_proto::convert::time_mode_of_plant(time_mode));
        }
        inner.mode.unwrap_or(TimeMode::RealTime)
    }
}

/// Real time: applies released commands upstream one at a time, in release order (so FIFO
/// holds on the way to the plant as well).
pub async fn run_forwarder(shared: Arc<Shared>, mut rx: mpsc::UnboundedReceiver<Forward>) {
    while let Some(f) = rx.recv().await {
        let stale = {
            let inner = shared.lock();
            (f.epoch != inner.epoch).then(|| inner.epoch_reason.clone())
        };
        if let Some(reason) = stale {
            shared.lock().dropped(&f.msg, &reason);
            if let Some(reply) = f.reply {
                let _ = reply.send(Err(Status::unavailable(format!("netem: {reason}"))));
            }
            continue;
        }
        let result = shared.up(shared.client().apply_command(f.command)).await;
        let reply = match result {
            Ok(r) => {
                shared.lock().delivered(&f.msg, f.release_error_ns);
                Ok(r.into_inner())
            }
            Err(s) => {
                let reason = if s.code() == tonic::Code::Unavailable {
                    format!("upstream unavailable: {}", s.message())
                } else {
                    format!("refused by the plant: {}", s.message())
                };
                shared.lock().dropped(&f.msg, &reason);
                Err(s)
            }
        };
        if let Some(tx) = f.reply {
            let _ = tx.send(reply);
        }
    }
}

/// Polls a gone upstream until it answers again.
pub async fn run_probe(shared: Arc<Shared>, interval: std::time::Duration) {
    let mut tick = tokio::time::interval(interval);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tick.tick().await;
        if shared.lock().upstream_connected {
            continue;
        }
        if let Ok(d) = shared.client().describe(pb::DescribeRequest {}).await {
            shared.upstream_ok();
            shared.learn_mode(d.into_inner().time_mode);
        }
    }
}

/// The items of `stream` until netem starts shutting down (or the reader leaves).
pub fn until_closed<T: Send + 'static>(
    stream: impl tokio_stream::Stream<Item = T> + Send + 'static,
    closing: impl std::future::Future<Output = ()> + Send + 'static,
) -> tokio_stream::wrappers::ReceiverStream<T> {
    use tokio_stream::StreamExt;
    let (tx, rx) = mpsc::channel(RELAY_BUFFER);
    tokio::spawn(async move {
        tokio::pin!(stream);
        tokio::pin!(closing);
        loop {
            tokio::select! {
                item = stream.next() => match item {
                    Some(i) => {
                        if tx.send(i).await.is_err() {
                            break;
                        }
                    }
                    None => break,
                },
                () = &mut closing => break,
                () = tx.closed() => break,
            }
        }
    });
    tokio_stream::wrappers::ReceiverStream::new(rx)
}
