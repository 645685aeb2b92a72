//! The truth simulation wrapped by the plant service: RK4 on a fixed grid of plant time,
//! actuator saturation, collision events, a command watchdog, and run statistics.
//!
//! Integration sub-steps end at every multiple of `step_ns` and at every time where the caller
//! stops (a command arrives, a sample is taken). Observing the simulation therefore never moves
//! a step boundary, and two runs with the same commands at the same plant times are
//! bit-identical however their `advance` calls were split on the grid.

use crate::geometry::{Cylinder, GROUND_INDEX};
use crate::model::{Input, InputBounds, MavModel, State, rk4_step};
use crate::ns_to_s;
use crate::scenario::Scenario;

/// The plant's default watchdog timeout, ns: like PX4's offboard-loss timeout, half a second
/// without a command means the link is down rather than slow.
pub const DEFAULT_WATCHDOG_TIMEOUT_NS: u64 = 500_000_000;

/// How often the braking watchdog recomputes its command, ns (50 Hz, on the plant-time grid).
pub const WATCHDOG_BRAKE_PERIOD_NS: u64 = 20_000_000;

/// What the plant does when no command arrived for the watchdog's timeout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum WatchdogAction {
    /// Brake to a standstill on board, as PX4's Hold failsafe does: the controller's braking
    /// law ([`crate::command::braking_command`], gain
    /// [`crate::command::DEFAULT_BRAKE_GAIN_PER_S`]) recomputed from the true state every
    /// [`WATCHDOG_BRAKE_PERIOD_NS`], until the next command. A command is then never held
    /// longer than the timeout, which is what lets a controller's fail-safe check cover any
    /// delay (`mpc::fail_safe`).
    #[default]
    Brake,
    /// Level attitude at hover thrust: the vehicle coasts on (drag slows it).
    Hover,
}

/// Settings of the truth simulation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimSettings {
    /// Integration step of RK4, ns (default 1 ms, the plant's 1 kHz rate).
    pub step_ns: u64,
    /// The watchdog fires when no command arrived for this long, ns; `None` disables it.
    pub watchdog_timeout_ns: Option<u64>,
    /// What the watchdog does until the next command.
    pub watchdog_action: WatchdogAction,
}

impl Default for SimSettings {
    fn default() -> Self {
        Self {
            step_ns: 1_000_000,
            watchdog_timeout_ns: Some(DEFAULT_WATCHDOG_TIMEOUT_NS),
            watchdog_action: WatchdogAction::Brake,
        }
    }
}

impl SimSettings {
    /// Step from a rate in Hz (must be in 1 Hz ..= 1 MHz).
    pub fn with_rate_hz(rate_hz: f64) -> Result<Self, SimError> {
        if !rate_hz.is_finite() || !(1.0..=1e6).contains(&rate_hz) {
            return Err(SimError::Invalid { field: "rate_hz", reason: "must be in [1, 1e6] Hz" });
        }
        Ok(Self { step_ns: (1e9 / rate_hz).round() as u64, ..Self::default() })
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    #[error("invalid `{field}`: {reason}")]
    Invalid { field: &'static str, reason: &'static str },
}

/// What a command says about where it came from; echoed back in state samples so that a
/// controller can measure its round-trip delay from plant time stamps alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CommandMeta {
    pub command_seq: u64,
    pub based_on_sample_seq: u64,
    pub based_on_sample_time_ns: u64,
}

/// The command in force, after saturation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AppliedCommand {
    pub input: Input,
    pub meta: CommandMeta,
    pub applied_time_ns: u64,
    pub saturated: bool,
    /// True until the first command after reset: the start input `u_{-1}`.
    pub initial: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CollisionKind {
    Cylinder,
    Ground,
}

/// Entry into an obstacle or the ground.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CollisionEvent {
    pub kind: CollisionKind,
    /// Index into the obstacle list; `GROUND_INDEX` for the ground.
    pub obstacle_index: u32,
    pub time_ns: u64,
    pub position_m: [f64; 3],
    /// How far inside at the moment of entry, m (>= 0).
    pub penetration_m: f64,
    /// The deepest it went during this contact (so far, while still inside), m (>= 0).
    pub depth_m: f64,
}

/// One state sample with everything the plant API reports.
#[derive(Debug, Clone, PartialEq)]
pub struct PlantSample {
    pub seq: u64,
    pub time_ns: u64,
    pub state: State,
    pub last_command: AppliedCommand,
    pub watchdog_hover: bool,
    pub collided: bool,
    pub min_clearance_m: f64,
    pub path_length_m: f64,
    pub collisions: Vec<CollisionEvent>,
    /// Plant time spent holding hover under the watchdog since reset, ns.
    pub watchdog_hover_ns: u64,
    /// Which flight of the plant the sample belongs to: a plant service gives every reset, and
    /// every start of its process, a new id, so that a controller can tell that the plant it
    /// flies was reset or restarted under it; 0 = not told (the simulation alone).
    pub flight_id: u64,
}

/// Contacts with the obstacles and the ground along a trajectory: collision events (entry
/// into a cylinder, or the ground after lift-off or sinking into it from the start), the
/// deepest penetration of each, and the smallest clearance. The one implementation of what a
/// collision is: the truth simulation observes its own states with it, and a vehicle gateway
/// observes the states a real vehicle reports.
#[derive(Debug, Clone, PartialEq)]
pub struct Contacts {
    obstacles: Vec<Cylinder>,
    ground_z_m: f64,
    /// Per obstacle, then the ground: currently inside?
    inside: Vec<bool>,
    lifted_off: bool,
    collisions: Vec<CollisionEvent>,
    min_clearance_m: f64,
}

impl Contacts {
    /// No contact yet with `obstacles` and the ground at `ground_z_m`.
    pub fn new(obstacles: Vec<Cylinder>, ground_z_m: f64) -> Self {
        let inside = vec![false; obstacles.len() + 1];
        Self {
            obstacles,
            ground_z_m,
            inside,
            lifted_off: false,
            collisions: Vec::new(),
            min_clearance_m: f64::INFINITY,
        }
    }

    /// Forgets every contact (same obstacles).
    pub fn reset(&mut self) {
        self.inside.iter_mut().for_each(|b| *b = false);
        self.lifted_off = false;
        self.collisions.clear();
        self.min_clearance_m = f64::INFINITY;
    }

    pub fn obstacles(&self) -> &[Cylinder] {
        &self.obstacles
    }
    pub fn collisions(&self) -> &[CollisionEvent] {
        &self.collisions
    }
    pub fn collided(&self) -> bool {
        !self.collisions.is_empty()
    }
    /// The smallest clearance to any obstacle observed (infinite before the first).
    pub fn min_clearance_m(&self) -> f64 {
        self.min_clearance_m
    }

    /// Records the contacts of `state` at plant time `time_ns`.
    pub fn observe(&mut self, time_ns: u64, state: &State) {
        let (px, py, pz, vz) = (state[0], state[1], state[2], state[5]);
        for i in 0..self.obstacles.len() {
            let clearance = self.obstacles[i].clearance_m(px, py, pz);
            self.min_clearance_m = self.min_clearance_m.min(clearance);
            let now_inside = clearance < 0.0;
            if now_inside && !self.inside[i] {
                self.collisions.push(CollisionEvent {
                    kind: CollisionKind::Cylinder,
                    obstacle_index: i as u32,
                    time_ns,
                    position_m: [px, py, pz],
                    penetration_m: -clearance,
                    depth_m: -clearance,
                });
            } else if now_inside {
                self.deepen(CollisionKind::Cylinder, i as u32, -clearance);
            }
            self.inside[i] = now_inside;
        }
        // The paper's model has no floor. Below the ground after lift-off, or sinking into it
        // from the start, is ground contact: a crash, not a landing.
        self.lifted_off |= pz > self.ground_z_m;
        let g = self.obstacles.len();
        let below = pz < self.ground_z_m && (self.lifted_off || vz < 0.0);
        if below && !self.inside[g] {
            self.collisions.push(CollisionEvent {
                kind: CollisionKind::Ground,
                obstacle_index: GROUND_INDEX,
                time_ns,
                position_m: [px, py, pz],
                penetration_m: self.ground_z_m - pz,
                depth_m: self.ground_z_m - pz,
            });
        } else if below {
            self.deepen(CollisionKind::Ground, GROUND_INDEX, self.ground_z_m - pz);
        }
        self.inside[g] = below;
    }

    /// The contact in progress with (`kind`, `index`) went `depth_m` deep.
    fn deepen(&mut self, kind: CollisionKind, index: u32, depth_m: f64) {
        if let Some(c) =
            self.collisions.iter_mut().rev().find(|c| c.kind == kind && c.obstacle_index == index)
        {
            c.depth_m = c.depth_m.max(depth_m);
        }
    }
}

/// The truth simulation.
#[derive(Debug, Clone)]
pub struct PlantSim {
    model: MavModel,
    bounds: InputBounds,
    settings: SimSettings,
    state: State,
    time_ns: u64,
    /// The input the dynamics see (the last command, or hover while the watchdog holds).
    effective_input: Input,
    last_command: AppliedCommand,
    watchdog_hover: bool,
    /// Plant time of the last command (or of the reset).
    last_command_time_ns: u64,
    contacts: Contacts,
    path_length_m: f64,
    sample_seq: u64,
    watchdog_hover_ns: u64,
    flight_id: u64,
}

impl PlantSim {
    /// A simulation of `scenario`, at rest in its start state.
    pub fn new(scenario: &Scenario, settings: SimSettings) -> Result<Self, SimError> {
        if settings.step_ns == 0 {
            return Err(SimError::Invalid { field: "step_ns", reason: "must be > 0" });
        }
        if settings.watchdog_timeout_ns == Some(0) {
            return Err(SimError::Invalid { field: "watchdog_timeout_ns", reason: "must be > 0 when set" });
        }
        let hover = scenario.model.hover_input();
        let mut sim = Self {
            model: MavModel::new(scenario.model),
            bounds: scenario.bounds,
            settings,
            state: scenario.start_state(),
            time_ns: 0,
            effective_input: hover,
            last_command: AppliedCommand {
                input: hover,
                meta: CommandMeta::default(),
                applied_time_ns: 0,
                saturated: false,
                initial: true,
            },
            watchdog_hover: false,
            last_command_time_ns: 0,
            contacts: Contacts::new(scenario.obstacles.clone(), scenario.ground_z_m),
            path_length_m: 0.0,
            sample_seq: 0,
            watchdog_hover_ns: 0,
            flight_id: 0,
        };
        sim.reset(scenario.start_state())?;
        Ok(sim)
    }

    /// Back to time zero in `state`, with the start input `u_{-1} = [g, 0, 0]` and fresh statistics.
    pub fn reset(&mut self, state: State) -> Result<(), SimError> {
        if state.iter().any(|v| !v.is_finite()) {
            return Err(SimError::Invalid { field: "state", reason: "must be finite" });
        }
        let hover = self.model.params.hover_input();
        self.state = state;
        self.time_ns = 0;
        self.effective_input = hover;
        self.last_command = AppliedCommand {
            input: hover,
            meta: CommandMeta::default(),
            applied_time_ns: 0,
            saturated: false,
            initial: true,
        };
        self.watchdog_hover = false;
        self.last_command_time_ns = 0;
        self.contacts.reset();
        self.path_length_m = 0.0;
        self.sample_seq = 0;
        self.watchdog_hover_ns = 0;
        self.contacts.observe(self.time_ns, &self.state);
        Ok(())
    }

    pub fn state(&self) -> &State {
        &self.state
    }
    pub fn time_ns(&self) -> u64 {
        self.time_ns
    }
    pub fn settings(&self) -> &SimSettings {
        &self.settings
    }
    pub fn bounds(&self) -> &InputBounds {
        &self.bounds
    }
    pub fn obstacles(&self) -> &[Cylinder] {
        &self.contacts.obstacles
    }
    pub fn model(&self) -> &MavModel {
        &self.model
    }
    pub fn ground_z_m(&self) -> f64 {
        self.contacts.ground_z_m
    }
    pub fn last_command(&self) -> &AppliedCommand {
        &self.last_command
    }
    pub fn effective_input(&self) -> &Input {
        &self.effective_input
    }
    pub fn watchdog_hover(&self) -> bool {
        self.watchdog_hover
    }
    /// Plant time spent holding hover under the watchdog since reset, ns.
    pub fn watchdog_hover_ns(&self) -> u64 {
        self.watchdog_hover_ns
    }
    /// The id its samples carry (see [`PlantSample::flight_id`]); a reset keeps it, so the
    /// service that resets sets a new one.
    pub fn set_flight_id(&mut self, flight_id: u64) {
        self.flight_id = flight_id;
    }
    pub fn collisions(&self) -> &[CollisionEvent] {
        self.contacts.collisions()
    }
    pub fn collided(&self) -> bool {
        self.contacts.collided()
    }
    pub fn min_clearance_m(&self) -> f64 {
        self.contacts.min_clearance_m()
    }
    pub fn path_length_m(&self) -> f64 {
        self.path_length_m
    }

    /// Applies a command now (at the current plant time), saturated at the actuator limits.
    /// A non-finite input is refused and changes nothing.
    pub fn apply(&mut self, input: Input, meta: CommandMeta) -> Result<AppliedCommand, SimError> {
        const FIELDS: [&str; 3] = ["thrust_mps2", "roll_rad", "pitch_rad"];
        if let Some(i) = input.iter().position(|v| !v.is_finite()) {
            return Err(SimError::Invalid { field: FIELDS[i], reason: "must be finite" });
        }
        let (saturated_input, saturated) = self.bounds.saturate(&input);
        self.last_command = AppliedCommand {
            input: saturated_input,
            meta,
            applied_time_ns: self.time_ns,
            saturated,
            initial: false,
        };
        self.effective_input = saturated_input;
        self.watchdog_hover = false;
        self.last_command_time_ns = self.time_ns;
        Ok(self.last_command)
    }

    /// Integrates for `duration_ns`, calling `observer` after every sub-step.
    pub fn advance(&mut self, duration_ns: u64, mut observer: impl FnMut(&PlantSim)) {
        let target = self.time_ns.saturating_add(duration_ns);
        let step = self.settings.step_ns;
        while self.time_ns < target {
            let next_grid = (self.time_ns / step + 1).saturating_mul(step);
            let end = next_grid.min(target);
            self.integrate_to(end);
            observer(self);
        }
    }

    /// Integrates to plant time `time_ns` (no-op when it is not in the future).
    pub fn advance_to(&mut self, time_ns: u64, observer: impl FnMut(&PlantSim)) {
        if time_ns > self.time_ns {
            self.advance(time_ns - self.time_ns, observer);
        }
    }

    fn integrate_to(&mut self, end_ns: u64) {
        let dt_s = ns_to_s(end_ns - self.time_ns);
        if self.watchdog_hover {
            self.watchdog_hover_ns += end_ns - self.time_ns;
        }
        let speed_before = self.speed();
        self.state = rk4_step(&self.model, &self.state, &self.effective_input, dt_s);
        self.time_ns = end_ns;
        self.path_length_m += 0.5 * (speed_before + self.speed()) * dt_s;
        self.contacts.observe(self.time_ns, &self.state);
        if let Some(timeout) = self.settings.watchdog_timeout_ns
            && !self.watchdog_hover
            && self.time_ns.saturating_sub(self.last_command_time_ns) >= timeout
        {
            self.watchdog_hover = true;
            self.effective_input = self.watchdog_input();
        } else if self.watchdog_hover
            && self.settings.watchdog_action == WatchdogAction::Brake
            && self.time_ns.is_multiple_of(WATCHDOG_BRAKE_PERIOD_NS)
        {
            self.effective_input = self.watchdog_input();
        }
    }

    /// The watchdog's command from the current state.
    fn watchdog_input(&self) -> Input {
        match self.settings.watchdog_action {
            WatchdogAction::Hover => self.model.params.hover_input(),
            WatchdogAction::Brake => Input::from(crate::command::braking_command(
                &self.model.params,
                &self.bounds,
                &self.state.into(),
                crate::command::DEFAULT_BRAKE_GAIN_PER_S,
            )),
        }
    }

    fn speed(&self) -> f64 {
        (self.state[3] * self.state[3] + self.state[4] * self.state[4] + self.state[5] * self.state[5]).sqrt()
    }

    /// Takes a sample of the current state (numbered in order of sampling).
    pub fn sample(&mut self) -> PlantSample {
        let s = self.peek();
        self.sample_seq += 1;
        s
    }

    /// The sample `sample()` would return, without consuming a sequence number.
    pub fn peek(&self) -> PlantSample {
        PlantSample {
            seq: self.sample_seq,
            time_ns: self.time_ns,
            state: self.state,
            last_command: self.last_command,
            watchdog_hover: self.watchdog_hover,
            collided: self.collided(),
            min_clearance_m: self.contacts.min_clearance_m,
            path_length_m: self.path_length_m,
            collisions: self.contacts.collisions.clone(),
            watchdog_hover_ns: self.watchdog_hover_ns,
            flight_id: self.flight_id,
        }
    }
}

#[cfg(test)]
mod tests;
