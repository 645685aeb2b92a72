//! The model's frame and the autopilot's, both ways: the one implementation the gateway and the
//! simulator share.
//!
//! The model (`docs/spec.md`) lives in a right-handed world frame with z up and a body frame
//! with x forward, y left, z up (FLU), and has no yaw: its thrust axis is
//! `R_y(theta) R_x(phi) e_z = (cos(phi) sin(theta), -sin(phi), cos(phi) cos(theta))`.
//! MAVLink's local frame is NED (x north, y east, z down) with an FRD body. The two world
//! frames differ by a half turn about x, `P = diag(1, -1, -1)`:
//!
//! - position and velocity: `x = x_n`, `y = -y_e`, `z = -z_d` (the same for `v`);
//! - attitude: `R_model = P R_ned P`, so with `R_ned = R_z(yaw) R_y(pitch) R_x(roll)` (ZYX),
//!   `R_model = R_z(-yaw) R_y(-pitch) R_x(roll)`. At yaw 0 that is `phi = roll`,
//!   `theta = -pitch`.
//!
//! A vehicle has a yaw, the model has none, so the angles are matched through the thrust axis,
//! which is what moves the vehicle: the model's `(phi, theta)` are the angles whose thrust
//! axis (above) is the vehicle's, `d = R_model e_z`: `phi = asin(-d_y)`,
//! `theta = atan2(d_x, d_z)`. Commands go the other way at the yaw held since arming: the NED
//! roll and pitch that, at that yaw, put the thrust axis where the model's angles put it.
//! The model's x and y stay the autopilot's local north and west whatever the vehicle's
//! heading, so obstacles are placed in the autopilot's local frame.

use mav::State;

/// What MAVLink reports of a vehicle: `LOCAL_POSITION_NED` and `ATTITUDE`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NedState {
    /// North, east, down, m.
    pub position_m: [f64; 3],
    /// North, east, down, m/s.
    pub velocity_mps: [f64; 3],
    /// ZYX Euler angles of the FRD body in NED, rad.
    pub roll_rad: f64,
    pub pitch_rad: f64,
    pub yaw_rad: f64,
}

/// The model's thrust axis for its angles (world frame, z up).
fn thrust_axis(phi: f64, theta: f64) -> [f64; 3] {
    let (sp, cp) = phi.sin_cos();
    let (st, ct) = theta.sin_cos();
    [cp * st, -sp, cp * ct]
}

/// The model's angles whose thrust axis is `d` (a unit vector).
fn angles_of_axis(d: [f64; 3]) -> (f64, f64) {
    ((-d[1]).clamp(-1.0, 1.0).asin(), d[0].atan2(d[2]))
}

/// Rotates `v` about z by `a`.
fn rot_z(a: f64, v: [f64; 3]) -> [f64; 3] {
    let (s, c) = a.sin_cos();
    [c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]]
}

/// The model's `(phi, theta)` for a vehicle at NED `roll`, `pitch`, `yaw`.
pub fn model_angles(roll_rad: f64, pitch_rad: f64, yaw_rad: f64) -> (f64, f64) {
    // R_model e_z = R_z(-yaw) R_y(-pitch) R_x(roll) e_z, and R_y(-pitch) R_x(roll) e_z is the
    // model's axis of (roll, -pitch).
    angles_of_axis(rot_z(-yaw_rad, thrust_axis(roll_rad, -pitch_rad)))
}

/// The NED `(roll, pitch)` that, at `yaw`, gives the model's angles `(phi, theta)`: the
/// inverse of [`model_angles`] at that yaw.
pub fn ned_angles(phi_rad: f64, theta_rad: f64, yaw_rad: f64) -> (f64, f64) {
    let (roll, minus_pitch) = angles_of_axis(rot_z(yaw_rad, thrust_axis(phi_rad, theta_rad)));
    (roll, -minus_pitch)
}

/// The model's state of a vehicle.
pub fn model_state(v: &NedState) -> State {
    let (phi, theta) = model_angles(v.roll_rad, v.pitch_rad, v.yaw_rad);
    let [pn, pe, pd] = v.position_m;
    let [vn, ve, vd] = v.velocity_mps;
    State::from([pn, -pe, -pd, vn, -ve, -vd, phi, theta])
}

/// What a vehicle at yaw `yaw_rad` in the model's state `x` reports (the simulator's side).
pub fn ned_state(x: &State, yaw_rad: f64) -> NedState {
    let (roll_rad, pitch_rad) = ned_angles(x[6], x[7], yaw_rad);
    NedState {
        position_m: [x[0], -x[1], -x[2]],
        velocity_mps: [x[3], -x[4], -x[5]],
        roll_rad,
        pitch_rad,
        yaw_rad,
    }
}

/// The quaternion `[w, x, y, z]` (MAVLink's order) of ZYX Euler angles.
pub fn quaternion_from_euler(roll_rad: f64, pitch_rad: f64, yaw_rad: f64) -> [f64; 4] {
    let (sr, cr) = (0.5 * roll_rad).sin_cos();
    let (sp, cp) = (0.5 * pitch_rad).sin_cos();
    let (sy, cy) = (0.5 * yaw_rad).sin_cos();
    [
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ]
}

/// ZYX Euler angles `(roll, pitch, yaw)` of a quaternion `[w, x, y, z]` (normalised here), or
/// `None` when it is not finite or has no length.
pub fn euler_from_quaternion(q: [f64; 4]) -> Option<(f64, f64, f64)> {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !n.is_finite() || n < 1e-6 {
        return None;
    }
    let [w, x, y, z] = q.map(|v| v / n);
    let roll = (2.0 * (w * x + y * z)).atan2(1.0 - 2.0 * (x * x + y * y));
    let pitch = (2.0 * (w * y - z * x)).clamp(-1.0, 1.0).asin();
    let yaw = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
    Some((roll, pitch, yaw))
}

/// The attitude setpoint quaternion (NED, FRD body) for the model's desired angles at `yaw`.
pub fn setpoint_quaternion(phi_rad: f64, theta_rad: f64, yaw_rad: f64) -> [f64; 4] {
    let (roll, pitch) = ned_angles(phi_rad, theta_rad, yaw_rad);
    quaternion_from_euler(roll, pitch, yaw_rad)
}

/// The model's desired angles of an attitude setpoint quaternion (the simulator's side), and
/// the yaw it asks for; `None` for a quaternion that is not finite or has no length.
pub fn setpoint_angles(q: [f64; 4]) -> Option<(f64, f64, f64)> {
    let (roll, pitch, yaw) = euler_from_quaternion(q)?;
    let (phi, theta) = model_angles(roll, pitch, yaw);
    Some((phi, theta, yaw))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const TILT: f64 = 0.6; // rad, beyond the paper's 10 degrees

    #[test]
    fn at_yaw_0_the_mapping_is_a_half_turn_about_north() {
        let v = NedState {
            position_m: [1.0, 2.0, -3.0],
            velocity_mps: [0.5, -0.25, 0.125],
            roll_rad: 0.1,
            pitch_rad: 0.2,
            yaw_rad: 0.0,
        };
        let x = model_state(&v);
        let expect = [1.0, -2.0, 3.0, 0.5, 0.25, -0.125, 0.1, -0.2];
        for (i, e) in expect.iter().enumerate() {
            assert!((x[i] - e).abs() < 1e-15, "x[{i}] = {} != {e}", x[i]);
        }
        // Positive model pitch accelerates towards +x = north: a nose-down NED pitch.
        let (roll, pitch) = ned_angles(0.0, 0.1, 0.0);
        assert!(roll.abs() < 1e-15 && (pitch + 0.1).abs() < 1e-15);
        // Positive model roll accelerates towards -y = east: right wing down, NED roll > 0.
        let (roll, pitch) = ned_angles(0.1, 0.0, 0.0);
        assert!((roll - 0.1).abs() < 1e-15 && pitch.abs() < 1e-15);
    }

    #[test]
    fn the_thrust_axis_is_the_same_in_both_frames_at_any_yaw() {
        // Model angles -> NED attitude at yaw -> the body's thrust axis in NED (-R e_z of the
        // FRD body), flipped to z up, equals the model's thrust axis.
        for yaw in [0.0, 0.7, -2.0, 3.1] {
            let (phi, theta) = (0.15, -0.08);
            let (roll, pitch) = ned_angles(phi, theta, yaw);
            let [w, x, y, z] = quaternion_from_euler(roll, pitch, yaw);
            // Third column of the rotation matrix: R e_z.
            let rz = [2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)];
            let up_ned = [-rz[0], -rz[1], -rz[2]]; // thrust points along -z_body
            let up_model = [up_ned[0], -up_ned[1], -up_ned[2]];
            let m = thrust_axis(phi, theta);
            for i in 0..3 {
                assert!((up_model[i] - m[i]).abs() < 1e-12, "yaw {yaw}: {up_model:?} != {m:?}");
            }
        }
    }

    proptest! {
        #[test]
        fn states_round_trip_both_ways(
            p in proptest::array::uniform3(-100.0f64..100.0),
            v in proptest::array::uniform3(-10.0f64..10.0),
            phi in -TILT..TILT, theta in -TILT..TILT, yaw in -3.1f64..3.1,
        ) {
            let x = State::from([p[0], p[1], p[2], v[0], v[1], v[2], phi, theta]);
            let back = model_state(&ned_state(&x, yaw));
            for i in 0..8 {
                prop_assert!((back[i] - x[i]).abs() < 1e-12, "x[{}]: {} != {}", i, back[i], x[i]);
            }
            let n = ned_state(&x, yaw);
            let again = ned_state(&model_state(&n), yaw);
            prop_assert!((again.roll_rad - n.roll_rad).abs() < 1e-12);
            prop_assert!((again.pitch_rad - n.pitch_rad).abs() < 1e-12);
        }

        #[test]
        fn setpoints_round_trip_through_the_quaternion(
            phi in -TILT..TILT, theta in -TILT..TILT, yaw in -3.1f64..3.1,
        ) {
            let q = setpoint_quaternion(phi, theta, yaw);
            let (p2, t2, y2) = setpoint_angles(q).expect("unit quaternion");
            prop_assert!((p2 - phi).abs() < 1e-12 && (t2 - theta).abs() < 1e-12);
            prop_assert!((y2 - yaw).abs() < 1e-12);
            // Through MAVLink's f32 as well.
            let q32 = q.map(|v| f64::from(v as f32));
            let (p3, t3, _) = setpoint_angles(q32).expect("unit quaternion");
            prop_assert!((p3 - phi).abs() < 1e-6 && (t3 - theta).abs() < 1e-6);
        }
    }

    #[test]
    fn a_quaternion_without_length_or_finite_values_has_no_angles() {
        assert_eq!(setpoint_angles([0.0; 4]), None);
        assert_eq!(setpoint_angles([f64::NAN, 0.0, 0.0, 1.0]), None);
    }
}
