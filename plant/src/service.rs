//! The `hilbench.v1.Plant` service: decode and validate (in `hilbench_proto::convert`), call
//! the truth simulation of `mav`, encode. The service owns the clock and passes plant times
//! into the simulation.

use crate::clock::Clock;
use crate::config::{ConfigError, PlantConfig};
use hilbench_proto::convert::FieldError;
use hilbench_proto::convert::plant::{self as conv, Command, Reset, Step, StreamState};
use hilbench_proto::pb;
use hilbench_svc::streams::{Guarded, Pushed, StreamSlots, Writer, drop_oldest};
use mav::{PlantSim, Scenario, SimSettings, TimeMode};
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use tokio_stream::StreamExt;
use tonic::{Request, Response, Status};

/// What the plant calls itself in `PlantDescription.implementation`.
pub const IMPLEMENTATION: &str = concat!("hilbench-plant ", env!("CARGO_PKG_VERSION"), " (simulated)");

/// Lockstep advances longer than this (plant time, ns) run on the blocking pool instead of a
/// runtime worker. Shorter ones (a control cycle, the 1 ms bench step) cost microseconds and run
/// inline, which keeps the round trip short.
const INLINE_ADVANCE_MAX_NS: u64 = 100_000_000;

/// One `StreamState` subscriber.
struct Subscriber {
    /// The period in force: the one asked for, and at least one step (0 asks for every step).
    period_ns: u64,
    /// `floor(time / period)` of the last sample sent.
    last_slot: u64,
    /// Its buffer of `PlantConfig::stream_buffer` samples, which drops its oldest when full.
    tx: Writer<pb::StateSample>,
    /// Samples evicted from its full buffer.
    dropped: u64,
}

/// The `StreamState` subscribers, and what their buffers discarded.
#[derive(Default)]
struct Subscribers {
    list: Vec<Subscriber>,
    /// Samples evicted from a subscriber's full buffer, over every subscriber since start.
    overflow_dropped: u64,
}

/// Everything behind the lock.
struct Inner {
    scenario: Scenario,
    sim: PlantSim,
    /// Clock reading at the last reset; in real time, plant time is `now - epoch`.
    epoch_ns: u64,
    /// Sequence number of the next sample produced (every sample, on every path, is numbered
    /// once; subscribers of the same instant share one sample).
    next_seq: u64,
    /// The sample of the current instant, once produced; cleared whenever the state, the time
    /// or the last command changes.
    current: Option<pb::StateSample>,
    subscribers: Subscribers,
    /// Set at shutdown: streams are closed and no new ones are accepted.
    closed: bool,
    /// The id of the next flight (every reset starts one; see `mav::PlantSample::flight_id`).
    next_flight_id: u64,
}

/// The sample of the current instant (produced and numbered on first use).
fn current_sample(
    sim: &PlantSim,
    next_seq: &mut u64,
    current: &mut Option<pb::StateSample>,
) -> pb::StateSample {
    current
        .get_or_insert_with(|| {
            let mut s = sim.peek();
            s.seq = *next_seq;
            *next_seq += 1;
            pb::StateSample::from(&s)
        })
        .clone()
}

/// Called after every integration sub-step. It only reads the simulation, so observing never
/// changes the physics (the step boundaries are the simulation's own).
///
/// Streams are fed at step boundaries only (plant time a multiple of the step): a subscriber
/// gets the first boundary at or after each multiple of its period, so every step's time
/// exactly once, in order, with period 0. The other sub-steps end wherever a caller stopped
/// (a command's arrival, a lockstep read, a real-time tick catching up with the clock at
/// whatever time it woke), and feeding streams there gave a period-0 subscriber of a
/// real-time plant about two samples per step at irregular times.
fn on_step(
    sim: &PlantSim,
    next_seq: &mut u64,
    current: &mut Option<pb::StateSample>,
    subs: &mut Subscribers,
) {
    *current = None;
    let t = sim.time_ns();
    if subs.list.is_empty() || !t.is_multiple_of(sim.settings().step_ns) {
        return;
    }
    let mut sample: Option<pb::StateSample> = None;
    let Subscribers { list, overflow_dropped } = subs;
    list.retain_mut(|s| {
        let slot = t / s.period_ns;
        if slot <= s.last_slot {
            return true;
        }
        s.last_slot = slot;
        let msg = sample.get_or_insert_with(|| current_sample(sim, next_seq, current)).clone();
        offer(s, msg, overflow_dropped)
    });
}

/// Hands a sample to a subscriber without ever waiting: a slow subscriber must not hold up the
/// simulation (nor the other subscribers). When its buffer is full its oldest sample is
/// discarded for this one, so that it finds the freshest state when it reads again (what a
/// controller needs: a stale sample is worth less than a new one) and sees a gap in `seq`.
/// Counted per subscriber and in `overflow_dropped`, logged at every power of two. Returns
/// false when the subscriber is gone.
fn offer(s: &mut Subscriber, msg: pb::StateSample, overflow_dropped: &mut u64) -> bool {
    match s.tx.push(msg) {
        Pushed::Queued => true,
        Pushed::Evicted(_) => {
            s.dropped += 1;
            *overflow_dropped += 1;
            if s.dropped.is_power_of_two() {
                tracing::warn!(
                    dropped = s.dropped,
                    all_streams = *overflow_dropped,
                    "a state stream subscriber is too slow: the oldest samples of its buffer are discarded"
                );
            }
            true
        }
        Pushed::Closed(_) => {
            tracing::debug!(dropped = s.dropped, "state stream subscriber left");
            false
        }
    }
}

impl Inner {
    /// Integrates to plant time `time_ns`, feeding the subscribers.
    fn advance_to(&mut self, time_ns: u64) {
        let Inner { sim, next_seq, current, subscribers, .. } = self;
        sim.advance_to(time_ns, |s| on_step(s, next_seq, current, subscribers));
    }

    fn advance(&mut self, duration_ns: u64) {
        let target = self.sim.time_ns().saturating_add(duration_ns);
        self.advance_to(target);
    }

    fn apply(&mut self, c: &Command) -> Result<pb::AppliedCommand, Status> {
        let applied = self.sim.apply(c.input, c.meta).map_err(|e| Status::invalid_argument(e.to_string()))?;
        self.current = None;
        Ok(pb::AppliedCommand::from(&applied))
    }

    fn sample(&mut self) -> pb::StateSample {
        current_sample(&self.sim, &mut self.next_seq, &mut self.current)
    }
}

struct Shared {
    inner: Mutex<Inner>,
    time_mode: TimeMode,
    settings: SimSettings,
    /// The configured scenario (what an empty `Reset.scenario` means at start).
    config_scenario: Scenario,
    stream_buffer: usize,
    /// The cap on open `StreamState` streams.
    slots: StreamSlots,
    clock: Arc<dyn Clock>,
}

impl Shared {
    /// The simulation never panics on validated input; if a panic ever poisoned the lock, the
    /// state is still a valid simulation state, so keep serving it rather than fail every call.
    fn lock(&self) -> MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Real time: integrate up to the clock's current plant time.
    fn catch_up(&self, inner: &mut Inner) {
        if self.time_mode == TimeMode::RealTime {
            let now = self.clock.now_ns().saturating_sub(inner.epoch_ns);
            inner.advance_to(now);
        }
    }

    fn resolve(&self, current: &Scenario, name: Option<&str>) -> Result<Scenario, FieldError> {
        match name {
            None => Ok(current.clone()),
            Some(n) if n == current.name => Ok(current.clone()),
            Some(n) if n == self.config_scenario.name => Ok(self.config_scenario.clone()),
            Some(n) => conv::scenario_by_name("scenario", n),
        }
    }

    fn describe(&self, inner: &Inner) -> pb::PlantDescription {
        conv::plant_description(&inner.scenario, &self.settings, self.time_mode, IMPLEMENTATION)
    }
}

/// The plant service: a small handle around the shared simulation (cheap to clone).
#[derive(Clone)]
pub struct PlantService {
    shared: Arc<Shared>,
}

impl PlantService {
    /// A service on `config`, whose real-time mode reads `clock`. In real time, something must
    /// call [`PlantService::tick`] regularly (`serve` spawns a task for it).
    pub fn new(config: PlantConfig, clock: Arc<dyn Clock>) -> Result<Self, ConfigError> {
        let settings = config.validate()?;
        let mut sim = PlantSim::new(&config.scenario, settings)
            .map_err(|e| ConfigError { field: "scenario".into(), reason: e.to_string() })?;
        // Flight ids start at a random point per process, so that a restarted plant's first
        // flight is not taken for the flight it replaces.
        let first_flight_id = std::hash::BuildHasher::hash_one(
            &std::collections::hash_map::RandomState::new(),
            std::process::id(),
        )
        .max(1);
        sim.set_flight_id(first_flight_id);
        let inner = Inner {
            scenario: config.scenario.clone(),
            sim,
            epoch_ns: clock.now_ns(),
            next_seq: 0,
            current: None,
            subscribers: Subscribers::default(),
            closed: false,
            next_flight_id: first_flight_id.wrapping_add(1).max(1),
        };
        Ok(Self {
            shared: Arc::new(Shared {
                inner: Mutex::new(inner),
                time_mode: config.time_mode,
                settings,
                config_scenario: config.scenario,
                stream_buffer: config.stream_buffer,
                slots: StreamSlots::new(
                    "plant",
                    config.max_streams,
                    config.connections.max_streams_per_client,
                ),
                clock,
            }),
        })
    }

    pub fn time_mode(&self) -> TimeMode {
        self.shared.time_mode
    }

    /// Integration step, ns.
    pub fn step_ns(&self) -> u64 {
        self.shared.settings.step_ns
    }

    /// Real time: integrate to the clock's current plant time (a no-op in lockstep). Returns
    /// the step boundaries it integrated over (each one's sample went to the streams): 1 for
    /// a tick on time, more for a tick that came a step late or later.
    pub fn tick(&self) -> u64 {
        let mut inner = self.shared.lock();
        let before = inner.sim.time_ns();
        self.shared.catch_up(&mut inner);
        let step = self.shared.settings.step_ns;
        (inner.sim.time_ns() / step).saturating_sub(before / step)
    }

    /// Real time: how long, on the service's clock, until plant time reaches its next step
    /// boundary (a multiple of the step since the last reset), ns; a whole step when it is on
    /// one. The step loop wakes then, so that each step's sample goes out when its time comes
    /// rather than at a phase of its own.
    pub fn until_next_step_ns(&self) -> u64 {
        let epoch_ns = self.shared.lock().epoch_ns;
        let step = self.shared.settings.step_ns;
        step - self.shared.clock.now_ns().saturating_sub(epoch_ns) % step
    }

    /// Plant time the simulation has been integrated to, ns.
    pub fn plant_time_ns(&self) -> u64 {
        self.shared.lock().sim.time_ns()
    }

    /// Samples discarded from full `StreamState` buffers since start, over every subscriber
    /// (each subscriber's count is in the log, at every power of two).
    pub fn stream_overflow_dropped(&self) -> u64 {
        self.shared.lock().subscribers.overflow_dropped
    }

    /// Ends every state stream and refuses new ones (at shutdown, so that the server can
    /// finish its open calls).
    pub fn close(&self) {
        let mut inner = self.shared.lock();
        inner.closed = true;
        inner.subscribers.list.clear();
    }

    /// Lockstep advance, off the runtime workers when it is long.
    async fn advance_and_sample(
        &self,
        command: Option<Command>,
        duration_ns: u64,
    ) -> Result<pb::StateSample, Status> {
        let shared = self.shared.clone();
        let work = move || -> Result<pb::StateSample, Status> {
            let mut inner = shared.lock();
            shared.catch_up(&mut inner);
            if let Some(c) = &command {
                inner.apply(c)?;
            }
            inner.advance(duration_ns);
            Ok(inner.sample())
        };
        if duration_ns <= INLINE_ADVANCE_MAX_NS {
            work()
        } else {
            tokio::task::spawn_blocking(work)
                .await
                .map_err(|e| Status::internal(format!("advance task failed: {e}")))?
        }
    }

    fn refuse_in_real_time(&self, what: &str) -> Result<(), Status> {
        match self.shared.time_mode {
            TimeMode::Lockstep => Ok(()),
            TimeMode::RealTime => Err(Status::failed_precondition(format!(
                "the plant runs in real time: {what} with a duration > 0 is only served in lockstep"
            ))),
        }
    }
}

type SampleStream =
    Pin<Box<dyn tokio_stream::Stream<Item = Result<pb::StateSample, Status>> + Send + 'static>>;

#[tonic::async_trait]
impl pb::plant_server::Plant for PlantService {
    async fn reset(&self, request: Request<pb::ResetRequest>) -> Result<Response<pb::ResetResponse>, Status> {
        let req = Reset::try_from(request.get_ref())?;
        let shared = &self.shared;
        let mut inner = shared.lock();
        let scenario = match req.definition {
            Some(definition) => definition,
            None => shared.resolve(&inner.scenario, req.scenario.as_deref())?,
        };
        let start = req.initial_state.unwrap_or_else(|| scenario.start_state());
        // A start under the ground would be a collision before the first step: refused, with
        // nothing changed (the scenario's own start is checked by `Scenario::validate`).
        if start[2] < scenario.ground_z_m {
            return Err(FieldError::new(
                "initial_state.x[2]",
                format!(
                    "is below the ground (ground_z_m = {} m), got {} m",
                    scenario.ground_z_m,
                    mav::Number(start[2])
                ),
            )
            .into());
        }
        // Build the new simulation completely before touching the current one.
        let mut sim = PlantSim::new(&scenario, shared.settings)
            .map_err(|e| Status::internal(format!("scenario: {e}")))?;
        sim.reset(start).map_err(|e| FieldError::new("initial_state", e.to_string()))?;
        sim.set_flight_id(inner.next_flight_id);
        inner.next_flight_id = inner.next_flight_id.wrapping_add(1).max(1);
        tracing::info!(scenario = %scenario.name, custom_start = req.initial_state.is_some(), "reset");
        inner.sim = sim;
        inner.scenario = scenario;
        inner.epoch_ns = shared.clock.now_ns();
        inner.next_seq = 0;
        inner.current = None;
        let sample = inner.sample();
        let description = shared.describe(&inner);
        // Every subscriber learns about the reset: it gets the new first sample (a full buffer
        // makes room for it).
        let Subscribers { list, overflow_dropped } = &mut inner.subscribers;
        list.retain_mut(|s| {
            s.last_slot = 0;
            offer(s, sample.clone(), overflow_dropped)
        });
        Ok(Response::new(pb::ResetResponse { description: Some(description), sample: Some(sample) }))
    }

    type StreamStateStream = SampleStream;

    async fn stream_state(
        &self,
        request: Request<pb::StreamStateRequest>,
    ) -> Result<Response<Self::StreamStateStream>, Status> {
        let req = StreamState::try_from(request.get_ref())?;
        let slot = self.shared.slots.acquire(&request, "StreamState")?;
        let (tx, rx) = drop_oldest(self.shared.stream_buffer);
        let mut inner = self.shared.lock();
        if inner.closed {
            return Err(Status::unavailable("the plant is shutting down"));
        }
        // The stream starts with the current sample.
        let first = inner.sample();
        let period_ns = req.period_ns.max(self.shared.settings.step_ns);
        let sub = Subscriber { period_ns, last_slot: first.time_ns / period_ns, tx, dropped: 0 };
        let _ = sub.tx.push(first); // a new buffer has room
        inner.subscribers.list.push(sub);
        tracing::debug!(
            period_ns = req.period_ns,
            subscribers = inner.subscribers.list.len(),
            "state stream opened"
        );
        Ok(Response::new(Box::pin(Guarded::new(rx.map(Ok), slot))))
    }

    async fn get_state(
        &self,
        _request: Request<pb::GetStateRequest>,
    ) -> Result<Response<pb::StateSample>, Status> {
        // In real time this is the state at the last integration tick: reading never adds a
        // step boundary.
        Ok(Response::new(self.shared.lock().sample()))
    }

    async fn apply_command(
        &self,
        request: Request<pb::Command>,
    ) -> Result<Response<pb::ApplyCommandResponse>, Status> {
        hilbench_svc::inject_panic("plant-command");
        let command = Command::try_from(request.get_ref())?;
        let mut inner = self.shared.lock();
        // Real time: the command takes effect at its arrival time, not at the next tick.
        self.shared.catch_up(&mut inner);
        let applied = inner.apply(&command)?;
        Ok(Response::new(pb::ApplyCommandResponse { applied: Some(applied) }))
    }

    // `wait_for_command_seq` of Advance/Step is already satisfied here: the plant applies every
    // command on arrival, so no command is ever pending (it matters to a delaying proxy).
    async fn advance(
        &self,
        request: Request<pb::AdvanceRequest>,
    ) -> Result<Response<pb::AdvanceResponse>, Status> {
        let duration_ns = conv::advance_duration_ns(request.get_ref())?;
        self.refuse_in_real_time("Advance")?;
        let sample = self.advance_and_sample(None, duration_ns).await?;
        Ok(Response::new(pb::AdvanceResponse { sample: Some(sample) }))
    }

    async fn step(&self, request: Request<pb::StepRequest>) -> Result<Response<pb::AdvanceResponse>, Status> {
        let step = Step::try_from(request.get_ref())?;
        if step.command.is_some() {
            hilbench_svc::inject_panic("plant-command");
        }
        if step.duration_ns > 0 {
            self.refuse_in_real_time("Step")?;
        }
        let sample = self.advance_and_sample(step.command, step.duration_ns).await?;
        Ok(Response::new(pb::AdvanceResponse { sample: Some(sample) }))
    }

    async fn describe(
        &self,
        _request: Request<pb::DescribeRequest>,
    ) -> Result<Response<pb::PlantDescription>, Status> {
        let inner = self.shared.lock();
        Ok(Response::new(self.shared.describe(&inner)))
    }
}

#[cfg(test)]
mod tests {
    //! The service's logic called directly (no network), with a manual clock for real time.
    use super::*;
    use crate::clock::ManualClock;
    use pb::plant_server::Plant;

    fn cmd(thrust: f64, roll: f64, seq: u64) -> pb::Command {
        pb::Command {
            input: Some(pb::ControlInput { thrust_mps2: thrust, roll_rad: roll, pitch_rad: 0.0 }),
            command_seq: seq,
            ..Default::default()
        }
    }

    fn time_of(s: &pb::StateSample) -> u64 {
        s.time_ns
    }

    #[tokio::test]
    async fn real_time_follows_the_clock_and_the_watchdog_holds_hover() {
        let clock = Arc::new(ManualClock::new(5_000));
        let svc =
            PlantService::new(PlantConfig::real_time(Scenario::paper_1()), clock.clone()).expect("valid");
        clock.advance(2_500_000);
        svc.tick();
        let s = svc.get_state(Request::new(pb::GetStateRequest {})).await.expect("ok").into_inner();
        assert_eq!(time_of(&s), 2_500_000);
        // A command arriving between ticks takes effect at its arrival time.
        clock.advance(300_000);
        let applied = svc.apply_command(Request::new(cmd(12.0, 0.05, 1))).await.expect("ok").into_inner();
        assert_eq!(applied.applied.map(|a| a.applied_time_ns), Some(2_800_000));
        // Advance is refused, a zero-duration Step (apply and read) is served.
        let err = svc
            .advance(Request::new(pb::AdvanceRequest { duration_ns: 1_000_000, ..Default::default() }))
            .await
            .expect_err("refused");
        assert_eq!(err.code(), tonic::Code::FailedPrecondition);
        let read = svc
            .step(Request::new(pb::StepRequest { command: None, duration_ns: 0, ..Default::default() }))
            .await
            .expect("ok")
            .into_inner();
        assert_eq!(read.sample.map(|s| s.time_ns), Some(2_800_000));
        // No command for 500 ms: hover.
        clock.advance(499_000_000);
        svc.tick();
        let s = svc.get_state(Request::new(pb::GetStateRequest {})).await.expect("ok").into_inner();
        assert!(!s.watchdog_hover);
        clock.advance(1_000_000);
        svc.tick();
        let s = svc.get_state(Request::new(pb::GetStateRequest {})).await.expect("ok").into_inner();
        assert!(s.watchdog_hover, "at {} ns", s.time_ns);
        assert_eq!(s.time_ns, 502_800_000);
        // Reset restarts plant time from the clock.
        svc.reset(Request::new(pb::ResetRequest::default())).await.expect("ok");
        clock.advance(7_000_000);
        svc.tick();
        let s = svc.get_state(Request::new(pb::GetStateRequest {})).await.expect("ok").into_inner();
        assert_eq!((s.time_ns, s.seq, s.watchdog_hover), (7_000_000, 1, false));
    }

    #[tokio::test]
    async fn the_next_step_is_counted_from_the_last_reset_and_a_late_tick_says_how_many_steps_it_passed() {
        let clock = Arc::new(ManualClock::new(1_234_567));
        let svc =
            PlantService::new(PlantConfig::real_time(Scenario::paper_1()), clock.clone()).expect("valid");
        assert_eq!(svc.until_next_step_ns(), 1_000_000);
        clock.advance(300_000);
        assert_eq!(svc.until_next_step_ns(), 700_000);
        assert_eq!(svc.tick(), 0);
        clock.advance(700_000);
        assert_eq!((svc.until_next_step_ns(), svc.tick()), (1_000_000, 1));
        // Woken 2.5 steps late: three boundaries at once.
        clock.advance(3_500_000);
        assert_eq!(svc.tick(), 3);
        // A reset moves the boundaries to its own time.
        clock.advance(100_000);
        svc.reset(Request::new(pb::ResetRequest::default())).await.expect("ok");
        clock.advance(250_000);
        assert_eq!(svc.until_next_step_ns(), 750_000);
    }

    #[tokio::test]
    async fn every_reset_and_every_plant_starts_a_new_flight_id_and_hover_time_is_counted() {
        let clock = Arc::new(ManualClock::new(0));
        let svc =
            PlantService::new(PlantConfig::real_time(Scenario::paper_1()), clock.clone()).expect("valid");
        let state = async |svc: &PlantService| {
            svc.tick();
            svc.get_state(Request::new(pb::GetStateRequest {})).await.expect("ok").into_inner()
        };
        let first = state(&svc).await;
        assert_ne!(first.flight_id, 0);
        // 500 ms to the watchdog, then 300 ms of hover.
        clock.advance(800_000_000);
        let s = state(&svc).await;
        assert_eq!((s.flight_id, s.watchdog_hover_ns), (first.flight_id, 300_000_000));
        svc.reset(Request::new(pb::ResetRequest::default())).await.expect("ok");
        let after_reset = state(&svc).await;
        assert_ne!(after_reset.flight_id, first.flight_id);
        assert_eq!(after_reset.watchdog_hover_ns, 0);
        // Another process (here: another service) never starts with the same id.
        let other = PlantService::new(PlantConfig::real_time(Scenario::paper_1()), clock).expect("valid");
        let other_first = state(&other).await;
        assert_ne!(other_first.flight_id, first.flight_id);
        assert_ne!(other_first.flight_id, after_reset.flight_id);
    }

    #[tokio::test]
    async fn streams_emit_on_period_boundaries_and_samples_are_numbered_once() {
        let svc = PlantService::new(PlantConfig::default(), Arc::new(ManualClock::new(0))).expect("valid");
        let every = svc
            .stream_state(Request::new(pb::StreamStateRequest { period_ns: 0 }))
            .await
            .expect("ok")
            .into_inner();
        let coarse = svc
            .stream_state(Request::new(pb::StreamStateRequest { period_ns: 2_500_000 }))
            .await
            .expect("ok")
            .into_inner();
        let r = svc
            .advance(Request::new(pb::AdvanceRequest { duration_ns: 6_000_000, ..Default::default() }))
            .await
            .expect("ok");
        let last = r.into_inner().sample.expect("sample");
        svc.close();
        use tokio_stream::StreamExt;
        let every: Vec<_> = every.map(|s| s.expect("ok")).collect().await;
        let coarse: Vec<_> = coarse.map(|s| s.expect("ok")).collect().await;
        let times: Vec<u64> = every.iter().map(time_of).collect();
        assert_eq!(times, vec![0, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 5_000_000, 6_000_000]);
        let times: Vec<u64> = coarse.iter().map(time_of).collect();
        assert_eq!(times, vec![0, 3_000_000, 5_000_000]);
        // One sample per instant, shared by every path that reads it.
        let seqs: Vec<u64> = every.iter().map(|s| s.seq).collect();
        assert_eq!(seqs, (0..7).collect::<Vec<_>>());
        assert_eq!(coarse[1].seq, every[3].seq);
        assert_eq!(last.seq, every[6].seq);
        // Closed: no new streams.
        let err = svc.stream_state(Request::new(pb::StreamStateRequest { period_ns: 0 })).await;
        assert_eq!(err.err().map(|e| e.code()), Some(tonic::Code::Unavailable));
    }

    #[tokio::test]
    async fn in_real_time_period_0_gives_every_step_once_whenever_the_ticks_and_commands_come() {
        let clock = Arc::new(ManualClock::new(0));
        let svc =
            PlantService::new(PlantConfig::real_time(Scenario::paper_1()), clock.clone()).expect("valid");
        let open = |period_ns| svc.stream_state(Request::new(pb::StreamStateRequest { period_ns }));
        let every = open(0).await.expect("ok").into_inner();
        let coarse = open(2_500_000).await.expect("ok").into_inner();
        // Ticks that wake late and early, and commands that arrive between them: each ends an
        // integration sub-step off the 1 ms grid.
        for (wait_ns, command) in [
            (1_300_000, false),
            (700_000, false),
            (450_000, true),
            (1_020_000, false),
            (2_900_000, true),
            (30_000, false),
            (600_000, false),
        ] {
            clock.advance(wait_ns);
            if command {
                svc.apply_command(Request::new(cmd(10.0, 0.0, 1))).await.expect("applied");
            } else {
                svc.tick();
            }
        }
        let last = svc.get_state(Request::new(pb::GetStateRequest {})).await.expect("ok").into_inner();
        assert_eq!(last.time_ns, 7_000_000);
        svc.close();
        let every: Vec<u64> = every.map(|s| s.expect("ok").time_ns).collect().await;
        let coarse: Vec<u64> = coarse.map(|s| s.expect("ok").time_ns).collect().await;
        assert_eq!(every, (0..=7).map(|k| k * 1_000_000).collect::<Vec<_>>());
        assert_eq!(coarse, vec![0, 3_000_000, 5_000_000]);
    }

    #[tokio::test]
    async fn a_subscriber_that_does_not_read_finds_the_newest_samples_and_never_blocks_the_plant() {
        let config = PlantConfig { stream_buffer: 2, ..Default::default() };
        let svc = PlantService::new(config, Arc::new(ManualClock::new(0))).expect("valid");
        let mut stream = svc
            .stream_state(Request::new(pb::StreamStateRequest { period_ns: 0 }))
            .await
            .expect("ok")
            .into_inner();
        let r = svc
            .advance(Request::new(pb::AdvanceRequest { duration_ns: 50_000_000, ..Default::default() }))
            .await
            .expect("ok");
        assert_eq!(r.into_inner().sample.map(|s| s.time_ns), Some(50_000_000));
        // 51 samples (0 to 50 ms) for a buffer of 2: the 49 oldest were discarded.
        assert_eq!(svc.stream_overflow_dropped(), 49);
        let first = stream.next().await.and_then(Result::ok).map(|s| s.time_ns);
        let second = stream.next().await.and_then(Result::ok).map(|s| s.time_ns);
        assert_eq!((first, second), (Some(49_000_000), Some(50_000_000)));
        // Read up: the next step is delivered, and nothing more is discarded.
        svc.advance(Request::new(pb::AdvanceRequest { duration_ns: 1_000_000, ..Default::default() }))
            .await
            .expect("ok");
        let third = stream.next().await.and_then(Result::ok).expect("sample");
        assert_eq!(third.time_ns, 51_000_000);
        assert_eq!(svc.stream_overflow_dropped(), 49);
    }

    #[tokio::test]
    async fn a_subscriber_with_a_full_buffer_still_gets_the_reset_sample() {
        let config = PlantConfig { stream_buffer: 2, ..Default::default() };
        let svc = PlantService::new(config, Arc::new(ManualClock::new(0))).expect("valid");
        let mut stream = svc
            .stream_state(Request::new(pb::StreamStateRequest { period_ns: 0 }))
            .await
            .expect("ok")
            .into_inner();
        svc.advance(Request::new(pb::AdvanceRequest { duration_ns: 10_000_000, ..Default::default() }))
            .await
            .expect("ok");
        let reset = svc.reset(Request::new(pb::ResetRequest::default())).await.expect("ok").into_inner();
        let reset = reset.sample.expect("sample");
        let mut got = Vec::new();
        for _ in 0..2 {
            let s = stream.next().await.and_then(Result::ok).expect("sample");
            got.push((s.time_ns, s.seq));
        }
        assert_eq!(got, vec![(10_000_000, 10), (reset.time_ns, reset.seq)]);
    }
}
