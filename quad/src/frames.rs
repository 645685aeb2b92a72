//! Conversions between the crate's frames (world ENU, body FLU) and the aerospace frames
//! flight firmware uses (world NED, body FRD).
//!
//! Both changes are half turns, so each conversion is its own inverse: ENU <-> NED swaps x and
//! y and negates z (a half turn about the horizontal axis between east and north), FLU <-> FRD
//! negates y and z (a half turn about the nose).

use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// A world vector from ENU to NED, or back.
pub fn enu_to_ned(v: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(v.y, v.x, -v.z)
}

/// A world vector from NED to ENU (the same map as [`enu_to_ned`]).
pub fn ned_to_enu(v: &Vector3<f64>) -> Vector3<f64> {
    enu_to_ned(v)
}

/// A body vector (or angular velocity) from FLU to FRD, or back.
pub fn flu_to_frd(v: &Vector3<f64>) -> Vector3<f64> {
    Vector3::new(v.x, -v.y, -v.z)
}

/// A body vector from FRD to FLU (the same map as [`flu_to_frd`]).
pub fn frd_to_flu(v: &Vector3<f64>) -> Vector3<f64> {
    flu_to_frd(v)
}

/// NED from ENU: the half turn about `(1, 1, 0) / sqrt(2)`.
fn ned_from_enu() -> UnitQuaternion<f64> {
    let h = std::f64::consts::FRAC_1_SQRT_2;
    UnitQuaternion::new_unchecked(Quaternion::new(0.0, h, h, 0.0))
}

/// FLU from FRD: the half turn about x.
fn flu_from_frd() -> UnitQuaternion<f64> {
    UnitQuaternion::new_unchecked(Quaternion::new(0.0, 1.0, 0.0, 0.0))
}

/// The attitude as body FRD to world NED, from body FLU to world ENU: what Betaflight's SITL
/// takes as `imu_orientation_quat`.
pub fn attitude_frd_ned(flu_to_enu: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    ned_from_enu() * flu_to_enu * flu_from_frd()
}

/// The attitude as body FLU to world ENU, from body FRD to world NED.
pub fn attitude_flu_enu(frd_to_ned: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    // Both half turns are their own inverses (as rotations).
    ned_from_enu() * frd_to_ned * flu_from_frd()
}

/// Aerospace Euler angles `(roll, pitch, yaw)`, rad, of a body FRD to world NED attitude
/// (Z-Y-X: yaw about down, then pitch, then roll): roll > 0 is the right side down, pitch > 0
/// the nose up, yaw the heading clockwise from north.
pub fn euler_frd_ned(frd_to_ned: &UnitQuaternion<f64>) -> (f64, f64, f64) {
    frd_to_ned.euler_angles()
}
