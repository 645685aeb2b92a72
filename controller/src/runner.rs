//! The control loop: a Plant API client running `docs/spec.md`'s cycle.
//!
//! Lockstep (the controller drives plant time): at `t_k` it solves from the sample and sends
//! the command with the cycle's advance in one call, `Step(command, min_cycle,
//! wait_for_command_seq = k)`, so the next sample comes at `t_k + max(min_cycle, d_k)`
//! whatever sits between it and the plant. Real time:
//! one cycle every `min_cycle` of wall time, from the freshest sample, with a solve deadline.
//!
//! The cycle itself (delay measured from the sample's stamps, weights, solve, safety layer,
//! command) is `mpc::Episode`'s, the same one the in-process loop runs: this module only
//! carries samples in and commands out, decoded and encoded by `proto`'s convert module.
//!
//! A broken link is retried with exponential backoff; the episode (solver warm start, delay
//! window, command numbering) survives, and the plant is not reset on reconnection.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use hilbench_proto::convert::controller::telemetry_of;
use hilbench_proto::convert::netem::{Stamp, StampOutcome, Stamped};
use hilbench_proto::convert::plant::Command;
use hilbench_proto::pb;
use hilbench_proto::pb::plant_client::PlantClient;
use mav::{PlantSample, Scenario, ScenarioError};
use mpc::{ControllerMode, CycleOutput, CycleTiming, Episode, EpisodeSettings, RunEnd};
use tokio::sync::{Notify, broadcast, watch};
use tonic::transport::Channel;

use crate::config::ControllerConfig;

/// What the service reports in `GetStatus`.
#[derive(Debug, Clone, Default)]
pub struct Status {
    pub scenario: String,
    pub mode: String,
    pub plant_connected: bool,
    pub plant_address: String,
    pub cycles: u64,
    pub goal_m: [f64; 3],
    pub weights: Vec<f64>,
    pub sampling_times_s: Vec<f64>,
    pub last_solve: Option<pb::SolveStats>,
    pub reconnects: u64,
    pub last_error: String,
    pub reached: bool,
    /// Episodes started (0 = none yet).
    pub episode: u64,
    /// The current episode has ended and the loop idles until the next request.
    pub episode_finished: bool,
    /// Episodes ended.
    pub episodes_finished: u64,
    /// Why the last episode ended; `None` while one runs.
    pub finish_reason: Option<RunEnd>,
    /// Outages of the plant link during the current episode: failed calls, or in real time no
    /// completed cycle for longer than the stall timeout (one per outage).
    pub link_losses: u64,
    /// Wall time from the last completed cycle before each outage to the first one after it,
    /// summed over the ended outages of the current episode, s.
    pub link_down_s: f64,
    /// The longest of those outages, s.
    pub longest_link_down_s: f64,
    /// The plant was reset or restarted under the current episode (which then ended).
    pub plant_resets: u64,
    /// Plant time of the last sample of the episode's flight before the reset, s.
    pub plant_reset_time_s: f64,
    /// Solves of the current episode that stopped at the iteration limit.
    pub iteration_limits: u64,
    /// Of those, the ones whose plan was predicted inside a cylinder
    /// (`SolveStatus::InfeasibleAtLimit`).
    pub infeasible_at_limit: u64,
    /// The scenario of the current episode; before the first, the one the controller was
    /// started with (`--scenario`), as it will fly it.
    pub definition: Option<Scenario>,
}

/// Requests from the Controller API, taken by the loop at the start of the next cycle.
#[derive(Debug, Default)]
struct Requests {
    goal: Option<[f64; 3]>,
    scenario: Option<(Scenario, Option<ControllerMode>)>,
}

/// The requests not yet taken, and the scenario they lead to: what a new goal is checked
/// against (the pending scenario if there is one, else the one flown).
#[derive(Debug)]
struct RequestState {
    pending: Requests,
    target: Scenario,
}

/// State shared between the loop and the gRPC service.
#[derive(Debug)]
pub struct Shared {
    status: Mutex<Status>,
    requests: Mutex<RequestState>,
    wake: Notify,
    closed: AtomicBool,
    /// Turns true at [`Shared::close`]: the telemetry streams end.
    closing: watch::Sender<bool>,
    telemetry: broadcast::Sender<pb::CycleTelemetry>,
    /// The link's wall-clock record of the current episode.
    link: Mutex<LinkClock>,
    /// `ControllerConfig::min_altitude_m`, for the scenarios `SetScenario` asks for.
    floor_m: Option<f64>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding the lock leaves plain data behind; keep serving it.
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl Shared {
    pub fn new(config: &ControllerConfig) -> Arc<Self> {
        let (telemetry, _) = broadcast::channel(config.telemetry_buffer.max(1));
        let status = Status {
            scenario: config.scenario.name.clone(),
            mode: config.episode.mode.name().to_string(),
            plant_address: config.plant.clone(),
            goal_m: config.scenario.goal_m,
            definition: Some(config.adapt(config.scenario.clone())),
            ..Status::default()
        };
        Arc::new(Self {
            status: Mutex::new(status),
            requests: Mutex::new(RequestState {
                pending: Requests::default(),
                target: config.adapt(config.scenario.clone()),
            }),
            wake: Notify::new(),
            closed: AtomicBool::new(false),
            closing: watch::channel(false).0,
            telemetry,
            link: Mutex::new(LinkClock::new(config.stall_timeout)),
            floor_m: config.min_altitude_m,
        })
    }

    pub fn status(&self) -> Status {
        lock(&self.status).clone()
    }

    pub fn subscribe(&self) -> broadcast::Receiver<pb::CycleTelemetry> {
        self.telemetry.subscribe()
    }

    /// Asks for a new goal from the next cycle on, in the scenario the requests so far lead to
    /// (a `SetScenario` not yet taken included: the goal then applies to that scenario).
    /// Refused, with nothing changed, when it cannot be that scenario's goal.
    pub fn request_goal(&self, goal: [f64; 3]) -> Result<(), ScenarioError> {
        let mut r = lock(&self.requests);
        r.target.check_goal(goal)?;
        r.target.goal_m = goal;
        match &mut r.pending.scenario {
            Some((scenario, _)) => scenario.goal_m = goal,
            None => r.pending.goal = Some(goal),
        }
        self.wake.notify_one();
        Ok(())
    }

    /// Asks for a new episode of `scenario` (with its own goal: an earlier goal request not
    /// yet taken is superseded).
    pub fn request_scenario(&self, scenario: Scenario, mode: Option<ControllerMode>) {
        let scenario = crate::config::with_floor(scenario, self.floor_m);
        let mut r = lock(&self.requests);
        r.target = scenario.clone();
        r.pending = Requests { goal: None, scenario: Some((scenario, mode)) };
        self.wake.notify_one();
    }

    pub fn close(&self) {
        self.closed.store(true, Ordering::SeqCst);
        self.closing.send_replace(true);
        self.wake.notify_one();
    }

    /// Turns true once the service is closing.
    pub fn closing(&self) -> watch::Receiver<bool> {
        self.closing.subscribe()
    }

    fn take_requests(&self) -> Requests {
        std::mem::take(&mut lock(&self.requests).pending)
    }

    fn update(&self, f: impl FnOnce(&mut Status)) {
        f(&mut lock(&self.status));
    }

    /// A whole cycle went through the plant API (state read, command applied): ends an outage
    /// (adding it to the episode's link faults). Not on `Describe` alone: a gateway that
    /// answers it but fails every cycle is still down, and its retries one outage.
    fn link_answered(&self, real_time: bool) {
        let outage = lock(&self.link).cycle_completed(Instant::now(), real_time);
        if let Some(outage) = outage {
            let down_s = outage.down.as_secs_f64();
            self.update(|st| {
                st.link_losses += u64::from(outage.undetected);
                st.link_down_s += down_s;
                st.longest_link_down_s = st.longest_link_down_s.max(down_s);
            });
        }
    }

    /// A working plant link failed: starts an outage (retries of the same outage count once).
    /// True when this starts a new outage (the link had answered since the last one).
    fn link_lost(&self) -> bool {
        let new = lock(&self.link).call_failed(Instant::now());
        if new {
            self.update(|st| st.link_losses += 1);
        }
        new
    }
}

/// The plant link's outages, measured on the wall clock from completed cycles: an outage runs
/// from the last cycle completed before it to the first one after it, so that the time it took
/// to notice (an RPC timeout) is part of it.
#[derive(Debug)]
struct LinkClock {
    /// Real time: no completed cycle for longer than this is an outage even without a failed
    /// call (a link that hangs, or a plant that stalls).
    stall_timeout: Duration,
    /// When the last cycle of the episode completed (`None` before the first).
    last_cycle: Option<Instant>,
    /// An outage is open: since when (the last completed cycle, or the failure when none).
    down_since: Option<Instant>,
}

/// An outage that a completed cycle has ended.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Outage {
    down: Duration,
    /// No failed call announced it (a stall): it is counted now.
    undetected: bool,
}

impl LinkClock {
    fn new(stall_timeout: Duration) -> Self {
        Self { stall_timeout, last_cycle: None, down_since: None }
    }

    /// A new episode: its outages are counted from its first cycle on.
    fn restart(&mut self) {
        self.last_cycle = None;
        self.down_since = None;
    }

    /// A plant call failed at `now`; true when this opens an outage.
    fn call_failed(&mut self, now: Instant) -> bool {
        if self.down_since.is_some() {
            return false;
        }
        self.down_since = Some(self.last_cycle.unwrap_or(now));
        true
    }

    /// A cycle completed at `now`: the outage it ends, if any.
    fn cycle_completed(&mut self, now: Instant, real_time: bool) -> Option<Outage> {
        let last = self.last_cycle.replace(now);
        if let Some(since) = self.down_since.take() {
            return Some(Outage { down: now.saturating_duration_since(since), undetected: false });
        }
        let gap = now.saturating_duration_since(last?);
        (real_time && gap > self.stall_timeout).then_some(Outage { down: gap, undetected: true })
    }
}

/// The episode in flight, with what the loop keeps across reconnections besides it.
struct Flight {
    episode: Episode,
    /// Number of this episode (1 for the first).
    number: u64,
    /// Lockstep: the sample the last `Advance` returned.
    pending_sample: Option<pb::StateSample>,
}

/// What the loop flies: the scenario and mode of the next episode, and the episode in flight.
struct Current {
    scenario: Scenario,
    mode: ControllerMode,
    flight: Option<Flight>,
}

/// The settings of an episode of `mode` under `config` (the scenario's own delay model says
/// whether delays are expected).
fn episode_settings(config: &ControllerConfig, scenario: &Scenario, mode: ControllerMode) -> EpisodeSettings {
    EpisodeSettings { mode, delays_expected: scenario.delays_expected(), ..config.episode.clone() }
}

enum Outcome {
    /// Reached the goal or the time limit (lockstep); wait for the next request.
    Finished,
    /// A new scenario was requested: start a new episode.
    Restart,
    Stopped,
}

#[derive(Debug, thiserror::Error)]
enum LoopError {
    #[error("plant: {0}")]
    Rpc(#[from] tonic::Status),
    #[error("plant: no answer to {call} within {after:?}")]
    Timeout { call: &'static str, after: Duration },
    // The chain: tonic's transport error says only "transport error"; its sources say why
    // (refused, a TLS handshake failure, a certificate for another name).
    #[error("connect: {}", hilbench_svc::error_chain(.0))]
    Connect(#[from] tonic::transport::Error),
    #[error("{0}")]
    Bad(String),
    /// The plant was reset or restarted under the episode (`last_time_s`: plant time of the
    /// episode's flight's last sample).
    #[error("{message}")]
    PlantReset { message: String, last_time_s: f64 },
}

/// An error of the episode: a plant reset, or a sample or goal the episode refuses.
fn episode_error(e: mpc::MpcError) -> LoopError {
    match e {
        mpc::MpcError::PlantReset { last_time_s, .. } => {
            LoopError::PlantReset { message: format!("{e}; the episode ends"), last_time_s }
        }
        e => LoopError::Bad(e.to_string()),
    }
}

impl LoopError {
    /// The plant (or netem) refused what the controller sent, for a reason a retry would meet
    /// again: the episode ends with this error rather than retrying forever. A lost or silent
    /// link, or a bad sample, is retried.
    fn ends_episode(&self) -> bool {
        use tonic::Code;
        if matches!(self, LoopError::PlantReset { .. }) {
            return true;
        }
        matches!(self, LoopError::Rpc(s) if matches!(
            s.code(),
            Code::InvalidArgument
                | Code::OutOfRange
                | Code::FailedPrecondition
                | Code::Unimplemented
                | Code::NotFound
                | Code::PermissionDenied
                | Code::Unauthenticated
        ))
    }
}

/// Runs until `stop` turns true.
pub async fn run(config: ControllerConfig, shared: Arc<Shared>, mut stop: watch::Receiver<bool>) {
    let mut current =
        Current { scenario: config.adapt(config.scenario.clone()), mode: config.episode.mode, flight: None };
    let mut active = config.autostart;
    let mut backoff = config.backoff_min;
    loop {
        if *stop.borrow() || shared.closed.load(Ordering::SeqCst) {
            return;
        }
        if !active {
            let requests = shared.take_requests();
            if let Some((s, m)) = requests.scenario {
                current.scenario = s;
                current.mode = m.unwrap_or(current.mode);
                current.flight = None;
                active = true;
                continue;
            }
            if let Some(goal) = requests.goal {
                current.scenario.goal_m = goal;
                shared.update(|st| st.goal_m = goal);
                active = true;
                continue;
            }
            tokio::select! {
                _ = shared.wake.notified() => {}
                _ = stop.changed() => return,
            }
            continue;
        }
        // A stop ends a hanging call at once rather than after `rpc_timeout`.
        let mut stop_during_call = stop.clone();
        let outcome = tokio::select! {
            outcome = async {
                let channel = config
                    .plant_endpoint()
                    .map_err(|e| LoopError::Bad(e.to_string()))?
                    .connect_timeout(Duration::from_secs(2))
                    .tcp_nodelay(true)
                    .connect()
                    .await?;
                let mut client = PlantClient::new(channel);
                fly(&config, &shared, &mut client, &mut current, &mut stop).await
            } => outcome,
            _ = stop_during_call.wait_for(|stop| *stop) => return,
        };
        match outcome {
            Ok(Outcome::Stopped) => return,
            Ok(Outcome::Finished) => {
                active = false;
                current.flight = None;
                backoff = config.backoff_min;
            }
            Ok(Outcome::Restart) => {
                current.flight = None;
                backoff = config.backoff_min;
            }
            Err(e) if e.ends_episode() => {
                tracing::error!(error = %e, "the episode ends with an error");
                shared.update(|st| {
                    if let LoopError::PlantReset { last_time_s, .. } = &e {
                        st.plant_resets += 1;
                        st.plant_reset_time_s = *last_time_s;
                    }
                    st.last_error = e.to_string();
                    st.episode_finished = true;
                    st.episodes_finished += 1;
                    st.finish_reason = Some(RunEnd::Error);
                });
                active = false;
                current.flight = None;
            }
            Err(e) => {
                if !matches!(e, LoopError::Bad(_)) && shared.link_lost() {
                    // A new outage: retry soon, whatever the last one's backoff had grown to.
                    backoff = config.backoff_min;
                }
                if let Some(flight) = current.flight.as_mut() {
                    flight.episode.forget_in_flight();
                }
                tracing::warn!(error = %e, retry_in_ms = backoff.as_millis() as u64, "plant link lost; retrying");
                shared.update(|st| {
                    st.plant_connected = false;
                    st.last_error = e.to_string();
                    st.reconnects += 1;
                });
                tokio::select! {
                    _ = tokio::time::sleep(backoff) => {}
                    _ = stop.changed() => return,
                }
                backoff = (backoff * 2).min(config.backoff_max);
            }
        }
    }
}

/// Smallest per-call timeout in lockstep (see `call_timeout` in `fly`).
const LOCKSTEP_MIN_RPC_TIMEOUT: Duration = Duration::from_secs(60);

/// One plant call, given up after `limit`: a link that goes silent without closing (a frozen
/// gateway) is then a lost link like a closed one.
async fn within<T>(
    limit: Duration,
    call: &'static str,
    request: impl std::future::Future<Output = Result<tonic::Response<T>, tonic::Status>>,
) -> Result<T, LoopError> {
    match tokio::time::timeout(limit, request).await {
        Ok(answer) => Ok(answer?.into_inner()),
        Err(_) => Err(LoopError::Timeout { call, after: limit }),
    }
}

/// The answer to a cycle's command: lockstep's `Step` (with the next sample) or real time's
/// `ApplyCommand`.
enum Answer {
    Step(tonic::Response<pb::AdvanceResponse>),
    Command(tonic::Response<pb::ApplyCommandResponse>),
}

/// What netem's stamp says of a command, read once: the delay it put on a command it did not
/// drop, s (`None` without netem's stamps, with stamps that do not read, or for a dropped
/// command), and whether it dropped it.
fn command_fate(md: &tonic::metadata::MetadataMap) -> (Option<f64>, bool) {
    match Stamp::read(md, Stamped::Command) {
        Ok(Some(stamp)) if stamp.outcome == StampOutcome::Dropped => (None, true),
        Ok(Some(stamp)) => (Some(mav::ns_to_s(stamp.delay_ns)), false),
        _ => (None, false),
    }
}

/// A sample from the plant, validated by `proto`'s conversion.
fn decode(sample: &pb::StateSample) -> Result<PlantSample, LoopError> {
    PlantSample::try_from(sample).map_err(|e| LoopError::Bad(format!("plant sent {e}")))
}

async fn fly(
    config: &ControllerConfig,
    shared: &Shared,
    client: &mut PlantClient<Channel>,
    current: &mut Current,
    stop: &mut watch::Receiver<bool>,
) -> Result<Outcome, LoopError> {
    let description = within(config.rpc_timeout, "Describe", client.describe(pb::DescribeRequest {})).await?;
    shared.update(|st| st.plant_connected = true);
    let lockstep =
        config.time_mode.resolve(hilbench_proto::convert::time_mode_of_plant(description.time_mode))
            == mav::TimeMode::Lockstep;
    // A lockstep call does a whole cycle's integration before it answers, and a stall of the
    // machine must not turn into a link loss (the run would then depend on wall-clock time).
    let call_timeout =
        if lockstep { config.rpc_timeout.max(LOCKSTEP_MIN_RPC_TIMEOUT) } else { config.rpc_timeout };
    if current.flight.is_none() {
        let number = shared.status().episode + 1;
        let mut settings = episode_settings(config, &current.scenario, current.mode);
        // The fail-safe check counts on the plant's braking watchdog only where the plant says
        // it has one (a gateway's watchdog only levels the vehicle).
        settings.plant_watchdog_s = hilbench_proto::convert::plant::braking_watchdog_s(&description);
        let episode =
            Episode::new(current.scenario.clone(), settings).map_err(|e| LoopError::Bad(e.to_string()))?;
        let sample = if config.reset_plant {
            // The whole scenario, so that a plant (or gateway) flies exactly the controller's
            // world, whether or not it knows the scenario by name.
            let reset = pb::ResetRequest {
                scenario: String::new(),
                initial_state: None,
                definition: Some((&current.scenario).into()),
            };
            within(call_timeout, "Reset", client.reset(reset)).await?.sample
        } else {
            Some(within(call_timeout, "GetState", client.get_state(pb::GetStateRequest {})).await?)
        };
        shared.update(|st| {
            st.scenario = current.scenario.name.clone();
            st.definition = Some(current.scenario.clone());
            st.mode = current.mode.name().to_string();
            st.goal_m = current.scenario.goal_m;
            st.cycles = 0;
            st.reached = false;
            st.episode = number;
            st.episode_finished = false;
            st.finish_reason = None;
            (st.link_losses, st.link_down_s, st.longest_link_down_s) = (0, 0.0, 0.0);
            (st.plant_resets, st.plant_reset_time_s) = (0, 0.0);
            (st.iteration_limits, st.infeasible_at_limit) = (0, 0);
            st.sampling_times_s = episode.controller().definition().sampling_times_s.clone();
        });
        tracing::info!(scenario = %current.scenario.name, mode = current.mode.name(), lockstep, "episode started");
        lock(&shared.link).restart();
        current.flight = Some(Flight { episode, number, pending_sample: sample });
    }
    let Some(flight) = current.flight.as_mut() else {
        return Err(LoopError::Bad("no episode".into()));
    };
    let min_cycle = Duration::from_nanos(flight.episode.min_cycle_ns());
    let timing = if lockstep {
        CycleTiming::Lockstep
    } else {
        CycleTiming::RealTime { deadline: min_cycle.mul_f64(config.deadline_fraction) }
    };
    loop {
        if *stop.borrow() || shared.closed.load(Ordering::SeqCst) {
            return Ok(Outcome::Stopped);
        }
        let requests = shared.take_requests();
        if let Some((s, m)) = requests.scenario {
            current.scenario = s;
            current.mode = m.unwrap_or(current.mode);
            return Ok(Outcome::Restart);
        }
        if let Some(goal) = requests.goal {
            flight.episode.set_goal(goal).map_err(|e| LoopError::Bad(e.to_string()))?;
            current.scenario.goal_m = goal;
            shared.update(|st| {
                st.goal_m = goal;
                if let Some(d) = st.definition.as_mut() {
                    d.goal_m = goal;
                }
                st.reached = false;
            });
        }
        let cycle_start = Instant::now();
        let wire_sample = match (lockstep, flight.pending_sample.take()) {
            (true, Some(s)) => s,
            _ => within(call_timeout, "GetState", client.get_state(pb::GetStateRequest {})).await?,
        };
        let sample = decode(&wire_sample)?;
        hilbench_svc::inject_panic("controller-cycle");
        flight.episode.check_flight(&sample).map_err(episode_error)?;
        match flight.episode.finish(&sample) {
            Some(end @ RunEnd::Reached { .. }) => {
                shared.update(|st| st.reached = true);
                if lockstep {
                    tracing::info!(
                        t_s = mav::ns_to_s(sample.time_ns),
                        cycles = flight.episode.cycles(),
                        "goal reached"
                    );
                    finish(shared, end);
                    return Ok(Outcome::Finished);
                }
            }
            Some(end @ (RunEnd::Collided | RunEnd::TimeLimit)) if lockstep => {
                tracing::info!(
                    t_s = mav::ns_to_s(sample.time_ns),
                    cycles = flight.episode.cycles(),
                    end = end.name(),
                    "the episode ends"
                );
                finish(shared, end);
                return Ok(Outcome::Finished);
            }
            _ => {}
        }
        let mut out = flight.episode.on_sample(&sample, &timing).map_err(episode_error)?;
        let command = pb::Command::from(&Command { input: out.record.command.into(), meta: out.meta });
        // Lockstep: one call per cycle, `Step` (the command, then the cycle's advance, to the
        // command's release at least: `wait_for_command_seq`, and the next sample), which the
        // plant and netem run as `ApplyCommand` then `Advance`. Real time: the command alone.
        let (call, answer) = if lockstep {
            let step = pb::StepRequest {
                command: Some(command),
                duration_ns: flight.episode.min_cycle_ns(),
                wait_for_command_seq: flight.episode.commands_sent(),
            };
            ("Step", tokio::time::timeout(call_timeout, client.step(step)).await.map(|a| a.map(Answer::Step)))
        } else {
            let answer = tokio::time::timeout(call_timeout, client.apply_command(command)).await;
            ("ApplyCommand", answer.map(|a| a.map(Answer::Command)))
        };
        let answer = match answer {
            Ok(answer) => answer.map_err(LoopError::from),
            Err(_) => Err(LoopError::Timeout { call, after: call_timeout }),
        };
        // The cycle happened (it was solved and its command numbered) whether or not the
        // command got through: its telemetry is published either way, so that the record of
        // an episode has no gap (a command that did not get through has no injected delay).
        let answer = match answer {
            Ok(answer) => answer,
            Err(e) => {
                publish(shared, flight, &wire_sample, out);
                return Err(e);
            }
        };
        let metadata = match &answer {
            Answer::Step(r) => r.metadata(),
            Answer::Command(r) => r.metadata(),
        };
        (out.record.injected_delay_s, out.record.command_lost) = command_fate(metadata);
        shared.link_answered(!lockstep);
        publish(shared, flight, &wire_sample, out);
        if let Answer::Step(r) = answer {
            flight.pending_sample = r.into_inner().sample;
        } else {
            let next = cycle_start + min_cycle;
            tokio::select! {
                _ = tokio::time::sleep_until(next.into()) => {}
                _ = stop.changed() => return Ok(Outcome::Stopped),
            }
        }
    }
}

/// Marks the current episode as ended (the loop idles until the next request).
fn finish(shared: &Shared, end: RunEnd) {
    shared.update(|st| {
        st.episode_finished = true;
        st.episodes_finished += 1;
        st.finish_reason = Some(end);
    });
}

/// The cycle's status, and its telemetry to the subscribers (predictions computed only when
/// somebody listens).
fn publish(shared: &Shared, flight: &Flight, wire_sample: &pb::StateSample, mut out: CycleOutput) {
    let stats = pb::SolveStats::from(&out.record.solve);
    let status = out.record.solve.status;
    shared.update(|st| {
        st.iteration_limits += u64::from(status.at_iteration_limit());
        st.infeasible_at_limit += u64::from(status == mpc::SolveStatus::InfeasibleAtLimit);
        st.cycles = flight.episode.cycles();
        st.weights = out.record.weights.clone();
        st.last_solve = Some(stats);
    });
    if shared.telemetry.receiver_count() == 0 {
        return;
    }
    out.record.predictions = flight.episode.predictions(&out.record.weights);
    let qp = out.outcome.selection.as_ref().and_then(|s| s.qp_report.as_ref());
    // No subscriber left is not an error.
    let _ = shared.telemetry.send(telemetry_of(&out.record, wire_sample, flight.number, qp));
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field(r: Result<(), ScenarioError>) -> String {
        match r {
            Err(ScenarioError::Invalid { field, .. }) => field,
            other => format!("{other:?}"),
        }
    }

    #[test]
    fn a_goal_is_checked_against_the_scenario_it_will_apply_to_and_never_dropped() {
        let config = ControllerConfig::new("127.0.0.1:1", Scenario::paper_1(), ControllerMode::Nmpc);
        let shared = Shared::new(&config);
        // Inside paper-1's cylinder: refused, nothing pending.
        assert_eq!(field(shared.request_goal([0.3, 6.0, 1.0])), "goal_m");
        let r = shared.take_requests();
        assert!(r.goal.is_none() && r.scenario.is_none());
        // A goal for the scenario flown.
        assert_eq!(shared.request_goal([1.0, 8.0, 1.5]), Ok(()));
        assert_eq!(shared.take_requests().goal, Some([1.0, 8.0, 1.5]));
        // A goal after a SetScenario not yet taken belongs to that scenario: checked against
        // it (this point is clear of paper-1's cylinder but inside paper-2's 0.4 m one) and
        // carried by it, not dropped when the loop takes the scenario.
        shared.request_scenario(Scenario::paper_2(), None);
        assert_eq!(field(shared.request_goal([2.8, 3.0, 1.0])), "goal_m");
        assert_eq!(shared.request_goal([3.0, 4.5, 1.2]), Ok(()));
        let r = shared.take_requests();
        assert!(r.goal.is_none());
        let (scenario, _) = r.scenario.expect("the scenario request");
        assert_eq!((scenario.name.as_str(), scenario.goal_m), ("paper-2", [3.0, 4.5, 1.2]));
        // A SetScenario supersedes an earlier goal request: its own goal stands.
        assert_eq!(shared.request_goal([3.5, 4.8, 1.0]), Ok(()));
        shared.request_scenario(Scenario::paper_3(), None);
        let r = shared.take_requests();
        assert!(r.goal.is_none());
        assert_eq!(r.scenario.map(|(s, _)| s.goal_m), Some(Scenario::paper_3().goal_m));
    }

    #[test]
    fn an_outage_runs_from_the_last_completed_cycle_and_a_stall_counts_in_real_time_only() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        let mut link = LinkClock::new(Duration::from_millis(500));
        assert_eq!(link.cycle_completed(at(0), true), None, "the first cycle");
        assert_eq!(link.cycle_completed(at(50), true), None);
        // Frozen at 50 ms; the RPC timeout notices at 5050 ms, retries fail until 7000 ms.
        assert!(link.call_failed(at(5050)));
        assert!(!link.call_failed(at(5500)), "one outage, however many retries");
        let outage = link.cycle_completed(at(7000), true).expect("an outage");
        assert_eq!(outage, Outage { down: Duration::from_millis(6950), undetected: false });
        // Frozen for 3 s, less than the RPC timeout: no call fails, the gap is the outage.
        let stall = link.cycle_completed(at(10_000), true).expect("a stall");
        assert_eq!(stall, Outage { down: Duration::from_millis(3000), undetected: true });
        assert_eq!(link.cycle_completed(at(10_400), true), None, "shorter than the stall timeout");
        // Lockstep cycles take what the machine gives them: a slow one is no outage.
        assert_eq!(link.cycle_completed(at(20_000), false), None);
        // A failure before the episode's first cycle counts from the failure.
        link.restart();
        assert!(link.call_failed(at(30_000)));
        let first = link.cycle_completed(at(30_200), true).expect("an outage");
        assert_eq!(first.down, Duration::from_millis(200));
    }

    #[test]
    fn the_controllers_floor_goes_with_every_scenario_set_later() {
        let mut config = ControllerConfig::new("127.0.0.1:1", Scenario::paper_1(), ControllerMode::Nmpc);
        config.min_altitude_m = Some(0.5);
        let shared = Shared::new(&config);
        // Below the floor of the scenario flown: refused.
        assert_eq!(field(shared.request_goal([1.0, 8.0, 0.3])), "goal_m[2]");
        shared.request_scenario(Scenario::paper_2(), None);
        assert_eq!(field(shared.request_goal([3.0, 4.5, 0.3])), "goal_m[2]");
        let (scenario, _) = shared.take_requests().scenario.expect("the scenario request");
        assert_eq!((scenario.name.as_str(), scenario.min_altitude_m), ("paper-2", Some(0.5)));
        // Without a floor of its own the controller keeps each scenario's.
        let plain =
            Shared::new(&ControllerConfig::new("127.0.0.1:1", Scenario::paper_1(), ControllerMode::Nmpc));
        plain.request_scenario(Scenario::paper_2(), None);
        let (scenario, _) = plain.take_requests().scenario.expect("the scenario request");
        assert_eq!(scenario.min_altitude_m, None);
    }
}
