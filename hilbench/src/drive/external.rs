//! An external controller under test: a process that speaks the Plant API as a client, flown
//! against a plant and netem served here on loopback, judged from the plant's truth alone.
//!
//! [`run_external`] flies one run: it starts a plant (lockstep or real time) and a netem with the
//! scenario's network in front of it, resets the plant to the scenario, subscribes to the
//! plant's `StreamState` with period 0 (every integration step, on the plant itself, not
//! through netem), then starts the controller's command line (`sh -c`) in a process group of
//! its own with `HILBENCH_PLANT_ADDR` (netem's address), `HILBENCH_SCENARIO` (the scenario as
//! flown, written to a temporary file) and `HILBENCH_TIME_MODE`. The controller flies: in
//! lockstep it calls `Step` itself (netem delays its commands and advances the plant on to
//! each release), in real time it streams.
//!
//! The run ends at the first plant step whose sample ends a flight (`mpc::end::finish_at`,
//! the rule of the bench's own controller: a collision unless the scenario goes on after one,
//! the goal within `goal_tolerance_m` and `goal_speed_tolerance_mps`, or `max_duration_s` of
//! plant time). The summary is that sample's: path length, smallest clearance, collisions,
//! time to the goal, all integrated by the plant. Judging at every step (1 ms) rather than at
//! the controller's calls makes the end independent of how the controller splits its steps,
//! and lockstep runs of a deterministic controller bit-identical. What the controller does after
//! that step (it is still stepping until the bench's SIGTERM lands) is not judged.
//!
//! A run fails, with the controller's last lines of output in the error, when the controller
//! exits before the run ends (whatever its status), when plant time stops moving for
//! [`ExternalSettings::stall_timeout`] (a hung controller in lockstep; a dead plant in real
//! time), or when the plant is reset under the run. The process group is always killed: at the
//! end of a run SIGTERM, then SIGKILL after [`ExternalSettings::stop_grace`]; on any error, and
//! when the run is dropped, SIGKILL.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::process::{ExitStatus, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use anyhow::{Context, anyhow, bail};
use hilbench_proto::pb;
use hilbench_proto::pb::netem_control_client::NetemControlClient;
use hilbench_proto::pb::plant_client::PlantClient;
use mav::{PlantSample, Scenario, TimeMode, ns_to_s};
use mpc::{ControllerMode, RunEnd, RunSummary};
use tokio::io::{AsyncBufReadExt, AsyncRead, BufReader};
use tokio::process::{Child, Command};

use super::services::{Running, connect, netem_config, plant_config, start_netem, start_plant, stop};
use crate::run::{
    ControllerStopped, CycleRow, DelayProfileInForce, DelaySource, ExternalFacts, FinishedRun, Job,
    RunFailure, RunFaults, RunTiming,
};
use crate::scenario_file::ScenarioFile;

/// `RunSummary::controller` of an external controller's run (and its CSV's name).
pub const CONTROLLER_NAME: &str = crate::run::EXTERNAL_CONTROLLER;

/// Lines of the controller's output (stdout and stderr) kept for error messages.
const TAIL_LINES: usize = 20;
/// The longest line kept, characters.
const TAIL_LINE_CHARS: usize = 400;
/// The most bytes of one line of the controller's output held while it is read (enough for
/// [`TAIL_LINE_CHARS`] characters of UTF-8): the rest of a longer line is skipped.
const LINE_CAP_BYTES: usize = 4 * TAIL_LINE_CHARS;
/// Lockstep: after the controller's exit, how long the plant's stream may stay quiet before
/// what it produced is taken as complete.
const DRAIN_QUIET: Duration = Duration::from_millis(200);

/// How an external controller's runs are flown (the command line is the job's,
/// `crate::run::Controller::External`).
#[derive(Debug, Clone)]
pub struct ExternalDriver {
    pub time_mode: TimeMode,
    pub settings: ExternalSettings,
    /// A running plant or a vehicle's gateway (`--plant`) to fly instead of a plant started
    /// here; netem is started in front of it all the same.
    pub plant: Option<String>,
    /// Each run starts where the plant's vehicle is (`--start-from-vehicle`).
    pub start_from_vehicle: bool,
}

/// Wall-clock bounds of an external run.
#[derive(Debug, Clone)]
pub struct ExternalSettings {
    /// Bound on the whole run; a run that takes longer is an error.
    pub timeout: Duration,
    /// Plant time does not move for this long (no new plant step): the run fails. In lockstep
    /// this is a controller that stopped calling `Step` (hung, or waiting on something); it
    /// includes the controller's start-up before its first `Step`.
    pub stall_timeout: Duration,
    /// After SIGTERM at the end of a run, how long the controller may take to exit before
    /// SIGKILL.
    pub stop_grace: Duration,
}

impl Default for ExternalSettings {
    fn default() -> Self {
        Self {
            timeout: Duration::from_secs(600),
            stall_timeout: Duration::from_secs(10),
            stop_grace: Duration::from_secs(2),
        }
    }
}

/// One run of an external controller.
#[derive(Debug, Clone)]
pub struct ExternalRun {
    pub summary: RunSummary,
    /// One row per command the plant applied (see [`Judge`]).
    pub rows: Vec<CycleRow>,
    /// The plant's sample of the step that ended the run.
    pub final_sample: PlantSample,
    pub timing: RunTiming,
    /// The plant's watchdog (the bench does not see the controller's link).
    pub faults: RunFaults,
    pub delay_profile: DelayProfileInForce,
    /// The plant's `PlantDescription.implementation` (from its `Reset`).
    pub plant: String,
    pub facts: ExternalFacts,
}

impl ExternalRun {
    /// The run of `job` for the outputs (`error`: it failed part-way and this is what flew).
    pub fn finished(self, job: Job, error: Option<String>) -> FinishedRun {
        FinishedRun {
            job,
            summary: self.summary,
            rows: self.rows,
            records: Vec::new(),
            timing: Some(self.timing),
            faults: self.faults,
            delay_profile: self.delay_profile,
            plant: self.plant,
            external: Some(self.facts),
            error,
        }
    }
}

/// A run that failed: the error, and what the plant flew before it (`None` when it failed
/// before the plant's first sample), its `end_reason` "error".
pub type ExternalFailure = RunFailure<ExternalRun>;

/// Flies `scenario` with the controller `command` (a shell command line, run with `sh -c`,
/// e.g. `python examples/python-controller/controller.py`) the way `controller` says, against
/// a plant and netem started here (see the module's documentation).
pub async fn run_external(
    scenario: &Scenario,
    command: &str,
    controller: &ExternalDriver,
) -> Result<ExternalRun, ExternalFailure> {
    let started = Instant::now();
    let network = scenario.network().map_err(|e| anyhow!("{e}"))?;
    let network = network.unwrap_or_else(|| delay::NetworkProfile::none(scenario.seed));
    let delay_profile = DelayProfileInForce::of(DelaySource::Scenario, &network);
    let (plant, plant_addr) = match &controller.plant {
        Some(addr) => {
            // A vehicle behind a gateway must be up and flying setpoints before its run, as
            // for the bench's own controller.
            let deadline = Instant::now() + PLANT_READY_WAIT;
            // In the run's time mode, as the bench's own controller's plant must be.
            let mut described = PlantClient::new(connect(addr, deadline).await?);
            super::grpc::described_in(&mut described, addr, controller.time_mode).await?;
            super::grpc::vehicle_ready(addr, &Default::default(), deadline).await?;
            (None, addr.clone())
        }
        None => {
            let mut config = plant_config(scenario, controller.time_mode);
            config.stream_buffer = stream_buffer(scenario, config.rate_hz);
            let (plant, addr) = start_plant(config).await?;
            (Some(plant), addr)
        }
    };
    let netem = match netem_config(&plant_addr, scenario, controller.time_mode) {
        Ok(config) => start_netem(config).await,
        Err(e) => Err(e),
    };
    let (netem, netem_addr) = match netem {
        Ok(n) => n,
        Err(e) => {
            if let Some(plant) = plant {
                let _ = stop(plant).await;
            }
            return Err(e.into());
        }
    };
    let mut flight = ExternalFlight::new(scenario, command, controller, delay_profile);
    let result = flight.fly(&plant_addr, &netem_addr, started).await;
    if result.is_err() && flight.commands_delayed.is_none() {
        // A run that ended in an error still says what netem delayed and refused (a controller
        // that gave up after refusals is the case to explain), before netem is stopped.
        flight.commands_delayed =
            commands_delayed(&netem_addr, Instant::now() + ASK_NETEM_AFTER_ERROR, None).await;
    }
    let stopping = Instant::now();
    let stopped = stop_all([Some(netem), plant]).await;
    match result {
        Ok(mut run) => {
            stopped.map_err(ExternalFailure::from)?;
            run.timing.teardown_s += stopping.elapsed().as_secs_f64();
            Ok(run)
        }
        Err(error) => Err(ExternalFailure { error, partial: flight.partial().map(Box::new) }),
    }
}

/// The plant's stream buffer: the whole run's steps (and a second past its end), so that a
/// controller that advances far in one call loses the bench none; at most two minutes of steps.
fn stream_buffer(scenario: &Scenario, rate_hz: f64) -> usize {
    let steps = (scenario.max_duration_s + 1.0) * rate_hz;
    (steps.ceil() as usize).clamp(plant::config::DEFAULT_STREAM_BUFFER, 120_000)
}

async fn stop_all(running: [Option<Running>; 2]) -> anyhow::Result<()> {
    let mut result = Ok(());
    for r in running.into_iter().flatten() {
        let stopped = stop(r).await;
        if result.is_ok() {
            result = stopped;
        }
    }
    result
}

/// One run as it goes: the judge, the process, the facts.
struct ExternalFlight<'a> {
    scenario: &'a Scenario,
    command: &'a str,
    controller: &'a ExternalDriver,
    judge: Judge,
    delay_profile: DelayProfileInForce,
    exit: Option<String>,
    /// netem's counts of commands delayed and refused as invalid, asked when the end was
    /// judged.
    commands_delayed: Option<(u64, u64)>,
    setup_s: f64,
    /// Stopping the controller's process, s (part of the run's teardown).
    stop_s: f64,
    episode_started: Option<Instant>,
    /// The plant's `implementation`, from its `Reset`.
    plant: String,
}

impl<'a> ExternalFlight<'a> {
    fn new(
        scenario: &'a Scenario,
        command: &'a str,
        controller: &'a ExternalDriver,
        delay_profile: DelayProfileInForce,
    ) -> Self {
        Self {
            scenario,
            command,
            controller,
            judge: Judge::new(scenario),
            delay_profile,
            exit: None,
            commands_delayed: None,
            setup_s: 0.0,
            stop_s: 0.0,
            episode_started: None,
            plant: String::new(),
        }
    }

    async fn fly(
        &mut self,
        plant_addr: &str,
        netem_addr: &str,
        started: Instant,
    ) -> anyhow::Result<ExternalRun> {
        let settings = &self.controller.settings;
        let deadline = started + settings.timeout;
        let mut plant = PlantClient::new(connect(plant_addr, deadline).await?);
        // The bench resets the plant to the scenario, whole, for every run (from where the
        // vehicle is, with --start-from-vehicle: a gateway never moves its vehicle to a start).
        let start = if self.controller.start_from_vehicle {
            Some(
                super::grpc::with_vehicle_start(plant_addr, &Default::default(), self.scenario, deadline)
                    .await?,
            )
        } else {
            None
        };
        let reset = plant
            .reset(pb::ResetRequest {
                scenario: String::new(),
                initial_state: None,
                definition: Some(start.as_ref().unwrap_or(self.scenario).into()),
            })
            .await
            .context("plant Reset")?
            .into_inner();
        if let Some(d) = &reset.description {
            self.plant = d.implementation.clone();
        }
        self.judge.step_ns = reset.description.map(|d| d.step_ns).filter(|&s| s > 0);
        // On the plant itself: the truth, undelayed. It starts with the reset's sample.
        let mut stream = plant
            .stream_state(pb::StreamStateRequest { period_ns: 0 })
            .await
            .context("plant StreamState")?
            .into_inner();
        let scenario_file = ScenarioTempFile::write(start.as_ref().unwrap_or(self.scenario))?;
        let mut process = Process::spawn(
            self.command,
            &[
                ("HILBENCH_PLANT_ADDR", netem_addr),
                ("HILBENCH_SCENARIO", &scenario_file.path.display().to_string()),
                ("HILBENCH_TIME_MODE", self.controller.time_mode.name()),
            ],
        )?;
        self.setup_s = started.elapsed().as_secs_f64();
        let episode_started = Instant::now();
        self.episode_started = Some(episode_started);
        let mut panicked = crate::panics::watch();
        let mut last_step_at = Instant::now();
        let mut exited: Option<ExitStatus> = None;
        while self.judge.end.is_none() {
            let stall = tokio::time::Instant::from_std(last_step_at + settings.stall_timeout);
            tokio::select! {
                item = stream.message() => {
                    let item = item.context("the plant's state stream")?
                        .ok_or_else(|| anyhow!("the plant ended its state stream"))?;
                    self.judge.see(&item)?;
                    last_step_at = Instant::now();
                }
                status = process.child.wait(), if exited.is_none() => {
                    let status = status.context("waiting for the controller")?;
                    exited = Some(status);
                    self.exit = Some(format!("exited: {status}"));
                    // What the plant produced before the exit still counts: a controller may
                    // stop once it sees the goal. In lockstep until the stream is quiet (a
                    // call in flight may still advance the plant); in real time the plant
                    // flies on without it, so only what has already arrived.
                    let quiet = match self.controller.time_mode {
                        TimeMode::Lockstep => DRAIN_QUIET,
                        TimeMode::RealTime => Duration::ZERO,
                    };
                    while let Ok(item) = tokio::time::timeout(quiet, stream.message()).await {
                        let item = item.context("the plant's state stream")?
                            .ok_or_else(|| anyhow!("the plant ended its state stream"))?;
                        self.judge.see(&item)?;
                        if self.judge.end.is_some() {
                            break;
                        }
                    }
                    if self.judge.end.is_none() {
                        return Err(ControllerStopped(format!(
                            "the controller exited ({status}) before the run ended ({}){}",
                            self.judge.where_now(),
                            process.tail_text()
                        ))
                        .into());
                    }
                }
                () = tokio::time::sleep_until(stall) => {
                    process.kill();
                    let message = format!(
                        "plant time has not moved for {:.0} s ({}): the controller {}{}",
                        settings.stall_timeout.as_secs_f64(),
                        self.judge.where_now(),
                        match self.controller.time_mode {
                            TimeMode::Lockstep => "stopped calling Step (hung?)",
                            TimeMode::RealTime => "cannot move it in real time: the plant stalled",
                        },
                        process.tail_text()
                    );
                    // In lockstep only the controller moves plant time.
                    if self.controller.time_mode == TimeMode::Lockstep {
                        return Err(ControllerStopped(message).into());
                    }
                    bail!(message);
                }
                () = tokio::time::sleep_until(tokio::time::Instant::from_std(deadline)) => {
                    process.kill();
                    bail!("the run did not end within {:?} ({})", settings.timeout, self.judge.where_now());
                }
                panic = panicked.changed() => {
                    let what = panic.ok().and_then(|()| panicked.borrow().clone());
                    bail!("a task of the run panicked: {}", what.unwrap_or_default());
                }
            }
        }
        let episode_s = episode_started.elapsed().as_secs_f64();
        // Every command sent before the end has had its delay drawn by now (the plant stepped
        // to the end while netem advanced it for a command already delayed). In lockstep netem
        // counts those sent at plant times before the end's, whatever the controller sends
        // while it is asked; in real time it is asked before the controller is stopped, so
        // that its count is never short of what a replay needs.
        let lockstep_end_ns = match self.controller.time_mode {
            TimeMode::Lockstep => self.judge.end.as_ref().map(|(_, s)| s.time_ns),
            TimeMode::RealTime => None,
        };
        self.commands_delayed = commands_delayed(netem_addr, deadline, lockstep_end_ns).await;
        let stopping = Instant::now();
        if exited.is_none() {
            self.exit = Some(process.stop(settings.stop_grace).await);
        }
        self.stop_s = stopping.elapsed().as_secs_f64();
        let (end, last) = self.judge.end.clone().ok_or_else(|| anyhow!("the run has no end"))?;
        let summary = self.judge.summary(&last, end);
        Ok(self.run(summary, last, episode_s))
    }

    /// The run, ended at `last` with `summary`, and the commands netem refused said in its
    /// explanation, where the user looks first (the printed summary, summary.json).
    fn run(&self, mut summary: RunSummary, last: PlantSample, episode_s: f64) -> ExternalRun {
        if let Some((_, refused)) = self.commands_delayed
            && refused > 0
        {
            summary.explanation.push(format!(
                "netem refused {refused} of the controller's commands as invalid (INVALID_ARGUMENT: a NaN, \
                 a value out of range or a wrong length); they were never applied \
                 (external_controller.commands_refused)"
            ));
        }
        ExternalRun {
            summary,
            rows: self.judge.rows.clone(),
            faults: faults_of(&last),
            final_sample: last,
            timing: RunTiming { setup_s: self.setup_s, episode_s, solver_s: 0.0, teardown_s: self.stop_s },
            delay_profile: self.delay_profile.clone(),
            plant: self.plant.clone(),
            facts: self.facts(),
        }
    }

    fn facts(&self) -> ExternalFacts {
        ExternalFacts {
            command: self.command.to_string(),
            exit: self.exit.clone().unwrap_or_else(|| "killed by the bench".to_string()),
            commands_applied: self.judge.rows.len() as u64,
            commands_delayed: self.commands_delayed.map(|(sent, _)| sent),
            commands_refused: self.commands_delayed.map(|(_, refused)| refused),
            commands_saturated: self.judge.saturated,
            plant_steps_judged: self.judge.steps,
            plant_steps_missed: self.judge.missed,
        }
    }

    /// The run as far as the plant flew it (after an error): `None` before its first sample.
    fn partial(&self) -> Option<ExternalRun> {
        let last = self.judge.last.clone()?;
        let summary = self.judge.summary(&last, RunEnd::Error);
        let episode_s = self.episode_started.map_or(0.0, |t| t.elapsed().as_secs_f64());
        Some(self.run(summary, last, episode_s))
    }
}

/// How long a plant given with `--plant` may take to say it is ready (a gateway's vehicle
/// armed and flying setpoints).
const PLANT_READY_WAIT: Duration = Duration::from_secs(10);

/// How long a run that ended in an error waits for netem's counts.
const ASK_NETEM_AFTER_ERROR: Duration = Duration::from_secs(5);

/// netem's commands that drew a delay and those it refused as invalid, or `None` when it cannot
/// be asked (summary.json then says `null`, and a failure's trace keeps every delay the run
/// had). With `lockstep_end_ns` (the plant time of the run's end, in lockstep) the commands
/// sent before it (`NetemControl.CommandsSentBefore`): the same for identical runs, however
/// long the controller stepped on after the end; otherwise every command sent so far.
async fn commands_delayed(
    netem_addr: &str,
    deadline: Instant,
    lockstep_end_ns: Option<u64>,
) -> Option<(u64, u64)> {
    let asked = async {
        let mut control = NetemControlClient::new(connect(netem_addr, deadline).await?);
        let stats = control.get_stats(pb::GetStatsRequest {}).await.context("netem GetStats")?.into_inner();
        let (sent, refused) = stats.controller_to_plant.map_or((0, 0), |d| (d.sent, d.refused_invalid));
        let delayed = match lockstep_end_ns {
            Some(t) => {
                control
                    .commands_sent_before(pb::CommandsSentBeforeRequest { before_plant_time_ns: t })
                    .await
                    .context("netem CommandsSentBefore")?
                    .into_inner()
                    .commands
            }
            None => sent,
        };
        anyhow::Ok((delayed, refused))
    };
    asked.await.ok()
}

fn faults_of(last: &PlantSample) -> RunFaults {
    RunFaults { watchdog_hover_s: ns_to_s(last.watchdog_hover_ns), ..RunFaults::default() }
}

/// Judges a run from the plant's samples, one per integration step.
///
/// The per-cycle rows are the plant's view: a row per command applied, at the first step at or
/// after its application (`t_s` and the state are that step's; `command` the input applied,
/// after clipping; `known_delay_s` the command's round trip from the plant's stamps, applied
/// time minus the `based_on_sample_time_ns` the controller stamped it with: meaningful only
/// when it stamps its commands, as the Plant API asks). The controller's internals are unknown: no weights, `status` `external`,
/// `iterations` 0, `solve_ms`, `cost`, `constraint_violation` and `predicted_clearance_m` NaN,
/// `decision`, `cost_gap` and `injected_delay_s` empty.
struct Judge {
    scenario: Scenario,
    /// The plant's integration step (its description's `step_ns`): the stream's spacing.
    step_ns: Option<u64>,
    flight_id: Option<u64>,
    /// The newest sample judged.
    last: Option<PlantSample>,
    /// Why and where the run ended: the first step that ends it.
    end: Option<(RunEnd, PlantSample)>,
    rows: Vec<CycleRow>,
    /// The last command seen: (`command_seq`, applied time).
    command: Option<(u64, u64)>,
    saturated: u64,
    steps: u64,
    missed: u64,
}

impl Judge {
    fn new(scenario: &Scenario) -> Self {
        Self {
            scenario: scenario.clone(),
            step_ns: None,
            flight_id: None,
            last: None,
            end: None,
            rows: Vec::new(),
            command: None,
            saturated: 0,
            steps: 0,
            missed: 0,
        }
    }

    fn see(&mut self, item: &pb::StateSample) -> anyhow::Result<()> {
        if self.end.is_some() {
            return Ok(());
        }
        let sample = PlantSample::try_from(item).map_err(|e| anyhow!("the plant's sample: {e}"))?;
        match self.flight_id {
            None => self.flight_id = Some(sample.flight_id),
            Some(id) if id != sample.flight_id => bail!(
                "the plant was reset under the run at plant time {:.3} s (the bench resets it; a controller must not call Reset)",
                self.last.as_ref().map_or(0.0, |s| ns_to_s(s.time_ns))
            ),
            Some(_) => {}
        }
        if let (Some(prev), Some(step)) = (&self.last, self.step_ns) {
            self.missed += steps_missed_between(prev.time_ns, sample.time_ns, step);
        }
        self.steps += 1;
        let applied = &sample.last_command;
        let key = (applied.meta.command_seq, applied.applied_time_ns);
        if !applied.initial && self.command != Some(key) {
            self.command = Some(key);
            self.saturated += u64::from(applied.saturated);
            let round_trip_ns = applied.applied_time_ns.saturating_sub(applied.meta.based_on_sample_time_ns);
            self.rows.push(CycleRow {
                cycle: self.rows.len() as u64,
                t_s: ns_to_s(sample.time_ns),
                state: sample.state.into(),
                command: applied.input.into(),
                command_seq: applied.meta.command_seq,
                known_delay_s: ns_to_s(round_trip_ns),
                injected_delay_s: None,
                weights: Vec::new(),
                status: CONTROLLER_NAME.to_string(),
                iterations: 0,
                solve_ms: f64::NAN,
                cost: f64::NAN,
                constraint_violation: f64::NAN,
                predicted_clearance_m: f64::NAN,
                decision: String::new(),
                reason: String::new(),
                cost_gap: None,
            });
        }
        if let Some(end) = mpc::end::finish_at(&self.scenario, &sample) {
            self.end = Some((end, sample.clone()));
        }
        self.last = Some(sample);
        Ok(())
    }

    /// Plant time and distance to the goal of the newest sample, for errors.
    fn where_now(&self) -> String {
        match &self.last {
            None => "no plant sample yet".to_string(),
            Some(s) => {
                let g = self.scenario.goal_m;
                let d =
                    ((s.state[0] - g[0]).powi(2) + (s.state[1] - g[1]).powi(2) + (s.state[2] - g[2]).powi(2))
                        .sqrt();
                format!(
                    "plant time {:.3} s, {d:.2} m from the goal, {} command(s) applied",
                    ns_to_s(s.time_ns),
                    self.rows.len()
                )
            }
        }
    }

    /// The one summary (`mpc::summarize`) of the plant's `last` sample; the controller's
    /// solve statistics are unknown (no records), its cycles are the commands applied, and
    /// its commands lost are not the bench's to count (netem's counts are its `external`).
    fn summary(&self, last: &PlantSample, end: RunEnd) -> RunSummary {
        let mut summary = mpc::summarize(&self.scenario.name, CONTROLLER_NAME, &[], last, end);
        summary.cycles = self.rows.len() as u64;
        summary.commands_lost = None;
        summary
    }
}

/// Step boundaries (multiples of `step_ns`) strictly between two consecutive samples of a
/// period-0 stream at plant times `prev_ns` and `next_ns`: the steps the stream did not bring.
///
/// Counted by boundary, not by the gap: the stream's first sample is the current one, which in
/// real time lies between steps, so the gap from it to the first step is shorter than a step
/// (taking that gap for the step counted every later step as two or three missed ones).
fn steps_missed_between(prev_ns: u64, next_ns: u64, step_ns: u64) -> u64 {
    // Boundaries in (prev, next): the last one at or before `next` less the last one at or
    // before `prev`, less `next` itself when it is one.
    let crossed = (next_ns / step_ns).saturating_sub(prev_ns / step_ns);
    crossed.saturating_sub(u64::from(next_ns.is_multiple_of(step_ns)))
}

/// The scenario as flown, in a temporary file (`HILBENCH_SCENARIO`), removed on drop.
struct ScenarioTempFile {
    dir: PathBuf,
    path: PathBuf,
}

impl ScenarioTempFile {
    fn write(scenario: &Scenario) -> anyhow::Result<Self> {
        static RUNS: AtomicU64 = AtomicU64::new(0);
        let n = RUNS.fetch_add(1, Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("hilbench-external-{}-{n}", std::process::id()));
        std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let path = dir.join(format!("{}.toml", scenario.name));
        let text =
            ScenarioFile::as_flown(scenario, vec![ControllerMode::Multistage]).map_err(anyhow::Error::msg)?;
        std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
        Ok(Self { dir, path })
    }
}

impl Drop for ScenarioTempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// The variable that marks every process of one controller's run: set in its environment,
/// inherited by all it starts, kept by one that leaves the process group (`setsid`, a daemon).
const TOKEN_VAR: &str = "HILBENCH_CONTROLLER_TOKEN";

/// The controller's process, in a process group of its own (so that what its shell starts is
/// stopped with it), its output's last lines kept. Killed (the whole group, and any process that
/// left it but carries its token) when dropped.
struct Process {
    child: Child,
    group: Option<rustix::process::Pid>,
    tail: Arc<Mutex<VecDeque<String>>>,
    /// `TOKEN_VAR=<this process's pid>-<a counter>`: unique to this controller run.
    token: String,
}

/// Processes (other than this one) whose environment holds `entry` (`VAR=value`), from
/// `/proc/*/environ`; those of other users cannot be read and are not among them.
fn processes_with(entry: &str) -> Vec<rustix::process::Pid> {
    let me = std::process::id();
    let Ok(dir) = std::fs::read_dir("/proc") else { return Vec::new() };
    dir.filter_map(Result::ok)
        .filter_map(|e| e.file_name().to_str().and_then(|n| n.parse::<u32>().ok()))
        .filter(|&pid| pid != me)
        .filter(|pid| {
            std::fs::read(format!("/proc/{pid}/environ"))
                .is_ok_and(|env| env.split(|b| *b == 0).any(|v| v == entry.as_bytes()))
        })
        .filter_map(|pid| rustix::process::Pid::from_raw(pid as i32))
        .collect()
}

impl Process {
    fn spawn(command: &str, env: &[(&str, &str)]) -> anyhow::Result<Self> {
        static RUNS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let token =
            format!("{}-{}", std::process::id(), RUNS.fetch_add(1, std::sync::atomic::Ordering::Relaxed));
        // The trap makes the shell wait for the command on SIGTERM and exit after it (traps run
        // once the foreground command has finished; its own SIGTERM disposition is the default):
        // a shell killed at once would orphan the controller, and an orphan is reaped by
        // whatever PID 1 is, lazily or never in some containers.
        let mut child = Command::new("sh")
            .arg("-c")
            .arg(format!("trap 'exit 143' TERM\n{command}"))
            .envs(env.iter().copied())
            .env(TOKEN_VAR, &token)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .process_group(0)
            .kill_on_drop(true)
            .spawn()
            .with_context(|| format!("cannot start the controller `{command}` with sh"))?;
        let group = child.id().and_then(|id| rustix::process::Pid::from_raw(id as i32));
        let tail = Arc::new(Mutex::new(VecDeque::with_capacity(TAIL_LINES)));
        if let Some(out) = child.stdout.take() {
            tokio::spawn(keep_tail(out, tail.clone()));
        }
        if let Some(err) = child.stderr.take() {
            tokio::spawn(keep_tail(err, tail.clone()));
        }
        Ok(Self { child, group, tail, token: format!("{TOKEN_VAR}={token}") })
    }

    /// SIGKILL to every process that left the group but carries this run's token (a `setsid`
    /// child, a daemon): how many.
    fn kill_escaped(&self) -> usize {
        let escaped = processes_with(&self.token);
        for pid in &escaped {
            let _ = rustix::process::kill_process(*pid, rustix::process::Signal::KILL);
        }
        escaped.len()
    }

    /// The last lines of its output, for an error message.
    fn tail_text(&self) -> String {
        let tail = self.tail.lock().unwrap_or_else(PoisonError::into_inner);
        if tail.is_empty() {
            return "; it printed nothing".to_string();
        }
        let lines: Vec<&str> = tail.iter().map(String::as_str).collect();
        format!("; its last output:\n    {}", lines.join("\n    "))
    }

    fn signal(&self, signal: rustix::process::Signal) {
        if let Some(group) = self.group {
            let _ = rustix::process::kill_process_group(group, signal);
        }
    }

    fn kill(&mut self) {
        self.signal(rustix::process::Signal::KILL);
        self.group = None;
        self.kill_escaped();
    }

    /// SIGTERM to the group, SIGKILL to what is left of it after `grace`: how it ended. The
    /// whole group gets the grace, not just the shell: `sh -c` may die of the SIGTERM at once
    /// while the controller it started is still cleaning up.
    async fn stop(&mut self, grace: Duration) -> String {
        self.signal(rustix::process::Signal::TERM);
        let deadline = tokio::time::Instant::now() + grace;
        let mut exited = false;
        loop {
            exited = exited || matches!(self.child.try_wait(), Ok(Some(_)));
            let group_gone =
                self.group.is_none_or(|group| rustix::process::test_kill_process_group(group).is_err());
            if exited && group_gone {
                self.group = None;
                return format!("stopped by the bench{}", escaped_text(self.kill_escaped()));
            }
            if tokio::time::Instant::now() >= deadline {
                self.signal(rustix::process::Signal::KILL);
                self.group = None;
                let escaped = self.kill_escaped();
                let _ = self.child.wait().await;
                return format!("killed by the bench{}", escaped_text(escaped));
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }
}

/// What `exit` adds for processes that had left the controller's process group.
fn escaped_text(n: usize) -> String {
    match n {
        0 => String::new(),
        n => format!("; {n} process(es) it started outside its process group (setsid) killed"),
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Reads the controller's `output` into `tail`, a line at a time, holding at most
/// [`LINE_CAP_BYTES`] of a line: a longer line is kept up to the cap, marked as cut, and the
/// rest of it skipped up to its end (an unterminated 300 MB line used to be buffered whole).
/// Bytes that are not UTF-8 are shown replaced, and the reading goes on.
async fn keep_tail(output: impl AsyncRead + Unpin, tail: Arc<Mutex<VecDeque<String>>>) {
    let mut reader = BufReader::new(output);
    let mut line = Vec::with_capacity(LINE_CAP_BYTES);
    // Past the cap of the current line: skipping to its end.
    let mut skipping = false;
    loop {
        let chunk = match reader.fill_buf().await {
            Ok(chunk) if !chunk.is_empty() => chunk,
            _ => break,
        };
        let newline = chunk.iter().position(|b| *b == b'\n');
        let part = newline.unwrap_or(chunk.len());
        if !skipping {
            let take = part.min(LINE_CAP_BYTES - line.len());
            line.extend_from_slice(&chunk[..take]);
            if take < part {
                push_line(&tail, &line, true);
                line.clear();
                skipping = true;
            }
        }
        reader.consume(part + usize::from(newline.is_some()));
        if newline.is_some() {
            if !skipping {
                push_line(&tail, &line, false);
            }
            line.clear();
            skipping = false;
        }
    }
    if !line.is_empty() && !skipping {
        push_line(&tail, &line, false);
    }
}

/// Adds a line of output to `tail` (dropping its oldest beyond [`TAIL_LINES`]), at most
/// [`TAIL_LINE_CHARS`] of it, saying when it was cut (`over_cap`: longer than
/// [`LINE_CAP_BYTES`]).
fn push_line(tail: &Mutex<VecDeque<String>>, bytes: &[u8], over_cap: bool) {
    let text = String::from_utf8_lossy(bytes);
    let text = text.strip_suffix('\r').unwrap_or(&text);
    let mut kept: String = text.chars().take(TAIL_LINE_CHARS).collect();
    if over_cap || kept.len() < text.len() {
        let limit = if over_cap {
            format!("{LINE_CAP_BYTES} bytes")
        } else {
            format!("{TAIL_LINE_CHARS} characters")
        };
        kept.push_str(&format!(" [line cut: longer than {limit}]"));
    }
    let mut tail = tail.lock().unwrap_or_else(PoisonError::into_inner);
    if tail.len() == TAIL_LINES {
        tail.pop_front();
    }
    tail.push_back(kept);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn an_unterminated_line_is_cut_at_the_cap_and_said_to_be_without_waiting_for_its_end() {
        use tokio::io::AsyncWriteExt;
        let tail = Arc::new(Mutex::new(VecDeque::new()));
        // 8 MiB without a newline from a writer that stays open (a controller still printing).
        let (mut writer, reader) = tokio::io::duplex(64 << 10);
        let reading = tokio::spawn(keep_tail(reader, tail.clone()));
        let writing = tokio::spawn(async move {
            let block = vec![b'x'; 64 << 10];
            for _ in 0..128 {
                if writer.write_all(&block).await.is_err() {
                    return;
                }
            }
            writer.write_all(b"\nnext line\n").await.ok();
            std::future::pending::<()>().await;
        });
        let deadline = tokio::time::Instant::now() + Duration::from_secs(20);
        let lines = loop {
            let lines: Vec<String> =
                tail.lock().unwrap_or_else(PoisonError::into_inner).iter().cloned().collect();
            if lines.len() >= 2 || tokio::time::Instant::now() > deadline {
                break lines;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        };
        reading.abort();
        writing.abort();
        assert_eq!(lines.len(), 2, "{:?}", lines.iter().map(|l| l.len()).collect::<Vec<_>>());
        assert!(lines[0].starts_with(&"x".repeat(TAIL_LINE_CHARS)), "{}", lines[0]);
        assert!(
            lines[0].ends_with(&format!("[line cut: longer than {LINE_CAP_BYTES} bytes]")),
            "{}",
            lines[0]
        );
        assert_eq!(lines[1], "next line");
    }

    #[test]
    fn a_stream_that_starts_between_steps_misses_no_step() {
        let ms = 1_000_000;
        // The first sample 0.7 ms after the reset, then every step: nothing missed (the gap to
        // the first step, 0.3 ms, is not the step).
        assert_eq!(steps_missed_between(700_000, ms, ms), 0);
        assert_eq!(steps_missed_between(ms, 2 * ms, ms), 0);
        // Steps 2 and 3 ms did not come.
        assert_eq!(steps_missed_between(ms, 4 * ms, ms), 2);
        // From between steps past one: 1 ms did not come.
        assert_eq!(steps_missed_between(300_000, 2 * ms, ms), 1);
        // A sample between steps after a step (a stream never sends one, but it is no gap).
        assert_eq!(steps_missed_between(2 * ms, 2 * ms + 500_000, ms), 0);
    }

    #[tokio::test]
    async fn lines_are_kept_as_printed_and_a_long_one_says_it_was_cut() {
        let tail = Arc::new(Mutex::new(VecDeque::new()));
        let long = "y".repeat(TAIL_LINE_CHARS + 5);
        let text = format!("first\r\nnot utf-8 \u{fffd}\n{long}\nlast without newline");
        let mut bytes = text.into_bytes();
        bytes.extend_from_slice(b"\xff");
        keep_tail(&bytes[..], tail.clone()).await;
        let lines: Vec<String> =
            tail.lock().unwrap_or_else(PoisonError::into_inner).iter().cloned().collect();
        assert_eq!(lines[0], "first");
        assert_eq!(lines[1], "not utf-8 \u{fffd}");
        assert!(
            lines[2].ends_with(&format!("[line cut: longer than {TAIL_LINE_CHARS} characters]")),
            "{}",
            lines[2]
        );
        assert_eq!(lines[3], "last without newline\u{fffd}");
    }
}
