//! `quad` is a 6-DOF rigid-body quadrotor for flight firmware in the loop (Betaflight's SITL
//! first): a quaternion attitude, an X frame of four motors with first-order spin-up, thrust
//! and reaction torque quadratic in motor speed, linear drag, gravity and the ground,
//! integrated with RK4 on a fixed grid of plant time. It sits beside `mav`'s 8-state model
//! (which stays the bench's default plant) and shares its `Dynamics` trait and `rk4_step`.
//!
//! It is a pure library: no clock, no I/O, no async. Time is an argument (integer nanoseconds
//! of plant time), and two runs given the same commands at the same times are bit-identical.
//!
//! # Frames and signs
//! - **World: ENU**, x east, y north, z up, origin on the ground (z = 0 is the ground), as
//!   `mav`'s model (z up). Gravity is `-gravity_mps2` along z.
//! - **Body: FLU**, x forward, y left, z up, origin at the centre of mass. The thrust of every
//!   motor is along body +z.
//! - **Attitude**: the unit quaternion that rotates body vectors into the world
//!   (`v_world = q * v_body`); identity is level with the nose pointing east.
//! - **Rates**: the body's angular velocity in body axes (what a gyro measures), right-handed
//!   about FLU axes: `x > 0` rolls right (right side down), `y > 0` pitches the nose down,
//!   `z > 0` yaws the nose left (counter-clockwise seen from above).
//! - **Accelerometer**: specific force (the non-gravitational force per unit mass) in body
//!   axes, so a body at rest, level, reads `+g` along body z.
//! - Betaflight's SITL wants aerospace frames (world NED, body FRD): [`frames`] converts, and
//!   [`betaflight`] gives the values its state packet carries, in the frames `sitl.c` reads.
//!
//! # Motors
//! Betaflight's QUADX order and default spin (props in, `yaw_motors_reversed = off`): motor 1
//! rear right CW, 2 front right CCW, 3 rear left CCW, 4 front left CW, seen from above
//! ([`motors::MOTORS`]; where each fact comes from in Betaflight's source is in that module).
//! Commands are normalised, `[0, 1]` per motor, mapped linearly to a commanded motor speed.

pub mod betaflight;
pub mod frames;
pub mod model;
pub mod motors;
pub mod params;
pub mod sim;

pub use model::{QuadModel, QuadState, STATE_LEN};
pub use motors::{CommandReport, MOTORS, MotorGeometry, Spin};
pub use params::{ParamError, QuadParams};
pub use sim::{Contact, ImuReading, QuadSample, QuadSim, SimError, SimSettings, Touchdown};
