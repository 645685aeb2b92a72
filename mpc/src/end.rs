//! When a flight ends: the scenario's rule ([`finish_at`]), the same for every driver and time
//! mode (the control loop's [`crate::Episode`], `hilbench`'s gRPC driver from the telemetry, its
//! judge of an external controller from the plant's samples, in which no MPC is involved), and
//! the vocabulary of how a run ended ([`RunEnd`]).

use mav::{PlantSample, Scenario};

/// How a run ended: the one vocabulary of every driver (the in-process loop, the controller
/// service, `hilbench` over gRPC and with an external controller), decided once per sample by
/// [`finish_at`] and, for a run that failed, by the driver ([`RunEnd::Error`]). Its names are
/// `summary.json`'s `end_reason` and, through `proto`, the controller's `finish_reason`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunEnd {
    /// The sample at plant time `time_ns` is at the goal.
    Reached { time_ns: u64 },
    /// The sample is at or past the scenario's `max_duration_s` of plant time.
    TimeLimit,
    /// The vehicle has collided (a cylinder or the ground), and the scenario does not ask to
    /// go on (`continue_after_collision`).
    Collided,
    /// The run failed part-way (a service died, a trace ran out, ...): the driver's error says
    /// why.
    Error,
}

impl RunEnd {
    /// Every name, in the order of the variants.
    pub const NAMES: [&'static str; 4] = ["reached", "time_limit", "collided", "error"];

    pub fn name(self) -> &'static str {
        match self {
            RunEnd::Reached { .. } => "reached",
            RunEnd::TimeLimit => "time_limit",
            RunEnd::Collided => "collided",
            RunEnd::Error => "error",
        }
    }

    /// The plant time of the goal, when reached.
    pub fn time_to_goal_ns(self) -> Option<u64> {
        match self {
            RunEnd::Reached { time_ns } => Some(time_ns),
            _ => None,
        }
    }

    pub fn reached(self) -> bool {
        matches!(self, RunEnd::Reached { .. })
    }
}

impl std::fmt::Display for RunEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl serde::Serialize for RunEnd {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

/// Whether `sample` ends a flight of `scenario` ([`crate::Episode::finish`]; also how `hilbench`
/// judges an external controller from the plant's samples and ends a real-time run from the
/// telemetry): after a collision (unless the scenario asks to go on), at the goal, or at
/// the scenario's `max_duration_s`. The same rule in lockstep and in real time.
pub fn finish_at(scenario: &Scenario, sample: &PlantSample) -> Option<RunEnd> {
    if sample.collided && !scenario.continue_after_collision {
        Some(RunEnd::Collided)
    } else if scenario.goal_reached(&sample.state) {
        Some(RunEnd::Reached { time_ns: sample.time_ns })
    } else if sample.time_ns >= scenario.max_duration_ns() {
        Some(RunEnd::TimeLimit)
    } else {
        None
    }
}
