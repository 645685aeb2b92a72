//! The rigid body in plant time: RK4 on a fixed grid, the motor commands held between calls,
//! the ground, and the sensors' readings.
//!
//! Integration steps end at every multiple of `step_ns` and wherever the caller stops
//! ([`QuadSim::advance_to`]), as in `mav::sim`. Observing the simulation therefore never moves a
//! step boundary, and two runs given the same commands at the same plant times are
//! bit-identical however their `advance_to` calls were split on the grid. Nothing here reads a
//! clock, allocates after construction or depends on anything but its arguments.
//!
//! # The ground
//! The ground (world z = 0) is a perfectly plastic contact with full friction at the centre of
//! mass: a step that ends below it puts the body on it (z = 0), stops it (velocity and body
//! rates zero, attitude kept) and records a [`Touchdown`]. On the ground the body stays at
//! rest while its net vertical force (thrust, drag, weight) points down or vanishes, so a body
//! resting with its motors off (or at any thrust short of its weight) stays exactly where it
//! is; the motors spin up as commanded meanwhile. It lifts off at the first step that starts
//! with the thrust above the weight. A touchdown is found at the end of a step, so the body
//! may be up to one step's travel below the ground before it is put back on it (5 mm at
//! 5 m/s and 1 kHz). Tipping over, bouncing and landing gear are not modelled.

use mav::rk4_step;
use nalgebra::Vector3;

use crate::model::{MotorSpeeds, QuadModel, QuadState, StateVector, idx};
use crate::motors::{CommandReport, sanitize_commands};
use crate::params::{ParamError, QuadParams};

/// Shortest integration step, ns (1 MHz).
pub const MIN_STEP_NS: u64 = 1_000;
/// Longest integration step, ns: 1 kHz, the bench's plant rate and the slowest rate at which
/// RK4 resolves the motors' and the attitude's time constants with room to spare.
pub const MAX_STEP_NS: u64 = 1_000_000;

/// Settings of the simulation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimSettings {
    /// RK4 step, ns, in [`MIN_STEP_NS`, `MAX_STEP_NS`] and at most a quarter of the motors'
    /// time constant (default 1 ms, 1 kHz).
    pub step_ns: u64,
}

impl Default for SimSettings {
    fn default() -> Self {
        Self { step_ns: MAX_STEP_NS }
    }
}

impl SimSettings {
    /// Checks the step against its range and against the motors' time constant (RK4 on the
    /// motors' first-order lag is accurate only well inside `dt / tau < 2.8`, its stability limit).
    pub fn validate(&self, params: &QuadParams) -> Result<(), SimError> {
        if !(MIN_STEP_NS..=MAX_STEP_NS).contains(&self.step_ns) {
            return Err(SimError::Invalid { field: "step_ns", reason: "must be in [1_000, 1_000_000] ns" });
        }
        if mav::ns_to_s(self.step_ns) > params.motor_time_constant_s / 4.0 {
            return Err(SimError::Invalid {
                field: "step_ns",
                reason: "must be at most a quarter of motor_time_constant_s",
            });
        }
        Ok(())
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    #[error(transparent)]
    Params(#[from] ParamError),
    #[error("invalid `{field}`: {reason}")]
    Invalid { field: &'static str, reason: &'static str },
    #[error("time runs backwards: asked for {asked_ns} ns at {now_ns} ns")]
    TimeBackwards { now_ns: u64, asked_ns: u64 },
}

/// The body reaching the ground.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Touchdown {
    /// Plant time of the step that ended below the ground, ns.
    pub time_ns: u64,
    /// Descent rate at that step's end, m/s (>= 0).
    pub vertical_speed_mps: f64,
    /// Horizontal speed at that step's end, m/s.
    pub horizontal_speed_mps: f64,
}

/// The body's contact with the ground.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Contact {
    /// Resting on the ground after the last step.
    pub on_ground: bool,
    /// Touchdowns since the start (a start on the ground is not one).
    pub touchdowns: u64,
    pub last_touchdown: Option<Touchdown>,
}

/// What an IMU at the centre of mass reads, in body axes (FLU).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuReading {
    /// Specific force, m/s^2: `+g` along body z at rest, level.
    pub specific_force_body_mps2: Vector3<f64>,
    /// Angular velocity, rad/s.
    pub angular_velocity_body_rad_s: Vector3<f64>,
}

/// The simulation at one plant time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuadSample {
    pub time_ns: u64,
    pub state: QuadState,
    pub imu: ImuReading,
    pub contact: Contact,
}

/// Motor commands received since the start, per component.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CommandStats {
    /// Calls of [`QuadSim::set_commands`].
    pub commands: u64,
    /// Components clamped into `[0, 1]`.
    pub clamped: u64,
    /// Non-finite components, replaced by 0.
    pub non_finite: u64,
}

/// The quadrotor flying in plant time.
#[derive(Debug, Clone)]
pub struct QuadSim {
    model: QuadModel,
    settings: SimSettings,
    x: StateVector,
    time_ns: u64,
    commands: [f64; 4],
    speeds: MotorSpeeds,
    contact: Contact,
    stats: CommandStats,
}

impl QuadSim {
    /// A simulation at plant time 0 in `initial`, with every command 0. Refuses bad parameters,
    /// settings, or a state that is not finite, starts below the ground, or has a motor outside
    /// `[0, max_motor_speed_rad_s]`. A state at z = 0 starts resting on the ground.
    pub fn new(params: QuadParams, settings: SimSettings, initial: QuadState) -> Result<Self, SimError> {
        let model = QuadModel::new(params)?;
        settings.validate(&params)?;
        if !initial.is_finite() {
            return Err(SimError::Invalid { field: "initial", reason: "must be finite" });
        }
        if initial.position_m.z < 0.0 {
            return Err(SimError::Invalid {
                field: "initial.position_m",
                reason: "z must be >= 0 (the ground)",
            });
        }
        if initial.motor_speed_rad_s.iter().any(|w| !(0.0..=params.max_motor_speed_rad_s).contains(w)) {
            return Err(SimError::Invalid {
                field: "initial.motor_speed_rad_s",
                reason: "must be in [0, max_motor_speed_rad_s]",
            });
        }
        let x = QuadState::from_vector(&initial.to_vector()).to_vector();
        let on_ground = initial.position_m.z == 0.0;
        Ok(Self {
            model,
            settings,
            x,
            time_ns: 0,
            commands: [0.0; 4],
            speeds: MotorSpeeds::zeros(),
            contact: Contact { on_ground, ..Contact::default() },
            stats: CommandStats::default(),
        })
    }

    pub fn model(&self) -> &QuadModel {
        &self.model
    }

    pub fn settings(&self) -> &SimSettings {
        &self.settings
    }

    /// Plant time, ns.
    pub fn time_ns(&self) -> u64 {
        self.time_ns
    }

    pub fn state(&self) -> QuadState {
        QuadState::from_vector(&self.x)
    }

    pub fn contact(&self) -> Contact {
        self.contact
    }

    /// The commands in force after sanitising, motors 1 to 4.
    pub fn commands(&self) -> [f64; 4] {
        self.commands
    }

    pub fn command_stats(&self) -> CommandStats {
        self.stats
    }

    /// Holds normalised motor commands (motors 1 to 4, Betaflight's order) from now until the
    /// next call, after [`crate::motors::sanitize_commands`]; says what the sanitiser did.
    pub fn set_commands(&mut self, commands: [f64; 4]) -> CommandReport {
        let (clean, report) = sanitize_commands(commands);
        self.stats.commands += 1;
        self.stats.clamped += u64::from(report.clamped);
        self.stats.non_finite += u64::from(report.non_finite);
        self.commands = clean;
        self.speeds = self.model.commanded_speeds(&clean);
        report
    }

    /// Integrates to plant time `time_ns`, steps ending on the grid and at `time_ns`.
    pub fn advance_to(&mut self, time_ns: u64) -> Result<(), SimError> {
        if time_ns < self.time_ns {
            return Err(SimError::TimeBackwards { now_ns: self.time_ns, asked_ns: time_ns });
        }
        let step = self.settings.step_ns;
        while self.time_ns < time_ns {
            let next = ((self.time_ns / step + 1) * step).min(time_ns);
            self.integrate(next);
        }
        Ok(())
    }

    /// Integrates to the next point of the grid (one whole step when on it).
    pub fn step(&mut self) {
        let step = self.settings.step_ns;
        self.integrate((self.time_ns / step + 1) * step);
    }

    /// The state, the IMU's reading and the contact now.
    pub fn sample(&self) -> QuadSample {
        let state = self.state();
        let imu = if self.contact.on_ground {
            // At rest the contact force carries everything gravity does not: the specific
            // force is g straight up, seen in the body.
            ImuReading {
                specific_force_body_mps2: state.attitude.inverse_transform_vector(&Vector3::new(
                    0.0,
                    0.0,
                    self.model.params().gravity_mps2,
                )),
                angular_velocity_body_rad_s: Vector3::zeros(),
            }
        } else {
            ImuReading {
                specific_force_body_mps2: self.model.specific_force_body(&state),
                angular_velocity_body_rad_s: state.angular_velocity_rad_s,
            }
        };
        QuadSample { time_ns: self.time_ns, state, imu, contact: self.contact }
    }

    /// One RK4 step from `self.time_ns` to `end_ns`, then the ground.
    fn integrate(&mut self, end_ns: u64) {
        let dt_s = mav::ns_to_s(end_ns - self.time_ns);
        let held = self.contact.on_ground && self.model.vertical_acceleration(&self.x) <= 0.0;
        let mut x = rk4_step(&self.model, &self.x, &self.speeds, dt_s);
        normalize_attitude(&mut x);
        let touched = !held && x[idx::POSITION + 2] < 0.0;
        if held {
            // Resting: only the motors move (their derivative involves nothing else, so the
            // step's motor speeds are exact as computed).
            let mut rest = self.x;
            rest.fixed_rows_mut::<4>(idx::MOTORS).copy_from(&x.fixed_rows::<4>(idx::MOTORS));
            rest[idx::POSITION + 2] = 0.0;
            rest.fixed_rows_mut::<3>(idx::VELOCITY).fill(0.0);
            rest.fixed_rows_mut::<3>(idx::RATES).fill(0.0);
            x = rest;
        } else if touched {
            let v = idx::VELOCITY;
            self.contact.touchdowns += 1;
            self.contact.last_touchdown = Some(Touchdown {
                time_ns: end_ns,
                vertical_speed_mps: (-x[v + 2]).max(0.0),
                horizontal_speed_mps: x[v].hypot(x[v + 1]),
            });
            x[idx::POSITION + 2] = 0.0;
            x.fixed_rows_mut::<3>(idx::VELOCITY).fill(0.0);
            x.fixed_rows_mut::<3>(idx::RATES).fill(0.0);
        }
        self.contact.on_ground = held || touched;
        self.x = x;
        self.time_ns = end_ns;
    }
}

/// RK4 moves the quaternion off the unit sphere by O(dt^5) a step; put it back.
fn normalize_attitude(x: &mut StateVector) {
    let mut q = x.fixed_rows_mut::<4>(idx::ATTITUDE);
    let n = q.norm();
    q /= n;
}
