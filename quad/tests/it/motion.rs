//! Hover, free fall and the sign and size of each torque, against closed forms.

use approx::assert_relative_eq;
use quad::QuadParams;
use quad::betaflight::firmware_gyro;
use quad::frames::{attitude_frd_ned, euler_frd_ned, flu_to_frd};

use crate::fixtures::{SECOND_NS, advance, dragless, flying_at};

#[test]
fn hover_command_holds_the_body_still_for_ten_seconds() {
    let params = QuadParams::default();
    let mut sim = flying_at(params, 5.0, [params.hover_command(); 4]);
    let start = sim.state();
    advance(&mut sim, 10 * SECOND_NS);
    let end = sim.state();
    assert!((end.position_m - start.position_m).norm() < 1e-9, "drifted to {:?}", end.position_m);
    assert!(end.velocity_mps.norm() < 1e-9, "{:?}", end.velocity_mps);
    assert!(end.angular_velocity_rad_s.norm() < 1e-12, "{:?}", end.angular_velocity_rad_s);
    assert!(end.attitude.angle_to(&start.attitude) < 1e-12);
    assert!(!sim.contact().on_ground && sim.contact().touchdowns == 0);
    // The accelerometer feels the thrust that carries the weight: +g up the body.
    let f = sim.sample().imu.specific_force_body_mps2;
    assert_relative_eq!(f.z, params.gravity_mps2, max_relative = 1e-12);
    assert!(f.x.abs() < 1e-12 && f.y.abs() < 1e-12);
}

#[test]
fn free_fall_without_drag_is_the_parabola_to_rk4_precision() {
    let params = dragless();
    let z0 = 100.0;
    let mut sim = flying_at(params, z0, [0.0; 4]);
    for t_s in [0.5, 1.0, 2.0, 3.0] {
        advance(&mut sim, (t_s * 1e9) as u64);
        let s = sim.state();
        let g = params.gravity_mps2;
        assert_relative_eq!(s.position_m.z, z0 - 0.5 * g * t_s * t_s, max_relative = 1e-12);
        assert_relative_eq!(s.velocity_mps.z, -g * t_s, max_relative = 1e-12);
        assert_eq!((s.position_m.x, s.position_m.y), (0.0, 0.0));
        // Falling freely, an accelerometer reads nothing.
        assert!(sim.sample().imu.specific_force_body_mps2.norm() < 1e-15);
    }
}

/// Motors 1 and 4 (clockwise) above hover and 2 and 3 (counter-clockwise) below, the total
/// thrust the weight.
fn yaw_pair(params: &QuadParams, excess: f64) -> [f64; 4] {
    let w2 = params.hover_motor_speed_rad_s().powi(2);
    let hi = (w2 * (1.0 + excess)).sqrt() / params.max_motor_speed_rad_s;
    let lo = (w2 * (1.0 - excess)).sqrt() / params.max_motor_speed_rad_s;
    [hi, lo, lo, hi]
}

#[test]
fn clockwise_motors_faster_give_yaw_acceleration_torque_over_izz_to_the_left_and_no_roll_or_pitch() {
    let params = dragless();
    let commands = yaw_pair(&params, 0.1);
    let mut sim = flying_at(params, 10.0, commands);
    let w = sim.state().motor_speed_rad_s;
    let torque =
        params.torque_coefficient_n_m_per_rad2_s2 * (w[0] * w[0] + w[3] * w[3] - w[1] * w[1] - w[2] * w[2]);
    assert!(torque > 0.0);
    let alpha = torque / params.inertia_kg_m2[2];
    let t_s = 0.5;
    advance(&mut sim, SECOND_NS / 2);
    let s = sim.state();
    // Counter-clockwise seen from above: +z in FLU (nose left), -z in FRD.
    assert_relative_eq!(s.angular_velocity_rad_s.z, alpha * t_s, max_relative = 1e-12);
    assert!(s.angular_velocity_rad_s.x.abs() < 1e-12 && s.angular_velocity_rad_s.y.abs() < 1e-12);
    let (roll, pitch, _) = euler_frd_ned(&attitude_frd_ned(&s.attitude));
    assert!(roll.abs() < 1e-12 && pitch.abs() < 1e-12, "roll {roll} pitch {pitch}");
    // The yaw angle is the double integral: alpha t^2 / 2 about world up.
    let (_, _, yaw_enu) = s.attitude.euler_angles();
    assert_relative_eq!(yaw_enu, 0.5 * alpha * t_s * t_s, max_relative = 1e-9);
    assert!(flu_to_frd(&s.angular_velocity_rad_s).z < 0.0);
}

#[test]
fn left_motors_faster_roll_the_body_right_positive_frd_roll() {
    let params = dragless();
    let h = params.hover_command();
    let mut sim = flying_at(params, 10.0, [h; 4]);
    sim.set_commands([h, h, h + 0.02, h + 0.02]);
    advance(&mut sim, SECOND_NS / 5);
    let s = sim.state();
    assert!(s.angular_velocity_rad_s.x > 0.1, "{:?}", s.angular_velocity_rad_s);
    assert!(s.angular_velocity_rad_s.y.abs() < 1e-9 && s.angular_velocity_rad_s.z.abs() < 1e-9);
    let (roll, pitch, _) = euler_frd_ned(&attitude_frd_ned(&s.attitude));
    assert!(roll > 0.01 && pitch.abs() < 1e-9, "roll {roll} pitch {pitch}");
    // Rolled right, the thrust pushes the body to its right: south in ENU with the nose east.
    assert!(s.velocity_mps.y < 0.0);
}

#[test]
fn rear_motors_faster_pitch_the_nose_down_negative_frd_pitch() {
    let params = dragless();
    let h = params.hover_command();
    let mut sim = flying_at(params, 10.0, [h; 4]);
    sim.set_commands([h + 0.02, h, h + 0.02, h]);
    advance(&mut sim, SECOND_NS / 5);
    let s = sim.state();
    // Nose down is +y in FLU (about the left axis), -y (q < 0) in FRD.
    assert!(s.angular_velocity_rad_s.y > 0.1, "{:?}", s.angular_velocity_rad_s);
    assert!(s.angular_velocity_rad_s.x.abs() < 1e-9 && s.angular_velocity_rad_s.z.abs() < 1e-9);
    let (roll, pitch, _) = euler_frd_ned(&attitude_frd_ned(&s.attitude));
    assert!(pitch < -0.01 && roll.abs() < 1e-9, "roll {roll} pitch {pitch}");
    // Nose down, the thrust pushes the body forward: east with the nose east.
    assert!(s.velocity_mps.x > 0.0);
    // Betaflight's rate loop sees nose down as positive pitch.
    let gyro = firmware_gyro(flu_to_frd(&s.angular_velocity_rad_s).into());
    assert!(gyro[1] > 0.0);
}

#[test]
fn motors_follow_their_command_with_the_first_order_time_constant() {
    let params = dragless();
    let mut sim = flying_at(params, 50.0, [0.0; 4]);
    sim.set_commands([1.0; 4]);
    let tau = params.motor_time_constant_s;
    advance(&mut sim, (tau * 1e9) as u64);
    let expected = params.max_motor_speed_rad_s * (1.0 - (-1.0f64).exp());
    // RK4's relative error on a first-order lag is about (dt/tau)^5/120 a step: 1e-10 here.
    for w in sim.state().motor_speed_rad_s {
        assert_relative_eq!(w, expected, max_relative = 1e-8);
    }
}
