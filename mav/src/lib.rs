//! `mav` owns the physics of the bench: the paper's 8-state micro aerial vehicle model, its
//! explicit-Euler (controller prediction) and RK4 (plant truth) integrators, the obstacle
//! geometry (vertical cylinders and the ground), the scenario definitions of `docs/spec.md`, and the
//! truth simulation that the plant service wraps.
//!
//! It is a pure library: no clock, no I/O, no async. Time is an argument (integer nanoseconds
//! of plant time), so the same code runs in real time, in lockstep and inside tests.

pub mod command;
mod exact;
pub mod geometry;
pub mod latency;
pub mod mode;
pub mod model;
pub mod scenario;
pub mod sim;

pub use geometry::{Cylinder, GROUND_INDEX};
pub use mode::{ControllerMode, TimeMode, TimeModeChoice};
pub use model::{Dynamics, Input, InputBounds, MavModel, ModelParams, State, euler_step, rk4_step};
pub use scenario::{
    MAX_ABS_ANGLE_RAD, MAX_ABS_POSITION_M, MAX_ABS_VELOCITY_MPS, MAX_COEFFICIENT, MAX_CYCLE_S,
    MAX_NAME_CHARS, MAX_OBSTACLE_SIZE_M, MIN_CYCLE_S, NMPC_KEYS, PAPER_DELAY_GAMMA, PanocSolver, Scenario,
    ScenarioError, check_name,
};
pub use sim::{
    AppliedCommand, CollisionEvent, CollisionKind, CommandMeta, Contacts, DEFAULT_WATCHDOG_TIMEOUT_NS,
    PlantSample, PlantSim, SimError, SimSettings, WATCHDOG_BRAKE_PERIOD_NS, WatchdogAction,
};

/// The format of a refused value in messages (defined in `delay`).
pub use delay::Number;
/// The bench's one pair of time conversions (defined in `delay`, the crate below this one).
pub use delay::{NS_PER_S, ns_to_s, s_to_ns};
