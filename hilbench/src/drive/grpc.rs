//! Runs over real gRPC: a plant, netem and the controller, each served in this process on its
//! own loopback port (one fresh set of services per run) or running elsewhere ([`Endpoints`]).
//! Paper mode is lockstep; [`TimeMode::RealTime`] runs the same protocol on the wall clock.
//!
//! The controller is started idle (`autostart = false`) so that the telemetry subscription
//! exists before its first cycle; `SetScenario` with the whole scenario then starts the episode
//! (a built-in one or a file's, to a controller started here or elsewhere alike), and the run
//! ends when `ControllerStatus.episode_finished` says so. Everything in the [`RunSummary`]
//! comes from the wire, decoded by `proto`'s convert module: the per-cycle telemetry into
//! `mpc::CycleRecord`s, the plant's last state sample into a `mav::PlantSample`; then
//! `mpc::summarize` (the one summary, the in-process loop's too) makes the numbers.
//!
//! The delays: the scenario's network (`mav::Scenario::network`, seeded with the scenario's
//! seed) becomes netem's two profiles; a netem given by address keeps its own when asked or
//! when the scenario describes none ([`DelayProfileInForce`] says which). `mpc::run_closed_loop`
//! draws its `d_k` from the same `delay::DelayLine` as netem's command direction, so both runs
//! are bit-identical.
//!
//! Real time: the plant integrates on its clock (with its command watchdog), netem releases
//! commands on its own thread, and the controller cycles every `min_cycle_s` of wall time and
//! keeps flying after the goal (it is a service, and a vehicle must not be left uncontrolled),
//! so the run ends here, by the rule every driver uses (`mpc::end::finish_at`): at the
//! first telemetry cycle whose sample has collided (unless the scenario goes on after a
//! collision), is at the goal (its plant time is the time to the goal), or is past the
//! scenario's `max_duration_s` of plant time. The final state is read from the plant just
//! after, so in real time path length and clearance include the few milliseconds between the
//! two. A lost plant link is reported in the controller's status (`RunFaults`); the episode
//! goes on when the link comes back.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use anyhow::{Context, anyhow, bail};
use hilbench_proto::convert::controller::finish_reason_from_pb;
use hilbench_proto::pb;
use hilbench_proto::pb::controller_client::ControllerClient;
use hilbench_proto::pb::netem_control_client::NetemControlClient;
use hilbench_proto::pb::plant_client::PlantClient;
use hilbench_proto::pb::vehicle_control_client::VehicleControlClient;
use hilbench_svc::tls::Tls;
use mav::{PlantSample, Scenario, TimeMode};
use mpc::{ControllerMode, CycleRecord, RunEnd, RunSummary};

use super::services::{Endpoints, Services, connect_with, netem_config};
use crate::run::CycleSink;
use crate::run::{
    ControllerStopped, DelayProfileInForce, DelaySource, FinishedRun, Job, RunFailure, RunFaults, RunTiming,
};

/// How often the driver polls `GetStatus` while telemetry streams in.
const STATUS_POLL: Duration = Duration::from_millis(10);
/// How long one call of the run's loop may take: a controller that does not answer a
/// `GetStatus` within this is frozen (a stopped process, a paused VM, a deadlock), and the run
/// ends naming it rather than waiting on it for good.
const CALL_DEADLINE: Duration = Duration::from_secs(5);
/// How often the stall and the services are checked, on a timer of its own (not behind a
/// call that may hang).
const HEALTH_CHECK: Duration = Duration::from_secs(1);
/// How long a probe of the plant or netem (`Describe`) may take.
const PROBE_DEADLINE: Duration = Duration::from_secs(2);

/// One run over gRPC.
#[derive(Debug, Clone)]
pub struct GrpcRun {
    pub summary: RunSummary,
    /// Every cycle's record, decoded from its telemetry, in order (cycle 0 first).
    pub records: Vec<CycleRecord>,
    /// The plant's state sample when the episode ended.
    pub final_sample: PlantSample,
    pub timing: RunTiming,
    pub faults: RunFaults,
    /// The delay process netem had in force for the run.
    pub delay_profile: DelayProfileInForce,
    /// The plant's `Describe`: `PlantDescription.implementation`.
    pub plant: String,
}

impl GrpcRun {
    /// The run of `job` for the outputs (`error`: it failed part-way and this is what flew).
    pub fn finished(self, job: Job, error: Option<String>) -> FinishedRun {
        FinishedRun {
            job,
            rows: crate::run::rows_of(&self.records),
            records: self.records,
            summary: self.summary,
            timing: Some(self.timing),
            faults: self.faults,
            delay_profile: self.delay_profile,
            plant: self.plant,
            external: None,
            error,
        }
    }
}

/// Settings of a gRPC run.
#[derive(Debug, Clone)]
pub struct GrpcSettings {
    /// Bound on the whole episode (wall time); a run that takes longer is an error.
    pub timeout: Duration,
    /// No control cycle for this long (wall time) fails the run, with what the controller says
    /// of its plant link: a plant or netem that died does not leave the run waiting for
    /// `timeout`. Outages shorter than this are survived and counted.
    pub stall_timeout: Duration,
    /// A plant or netem that this driver cannot reach either (its `Describe` unanswered) for
    /// this long while no cycle comes ends the run, naming the service: a killed or stopped
    /// service ends a run within seconds, a short outage (a restart) is survived.
    pub service_timeout: Duration,
    /// Set to `true` by Ctrl-C: the run ends as interrupted with what it flew so far.
    pub cancel: Option<tokio::sync::watch::Receiver<bool>>,
}

impl Default for GrpcSettings {
    fn default() -> Self {
        Self {
            timeout: Duration::from_secs(600),
            stall_timeout: Duration::from_secs(30),
            service_timeout: Duration::from_secs(10),
            cancel: None,
        }
    }
}

/// The message of a run ended by Ctrl-C (`crate::fly` keeps what it flew, as interrupted).
pub const INTERRUPTED: &str = "interrupted (Ctrl-C)";

/// Resolves when `cancel` turns `true`; never without one.
async fn cancelled(cancel: &mut Option<tokio::sync::watch::Receiver<bool>>) {
    match cancel {
        Some(rx) => {
            if rx.wait_for(|stop| *stop).await.is_err() {
                std::future::pending::<()>().await;
            }
        }
        None => std::future::pending::<()>().await,
    }
}

/// `call` of the service at `addr`, given up after `deadline` with an error naming both.
async fn within<T>(
    deadline: Duration,
    service: &str,
    addr: &str,
    call: &str,
    fut: impl std::future::Future<Output = Result<tonic::Response<T>, tonic::Status>>,
) -> anyhow::Result<Result<T, tonic::Status>> {
    match tokio::time::timeout(deadline, fut).await {
        Ok(answer) => Ok(answer.map(tonic::Response::into_inner)),
        Err(_) => bail!(
            "the {service} at {addr} did not answer {call} within {:.0} s: it is frozen (a stopped \
             process, a paused VM, a deadlock) or the link to it drops everything",
            deadline.as_secs_f64()
        ),
    }
}

/// Runs `scenario` with `mode` over gRPC on a fresh set of services.
pub async fn run_over_grpc(
    scenario: &Scenario,
    mode: ControllerMode,
    settings: &GrpcSettings,
) -> Result<GrpcRun, RunFailure<GrpcRun>> {
    run_against(scenario, mode, settings, &Endpoints::default()).await
}

/// Runs `scenario` with `mode` over gRPC against `endpoints`, starting what they do not name.
/// A run that fails part-way returns what it flew with the error ([`RunFailure`]).
pub async fn run_against(
    scenario: &Scenario,
    mode: ControllerMode,
    settings: &GrpcSettings,
    endpoints: &Endpoints,
) -> Result<GrpcRun, RunFailure<GrpcRun>> {
    let started = Instant::now();
    let services = Services::start_missing(scenario, mode, endpoints).await?;
    let mut progress = Progress::default();
    let live = endpoints.live.as_deref();
    let result = drive(&services, scenario, mode, settings, started, &mut progress, live).await;
    let result = match result {
        Ok(run) => Ok(run),
        Err(error) => {
            let partial = partial_run(&services, scenario, mode, progress).await.map(Box::new);
            Err(RunFailure { error, partial })
        }
    };
    let stopping = Instant::now();
    let stopped = services.stop().await;
    let mut run = result?;
    stopped?;
    run.timing.teardown_s = stopping.elapsed().as_secs_f64();
    Ok(run)
}

/// What a run has seen so far, kept outside [`drive`] so that a run that fails part-way can
/// still be summarised.
#[derive(Debug, Default)]
struct Progress {
    /// Telemetry records per episode started after the request.
    episodes: BTreeMap<u64, Vec<CycleRecord>>,
    /// The plant's sample of the newest telemetry record, as it came (already validated with
    /// its record; decoded only if the run fails).
    last_sample: Option<pb::StateSample>,
    /// The controller's status at the last poll.
    status: Option<pb::ControllerStatus>,
    delay_profile: Option<DelayProfileInForce>,
    /// The plant's `Describe` (`implementation`), once asked.
    plant: Option<String>,
    setup_s: f64,
    episode_started: Option<Instant>,
}

/// The run so far, from `progress` (the controller's status asked once more, briefly: it
/// knows the link faults and a plant reset): `None` before the first cycle.
async fn partial_run(
    services: &Services,
    scenario: &Scenario,
    mode: ControllerMode,
    mut progress: Progress,
) -> Option<GrpcRun> {
    let (episode, records) = progress.episodes.pop_last()?;
    let last = PlantSample::try_from(&progress.last_sample.take()?).ok()?;
    let ask = async {
        let channel =
            connect_with(services.controller_addr(), &services.client_tls, Instant::now()).await.ok()?;
        let status = ControllerClient::new(channel).get_status(pb::GetStatusRequest {}).await.ok()?;
        Some(status.into_inner())
    };
    let status = match tokio::time::timeout(Duration::from_secs(2), ask).await {
        Ok(Some(s)) if s.episode == episode => Some(s),
        _ => progress.status.filter(|s| s.episode == episode),
    }
    .unwrap_or_default();
    let summary = mpc::summarize(&scenario.name, mode.name(), &records, &last, RunEnd::Error);
    let faults = faults_of(&status, &records, &last);
    let solver_s = summary.solver_s;
    let episode_s = progress.episode_started.map_or(0.0, |t| t.elapsed().as_secs_f64());
    Some(GrpcRun {
        summary,
        records,
        final_sample: last,
        timing: RunTiming { setup_s: progress.setup_s, episode_s, solver_s, teardown_s: 0.0 },
        faults,
        delay_profile: progress.delay_profile.unwrap_or_else(DelayProfileInForce::none),
        plant: progress.plant.unwrap_or_default(),
    })
}

/// How long a vehicle that does not fly setpoints yet is waited for: its heartbeat (1 Hz) may
/// not show an arm and mode switch made just before the run.
const VEHICLE_READY_WAIT: Duration = Duration::from_secs(3);

/// `scenario` starting where the vehicle (or plant) at `addr` is now (`--start-from-vehicle`):
/// its `GetState` as the start, so that the reset that begins the run is one a gateway accepts
/// (a gateway never moves its vehicle to a start: mavbridge's start check). The goal, the
/// obstacles and everything else stay the scenario's; a state the scenario refuses (below its
/// ground, inside a cylinder) is an error naming it.
pub(crate) async fn with_vehicle_start(
    addr: &str,
    tls: &Tls,
    scenario: &Scenario,
    deadline: Instant,
) -> anyhow::Result<Scenario> {
    let mut plant = PlantClient::new(connect_with(addr, tls, deadline).await?);
    // A vehicle just armed may not have reported its first state yet (UNAVAILABLE): waited
    // for, as long as for its readiness.
    let waited_until = Instant::now() + VEHICLE_READY_WAIT;
    let sample = loop {
        let asked =
            within(CALL_DEADLINE, "plant", addr, "GetState", plant.get_state(pb::GetStateRequest {})).await?;
        match asked {
            Err(e) if e.code() == tonic::Code::Unavailable && Instant::now() < waited_until => {
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
            asked => break asked.with_context(|| format!("--start-from-vehicle: GetState at {addr}"))?,
        }
    };
    let sample = PlantSample::try_from(&sample)
        .map_err(|e| anyhow!("--start-from-vehicle: the state at {addr}: {e}"))?;
    let mut moved = scenario.clone();
    moved.start = sample.state.into();
    moved.validate().map_err(|e| {
        anyhow!("--start-from-vehicle: the vehicle's state at {addr} cannot start {}: {e}", scenario.name)
    })?;
    Ok(moved)
}

/// The plant at `addr`'s description, refused unless it runs in `time_mode` (a real-time
/// plant never advances on Step; a lockstep one never moves without it).
pub(crate) async fn described_in(
    plant: &mut PlantClient<tonic::transport::Channel>,
    addr: &str,
    time_mode: TimeMode,
) -> anyhow::Result<pb::PlantDescription> {
    let described = within(CALL_DEADLINE, "plant", addr, "Describe", plant.describe(pb::DescribeRequest {}))
        .await?
        .context("plant Describe")?;
    let wanted = pb::TimeMode::from(time_mode);
    if described.time_mode != wanted as i32 {
        bail!(
            "the plant at {addr} runs in {:?}, this run needs {:?}",
            pb::TimeMode::try_from(described.time_mode).unwrap_or(pb::TimeMode::Unspecified),
            wanted
        );
    }
    Ok(described)
}

/// A plant that is a vehicle behind a gateway (it serves `VehicleControl`) must have its link
/// up and fly setpoints (armed, in its external mode) before a run starts: otherwise the run
/// would fly for its whole time limit with a vehicle that ignores it. A simulated plant (no
/// such service), or a gateway that does not let this client read the status, is not checked.
pub(crate) async fn vehicle_ready(addr: &str, tls: &Tls, deadline: Instant) -> anyhow::Result<()> {
    let mut control = VehicleControlClient::new(connect_with(addr, tls, deadline).await?);
    let waited_until = Instant::now() + VEHICLE_READY_WAIT;
    loop {
        let s = match control.get_status(pb::GetVehicleStatusRequest {}).await {
            Ok(s) => s.into_inner(),
            Err(e) if matches!(e.code(), tonic::Code::Unimplemented | tonic::Code::PermissionDenied) => {
                return Ok(());
            }
            Err(e) => bail!("the vehicle's status at {addr}: {}", e.message()),
        };
        if s.link_alive && s.flies_setpoints {
            return Ok(());
        }
        if Instant::now() >= waited_until {
            if !s.link_alive {
                // Frames that came but were refused for their signature are not a lost link:
                // the keys differ (or one side signs and the other does not).
                let signing = if s.dropped_unsigned > 0 || s.dropped_bad_signature > 0 {
                    format!(
                        "; the gateway refused {} unsigned and {} badly signed frames: the vehicle's \
                         MAVLink signing does not match the gateway's --mavlink-signing-key (the same \
                         key on both sides, or none)",
                        s.dropped_unsigned, s.dropped_bad_signature
                    )
                } else {
                    String::new()
                };
                bail!(
                    "the vehicle behind the gateway at {addr} is not talking: {}{signing} (check the \
                     autopilot's link, `vehiclectl --gateway {addr} status`)",
                    if s.heartbeat_seen {
                        format!("no heartbeat for {:.1} s", s.heartbeat_age_ns as f64 * 1e-9)
                    } else {
                        "no heartbeat yet".to_string()
                    }
                );
            }
            bail!(
                "the vehicle behind the gateway at {addr} would not fly the run: it is {}, in {}; arm \
                 it and set OFFBOARD (PX4) or GUIDED_NOGPS (ArduCopter), e.g. `vehiclectl --gateway \
                 {addr} arm-offboard`",
                if s.armed { "armed" } else { "disarmed" },
                s.mode
            );
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

/// Gives a netem running elsewhere the scenario's profiles.
async fn configure_netem(
    addr: &str,
    tls: &Tls,
    scenario: &Scenario,
    time_mode: TimeMode,
    deadline: Instant,
) -> anyhow::Result<()> {
    let config = netem_config(addr, scenario, time_mode)?;
    let mut control = NetemControlClient::new(connect_with(addr, tls, deadline).await?);
    for (direction, profile) in [
        (pb::Direction::PlantToController, &config.plant_to_controller),
        (pb::Direction::ControllerToPlant, &config.controller_to_plant),
    ] {
        control
            .set_profile(pb::SetProfileRequest {
                direction: direction as i32,
                profile: Some(pb::DirectionProfile::from(profile)),
                preset: String::new(),
            })
            .await
            .with_context(|| format!("netem SetProfile at {addr}"))?;
    }
    Ok(())
}

/// The profile netem has in force, both directions.
async fn netem_profile(addr: &str, tls: &Tls, deadline: Instant) -> anyhow::Result<delay::NetworkProfile> {
    let mut control = NetemControlClient::new(connect_with(addr, tls, deadline).await?);
    let mut get = async |direction: pb::Direction| -> anyhow::Result<delay::DirectionProfile> {
        let p = control
            .get_profile(pb::GetProfileRequest { direction: direction as i32 })
            .await
            .with_context(|| format!("netem GetProfile at {addr}"))?
            .into_inner();
        hilbench_proto::convert::netem::profile_from_pb(&p).map_err(|e| anyhow!("netem's profile: {e}"))
    };
    let to_plant = get(pb::Direction::ControllerToPlant).await?;
    let to_controller = get(pb::Direction::PlantToController).await?;
    Ok(delay::NetworkProfile { to_plant, to_controller })
}

async fn drive(
    services: &Services,
    scenario: &Scenario,
    mode: ControllerMode,
    settings: &GrpcSettings,
    started: Instant,
    progress: &mut Progress,
    live: Option<&dyn CycleSink>,
) -> anyhow::Result<GrpcRun> {
    let deadline = Instant::now() + settings.timeout;
    // A panic in a task of this run (an in-process service's, or this driver's own) ends it.
    let mut panicked = crate::panics::watch();
    // A netem running elsewhere gets the scenario's network, unless told to keep its own or
    // the scenario describes none; one started here was started with the scenario's.
    let keep = services.keep_netem_profile || scenario.delays.is_none();
    if services.configure_netem
        && !keep
        && let Some(addr) = services.netem_addr()
    {
        configure_netem(addr, &services.client_tls, scenario, services.time_mode, deadline).await?;
    }
    let delay_profile = match services.netem_addr() {
        Some(addr) => {
            let network = netem_profile(addr, &services.client_tls, deadline).await?;
            DelayProfileInForce::of(
                if services.configure_netem && keep { DelaySource::Netem } else { DelaySource::Scenario },
                &network,
            )
        }
        None => DelayProfileInForce::none(),
    };
    progress.delay_profile = Some(delay_profile.clone());
    let tls = &services.client_tls;
    let mut controller =
        ControllerClient::new(connect_with(services.controller_addr(), tls, deadline).await?);
    // The final state: from the plant, else through netem (an undelayed read).
    let state_addr = services
        .plant_addr()
        .or(services.netem_addr())
        .ok_or_else(|| anyhow!("no plant or netem address to read the final state from"))?;
    let mut plant = PlantClient::new(connect_with(state_addr, tls, deadline).await?);
    let real_time = services.time_mode == TimeMode::RealTime;
    let described = described_in(&mut plant, state_addr, services.time_mode).await?;
    progress.plant = Some(described.implementation.clone());
    vehicle_ready(state_addr, tls, deadline).await?;
    let moved;
    let scenario = if services.start_from_vehicle {
        moved = with_vehicle_start(state_addr, tls, scenario, deadline).await?;
        &moved
    } else {
        scenario
    };
    // Subscribe before the episode starts: the response headers mean the server subscribed.
    let controller_addr = services.controller_addr();
    let mut stream = within(
        CALL_DEADLINE,
        "controller",
        controller_addr,
        "StreamTelemetry",
        controller.stream_telemetry(pb::StreamTelemetryRequest {}),
    )
    .await?
    .context("controller StreamTelemetry")?;
    let before = within(
        CALL_DEADLINE,
        "controller",
        controller_addr,
        "GetStatus",
        controller.get_status(pb::GetStatusRequest {}),
    )
    .await?
    .context("controller GetStatus")?;
    let setup_s = started.elapsed().as_secs_f64();
    progress.setup_s = setup_s;

    let episode_started = Instant::now();
    progress.episode_started = Some(episode_started);
    // The whole scenario travels with the request, so a controller started elsewhere flies a
    // scenario file exactly as a built-in one (and resets the plant with it).
    let request = pb::SetScenarioRequest {
        scenario: String::new(),
        mode: mode.name().into(),
        definition: Some(scenario.into()),
    };
    within(CALL_DEADLINE, "controller", controller_addr, "SetScenario", controller.set_scenario(request))
        .await?
        .context("controller SetScenario")?;
    // The episode that runs this request is the last one started after `before`: one that was
    // running (or about to start at autostart) is restarted by the request, and a pending
    // request is taken before an episode can finish.
    let mut last_cycle_at = Instant::now();
    let mut poll = tokio::time::interval(STATUS_POLL);
    poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    // Real time: the episode whose telemetry ended the run, and how it ended (the controller
    // keeps its vehicle under control past the end; the run is over here).
    let mut real_time_end: Option<(u64, RunEnd)> = None;
    // The services the controller flies against, probed by this driver when no cycle comes.
    let mut probes = Probes::new(services, tls, deadline).await?;
    let mut health = tokio::time::interval(HEALTH_CHECK);
    health.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut cancel = settings.cancel.clone();
    let (status, telemetry) = loop {
        if Instant::now() >= deadline {
            bail!(
                "{} with {}: the episode did not finish within {:?} ({} cycles seen)",
                scenario.name,
                mode.name(),
                settings.timeout,
                progress.episodes.values().last().map_or(0, Vec::len)
            );
        }
        tokio::select! {
            panic = panicked.changed() => {
                let what = panic.ok().and_then(|()| panicked.borrow().clone());
                bail!("a task of the run panicked: {}", what.unwrap_or_default());
            }
            () = cancelled(&mut cancel) => bail!(INTERRUPTED),
            _ = health.tick() => {
                // On its own timer, so that no hung call can keep it from running.
                let idle = last_cycle_at.elapsed();
                if idle > settings.stall_timeout {
                    let s = progress.status.clone().unwrap_or_default();
                    let message = format!(
                        "{} with {}: no control cycle for {:.0} s (the controller's plant link is {}; its last error: {})",
                        scenario.name,
                        mode.name(),
                        settings.stall_timeout.as_secs_f64(),
                        if s.plant_connected { "up" } else { "down" },
                        if s.last_error.is_empty() { "none" } else { &s.last_error }
                    );
                    // With its plant link up, the controller is the one that stopped.
                    if s.plant_connected {
                        return Err(ControllerStopped(message).into());
                    }
                    bail!(message);
                }
                if idle > HEALTH_CHECK {
                    probes.check(settings.service_timeout).await?;
                } else {
                    probes.clear();
                }
            }
            item = stream.message() => {
                let mut item = item.map_err(|e| lost_controller(controller_addr, "telemetry stream", e))?
                    .ok_or_else(|| anyhow!("the controller ended the telemetry stream"))?;
                if item.episode <= before.episode {
                    continue;
                }
                let record = CycleRecord::try_from(&item)
                    .map_err(|e| anyhow!("telemetry of cycle {} of episode {}: {e}", item.cycle, item.episode))?;
                hilbench_svc::inject_panic("hilbench-run");
                last_cycle_at = Instant::now();
                if real_time && real_time_end.is_none() {
                    let sample = item.sample.as_ref().map(PlantSample::try_from).transpose()
                        .map_err(|e| anyhow!("telemetry of cycle {} of episode {}: sample: {e}", item.cycle, item.episode))?;
                    real_time_end = sample
                        .and_then(|sample| mpc::end::finish_at(scenario, &sample))
                        .map(|end| (item.episode, end));
                }
                let cycles = progress.episodes.entry(item.episode).or_default();
                if record.cycle != cycles.len() as u64 {
                    bail!(
                        "telemetry gap in episode {}: expected cycle {}, got {}",
                        item.episode,
                        cycles.len(),
                        record.cycle
                    );
                }
                if let Some(live) = live {
                    live.cycle(scenario, &record);
                }
                cycles.push(record);
                progress.last_sample = item.sample.take();
            }
            _ = poll.tick() => {
                let s = within(CALL_DEADLINE, "controller", controller_addr, "GetStatus", controller.get_status(pb::GetStatusRequest {}))
                    .await
                    .map_err(|e| ControllerStopped(format!("{e:#}")))?
                    .map_err(|e| lost_controller(controller_addr, "GetStatus", e))?;
                progress.status = Some(s.clone());
                if let Some((episode, _)) = real_time_end
                    && s.episode == episode
                {
                    let telemetry = progress.episodes.remove(&episode).unwrap_or_default();
                    break (s, telemetry);
                }
                // An episode that failed before its first cycle (a plant that refused the
                // Reset: a vehicle away from the start) ends without a new episode number:
                // counted in `episodes_finished`, it ends the run at once too.
                if (s.episode > before.episode || s.episodes_finished > before.episodes_finished)
                    && s.episode_finished
                    && s.finish_reason == pb::FinishReason::Error as i32
                {
                    let message = format!(
                        "{} with {}: the controller's episode ended with an error: {}",
                        scenario.name,
                        mode.name(),
                        s.last_error
                    );
                    // A plant reset under the episode is not the controller's doing.
                    if s.plant_resets > before.plant_resets {
                        bail!(message);
                    }
                    return Err(ControllerStopped(message).into());
                }
                let seen = progress.episodes.get(&s.episode).map_or(0, Vec::len) as u64;
                if !real_time && s.episode > before.episode && s.episode_finished && seen >= s.cycles {
                    let telemetry = progress.episodes.remove(&s.episode).unwrap_or_default();
                    break (s, telemetry);
                }
            }
        }
    };
    let episode_s = episode_started.elapsed().as_secs_f64();
    if !real_time && telemetry.len() as u64 != status.cycles {
        bail!("{} cycles of telemetry, the controller reports {}", telemetry.len(), status.cycles);
    }
    if status.scenario != scenario.name || status.mode != mode.name() {
        bail!(
            "the controller ran {} with {}, not {} with {}",
            status.scenario,
            status.mode,
            scenario.name,
            mode.name()
        );
    }
    let final_sample =
        within(CALL_DEADLINE, "plant", state_addr, "GetState", plant.get_state(pb::GetStateRequest {}))
            .await?
            .context("plant GetState")?;
    let final_sample =
        PlantSample::try_from(&final_sample).map_err(|e| anyhow!("the plant's last sample: {e}"))?;
    let end = match real_time_end {
        Some((_, end)) => end,
        None => finish_reason_from_pb(status.finish_reason, final_sample.time_ns)
            .map_err(|e| anyhow!("the controller's status: {e}"))?
            .ok_or_else(|| anyhow!("the controller's finished episode has no finish reason"))?,
    };
    let records = telemetry;
    let summary = mpc::summarize(&scenario.name, mode.name(), &records, &final_sample, end);
    let faults = faults_of(&status, &records, &final_sample);
    let solver_s = summary.solver_s;
    Ok(GrpcRun {
        summary,
        records,
        final_sample,
        timing: RunTiming { setup_s, episode_s, solver_s, teardown_s: 0.0 },
        faults,
        delay_profile,
        plant: described.implementation,
    })
}

/// The plant and netem of a run as this driver reaches them: when no cycle comes, each is
/// asked (the plant `GetState`, netem `Describe`); one that has not answered for the service
/// timeout ends the run, named.
struct Probes {
    services: Vec<(&'static str, String, PlantClient<tonic::transport::Channel>, Option<Instant>)>,
}

impl Probes {
    async fn new(services: &Services, tls: &Tls, deadline: Instant) -> anyhow::Result<Self> {
        let mut probes = Vec::new();
        for (name, addr) in [("plant", services.plant_addr()), ("netem", services.netem_addr())] {
            if let Some(addr) = addr {
                let client = PlantClient::new(connect_with(addr, tls, deadline).await?);
                probes.push((name, addr.to_string(), client, None));
            }
        }
        Ok(Self { services: probes })
    }

    /// A cycle came: whatever did not answer before is up again.
    fn clear(&mut self) {
        for probe in &mut self.services {
            probe.3 = None;
        }
    }

    /// Asks each service once; an error naming the first that has not answered for `timeout`.
    async fn check(&mut self, timeout: Duration) -> anyhow::Result<()> {
        for (name, addr, client, down_since) in &mut self.services {
            // The plant is asked for its state: a gateway whose vehicle (or firmware) is gone
            // still answers Describe, but refuses GetState (UNAVAILABLE, naming the link). netem
            // is asked Describe: its GetState is the plant's, through it.
            let (call, answer) = if *name == "plant" {
                let asked = tokio::time::timeout(PROBE_DEADLINE, client.get_state(pb::GetStateRequest {}));
                ("GetState", asked.await.map(|r| r.map(|_| ())))
            } else {
                let asked = tokio::time::timeout(PROBE_DEADLINE, client.describe(pb::DescribeRequest {}));
                ("Describe", asked.await.map(|r| r.map(|_| ())))
            };
            let why = match answer {
                Ok(Ok(())) => {
                    *down_since = None;
                    continue;
                }
                Ok(Err(e)) => format!("{call}: {}", e.message()),
                Err(_) => format!("{call} unanswered for {:.0} s", PROBE_DEADLINE.as_secs_f64()),
            };
            let since = *down_since.get_or_insert_with(Instant::now);
            if since.elapsed() >= timeout {
                bail!(
                    "the {name} at {addr} has not answered for {:.0} s ({why}): it was killed or stopped, or \
                     the link to it (or, behind a gateway, to its vehicle) is cut; the run cannot go on",
                    since.elapsed().as_secs_f64()
                );
            }
        }
        Ok(())
    }
}

/// The run's faults: the controller's status (link outages, plant resets), the telemetry and
/// the plant's last sample (its watchdog).
fn faults_of(status: &pb::ControllerStatus, records: &[CycleRecord], last: &PlantSample) -> RunFaults {
    RunFaults {
        link_losses: status.link_losses,
        link_down_s: status.link_down_s,
        longest_link_down_s: status.longest_link_down_s,
        watchdog_cycles: records.iter().filter(|r| r.watchdog_hover).count() as u64,
        watchdog_hover_s: mav::ns_to_s(last.watchdog_hover_ns),
        plant_resets: status.plant_resets,
        plant_reset_time_s: status.plant_reset_time_s,
    }
}

/// An error of the controller's `call` during a run: a connection that broke (the controller's
/// process killed or crashed, or the link cut) said as such, with the transport's reason;
/// anything else as the controller said it.
fn lost_controller(addr: &str, call: &str, status: tonic::Status) -> anyhow::Error {
    // Unavailable (no connection: a tcp connect error) and Cancelled (the connection dropped
    // under the call) are the link's; Unknown is when its message is the transport's (an h2
    // stream reset, a broken pipe).
    let transport = match status.code() {
        tonic::Code::Unavailable | tonic::Code::Cancelled => true,
        tonic::Code::Unknown => ["h2 protocol", "broken pipe", "connection", "transport"]
            .iter()
            .any(|w| status.message().to_lowercase().contains(w)),
        _ => false,
    };
    let message = if transport {
        format!(
            "the controller at {addr} went away during the run ({call}: {}): its process was killed or \
             crashed, or the link to it was cut",
            status.message()
        )
    } else {
        format!("controller {call}: {}: {}", status.code(), status.message())
    };
    ControllerStopped(message).into()
}
