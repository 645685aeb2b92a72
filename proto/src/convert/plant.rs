//! Conversions of the plant API messages (see the module above for the rules).
//!
//! Incoming requests (`Command`, `ResetRequest`, `AdvanceRequest`, `StepRequest`,
//! `StreamStateRequest`) become the validated types below or `mav` types; outgoing core values
//! (`mav::PlantSample`, `mav::AppliedCommand`, ...) become messages. For clients of the plant
//! API (controller, netem, bench CLI) the replies convert back with the same checks.
//!
//! Range policy for commands: a command inside the plausible ranges below but outside the
//! scenario's actuator limits is *saturated* by the plant (and reported as `saturated`); a
//! command outside the plausible ranges (negative thrust, a tilt of 90 degrees or more, ...) is a
//! bug in the sender and is refused with the field named.

use super::{FieldError, finite, finite_array, required};
use crate::pb;
use mav::{
    AppliedCommand, CollisionEvent, CollisionKind, CommandMeta, Cylinder, Input, InputBounds, ModelParams,
    PlantSample, Scenario, SimSettings, State,
};

pub use super::MAX_THRUST_MPS2;
pub use mav::{MAX_ABS_ANGLE_RAD, MAX_ABS_POSITION_M, MAX_ABS_VELOCITY_MPS};
/// Longest plant-time advance of one request, ns (one hour of plant time).
pub const MAX_ADVANCE_NS: u64 = 3_600 * 1_000_000_000;

const STATE_NAMES: [&str; 8] = ["px", "py", "pz", "vx", "vy", "vz", "phi", "theta"];

fn out_of_range(field: &str, v: f64, range: &str) -> FieldError {
    FieldError::new(field, format!("must be in {range}, got {}", delay::Number(v)))
}

// ---------------------------------------------------------------------------------------------
// Incoming

/// A validated command: the input as requested (saturation is the plant's job) and its origin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    pub input: Input,
    pub meta: CommandMeta,
}

/// A validated `ResetRequest`.
#[derive(Debug, Clone, PartialEq)]
pub struct Reset {
    /// Scenario to load by name; `None` keeps the current one. The name is not resolved here:
    /// the plant knows its catalogue (see [`scenario_by_name`] for the built-in one).
    pub scenario: Option<String>,
    /// A whole scenario to load (validated; `scenario` is then its name or `None`).
    pub definition: Option<Scenario>,
    /// Start state overriding the scenario's.
    pub initial_state: Option<State>,
}

/// A validated `StepRequest`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step {
    pub command: Option<Command>,
    /// Plant time to advance after applying the command, ns; 0 = apply and read only.
    pub duration_ns: u64,
}

/// A validated `StreamStateRequest`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamState {
    /// Emit the first step at or after each multiple of this, ns; 0 (or up to a step) = every
    /// step (`plant.proto`, `StreamStateRequest`).
    pub period_ns: u64,
}

/// A control input: finite, thrust in `[0, MAX_THRUST_MPS2]`, angles in
/// `(-MAX_ABS_ANGLE_RAD, MAX_ABS_ANGLE_RAD)`. `field` is the path of the `ControlInput`.
pub fn input_from_pb(field: &str, u: &pb::ControlInput) -> Result<Input, FieldError> {
    let [thrust, roll, pitch] = super::check_input(field, u)?;
    Ok(Input::new(thrust, roll, pitch))
}

/// A state of exactly 8 finite values (no range check: for samples reported by a plant).
pub fn state_from_pb(field: &str, s: &pb::MavState) -> Result<State, FieldError> {
    Ok(State::from(finite_array::<8>(&format!("{field}.x"), &s.x)?))
}

/// A state that a client asks the plant to start from: 8 finite values, positions within
/// `MAX_ABS_POSITION_M`, velocities within `MAX_ABS_VELOCITY_MPS`, angles within
/// `(-pi/2, pi/2)`. The error names the element, e.g. `initial_state.x[6]`.
pub fn initial_state_from_pb(field: &str, s: &pb::MavState) -> Result<State, FieldError> {
    let x = state_from_pb(field, s)?;
    check_state_envelope(|i| format!("{field}.x[{i}]"), &x.into())?;
    Ok(x)
}

/// Checks that a state of 8 values lies in the envelope of [`initial_state_from_pb`] (positions
/// within `MAX_ABS_POSITION_M`, velocities within `MAX_ABS_VELOCITY_MPS`, angles within
/// `(-pi/2, pi/2)`); the error names element `i` as `name(i)`. For states that come from a
/// user rather than from a plant (a reset, a logged problem for `controller solve`).
pub fn check_state_envelope(name: impl Fn(usize) -> String, x: &[f64; 8]) -> Result<(), FieldError> {
    for (i, v) in x.iter().enumerate() {
        let (ok, range) = match i {
            0..=2 => (v.abs() <= MAX_ABS_POSITION_M, "[-1e4, 1e4] m"),
            3..=5 => (v.abs() <= MAX_ABS_VELOCITY_MPS, "[-1e3, 1e3] m/s"),
            _ => (v.abs() < MAX_ABS_ANGLE_RAD, "(-pi/2, pi/2) rad"),
        };
        if !ok {
            return Err(out_of_range(&name(i), *v, &format!("{range} ({})", STATE_NAMES[i])));
        }
    }
    Ok(())
}

impl TryFrom<&pb::Command> for Command {
    type Error = FieldError;

    /// Field names are relative to the command (`input.thrust_mps2`); use
    /// [`FieldError::within`] when the command is nested.
    fn try_from(c: &pb::Command) -> Result<Self, FieldError> {
        let input = input_from_pb("input", required("input", &c.input)?)?;
        Ok(Self {
            input,
            meta: CommandMeta {
                command_seq: c.command_seq,
                based_on_sample_seq: c.based_on_sample_seq,
                based_on_sample_time_ns: c.based_on_sample_time_ns,
            },
        })
    }
}

impl TryFrom<&pb::ResetRequest> for Reset {
    type Error = FieldError;

    fn try_from(r: &pb::ResetRequest) -> Result<Self, FieldError> {
        let definition = match &r.definition {
            Some(_) => super::scenario::scenario_choice(
                "scenario",
                &r.scenario,
                "definition",
                r.definition.as_ref(),
            )?,
            None => None,
        };
        let scenario = match r.scenario.as_str() {
            "" => None,
            name if name.trim() != name || name.len() > 256 => {
                return Err(FieldError::new("scenario", format!("is not a scenario name: {name:?}")));
            }
            name => Some(name.to_string()),
        };
        let initial_state =
            r.initial_state.as_ref().map(|s| initial_state_from_pb("initial_state", s)).transpose()?;
        Ok(Self { scenario, definition, initial_state })
    }
}

/// A built-in scenario by name, or an error naming `field`.
pub fn scenario_by_name(field: &str, name: &str) -> Result<Scenario, FieldError> {
    Scenario::by_name(name).map_err(|e| FieldError::new(field, e.to_string()))
}

/// A duration in `(0, MAX_ADVANCE_NS]`, or an error naming `field`.
fn positive_duration(field: &str, ns: u64) -> Result<u64, FieldError> {
    if ns == 0 {
        return Err(FieldError::new(field, "must be > 0 ns"));
    }
    if ns > MAX_ADVANCE_NS {
        return Err(FieldError::new(field, format!("must be at most {MAX_ADVANCE_NS} ns (1 h), got {ns}")));
    }
    Ok(ns)
}

/// The duration of an `AdvanceRequest`: in `(0, MAX_ADVANCE_NS]` ns.
pub fn advance_duration_ns(r: &pb::AdvanceRequest) -> Result<u64, FieldError> {
    positive_duration("duration_ns", r.duration_ns)
}

impl TryFrom<&pb::StepRequest> for Step {
    type Error = FieldError;

    fn try_from(r: &pb::StepRequest) -> Result<Self, FieldError> {
        let command =
            r.command.as_ref().map(Command::try_from).transpose().map_err(|e| e.within("command"))?;
        let duration_ns = match r.duration_ns {
            0 => 0,
            ns => positive_duration("duration_ns", ns)?,
        };
        Ok(Self { command, duration_ns })
    }
}

impl TryFrom<&pb::StreamStateRequest> for StreamState {
    type Error = FieldError;

    /// Every period is valid: 0 means every integration step, anything else samples the first
    /// step at or after each of its multiples (a period shorter than the step gives every step).
    fn try_from(r: &pb::StreamStateRequest) -> Result<Self, FieldError> {
        Ok(Self { period_ns: r.period_ns })
    }
}

// ---------------------------------------------------------------------------------------------
// Outgoing

impl From<&State> for pb::MavState {
    fn from(x: &State) -> Self {
        Self { x: x.iter().copied().collect() }
    }
}

impl From<&Input> for pb::ControlInput {
    fn from(u: &Input) -> Self {
        Self { thrust_mps2: u[0], roll_rad: u[1], pitch_rad: u[2] }
    }
}

impl From<&Command> for pb::Command {
    fn from(c: &Command) -> Self {
        Self {
            input: Some((&c.input).into()),
            command_seq: c.meta.command_seq,
            based_on_sample_seq: c.meta.based_on_sample_seq,
            based_on_sample_time_ns: c.meta.based_on_sample_time_ns,
        }
    }
}

impl From<&AppliedCommand> for pb::AppliedCommand {
    fn from(a: &AppliedCommand) -> Self {
        Self {
            input: Some((&a.input).into()),
            command_seq: a.meta.command_seq,
            based_on_sample_seq: a.meta.based_on_sample_seq,
            based_on_sample_time_ns: a.meta.based_on_sample_time_ns,
            applied_time_ns: a.applied_time_ns,
            saturated: a.saturated,
            initial: a.initial,
        }
    }
}

impl From<CollisionKind> for pb::CollisionKind {
    fn from(k: CollisionKind) -> Self {
        match k {
            CollisionKind::Cylinder => Self::Cylinder,
            CollisionKind::Ground => Self::Ground,
        }
    }
}

impl From<&CollisionEvent> for pb::CollisionEvent {
    fn from(e: &CollisionEvent) -> Self {
        Self {
            kind: pb::CollisionKind::from(e.kind) as i32,
            obstacle_index: e.obstacle_index,
            time_ns: e.time_ns,
            position_m: e.position_m.to_vec(),
            penetration_m: e.penetration_m,
            depth_m: e.depth_m,
        }
    }
}

impl From<&PlantSample> for pb::StateSample {
    fn from(s: &PlantSample) -> Self {
        Self {
            seq: s.seq,
            time_ns: s.time_ns,
            state: Some((&s.state).into()),
            last_command: Some((&s.last_command).into()),
            watchdog_hover: s.watchdog_hover,
            collided: s.collided,
            min_clearance_m: s.min_clearance_m,
            path_length_m: s.path_length_m,
            collisions: s.collisions.iter().map(Into::into).collect(),
            watchdog_hover_ns: s.watchdog_hover_ns,
            flight_id: s.flight_id,
        }
    }
}

impl From<&Cylinder> for pb::Cylinder {
    fn from(c: &Cylinder) -> Self {
        Self { x_m: c.x_m, y_m: c.y_m, radius_m: c.radius_m, height_m: c.height_m }
    }
}

impl From<&ModelParams> for pb::ModelParameters {
    fn from(p: &ModelParams) -> Self {
        Self {
            gravity_mps2: p.gravity_mps2,
            drag_x_per_s: p.drag_x_per_s,
            drag_y_per_s: p.drag_y_per_s,
            drag_z_per_s: p.drag_z_per_s,
            tau_roll_s: p.tau_roll_s,
            tau_pitch_s: p.tau_pitch_s,
            gain_roll: p.gain_roll,
            gain_pitch: p.gain_pitch,
        }
    }
}

impl From<&InputBounds> for pb::InputLimits {
    fn from(b: &InputBounds) -> Self {
        Self { min: Some((&Input::from(b.min)).into()), max: Some((&Input::from(b.max)).into()) }
    }
}

/// The `PlantDescription` of a plant simulating `scenario` with `settings`.
pub fn plant_description(
    scenario: &Scenario,
    settings: &SimSettings,
    time_mode: mav::TimeMode,
    implementation: &str,
) -> pb::PlantDescription {
    pb::PlantDescription {
        scenario: scenario.name.clone(),
        model: Some((&scenario.model).into()),
        limits: Some((&scenario.bounds).into()),
        obstacles: scenario.obstacles.iter().map(Into::into).collect(),
        time_mode: pb::TimeMode::from(time_mode) as i32,
        step_ns: settings.step_ns,
        watchdog_timeout_ns: settings.watchdog_timeout_ns.unwrap_or(0),
        start: Some((&scenario.start_state()).into()),
        goal_m: scenario.goal_m.to_vec(),
        ground_z_m: scenario.ground_z_m,
        implementation: implementation.to_string(),
        definition: Some(scenario.into()),
        watchdog_action: match settings.watchdog_action {
            mav::WatchdogAction::Brake => pb::WatchdogAction::Brake,
            mav::WatchdogAction::Hover => pb::WatchdogAction::Hover,
        } as i32,
    }
}

/// The braking watchdog a plant describes, s: its timeout when the watchdog brakes, `None`
/// when it is off, only levels the vehicle, or is not described (what a controller's
/// fail-safe check may count on: `mpc::fail_safe::BrakingCheck::plant_watchdog_s`).
pub fn braking_watchdog_s(description: &pb::PlantDescription) -> Option<f64> {
    (description.watchdog_timeout_ns > 0 && description.watchdog_action == pb::WatchdogAction::Brake as i32)
        .then(|| mav::ns_to_s(description.watchdog_timeout_ns))
}

// ---------------------------------------------------------------------------------------------
// Replies, for clients of the plant API

impl TryFrom<&pb::AppliedCommand> for AppliedCommand {
    type Error = FieldError;

    fn try_from(a: &pb::AppliedCommand) -> Result<Self, FieldError> {
        let u = required("input", &a.input)?;
        let input = Input::from(finite_array::<3>("input", &[u.thrust_mps2, u.roll_rad, u.pitch_rad])?);
        Ok(Self {
            input,
            meta: CommandMeta {
                command_seq: a.command_seq,
                based_on_sample_seq: a.based_on_sample_seq,
                based_on_sample_time_ns: a.based_on_sample_time_ns,
            },
            applied_time_ns: a.applied_time_ns,
            saturated: a.saturated,
            initial: a.initial,
        })
    }
}

impl TryFrom<&pb::CollisionEvent> for CollisionEvent {
    type Error = FieldError;

    fn try_from(e: &pb::CollisionEvent) -> Result<Self, FieldError> {
        let kind = match pb::CollisionKind::try_from(e.kind) {
            Ok(pb::CollisionKind::Cylinder) => CollisionKind::Cylinder,
            Ok(pb::CollisionKind::Ground) => CollisionKind::Ground,
            _ => return Err(FieldError::new("kind", format!("must be CYLINDER or GROUND, got {}", e.kind))),
        };
        let penetration_m = finite("penetration_m", e.penetration_m)?;
        Ok(Self {
            kind,
            obstacle_index: e.obstacle_index,
            time_ns: e.time_ns,
            position_m: finite_array::<3>("position_m", &e.position_m)?,
            penetration_m,
            // A plant that does not follow the contact (0) reports its entry as its depth.
            depth_m: finite("depth_m", e.depth_m)?.max(penetration_m),
        })
    }
}

impl TryFrom<&pb::StateSample> for PlantSample {
    type Error = FieldError;

    fn try_from(s: &pb::StateSample) -> Result<Self, FieldError> {
        let state = state_from_pb("state", required("state", &s.state)?)?;
        let last_command = AppliedCommand::try_from(required("last_command", &s.last_command)?)
            .map_err(|e| e.within("last_command"))?;
        if s.min_clearance_m.is_nan() {
            return Err(FieldError::new("min_clearance_m", "must not be NaN"));
        }
        let collisions = s
            .collisions
            .iter()
            .enumerate()
            .map(|(i, c)| CollisionEvent::try_from(c).map_err(|e| e.within(&format!("collisions[{i}]"))))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            seq: s.seq,
            time_ns: s.time_ns,
            state,
            last_command,
            watchdog_hover: s.watchdog_hover,
            collided: s.collided,
            // +inf (no obstacle ever seen) is legitimate here.
            min_clearance_m: s.min_clearance_m,
            path_length_m: finite("path_length_m", s.path_length_m)?,
            collisions,
            watchdog_hover_ns: s.watchdog_hover_ns,
            flight_id: s.flight_id,
        })
    }
}

impl TryFrom<&pb::Cylinder> for Cylinder {
    type Error = FieldError;

    fn try_from(c: &pb::Cylinder) -> Result<Self, FieldError> {
        let cyl = Cylinder { x_m: c.x_m, y_m: c.y_m, radius_m: c.radius_m, height_m: c.height_m };
        cyl.validate().map_err(|f| FieldError::new(f, "must be finite (and > 0 for sizes)"))?;
        Ok(cyl)
    }
}

impl TryFrom<&pb::ModelParameters> for ModelParams {
    type Error = FieldError;

    fn try_from(p: &pb::ModelParameters) -> Result<Self, FieldError> {
        let params = ModelParams {
            gravity_mps2: p.gravity_mps2,
            drag_x_per_s: p.drag_x_per_s,
            drag_y_per_s: p.drag_y_per_s,
            drag_z_per_s: p.drag_z_per_s,
            tau_roll_s: p.tau_roll_s,
            tau_pitch_s: p.tau_pitch_s,
            gain_roll: p.gain_roll,
            gain_pitch: p.gain_pitch,
        };
        params.validate().map_err(|f| FieldError::new(f, "must be finite and positive"))?;
        Ok(params)
    }
}

impl TryFrom<&pb::InputLimits> for InputBounds {
    type Error = FieldError;

    fn try_from(l: &pb::InputLimits) -> Result<Self, FieldError> {
        let side = |name: &str, u: &Option<pb::ControlInput>| -> Result<[f64; 3], FieldError> {
            let u = required(name, u)?;
            finite_array::<3>(name, &[u.thrust_mps2, u.roll_rad, u.pitch_rad])
        };
        let bounds = InputBounds { min: side("min", &l.min)?, max: side("max", &l.max)? };
        bounds.validate().map_err(|f| FieldError::new(format!("max.{f}"), "must not be below min"))?;
        Ok(bounds)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_controller_counts_on_the_watchdog_only_when_the_plant_describes_a_braking_one() {
        let scenario = Scenario::paper_2();
        let describe =
            |settings: SimSettings| plant_description(&scenario, &settings, mav::TimeMode::Lockstep, "test");
        let brake = describe(SimSettings::default());
        assert_eq!(brake.watchdog_action, pb::WatchdogAction::Brake as i32);
        assert_eq!(braking_watchdog_s(&brake), Some(0.5));
        let hover =
            describe(SimSettings { watchdog_action: mav::WatchdogAction::Hover, ..Default::default() });
        assert_eq!(hover.watchdog_action, pb::WatchdogAction::Hover as i32);
        assert_eq!(braking_watchdog_s(&hover), None);
        assert_eq!(
            braking_watchdog_s(&describe(SimSettings { watchdog_timeout_ns: None, ..Default::default() })),
            None
        );
        let unsaid = pb::PlantDescription { watchdog_action: 0, ..brake };
        assert_eq!(braking_watchdog_s(&unsaid), None, "a plant that does not say brakes not");
    }

    fn field<T: std::fmt::Debug>(r: Result<T, FieldError>) -> String {
        match r {
            Ok(v) => panic!("expected an error, got {v:?}"),
            Err(e) => e.field,
        }
    }

    fn cmd(t: f64, r: f64, p: f64) -> pb::Command {
        pb::Command {
            input: Some(pb::ControlInput { thrust_mps2: t, roll_rad: r, pitch_rad: p }),
            command_seq: 3,
            based_on_sample_seq: 2,
            based_on_sample_time_ns: 1_000,
        }
    }

    #[test]
    fn commands_are_accepted_with_their_origin() {
        let c = Command::try_from(&cmd(30.0, 0.05, -0.3)).expect("valid");
        // Outside the actuator box is fine here: the plant saturates it.
        assert_eq!(c.input, Input::new(30.0, 0.05, -0.3));
        assert_eq!(
            c.meta,
            CommandMeta { command_seq: 3, based_on_sample_seq: 2, based_on_sample_time_ns: 1_000 }
        );
        assert_eq!(pb::Command::from(&c), cmd(30.0, 0.05, -0.3));
    }

    #[test]
    fn bad_commands_name_the_field() {
        assert_eq!(field(Command::try_from(&cmd(f64::NAN, 0.0, 0.0))), "input.thrust_mps2");
        assert_eq!(field(Command::try_from(&cmd(f64::INFINITY, 0.0, 0.0))), "input.thrust_mps2");
        assert_eq!(field(Command::try_from(&cmd(-1.0, 0.0, 0.0))), "input.thrust_mps2");
        assert_eq!(field(Command::try_from(&cmd(1e9, 0.0, 0.0))), "input.thrust_mps2");
        assert_eq!(field(Command::try_from(&cmd(9.81, f64::NEG_INFINITY, 0.0))), "input.roll_rad");
        assert_eq!(field(Command::try_from(&cmd(9.81, 0.0, 2.0))), "input.pitch_rad");
        assert_eq!(field(Command::try_from(&pb::Command::default())), "input");
    }

    #[test]
    fn states_need_exactly_eight_finite_values_in_range() {
        let ok = pb::MavState { x: vec![0.0, 1.0, 2.0, 0.5, 0.0, 0.0, 0.1, -0.1] };
        assert_eq!(initial_state_from_pb("s", &ok).expect("valid")[2], 2.0);
        let short = pb::MavState { x: vec![0.0; 7] };
        assert_eq!(field(initial_state_from_pb("s", &short)), "s.x");
        let long = pb::MavState { x: vec![0.0; 9] };
        assert_eq!(field(initial_state_from_pb("s", &long)), "s.x");
        let mut nan = ok.clone();
        nan.x[4] = f64::NAN;
        assert_eq!(field(initial_state_from_pb("s", &nan)), "s.x[4]");
        let mut tilted = ok.clone();
        tilted.x[7] = 1.6;
        assert_eq!(field(initial_state_from_pb("s", &tilted)), "s.x[7]");
        let mut far = ok.clone();
        far.x[0] = 1e5;
        assert_eq!(field(initial_state_from_pb("s", &far)), "s.x[0]");
        let mut fast = ok;
        fast.x[5] = -2e3;
        assert_eq!(field(initial_state_from_pb("s", &fast)), "s.x[5]");
    }

    #[test]
    fn reset_requests_are_checked() {
        let r = Reset::try_from(&pb::ResetRequest::default()).expect("valid");
        assert_eq!(r, Reset { definition: None, scenario: None, initial_state: None });
        let r = Reset::try_from(&pb::ResetRequest {
            definition: None,
            scenario: "paper-2".into(),
            initial_state: Some(pb::MavState { x: vec![1.0; 8] }),
        });
        assert_eq!(r.expect("valid").initial_state.map(|s| s[3]), Some(1.0));
        let bad = pb::ResetRequest {
            definition: None,
            scenario: String::new(),
            initial_state: Some(pb::MavState { x: vec![1.0] }),
        };
        assert_eq!(field(Reset::try_from(&bad)), "initial_state.x");
        let bad = pb::ResetRequest { definition: None, scenario: " paper-1".into(), initial_state: None };
        assert_eq!(field(Reset::try_from(&bad)), "scenario");
        assert_eq!(field(scenario_by_name("scenario", "paper-9")), "scenario");
        assert_eq!(scenario_by_name("scenario", "paper-3").expect("built in").name, "paper-3");
    }

    #[test]
    fn durations_must_be_positive_and_bounded() {
        assert_eq!(
            field(advance_duration_ns(&pb::AdvanceRequest { duration_ns: 0, ..Default::default() })),
            "duration_ns"
        );
        assert_eq!(
            field(advance_duration_ns(&pb::AdvanceRequest { duration_ns: u64::MAX, ..Default::default() })),
            "duration_ns"
        );
        assert_eq!(
            advance_duration_ns(&pb::AdvanceRequest { duration_ns: 1_000_000, ..Default::default() }),
            Ok(1_000_000)
        );
        let step = Step::try_from(&pb::StepRequest { command: None, duration_ns: 0, ..Default::default() })
            .expect("valid");
        assert_eq!(step, Step { command: None, duration_ns: 0 });
        let bad =
            pb::StepRequest { command: Some(cmd(9.81, f64::NAN, 0.0)), duration_ns: 1, ..Default::default() };
        assert_eq!(field(Step::try_from(&bad)), "command.input.roll_rad");
        let bad = pb::StepRequest {
            command: Some(cmd(9.81, 0.0, 0.0)),
            duration_ns: MAX_ADVANCE_NS + 1,
            ..Default::default()
        };
        assert_eq!(field(Step::try_from(&bad)), "duration_ns");
        assert_eq!(
            StreamState::try_from(&pb::StreamStateRequest { period_ns: 0 }),
            Ok(StreamState { period_ns: 0 })
        );
    }

    #[test]
    fn samples_round_trip_bit_for_bit() {
        let s = Scenario::paper_1();
        let mut sim = mav::PlantSim::new(&s, SimSettings::default()).expect("valid");
        sim.reset(State::from([0.0, 4.0, 1.0, 0.0, 3.0, 0.0, 0.0, 0.0])).expect("finite");
        sim.apply(Input::new(25.0, 0.01, 0.0), CommandMeta { command_seq: 9, ..Default::default() })
            .expect("finite");
        sim.advance(700_000_123, |_| {});
        let sample = sim.sample();
        assert!(!sample.collisions.is_empty());
        let wire = pb::StateSample::from(&sample);
        assert_eq!(wire.collisions[0].kind, pb::CollisionKind::Cylinder as i32);
        assert_eq!(wire.last_command.as_ref().map(|c| c.saturated), Some(true));
        let back = PlantSample::try_from(&wire).expect("valid");
        assert_eq!(back, sample);
        for (a, b) in back.state.iter().zip(sample.state.iter()) {
            assert_eq!(a.to_bits(), b.to_bits());
        }
        let mut bad = wire.clone();
        bad.collisions[0].kind = 0;
        assert_eq!(field(PlantSample::try_from(&bad)), "collisions[0].kind");
        let mut bad = wire;
        bad.last_command = None;
        assert_eq!(field(PlantSample::try_from(&bad)), "last_command");
    }

    #[test]
    fn descriptions_carry_the_scenario() {
        let s = Scenario::paper_2();
        let settings = SimSettings { watchdog_timeout_ns: Some(5), ..Default::default() };
        let d = plant_description(&s, &settings, mav::TimeMode::Lockstep, "test");
        assert_eq!(d.obstacles.len(), 3);
        assert_eq!(d.time_mode, pb::TimeMode::Lockstep as i32);
        assert_eq!(d.watchdog_timeout_ns, 5);
        assert_eq!(d.step_ns, 1_000_000);
        let limits = InputBounds::try_from(d.limits.as_ref().expect("set")).expect("valid");
        assert_eq!(limits, s.bounds);
        let model = ModelParams::try_from(d.model.as_ref().expect("set")).expect("valid");
        assert_eq!(model, s.model);
        let cyl = Cylinder::try_from(&d.obstacles[2]).expect("valid");
        assert_eq!(cyl, s.obstacles[2]);
        let bad = pb::Cylinder { radius_m: -1.0, ..d.obstacles[0] };
        assert_eq!(field(Cylinder::try_from(&bad)), "radius_m");
    }
}
