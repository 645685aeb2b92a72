//! The control loop, written once: an [`Episode`] takes each state sample of the plant and
//! returns the command to send, whoever carries the two (the in-process loop of
//! [`crate::closed_loop`] with `mav::PlantSim` and `delay::DelayLine`, or the controller
//! service over gRPC). One cycle is the paper's whole idea:
//!
//! delay measured from the sample's stamps → delay window → Gamma fit → scenario weights →
//! PANOC → safety layer → the one command sanitiser → command stamped with its sample.
//!
//! Both drivers hand over the same `mav::PlantSample` and get the same [`CycleOutput`], so a
//! gRPC run and an in-process run are bit-identical by construction (the contract test in
//! `tests` checks it end to end).
//!
//! Delays are measured from plant stamps only: a sample's `last_command` says which command
//! was applied at which plant time and which sample it was computed from, so
//! `applied_time - based_on_sample_time` is the whole round trip, in whole nanoseconds, as a
//! real vehicle gateway can report it too.
//!
//! Time is passed in (the sample's plant time, the solve budget); nothing here reads a clock.

use std::collections::VecDeque;

use mav::{CommandMeta, PlantSample, Scenario, ns_to_s, s_to_ns};

use crate::cycle::{CycleController, CycleOutcome};
use crate::delays::{GammaParams, ScenarioWeights, WeightSettings};
use crate::end::{RunEnd, finish_at};
use crate::error::MpcError;
use crate::fail_safe::InFlight;
use crate::problem::{ControllerMode, OcpDefinition};
use crate::record::CycleRecord;
use crate::safety::SafetySettings;
use crate::solver::{MpcSettings, SolveBudget};

/// How an episode's controller is built: everything but the scenario.
#[derive(Debug, Clone)]
pub struct EpisodeSettings {
    pub mode: ControllerMode,
    pub mpc: MpcSettings,
    /// The safety layer (cross-check and selection), adapted to each scenario by
    /// [`SafetySettings::for_scenario`]; `None` sends PANOC's input as it is (clipped), like
    /// the paper's controller.
    pub safety: Option<SafetySettings>,
    /// The safety layer's fail-safe check for every scenario, whether or not the scenario asks
    /// for it (the controller's `--fail-safe`).
    pub fail_safe: bool,
    /// The plant's braking watchdog, s (what its `Describe` says): the fail-safe check counts
    /// on a command never being held longer ([`crate::fail_safe::BrakingCheck::plant_watchdog_s`]).
    /// Default: the bench's plants' (`mav::DEFAULT_WATCHDOG_TIMEOUT_NS`, braking).
    pub plant_watchdog_s: Option<f64>,
    /// Whether round-trip delays are expected: the multi-stage weights are then the Gamma fit of
    /// the measured delays, otherwise the scenario's nominal weights.
    pub delays_expected: bool,
    /// A fault forced on PANOC (tests of the fallbacks).
    pub fault: Option<crate::cycle::FaultInjection>,
}

impl EpisodeSettings {
    /// `mode` with `mpc`, the default safety layer, no forced fail-safe check, no delays
    /// expected.
    pub fn new(mode: ControllerMode, mpc: MpcSettings) -> Self {
        Self {
            mode,
            mpc,
            safety: Some(SafetySettings::default()),
            fail_safe: false,
            plant_watchdog_s: Some(mav::ns_to_s(mav::DEFAULT_WATCHDOG_TIMEOUT_NS)),
            delays_expected: false,
            fault: None,
        }
    }
}

/// How the cycle is timed, which decides the solve budget and what is in flight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CycleTiming {
    /// The driver advances plant time and waits for each command to land before the next
    /// sample: iteration budgets only, so that runs are bit-identical, and nothing in flight.
    Lockstep,
    /// The plant runs on its clock: the solve gets a wall-clock deadline, and the commands sent
    /// but not yet seen applied are handed to the safety layer's fail-safe check.
    RealTime { deadline: std::time::Duration },
}

/// What one cycle decided.
#[derive(Debug, Clone)]
pub struct CycleOutput {
    /// What the cycle logs (state, command, weights, solve, decision); `predictions` empty
    /// (see [`Episode::predictions`]).
    pub record: CycleRecord,
    /// The stamps to send with the command.
    pub meta: CommandMeta,
    /// PANOC's full report and the safety layer's selection.
    pub outcome: CycleOutcome,
}

/// Commands remembered as in flight at most (older ones were lost on the link).
const MAX_IN_FLIGHT: usize = 64;

/// One flight of one scenario: the cycle controller, the scenario weights, the delay
/// measurement from stamps, the commands in flight, the command numbering.
///
/// ## Memory allocation
/// The cycle controller's workspaces (see [`CycleController`]), the delay window and two
/// in-flight buffers of [`MAX_IN_FLIGHT`], allocated in [`Episode::new`]; each cycle allocates
/// only its record's weight vector.
pub struct Episode {
    scenario: Scenario,
    settings: EpisodeSettings,
    controller: CycleController,
    weights: ScenarioWeights,
    /// Commands sent (the last one's `command_seq`).
    command_seq: u64,
    /// The newest command whose delay was measured.
    measured_seq: u64,
    cycle: u64,
    /// The last delay measured from stamps, s.
    last_delay_s: Option<f64>,
    /// Real time: commands sent and not yet seen applied, oldest first, as
    /// `(command_seq, time of the sample they came from, ns, command)`.
    sent: VecDeque<(u64, u64, [f64; 3])>,
    in_flight: Vec<InFlight>,
    hover: [f64; 3],
    min_cycle_ns: u64,
    /// The plant's flight id of the episode's first sample, and the plant time of the last
    /// sample of that flight (`None` before the first sample).
    flight: Option<(u64, u64)>,
}

impl Episode {
    /// An episode of `scenario` (validated here); nothing has flown yet.
    pub fn new(scenario: Scenario, settings: EpisodeSettings) -> Result<Self, MpcError> {
        scenario.validate().map_err(|e| MpcError::InvalidProblem(e.to_string()))?;
        let controller = build_controller(&scenario, &settings)?;
        let weights = scenario_weights(
            &scenario,
            settings.mode,
            settings.delays_expected,
            &controller.definition().sampling_times_s,
        );
        let hover = scenario.model.hover_input();
        let min_cycle_ns = s_to_ns(scenario.min_cycle_s).unwrap_or(50_000_000).max(1);
        Ok(Self {
            hover: [hover[0], hover[1], hover[2]],
            scenario,
            settings,
            controller,
            weights,
            command_seq: 0,
            measured_seq: 0,
            cycle: 0,
            last_delay_s: None,
            sent: VecDeque::with_capacity(MAX_IN_FLIGHT),
            in_flight: Vec::with_capacity(MAX_IN_FLIGHT),
            min_cycle_ns,
            flight: None,
        })
    }

    pub fn scenario(&self) -> &Scenario {
        &self.scenario
    }

    pub fn mode(&self) -> ControllerMode {
        self.settings.mode
    }

    pub fn controller(&self) -> &CycleController {
        &self.controller
    }

    /// Commands sent so far (the last one's `command_seq`).
    pub fn commands_sent(&self) -> u64 {
        self.command_seq
    }

    /// Real time: the commands the last cycle counted as in flight (sent, not yet seen
    /// applied), which the fail-safe check flew first. Empty in lockstep.
    pub fn in_flight(&self) -> &[InFlight] {
        &self.in_flight
    }

    /// Cycles run so far.
    pub fn cycles(&self) -> u64 {
        self.cycle
    }

    /// The shortest cycle (`min_cycle_s`), ns: the next sample comes at
    /// `t_k + max(min_cycle, d_k)`.
    pub fn min_cycle_ns(&self) -> u64 {
        self.min_cycle_ns
    }

    /// The scenario weights the next cycle will use.
    pub fn weights(&self) -> &[f64] {
        self.weights.weights()
    }

    /// The last round-trip delay measured from stamps, s (`None` before the first).
    pub fn last_delay_s(&self) -> Option<f64> {
        self.last_delay_s
    }

    /// Whether `sample` ends the episode: after a collision (unless the scenario asks to go on),
    /// at the goal, or at the time limit. A driver in
    /// lockstep stops there; one in real time keeps holding the goal (a vehicle must not be left
    /// uncontrolled) and only reports it.
    pub fn finish(&self, sample: &PlantSample) -> Option<RunEnd> {
        finish_at(&self.scenario, sample)
    }

    /// A new goal from the next cycle on. Refused, with nothing changed, when it cannot be the
    /// scenario's goal. The controller is rebuilt around it (a fresh warm start: the old plan
    /// flew elsewhere); the delay window and the command numbering go on.
    pub fn set_goal(&mut self, goal_m: [f64; 3]) -> Result<(), MpcError> {
        self.scenario.check_goal(goal_m).map_err(|e| MpcError::InvalidProblem(e.to_string()))?;
        let mut scenario = self.scenario.clone();
        scenario.goal_m = goal_m;
        self.controller = build_controller(&scenario, &self.settings)?;
        self.scenario = scenario;
        Ok(())
    }

    /// The link to the plant was lost: what was sent over it has landed or is lost with it, and
    /// after a reconnection the plant's stamps say what is applied (a restarted plant's clock
    /// starts again at 0, which would make the old commands look just sent).
    pub fn forget_in_flight(&mut self) {
        self.sent.clear();
    }

    /// Refuses a sample of another flight than the episode's first sample (a plant that does
    /// not number its flights, id 0, is not checked); `Ok` records the sample's time.
    pub fn check_flight(&mut self, sample: &PlantSample) -> Result<(), MpcError> {
        match &mut self.flight {
            None => self.flight = Some((sample.flight_id, sample.time_ns)),
            Some((id, last_ns)) if *id == sample.flight_id || *id == 0 || sample.flight_id == 0 => {
                *last_ns = (*last_ns).max(sample.time_ns);
            }
            Some((_, last_ns)) => {
                return Err(MpcError::PlantReset {
                    last_time_s: ns_to_s(*last_ns),
                    time_s: ns_to_s(sample.time_ns),
                });
            }
        }
        Ok(())
    }

    /// Runs one cycle from `sample`: measures the delay of the last command from its stamps,
    /// updates the weights, solves, selects and sanitises the command, and numbers it. `Err`
    /// only for an instance the solver refuses (nothing flown changes).
    pub fn on_sample(&mut self, sample: &PlantSample, timing: &CycleTiming) -> Result<CycleOutput, MpcError> {
        self.check_flight(sample)?;
        let last = &sample.last_command;
        if !last.initial
            && last.meta.command_seq > self.measured_seq
            && last.meta.command_seq <= self.command_seq
        {
            let delay_s = ns_to_s(last.applied_time_ns.saturating_sub(last.meta.based_on_sample_time_ns));
            self.weights.observe(delay_s);
            self.last_delay_s = Some(delay_s);
            self.measured_seq = last.meta.command_seq;
        }
        let x0: [f64; 8] = sample.state.into();
        let u_prev: [f64; 3] =
            if last.input.iter().all(|v| v.is_finite()) { last.input.into() } else { self.hover };
        let budget = match timing {
            CycleTiming::Lockstep => SolveBudget::default(),
            CycleTiming::RealTime { deadline } => {
                // What was sent and not seen applied is still on its way (the fail-safe check
                // flies it; lockstep waits for each command to land, so nothing is in flight).
                let applied_seq = if last.initial { 0 } else { last.meta.command_seq };
                self.sent.retain(|(seq, _, _)| *seq > applied_seq);
                self.in_flight.clear();
                self.in_flight.extend(self.sent.iter().map(|(_, sent_ns, command)| InFlight {
                    sent_ago_s: ns_to_s(sample.time_ns.saturating_sub(*sent_ns)),
                    command: *command,
                }));
                self.controller.set_in_flight(Some(&self.in_flight));
                SolveBudget { deadline: Some(*deadline), ..SolveBudget::default() }
            }
        };
        // The fail-safe check covers the delays this link has shown, the tail beyond the
        // scenario tree's largest sampling time included.
        self.controller.cover_delays_up_to(self.weights.window().max_s());
        let weights = self.weights.weights().to_vec();
        let outcome = self.controller.step(self.cycle, sample.time_ns, &x0, &u_prev, &weights, &budget)?;
        // Finite and inside the bounds by construction (the cycle controller sanitises); the
        // record says what leaves.
        let command = outcome.command;
        self.command_seq += 1;
        if matches!(timing, CycleTiming::RealTime { .. }) {
            if self.sent.len() == MAX_IN_FLIGHT {
                self.sent.pop_front();
            }
            self.sent.push_back((self.command_seq, sample.time_ns, command));
        }
        let meta = CommandMeta {
            command_seq: self.command_seq,
            based_on_sample_seq: sample.seq,
            based_on_sample_time_ns: sample.time_ns,
        };
        let record = CycleRecord::of_cycle(
            self.cycle,
            sample,
            command,
            self.command_seq,
            self.last_delay_s,
            weights,
            &outcome,
        );
        self.cycle += 1;
        Ok(CycleOutput { record, meta, outcome })
    }

    /// Predicted positions of every scenario under the plan selected in the last cycle, with
    /// each scenario's sampling time and the weight it had in that cycle's solve.
    pub fn predictions(&self, weights: &[f64]) -> Vec<crate::record::PredictedPath> {
        let ts = &self.controller.definition().sampling_times_s;
        self.controller
            .predictions()
            .iter()
            .zip(ts)
            .zip(weights)
            .map(|((traj, &sampling_time_s), &weight)| crate::record::PredictedPath {
                sampling_time_s,
                weight,
                positions_m: traj.iter().map(|s| [s[0], s[1], s[2]]).collect(),
            })
            .collect()
    }
}

/// The controller of `scenario`: its optimal control problem, its solver, and the safety layer
/// adapted to it (the scenario's margin, floor, fail-safe check and PANOC).
fn build_controller(scenario: &Scenario, settings: &EpisodeSettings) -> Result<CycleController, MpcError> {
    let def = OcpDefinition::from_scenario(
        scenario,
        settings.mode,
        settings.mpc.obstacle_margin_m,
        settings.mpc.formulation,
    );
    let safety = settings.safety.map(|s| {
        s.with_fail_safe(scenario, settings.fail_safe || scenario.fail_safe)
            .with_plant_watchdog(settings.plant_watchdog_s)
    });
    // The scenario may pin whose PANOC solves it; otherwise the controller's own setting.
    let mpc = MpcSettings { solver: scenario.solver.unwrap_or(settings.mpc.solver), ..settings.mpc };
    let controller = CycleController::new(def, mpc, safety)?;
    let controller = controller.with_fault(settings.fault);
    Ok(controller)
}

/// The weights of `mode`: fixed 1 for the standard NMPC; for the multi-stage controller the
/// nominal weights when no delays are expected, otherwise the Gamma fit of measured delays
/// (the scenario's prior until the window has enough of them).
pub fn scenario_weights(
    scenario: &Scenario,
    mode: ControllerMode,
    delays_expected: bool,
    sampling_times_s: &[f64],
) -> ScenarioWeights {
    let settings = WeightSettings {
        window: scenario.delay_window,
        prior: GammaParams { shape: scenario.prior_gamma.0, scale_s: scenario.prior_gamma.1 },
        ..WeightSettings::default()
    };
    match mode {
        ControllerMode::Nmpc => ScenarioWeights::new(settings, sampling_times_s, Some(&[1.0])),
        ControllerMode::Multistage if !delays_expected => {
            ScenarioWeights::new(settings, sampling_times_s, Some(&scenario.nominal_weights))
        }
        ControllerMode::Multistage => ScenarioWeights::new(settings, sampling_times_s, None),
    }
}
