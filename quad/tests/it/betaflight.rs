//! Betaflight's motor order, mixer signs and the frames of its SITL packets: what the firmware
//! asks for on each axis is what the body does, as the firmware sees it.

use approx::assert_relative_eq;
use nalgebra::{UnitQuaternion, Vector3};
use quad::betaflight::{
    FdmState, firmware_attitude, firmware_gyro, motors_from_servo_packet, quadx_mix, servo_packet_from_motors,
};
use quad::frames::{attitude_flu_enu, attitude_frd_ned, enu_to_ned, euler_frd_ned, flu_to_frd};
use quad::{MOTORS, QuadParams, Spin};

use crate::fixtures::{SECOND_NS, advance, dragless, flying_at};

#[test]
fn motor_order_and_spin_are_betaflights_quadx_props_in() {
    let names: Vec<_> = MOTORS.iter().map(|m| m.name).collect();
    assert_eq!(names, ["rear right", "front right", "rear left", "front left"]);
    let spins: Vec<_> = MOTORS.iter().map(|m| m.spin).collect();
    use Spin::{Clockwise as Cw, CounterClockwise as Ccw};
    assert_eq!(spins, [Cw, Ccw, Ccw, Cw]);
    // Front is +x and left is +y in FLU.
    for (m, (front, left)) in MOTORS.iter().zip([(false, false), (true, false), (false, true), (true, true)])
    {
        assert_eq!((m.direction_flu[0] > 0.0, m.direction_flu[1] > 0.0), (front, left), "{}", m.name);
    }
}

#[test]
fn quadx_mix_is_mixer_init_c_table_with_the_default_yaw_reversal() {
    // mixerQuadX (throttle, roll, pitch, yaw) rows REAR_R, FRONT_R, REAR_L, FRONT_L, and
    // mixer.c's negation of yaw when yaw_motors_reversed is off.
    let table =
        [[1.0, -1.0, 1.0, -1.0], [1.0, -1.0, -1.0, 1.0], [1.0, 1.0, 1.0, 1.0], [1.0, 1.0, -1.0, -1.0]];
    for (axis, demand) in
        [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
            .iter()
            .enumerate()
    {
        let got = quadx_mix(demand[0], demand[1], demand[2], demand[3]);
        let sign = if axis == 3 { -1.0 } else { 1.0 };
        let want: [f64; 4] = std::array::from_fn(|m| sign * table[m][axis]);
        assert_eq!(got, want, "axis {axis}");
    }
}

#[test]
fn servo_packet_carries_motors_2_3_4_1_and_is_put_back_in_betaflight_order() {
    assert_eq!(motors_from_servo_packet([2.0, 3.0, 4.0, 1.0]), [1.0, 2.0, 3.0, 4.0]);
    let motors = [0.25, 0.5, 0.75, 1.0];
    assert_eq!(motors_from_servo_packet(servo_packet_from_motors(motors)), motors);
}

/// Flies `demand` (roll, pitch, yaw in the firmware's axes) mixed by Betaflight's QUADX mix
/// about hover for 0.1 s, and returns what the firmware reads from the FDM packet: its gyro
/// and its attitude, before and after.
fn fly_demand(demand: [f64; 3]) -> ([f64; 3], [f64; 3], [f64; 3]) {
    let params = dragless();
    let mut sim = flying_at(params, 10.0, [params.hover_command(); 4]);
    let before = firmware_attitude(FdmState::from_sample(&sim.sample()).imu_orientation_quat);
    sim.set_commands(quadx_mix(params.hover_command(), demand[0], demand[1], demand[2]));
    advance(&mut sim, SECOND_NS / 10);
    let fdm = FdmState::from_sample(&sim.sample());
    (firmware_gyro(fdm.imu_angular_velocity_rpy), before, firmware_attitude(fdm.imu_orientation_quat))
}

#[test]
fn a_roll_right_demand_from_the_mixer_rolls_right_as_the_firmware_measures_it() {
    let (gyro, before, after) = fly_demand([0.02, 0.0, 0.0]);
    assert!(gyro[0] > 0.1, "{gyro:?}");
    assert!(gyro[1].abs() < 1e-9 && gyro[2].abs() < 1e-9, "{gyro:?}");
    // The firmware's roll angle moves the way its roll rate says: ANGLE mode closes the loop.
    assert!(after[0] > before[0]);
}

#[test]
fn a_pitch_demand_from_the_mixer_pitches_the_way_the_firmware_measures_it() {
    // Positive pitch in the firmware is nose down (forward stick).
    let (gyro, before, after) = fly_demand([0.0, 0.02, 0.0]);
    assert!(gyro[1] > 0.1, "{gyro:?}");
    assert!(gyro[0].abs() < 1e-9 && gyro[2].abs() < 1e-9, "{gyro:?}");
    assert!(after[1] > before[1], "{before:?} -> {after:?}");
}

#[test]
fn a_yaw_demand_from_the_mixer_yaws_the_way_the_firmware_measures_it() {
    // Positive yaw in the firmware's rate loop is nose left; its heading (clockwise from
    // north) then decreases.
    let (gyro, before, after) = fly_demand([0.0, 0.0, 0.05]);
    assert!(gyro[2] > 0.01, "{gyro:?}");
    assert!(gyro[0].abs() < 1e-9 && gyro[1].abs() < 1e-9, "{gyro:?}");
    assert!(after[2] < before[2], "{before:?} -> {after:?}");
}

#[test]
fn fdm_values_at_hover_are_level_frd_ned_with_minus_g_on_z() {
    let params = QuadParams::default();
    let sim = flying_at(params, 2.0, [params.hover_command(); 4]);
    let fdm = FdmState::from_sample(&sim.sample());
    assert!(fdm.imu_orientation_quat[0] >= 0.0);
    let [fx, fy, fz] = fdm.imu_linear_acceleration_xyz;
    assert!(fx.abs() < 1e-12 && fy.abs() < 1e-12);
    assert_relative_eq!(fz, -params.gravity_mps2, max_relative = 1e-12);
    // Nose east: heading 90 degrees, level.
    let [roll, pitch, heading] = firmware_attitude(fdm.imu_orientation_quat);
    assert!(roll.abs() < 1e-12 && pitch.abs() < 1e-12);
    assert_relative_eq!(heading, std::f64::consts::FRAC_PI_2, epsilon = 1e-12);
    assert_eq!(fdm.position_ned_m, [0.0, 0.0, -2.0]);
    assert_eq!(fdm.position_enu_m, [0.0, 0.0, 2.0]);
}

#[test]
fn frame_conversions_map_axes_and_aerospace_angles_as_documented() {
    let v = Vector3::new(1.0, 2.0, 3.0);
    assert_eq!(enu_to_ned(&v), Vector3::new(2.0, 1.0, -3.0));
    assert_eq!(flu_to_frd(&v), Vector3::new(1.0, -2.0, -3.0));
    // Nose north in ENU (yaw +90 degrees about up) is heading 0 in NED.
    let north = UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
    let (r, p, y) = euler_frd_ned(&attitude_frd_ned(&north));
    assert!(r.abs() < 1e-12 && p.abs() < 1e-12 && y.abs() < 1e-12, "{r} {p} {y}");
    // A right roll is about +x in both bodies; nose up is -y in FLU, +pitch in FRD.
    let (r, _, _) = euler_frd_ned(&attitude_frd_ned(&UnitQuaternion::from_euler_angles(0.1, 0.0, 0.0)));
    assert_relative_eq!(r, 0.1, epsilon = 1e-12);
    let (_, p, _) = euler_frd_ned(&attitude_frd_ned(&UnitQuaternion::from_euler_angles(0.0, -0.2, 0.0)));
    assert_relative_eq!(p, 0.2, epsilon = 1e-12);
    // Round trip, and the same body vector in both frames points the same way in the world.
    let q = UnitQuaternion::from_euler_angles(0.3, -0.5, 2.0);
    assert!(attitude_flu_enu(&attitude_frd_ned(&q)).angle_to(&q) < 1e-12);
    let world_enu = q * v;
    let world_ned = attitude_frd_ned(&q) * flu_to_frd(&v);
    assert!((enu_to_ned(&world_enu) - world_ned).norm() < 1e-12);
}

/// `sitl.c` re-estimates its clock rate from a state packet only when its timestamp is 0 to
/// 20 ms (exclusive) after the previous one's: the wall-clock stamps never fall in that window
/// and never go back, so the firmware's clock keeps the wall clock's rate.
#[test]
fn wall_clock_stamps_never_step_by_less_than_20_ms_nor_go_back() {
    use quad::betaflight::wall_clock_timestamp_s;
    let mut previous = wall_clock_timestamp_s(0);
    let mut steps = 0;
    // 30 s of 1 kHz state packets with a jittered period (0.3 to 1.7 ms).
    let mut t_ns = 0u64;
    for k in 0..30_000u64 {
        t_ns += 300_000 + (k * 7_919 % 1_400_000);
        let stamp = wall_clock_timestamp_s(t_ns);
        let delta = stamp - previous;
        assert!(delta == 0.0 || delta >= 0.02, "a step of {delta} s at {t_ns} ns");
        steps += usize::from(delta > 0.0);
        previous = stamp;
    }
    // They still say the time, to 0.1 s.
    assert!((previous - mav::ns_to_s(t_ns)).abs() < 0.1);
    assert!(steps > 100, "{steps} steps");
}
