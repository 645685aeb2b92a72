//! The control loop: a Plant API client running `SPEC.md`'s cycle.
//!
//! Lockstep (the controller drives plant time): at `t_k` it solves from the sample, sends the
//! command, and asks for `Advance(min_cycle, wait_for_command_seq = k)`, so the next sample
//! comes at `t_k + max(min_cycle, d_k)` whatever sits between it and the plant. Real time:
//! one cycle every `min_cycle` of wall time, from the freshest sample, with a solve deadline.
//!
//! Delays are measured from plant stamps only: a sample's `last_command` says which command
//! was applied at which plant time and which sample it was computed from, so
//! `d = applied_time - based_on_sample_time` is the whole round trip.
//!
//! A broken link is retried with exponential backoff; the episode (solver warm start, delay
//! window, command numbering) survives, and the plant is not reset on reconnection.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use hilbench_proto::pb;
use hilbench_proto::pb::plant_client::PlantClient;
use mav::{InputBounds, Scenario, ScenarioError};
use mpc::{
    ControllerMode, CycleController, CycleOutcome, GammaParams, InFlight, OcpDefinition, ScenarioWeights,
    SolveBudget, SolveStatus, WeightSettings,
};
use tokio::sync::{Notify, broadcast, watch};
use tonic::transport::{Channel, Endpoint};

use crate::config::{ControllerConfig, TimeModeSetting};

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
    /// Why the last episode ended (`reached`, `time_limit`); empty while one runs.
    pub finish_reason: String,
    /// Working plant links lost during the current episode (one per outage).
    pub link_losses: u64,
    /// Wall time without a plant link during the current episode (ended outages), s.
    pub link_down_s: f64,
    /// The longest of those outages, s.
    pub longest_link_down_s: f64,
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
    telemetry: broadcast::Sender<pb::CycleTelemetry>,
    /// Since when the plant link is down (`None` while it works or before it first worked).
    link_down_since: Mutex<Option<Instant>>,
    /// The plant API has answered at least once since the last loss.
    link_up: AtomicBool,
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
            mode: config.mode.name().to_string(),
            plant_address: config.plant.clone(),
            goal_m: config.scenario.goal_m,
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
            telemetry,
            link_down_since: Mutex::new(None),
            link_up: AtomicBool::new(false),
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
        self.wake.notify_one();
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
    fn link_answered(&self) {
        self.link_up.store(true, Ordering::SeqCst);
        if let Some(since) = lock(&self.link_down_since).take() {
            let down_s = since.elapsed().as_secs_f64();
            self.update(|st| {
                st.link_down_s += down_s;
                st.longest_link_down_s = st.longest_link_down_s.max(down_s);
            });
        }
    }

    /// A working plant link failed: starts an outage (retries of the same outage count once).
    /// True when this starts a new outage (the link had answered since the last one).
    fn link_lost(&self) -> bool {
        let was_up = self.link_up.swap(false, Ordering::SeqCst);
        if was_up {
            *lock(&self.link_down_since) = Some(Instant::now());
            self.update(|st| st.link_losses += 1);
        }
        was_up
    }
}

/// A command that is safe to send: finite and inside the bounds. A non-finite component makes
/// the whole command hover (a solver fault must not tilt the vehicle).
pub fn sanitize_command(u: [f64; 3], bounds: &InputBounds, hover: [f64; 3]) -> [f64; 3] {
    let base = if u.iter().all(|v| v.is_finite()) { u } else { hover };
    let mut out = [0.0; 3];
    for c in 0..3 {
        out[c] = base[c].clamp(bounds.min[c], bounds.max[c]);
    }
    out
}

/// Everything an episode keeps across reconnections.
struct Episode {
    scenario: Scenario,
    mode: ControllerMode,
    controller: CycleController,
    weights: ScenarioWeights,
    command_seq: u64,
    measured_seq: u64,
    cycle: u64,
    /// Lockstep: the sample the last `Advance` returned.
    pending_sample: Option<pb::StateSample>,
    last_delay_s: f64,
    /// Number of this episode (1 for the first).
    number: u64,
    /// Real time: commands sent and not yet seen applied, oldest first, as
    /// `(command_seq, time of the sample they came from, ns, command)`.
    sent: VecDeque<(u64, u64, [f64; 3])>,
    in_flight: Vec<InFlight>,
}

/// Commands remembered as in flight at most (older ones were lost on the link).
const MAX_IN_FLIGHT: usize = 64;

/// The controller of `scenario` in `mode`: its optimal control problem and the configured
/// safety layer. Errors are the solver's, as text.
fn build_controller(
    config: &ControllerConfig,
    scenario: &Scenario,
    mode: ControllerMode,
) -> Result<CycleController, String> {
    let def =
        OcpDefinition::from_scenario(scenario, mode, config.mpc.obstacle_margin_m, config.mpc.formulation);
    let safety = config.safety_for(scenario);
    CycleController::new(def, config.mpc, safety).map_err(|e| e.to_string())
}

impl Episode {
    fn new(
        config: &ControllerConfig,
        scenario: Scenario,
        mode: ControllerMode,
        number: u64,
    ) -> Result<Self, String> {
        let controller = build_controller(config, &scenario, mode)?;
        let weights = weight_estimator(&scenario, mode, &controller.definition().sampling_times_s);
        Ok(Self {
            scenario,
            mode,
            controller,
            weights,
            command_seq: 0,
            measured_seq: 0,
            cycle: 0,
            pending_sample: None,
            sent: VecDeque::with_capacity(MAX_IN_FLIGHT),
            in_flight: Vec::with_capacity(MAX_IN_FLIGHT),
            last_delay_s: f64::NAN,
            number,
        })
    }
}

/// The weights of `mode`: fixed 1 for the standard NMPC; for the multi-stage controller the
/// nominal weights when the scenario has no delays, otherwise the Gamma fit of measured delays.
pub fn weight_estimator(
    scenario: &Scenario,
    mode: ControllerMode,
    sampling_times_s: &[f64],
) -> ScenarioWeights {
    let settings = WeightSettings {
        window: scenario.delay_window,
        prior: GammaParams { shape: scenario.prior_gamma.0, scale_s: scenario.prior_gamma.1 },
        ..WeightSettings::default()
    };
    match mode {
        ControllerMode::Nmpc => ScenarioWeights::new(settings, sampling_times_s, Some(&[1.0])),
        ControllerMode::Multistage if scenario.delays == mav::DelayModel::None => {
            ScenarioWeights::new(settings, sampling_times_s, Some(&scenario.nominal_weights))
        }
        ControllerMode::Multistage => ScenarioWeights::new(settings, sampling_times_s, None),
    }
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
    #[error("connect: {0}")]
    Connect(#[from] tonic::transport::Error),
    #[error("{0}")]
    Bad(String),
}

/// Runs until `stop` turns true.
pub async fn run(config: ControllerConfig, shared: Arc<Shared>, mut stop: watch::Receiver<bool>) {
    let mut scenario = config.adapt(config.scenario.clone());
    let mut mode = config.mode;
    let mut active = config.autostart;
    let mut episode: Option<Episode> = None;
    let mut backoff = config.backoff_min;
    loop {
        if *stop.borrow() || shared.closed.load(Ordering::SeqCst) {
            return;
        }
        if !active {
            let requests = shared.take_requests();
            if let Some((s, m)) = requests.scenario {
                scenario = s;
                mode = m.unwrap_or(mode);
                episode = None;
                active = true;
                continue;
            }
            if let Some(goal) = requests.goal {
                scenario.goal_m = goal;
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
                let channel = Endpoint::from_shared(config.plant_uri())
                    .map_err(LoopError::Connect)?
                    .connect_timeout(Duration::from_secs(2))
                    .tcp_nodelay(true)
                    .connect()
                    .await?;
                let mut client = PlantClient::new(channel);
                fly(&config, &shared, &mut client, &mut scenario, &mut mode, &mut episode, &mut stop).await
            } => outcome,
            _ = stop_during_call.wait_for(|stop| *stop) => return,
        };
        match outcome {
            Ok(Outcome::Stopped) => return,
            Ok(Outcome::Finished) => {
                active = false;
                episode = None;
                backoff = config.backoff_min;
            }
            Ok(Outcome::Restart) => {
                episode = None;
                backoff = config.backoff_min;
            }
            Err(e) => {
                if !matches!(e, LoopError::Bad(_)) && shared.link_lost() {
                    // A new outage: retry soon, whatever the last one's backoff had grown to.
                    backoff = config.backoff_min;
                }
                // What was sent over the lost link has landed or is lost with it; after the
                // reconnection the plant's stamps say what is applied (a restarted plant's
                // clock starts again at 0, which would make the old commands look just sent).
                if let Some(ep) = episode.as_mut() {
                    ep.sent.clear();
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

fn state_of(sample: &pb::StateSample) -> Result<[f64; 8], LoopError> {
    let x =
        sample.state.as_ref().ok_or_else(|| LoopError::Bad("plant sent a sample without a state".into()))?;
    hilbench_proto::convert::finite_array::<8>("state.x", &x.x)
        .map_err(|e| LoopError::Bad(format!("plant sent {e}")))
}

fn applied_input(sample: &pb::StateSample, fallback: [f64; 3]) -> [f64; 3] {
    sample
        .last_command
        .as_ref()
        .and_then(|c| c.input.as_ref())
        .map(|u| [u.thrust_mps2, u.roll_rad, u.pitch_rad])
        .filter(|u| u.iter().all(|v| v.is_finite()))
        .unwrap_or(fallback)
}

#[allow(clippy::too_many_arguments)]
async fn fly(
    config: &ControllerConfig,
    shared: &Shared,
    client: &mut PlantClient<Channel>,
    scenario: &mut Scenario,
    mode: &mut ControllerMode,
    episode: &mut Option<Episode>,
    stop: &mut watch::Receiver<bool>,
) -> Result<Outcome, LoopError> {
    let description = within(config.rpc_timeout, "Describe", client.describe(pb::DescribeRequest {})).await?;
    shared.update(|st| st.plant_connected = true);
    let lockstep = match config.time_mode {
        TimeModeSetting::Lockstep => true,
        TimeModeSetting::RealTime => false,
        TimeModeSetting::Auto => description.time_mode == pb::TimeMode::Lockstep as i32,
    };
    // A lockstep call does a whole cycle's integration before it answers, and a stall of the
    // machine must not turn into a link loss (the run would then depend on wall-clock time).
    let call_timeout =
        if lockstep { config.rpc_timeout.max(LOCKSTEP_MIN_RPC_TIMEOUT) } else { config.rpc_timeout };
    if episode.is_none() {
        let number = shared.status().episode + 1;
        let mut ep = Episode::new(config, scenario.clone(), *mode, number).map_err(LoopError::Bad)?;
        let sample = if config.reset_plant {
            let reset = pb::ResetRequest { scenario: scenario.name.clone(), initial_state: None };
            within(call_timeout, "Reset", client.reset(reset)).await?.sample
        } else {
            Some(within(call_timeout, "GetState", client.get_state(pb::GetStateRequest {})).await?)
        };
        ep.pending_sample = sample;
        shared.update(|st| {
            st.scenario = scenario.name.clone();
            st.mode = mode.name().to_string();
            st.goal_m = scenario.goal_m;
            st.cycles = 0;
            st.reached = false;
            st.episode = number;
            st.episode_finished = false;
            st.finish_reason.clear();
            (st.link_losses, st.link_down_s, st.longest_link_down_s) = (0, 0.0, 0.0);
            st.sampling_times_s = ep.controller.definition().sampling_times_s.clone();
        });
        tracing::info!(scenario = %scenario.name, mode = mode.name(), lockstep, "episode started");
        *episode = Some(ep);
    }
    let Some(ep) = episode.as_mut() else {
        return Err(LoopError::Bad("no episode".into()));
    };
    let hover = ep.scenario.model.hover_input();
    let hover = [hover[0], hover[1], hover[2]];
    let min_cycle = Duration::from_secs_f64(ep.scenario.min_cycle_s);
    let min_cycle_ns = mav::s_to_ns(ep.scenario.min_cycle_s).unwrap_or(50_000_000);
    let max_ns = mav::s_to_ns(ep.scenario.max_duration_s).unwrap_or(u64::MAX);
    loop {
        if *stop.borrow() || shared.closed.load(Ordering::SeqCst) {
            return Ok(Outcome::Stopped);
        }
        let requests = shared.take_requests();
        if let Some((s, m)) = requests.scenario {
            *scenario = s;
            *mode = m.unwrap_or(*mode);
            return Ok(Outcome::Restart);
        }
        if let Some(goal) = requests.goal {
            scenario.goal_m = goal;
            ep.scenario.goal_m = goal;
            ep.controller = build_controller(config, &ep.scenario, ep.mode).map_err(LoopError::Bad)?;
            shared.update(|st| {
                st.goal_m = goal;
                st.reached = false;
            });
        }
        let cycle_start = Instant::now();
        let sample = match (lockstep, ep.pending_sample.take()) {
            (true, Some(s)) => s,
            _ => within(call_timeout, "GetState", client.get_state(pb::GetStateRequest {})).await?,
        };
        let x = state_of(&sample)?;
        if let Some(last) = &sample.last_command
            && last.command_seq > ep.measured_seq
            && last.command_seq <= ep.command_seq
            && !last.initial
        {
            let d_ns = last.applied_time_ns.saturating_sub(last.based_on_sample_time_ns);
            ep.last_delay_s = mav::ns_to_s(d_ns);
            ep.weights.observe(ep.last_delay_s);
            ep.measured_seq = last.command_seq;
        }
        let state = mav::State::from(x);
        if ep.scenario.goal_reached(&state) {
            shared.update(|st| st.reached = true);
            if lockstep {
                tracing::info!(t_s = mav::ns_to_s(sample.time_ns), cycles = ep.cycle, "goal reached");
                finish(shared, "reached");
                return Ok(Outcome::Finished);
            }
        }
        if lockstep && sample.time_ns >= max_ns {
            tracing::info!(cycles = ep.cycle, "time limit reached");
            finish(shared, "time_limit");
            return Ok(Outcome::Finished);
        }
        let u_prev = applied_input(&sample, hover);
        if !lockstep {
            // What was sent and not seen applied is still on its way (the fail-safe check
            // flies it; lockstep waits for each command to land, so nothing is in flight).
            let applied_seq =
                sample.last_command.as_ref().filter(|l| !l.initial).map_or(0, |l| l.command_seq);
            ep.sent.retain(|(seq, _, _)| *seq > applied_seq);
            ep.in_flight.clear();
            ep.in_flight.extend(ep.sent.iter().map(|(_, sent_ns, command)| InFlight {
                sent_ago_s: mav::ns_to_s(sample.time_ns.saturating_sub(*sent_ns)),
                command: *command,
            }));
            ep.controller.set_in_flight(Some(&ep.in_flight));
        }
        let budget = if lockstep {
            SolveBudget::default()
        } else {
            SolveBudget {
                deadline: Some(min_cycle.mul_f64(config.deadline_fraction)),
                ..SolveBudget::default()
            }
        };
        let weights = ep.weights.weights().to_vec();
        let outcome = ep
            .controller
            .step(ep.cycle, sample.time_ns, &x, &u_prev, &weights, &budget)
            .map_err(|e| LoopError::Bad(e.to_string()))?;
        // Finite and inside the bounds by construction; checked again at the edge.
        let command = sanitize_command(outcome.command, &ep.scenario.bounds, hover);
        ep.command_seq += 1;
        let pb_command = pb::Command {
            input: Some(pb::ControlInput {
                thrust_mps2: command[0],
                roll_rad: command[1],
                pitch_rad: command[2],
            }),
            command_seq: ep.command_seq,
            based_on_sample_seq: sample.seq,
            based_on_sample_time_ns: sample.time_ns,
        };
        within(call_timeout, "ApplyCommand", client.apply_command(pb_command)).await?;
        shared.link_answered();
        if !lockstep {
            if ep.sent.len() == MAX_IN_FLIGHT {
                ep.sent.pop_front();
            }
            ep.sent.push_back((ep.command_seq, sample.time_ns, command));
        }
        publish(shared, ep, &sample, command, &weights, &outcome);
        if lockstep {
            let advance =
                pb::AdvanceRequest { duration_ns: min_cycle_ns, wait_for_command_seq: ep.command_seq };
            ep.pending_sample = within(call_timeout, "Advance", client.advance(advance)).await?.sample;
        } else {
            let next = cycle_start + min_cycle;
            tokio::select! {
                _ = tokio::time::sleep_until(next.into()) => {}
                _ = stop.changed() => return Ok(Outcome::Stopped),
            }
        }
        ep.cycle += 1;
    }
}

/// Marks the current episode as ended (the loop idles until the next request).
fn finish(shared: &Shared, reason: &str) {
    shared.update(|st| {
        st.episode_finished = true;
        st.episodes_finished += 1;
        st.finish_reason = reason.to_string();
    });
}

/// What the cycle sent, as the wire names it: the safety layer's decision, or without the
/// layer PANOC (the previous plan shifted when it failed numerically).
fn solver_kind(outcome: &CycleOutcome) -> pb::SolverKind {
    match &outcome.selection {
        Some(s) => s.decision.into(),
        None if outcome.report.status == SolveStatus::NumericalFailure => pb::SolverKind::ShiftedPlan,
        None => pb::SolverKind::Panoc,
    }
}

fn publish(
    shared: &Shared,
    ep: &Episode,
    sample: &pb::StateSample,
    command: [f64; 3],
    weights: &[f64],
    outcome: &CycleOutcome,
) {
    let stats = pb::SolveStats::from(&outcome.report);
    shared.update(|st| {
        st.cycles = ep.cycle + 1;
        st.weights = weights.to_vec();
        st.last_solve = Some(stats);
    });
    if shared.telemetry.receiver_count() == 0 {
        return;
    }
    let ts = &ep.controller.definition().sampling_times_s;
    let predictions = ep
        .controller
        .predictions()
        .iter()
        .zip(ts)
        .zip(weights)
        .map(|((traj, &dt), &w)| pb::PredictedTrajectory {
            sampling_time_s: dt,
            weight: w,
            positions_m: traj.iter().flat_map(|s| [s[0], s[1], s[2]]).collect(),
        })
        .collect();
    let item = pb::CycleTelemetry {
        cycle: ep.cycle,
        sample: Some(sample.clone()),
        command: Some(pb::ControlInput {
            thrust_mps2: command[0],
            roll_rad: command[1],
            pitch_rad: command[2],
        }),
        command_seq: ep.command_seq,
        scenario_weights: weights.to_vec(),
        solve: Some(stats),
        solver: solver_kind(outcome) as i32,
        decision_reason: outcome.selection.as_ref().map(|s| s.reason()).unwrap_or_default(),
        cost_gap: outcome.selection.as_ref().and_then(|s| s.cost_gap),
        qp: outcome.selection.as_ref().and_then(|s| s.qp_report.as_ref()).map(pb::QpStats::from),
        predictions,
        measured_delay_s: if ep.last_delay_s.is_finite() { ep.last_delay_s } else { 0.0 },
        episode: ep.number,
    };
    // No subscriber left is not an error.
    let _ = shared.telemetry.send(item);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_are_clipped_and_non_finite_ones_become_hover() {
        let b = InputBounds::paper(9.81);
        let hover = [9.81, 0.0, 0.0];
        assert_eq!(
            sanitize_command([30.0, -1.0, 0.05], &b, hover),
            [19.62, -std::f64::consts::PI / 18.0, 0.05]
        );
        assert_eq!(sanitize_command([f64::NAN, 0.1, 0.1], &b, hover), hover);
        assert_eq!(sanitize_command([f64::INFINITY, 0.1, 0.1], &b, hover), hover);
    }

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
