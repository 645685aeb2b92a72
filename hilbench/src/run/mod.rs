//! What a run is and what is known of it once flown, whichever driver flew it: the [`Job`]
//! (scenario and controller), the [`FinishedRun`] the outputs are written from, and its facts
//! (where the time went, faults, the delays in force, an external controller's process, the
//! per-cycle rows). Plain data: this module imports no other module of the crate.

use mav::Scenario;
use mpc::{ControllerMode, CycleRecord, RunSummary};

mod verdict;
pub use verdict::Verdict;

/// A run to make: a scenario and the controller to fly it with.
#[derive(Debug, Clone, PartialEq)]
pub struct Job {
    pub scenario: Scenario,
    pub controller: Controller,
}

/// The controller a run flies.
#[derive(Debug, Clone, PartialEq)]
pub enum Controller {
    /// The bench's NMPC (`mpc`), in this mode.
    Bench(ControllerMode),
    /// The user's process (`--controller-cmd`): its command line, run with `sh -c`.
    External(String),
}

/// The name of an external controller in the outputs (`RunSummary::controller`, `runs.csv`,
/// its CSV log's name).
pub const EXTERNAL_CONTROLLER: &str = "external";

impl Controller {
    /// The controllers of a command: the user's when it gives one (one flight a run), else
    /// the bench's in each of `modes`.
    pub fn of(controller_cmd: Option<&str>, modes: &[ControllerMode]) -> Vec<Controller> {
        match controller_cmd {
            Some(command) => vec![Controller::External(command.to_string())],
            None => modes.iter().map(|&m| Controller::Bench(m)).collect(),
        }
    }

    /// As the outputs name it: the mode's name, or [`EXTERNAL_CONTROLLER`].
    pub fn name(&self) -> &'static str {
        match self {
            Controller::Bench(mode) => mode.name(),
            Controller::External(_) => EXTERNAL_CONTROLLER,
        }
    }

    /// The bench's controller's mode.
    pub fn mode(&self) -> Option<ControllerMode> {
        match self {
            Controller::Bench(mode) => Some(*mode),
            Controller::External(_) => None,
        }
    }

    /// The external controller's command line.
    pub fn command(&self) -> Option<&str> {
        match self {
            Controller::Bench(_) => None,
            Controller::External(command) => Some(command),
        }
    }
}

/// The runs of one command, in the order of their jobs.
#[derive(Debug, Clone)]
pub struct Batch {
    /// Every run that finished, and last the one that failed part-way (its `error` set) when
    /// it had flown at least one cycle.
    pub runs: Vec<FinishedRun>,
    /// The error that ended the command early (a run that failed: a service died, a trace ran
    /// out, the controller stopped, ...): no later run started.
    pub error: Option<RunError>,
    /// Ctrl-C stopped the command: `runs` holds the runs that finished before it.
    pub interrupted: bool,
    /// The driver's `summary.json` name (`transport`).
    pub driver: &'static str,
    pub time_mode: mav::TimeMode,
    pub wall_time_s: f64,
}

impl Batch {
    pub fn any_collided(&self) -> bool {
        self.runs.iter().any(|r| r.summary.collided)
    }

    /// The runs that finished (the failed one left out).
    pub fn finished(&self) -> impl Iterator<Item = &FinishedRun> {
        self.runs.iter().filter(|r| r.error.is_none())
    }

    /// Every run's summary, in order.
    pub fn summaries(&self) -> Vec<mpc::RunSummary> {
        self.runs.iter().map(|r| r.summary.clone()).collect()
    }

    /// Solver time summed over every run, s.
    pub fn solver_s(&self) -> f64 {
        total(self.runs.iter().map(|r| r.summary.solver_s))
    }
}

/// The sum of `values`, `0.0` for none. Rust's `Sum` of `f64` starts at `-0.0` (the identity
/// of IEEE addition), so a sum of nothing, or of `-0.0`s such as an external controller's
/// solver time, printed as "-0.0"; every time the bench adds up goes through here.
pub fn total(values: impl IntoIterator<Item = f64>) -> f64 {
    values.into_iter().fold(0.0, |a, b| a + b)
}

/// Where a run's cycles also go as they arrive (the live Foxglove view of `--foxglove-ws`).
pub trait CycleSink: Send + Sync + std::fmt::Debug {
    /// One cycle of a run of `scenario`.
    fn cycle(&self, scenario: &Scenario, record: &CycleRecord);
}

/// A run as flown (or, when `error` is set, as far as it flew before it failed).
#[derive(Debug, Clone)]
pub struct FinishedRun {
    pub job: Job,
    pub summary: RunSummary,
    /// The per-cycle rows (the CSV log).
    pub rows: Vec<CycleRow>,
    /// The controller's records, predicted trajectories included (the MCAP log); none for an
    /// external controller, which has no telemetry.
    pub records: Vec<CycleRecord>,
    /// Where the wall time went (runs over services only).
    pub timing: Option<RunTiming>,
    pub faults: RunFaults,
    pub delay_profile: DelayProfileInForce,
    /// What flew the run: the plant's `Describe` (`PlantDescription.implementation`: the
    /// simulated plant, or a gateway naming its vehicle and firmware, e.g. `BTFL 4.6.0`), or
    /// [`IN_PROCESS_PLANT`] (`summary.json`'s `plant`).
    pub plant: String,
    /// What the external controller's process did (`None` for the bench's controller).
    pub external: Option<ExternalFacts>,
    /// The error that stopped the run part-way (its `end_reason` is then "error").
    pub error: Option<String>,
}

impl FinishedRun {
    /// The name of the controller flown: the job's mode, or the external controller's.
    pub fn controller(&self) -> &str {
        &self.summary.controller
    }
}

/// The plant of an in-process run (`summary.json`'s `plant`).
pub const IN_PROCESS_PLANT: &str = "in-process model (mav's 8-state MAV, lockstep)";

/// What delayed the run's messages: `summary.json`'s `delay_profile` (a stable key).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DelayProfileInForce {
    pub source: DelaySource,
    /// The process, as a `[scenario.delays]` table (seeds aside: `scenario.seed` or netem's);
    /// a trace read from a file is named by its file, its delays left out.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub delays: Option<delay::DelaysTable>,
}

impl DelayProfileInForce {
    /// The table of `network`, traces from files named rather than listed.
    pub fn of(source: DelaySource, network: &delay::NetworkProfile) -> Self {
        fn name_only(t: &mut delay::DelaysTable) {
            if t.file.is_some() {
                t.delays_s = None;
            }
        }
        let mut table = delay::DelaysTable::from_network(network);
        name_only(&mut table);
        for direction in [&mut table.to_plant, &mut table.to_controller].into_iter().flatten() {
            name_only(direction);
        }
        Self { source, delays: Some(table) }
    }

    /// No netem between the controller and the plant.
    pub fn none() -> Self {
        Self { source: DelaySource::None, delays: None }
    }
}

/// Where the delays of a run came from (`summary.json`'s `delay_profile.source`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DelaySource {
    /// The scenario's `[scenario.delays]` (set on netem, or run in process).
    Scenario,
    /// The profile a netem running elsewhere had, left alone (`--keep-netem-profile`, or a
    /// scenario that does not describe its network).
    Netem,
    /// No netem between the controller and the plant (the link's own delays, unknown to the
    /// bench).
    None,
}

/// Faults of a run: its plant link's outages, the plant's watchdog and resets, from the
/// controller's status, the telemetry and the plant's last sample (all zero when nothing
/// failed; the `summary.json` keys of docs/output.md's schema).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct RunFaults {
    /// Outages of the controller's link to the Plant API during the episode: failed calls, or in
    /// real time no completed cycle for longer than the controller's stall timeout.
    pub link_losses: u64,
    /// Wall time from the last completed cycle before each outage to the first after it (the
    /// time to notice included), summed over the outages, s.
    pub link_down_s: f64,
    /// The longest outage, s.
    pub longest_link_down_s: f64,
    /// Cycles that started from a sample in which the plant's watchdog held hover (no command
    /// for longer than its timeout: in real time, the cycles after an outage until their first
    /// command has crossed the delays).
    pub watchdog_cycles: u64,
    /// Plant time the plant's watchdog held hover during the run, s (the plant's own count,
    /// cycles or none).
    pub watchdog_hover_s: f64,
    /// The plant was reset or restarted under the run (which then failed).
    pub plant_resets: u64,
    /// Plant time of the run's last sample before the reset, s (0 without one).
    pub plant_reset_time_s: f64,
}

impl RunFaults {
    /// Adds the keys to a run's `summary.json` entry.
    pub fn add_to(&self, entry: &mut serde_json::Value) {
        if let (Some(entry), serde_json::Value::Object(keys)) =
            (entry.as_object_mut(), serde_json::json!(self))
        {
            entry.extend(keys);
        }
    }
}

/// Whose doing it was that a run stopped before its end: it decides what a sweep or a
/// falsification makes of the run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RunErrorKind {
    /// The controller stopped the run: it ended its episode with an error (a problem it could
    /// not solve), froze, went away, exited early or stopped stepping the plant. A failure of
    /// the controller, and so of any property asked of it.
    Controller,
    /// Anything else: a trace that ran out, a plant or netem that died, a run that could not
    /// start.
    Bench,
}

/// Why a run stopped before its end, in words, and whose doing it was.
#[derive(Debug, Clone, PartialEq)]
pub struct RunError {
    pub kind: RunErrorKind,
    pub message: String,
}

impl RunError {
    pub fn bench(message: impl Into<String>) -> Self {
        Self { kind: RunErrorKind::Bench, message: message.into() }
    }

    pub fn controller(message: impl Into<String>) -> Self {
        Self { kind: RunErrorKind::Controller, message: message.into() }
    }

    /// The error of a driver's run, `what` in front: the controller's when a
    /// [`ControllerStopped`] is in its chain.
    pub fn of(what: &str, error: &anyhow::Error) -> Self {
        let kind = if error.chain().any(|e| e.is::<ControllerStopped>()) {
            RunErrorKind::Controller
        } else {
            RunErrorKind::Bench
        };
        Self { kind, message: format!("{what}: {error:#}") }
    }

    /// The controller stopped the run.
    pub fn is_controllers(&self) -> bool {
        self.kind == RunErrorKind::Controller
    }
}

impl std::fmt::Display for RunError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

/// In `summary.json` a run's error is its message.
impl serde::Serialize for RunError {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(&self.message)
    }
}

/// A driver's error that says the controller stopped the run ([`RunErrorKind::Controller`]).
#[derive(Debug)]
pub struct ControllerStopped(pub String);

impl std::fmt::Display for ControllerStopped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ControllerStopped {}

/// A run that failed part-way: the error, and what it flew before it (`None` when it failed
/// before its first cycle). The partial run's summary ends with `end_reason` "error", from the
/// last sample its telemetry carried. `R` is the run: the bench's controller's
/// (`drive::grpc::GrpcRun`) or an external one's (`drive::external::ExternalRun`).
#[derive(Debug)]
pub struct RunFailure<R> {
    pub error: anyhow::Error,
    pub partial: Option<Box<R>>,
}

impl<R> std::fmt::Display for RunFailure<R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:#}", self.error)
    }
}

impl<R: std::fmt::Debug> std::error::Error for RunFailure<R> {}

impl<R> From<anyhow::Error> for RunFailure<R> {
    fn from(error: anyhow::Error) -> Self {
        Self { error, partial: None }
    }
}

/// Where the wall time of a run went.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct RunTiming {
    /// Starting the three services, connecting and subscribing, s.
    pub setup_s: f64,
    /// From `SetScenario` to the end of the episode (all cycles), s.
    pub episode_s: f64,
    /// Sum of the controller's solve times (from telemetry), s; part of `episode_s`.
    pub solver_s: f64,
    /// Stopping the services, s.
    pub teardown_s: f64,
}

impl RunTiming {
    /// The rest of the episode: gRPC round trips, netem, plant integration, telemetry.
    pub fn loop_overhead_s(&self) -> f64 {
        (self.episode_s - self.solver_s).max(0.0)
    }

    pub fn total_s(&self) -> f64 {
        self.setup_s + self.episode_s + self.teardown_s
    }
}

/// What `summary.json` says of the external controller of a run (`external_controller`).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ExternalFacts {
    /// The command line.
    pub command: String,
    /// How its process ended: `stopped by the bench` (SIGTERM after the run ended), `killed by
    /// the bench` (SIGKILL: it outlived the grace, or the run failed), or its own exit
    /// (`exited: exit status: 1`) when that came first.
    pub exit: String,
    /// Commands the plant applied, as seen at its steps (one replaced within a step is not
    /// seen); the CSV has a row for each.
    pub commands_applied: u64,
    /// Commands netem drew a delay for before the end of the run: each took one entry of a
    /// trace, so a failure's trace keeps this many to replay; commands still in flight at the
    /// end are among them, and not in `commands_applied`. In lockstep those sent at plant times
    /// before the end's (`NetemControl.CommandsSentBefore`), the same for identical runs
    /// whatever the controller sent after the end; in real time netem's count of commands sent
    /// as soon as the end is judged (`GetStats`), which can exceed them (the controller goes on
    /// until it is stopped) and never falls short. `None` when netem could not be asked.
    pub commands_delayed: Option<u64>,
    /// Commands netem refused to the controller as invalid (`INVALID_ARGUMENT`: a NaN, a value
    /// out of range, a wrong length), never delayed nor applied; `None` when netem could not be
    /// asked.
    pub commands_refused: Option<u64>,
    /// Of them, commands the plant clipped at its actuator limits.
    pub commands_saturated: u64,
    /// Plant steps judged (samples of the plant's stream up to the end of the run).
    pub plant_steps_judged: u64,
    /// Plant steps the bench's stream missed (its buffer holds the whole run, so 0 unless a
    /// single call advanced further than that); the end is then judged at the next step seen.
    pub plant_steps_missed: u64,
}

/// One control cycle: a row of the CSV log (`output::cycle_log`).
#[derive(Debug, Clone, PartialEq)]
pub struct CycleRow {
    pub cycle: u64,
    /// Plant time of the sample the controller solved from, s.
    pub t_s: f64,
    pub state: [f64; 8],
    pub command: [f64; 3],
    /// The command's sequence number (`Command.command_seq`).
    pub command_seq: u64,
    /// The round-trip delay the controller knew at this cycle (that of the previous command,
    /// measured from plant stamps), s; 0 before the first measurement.
    pub known_delay_s: f64,
    /// The delay the network put on this cycle's command (netem's stamp, or the in-process
    /// delay line's draw), s; `None` (an empty cell) when the command was lost.
    pub injected_delay_s: Option<f64>,
    pub weights: Vec<f64>,
    pub status: String,
    pub iterations: u64,
    pub solve_ms: f64,
    pub cost: f64,
    pub constraint_violation: f64,
    pub predicted_clearance_m: f64,
    /// What the safety layer sent: `panoc`, `qp`, `shifted_plan`, `brake`, or `best_effort`
    /// when no candidate passed its checks (empty when the layer is off).
    pub decision: String,
    /// Why, in one line: the rejected candidates before the one sent (empty when the layer is
    /// off).
    pub reason: String,
    /// QP cost minus PANOC cost on the nonlinear model, when the cross-check ran.
    pub cost_gap: Option<f64>,
}

/// The rows of a run's records (the same from a gRPC run and an in-process one).
pub fn rows_of(records: &[CycleRecord]) -> Vec<CycleRow> {
    records
        .iter()
        .map(|r| CycleRow {
            cycle: r.cycle,
            t_s: r.t_s(),
            state: r.state,
            command: r.command,
            command_seq: r.command_seq,
            known_delay_s: r.known_delay_s.unwrap_or(0.0),
            injected_delay_s: r.injected_delay_s,
            weights: r.weights.clone(),
            status: r.solve.status.name().to_string(),
            iterations: r.solve.iterations,
            solve_ms: r.solve.solve_ms,
            cost: r.solve.cost,
            constraint_violation: r.solve.constraint_violation,
            predicted_clearance_m: r.solve.min_clearance_m,
            decision: r.decision_label().to_string(),
            reason: r.reason.clone(),
            cost_gap: r.cost_gap,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::{Controller, EXTERNAL_CONTROLLER, total};
    use mpc::ControllerMode;

    #[test]
    fn a_commands_controllers_are_the_users_alone_or_the_benchs_in_each_mode_and_name_themselves() {
        let modes = [ControllerMode::Nmpc, ControllerMode::Multistage];
        let bench = Controller::of(None, &modes);
        assert_eq!(
            bench,
            [Controller::Bench(ControllerMode::Nmpc), Controller::Bench(ControllerMode::Multistage)]
        );
        assert_eq!(bench.iter().map(Controller::name).collect::<Vec<_>>(), ["nmpc", "multistage"]);
        assert!(bench.iter().all(|c| c.command().is_none() && c.mode().is_some()));
        // The user's controller flies once a run, whatever the modes; it has no mode.
        let users = Controller::of(Some("python3 ctl.py"), &modes);
        assert_eq!(users, [Controller::External("python3 ctl.py".into())]);
        assert_eq!(
            (users[0].name(), users[0].command(), users[0].mode()),
            (EXTERNAL_CONTROLLER, Some("python3 ctl.py"), None)
        );
    }

    #[test]
    fn a_total_of_nothing_or_of_negative_zeros_prints_as_zero_not_minus_zero() {
        // An external controller's sweep printed "solver -0.0 s": `Sum` of no f64 is -0.0.
        assert_eq!(format!("{:.1}", [0.0f64; 0].iter().sum::<f64>()), "-0.0");
        assert_eq!(format!("{:.1}", total([])), "0.0");
        assert_eq!(format!("{:.1}", total([-0.0, -0.0])), "0.0");
        assert_eq!(total([0.25, 0.5]), 0.75);
    }
}
