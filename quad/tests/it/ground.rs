//! The ground: resting stays resting, a fall ends in a touchdown, full thrust lifts off.

use approx::assert_relative_eq;
use quad::{QuadParams, QuadState};

use crate::fixtures::{SECOND_NS, advance, dragless, flying_at, sim};

#[test]
fn resting_at_zero_throttle_stays_at_z_zero_without_nan() {
    let params = QuadParams::default();
    let mut s = sim(params, QuadState::resting_at(1.0, -2.0));
    for i in 1..=50 {
        advance(&mut s, i * SECOND_NS / 10);
        let x = s.state();
        assert!(x.is_finite());
        assert_eq!((x.position_m.x, x.position_m.y, x.position_m.z), (1.0, -2.0, 0.0));
        assert_eq!(x.velocity_mps.norm(), 0.0);
    }
    let c = s.contact();
    assert!(c.on_ground && c.touchdowns == 0 && c.last_touchdown.is_none());
    let imu = s.sample().imu;
    assert_relative_eq!(imu.specific_force_body_mps2.z, params.gravity_mps2, max_relative = 1e-15);
    assert_eq!(imu.angular_velocity_body_rad_s.norm(), 0.0);
}

#[test]
fn thrust_short_of_the_weight_stays_on_the_ground_and_spins_the_motors_up() {
    let params = QuadParams::default();
    let mut s = sim(params, QuadState::resting_at(0.0, 0.0));
    let c = 0.95 * params.hover_command();
    s.set_commands([c; 4]);
    advance(&mut s, 2 * SECOND_NS);
    assert_eq!(s.state().position_m.z, 0.0);
    assert!(s.contact().on_ground);
    for w in s.state().motor_speed_rad_s {
        assert_relative_eq!(w, c * params.max_motor_speed_rad_s, max_relative = 1e-9);
    }
}

#[test]
fn a_fall_from_one_metre_touches_down_at_sqrt_2gh_and_stops() {
    let params = dragless();
    let mut s = flying_at(params, 1.0, [0.0; 4]);
    advance(&mut s, 2 * SECOND_NS);
    let c = s.contact();
    let Some(touchdown) = c.last_touchdown else { panic!("no touchdown: {c:?}") };
    assert_eq!(c.touchdowns, 1);
    assert!(c.on_ground);
    let g = params.gravity_mps2;
    let expected = (2.0 * g * 1.0).sqrt();
    // Found at the end of the step that went below: at most one step's gain late.
    let step_s = 1e-3;
    assert!(
        touchdown.vertical_speed_mps >= expected && touchdown.vertical_speed_mps <= expected + g * step_s,
        "{touchdown:?} vs {expected}"
    );
    let t_expected_ns = (expected / g * 1e9) as u64;
    assert!(touchdown.time_ns >= t_expected_ns && touchdown.time_ns <= t_expected_ns + 1_000_000);
    assert_eq!(touchdown.horizontal_speed_mps, 0.0);
    let x = s.state();
    assert_eq!((x.position_m.z, x.velocity_mps.norm()), (0.0, 0.0));
}

#[test]
fn full_throttle_lifts_off_the_ground() {
    let params = QuadParams::default();
    let mut s = sim(params, QuadState::resting_at(0.0, 0.0));
    s.set_commands([1.0; 4]);
    advance(&mut s, SECOND_NS);
    assert!(s.state().position_m.z > 1.0, "{:?}", s.state().position_m);
    assert!(!s.contact().on_ground);
    assert_eq!(s.contact().touchdowns, 0);
}
