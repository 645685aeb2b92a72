//! The motor command sanitiser: clamped and non-finite components are replaced and counted.

use quad::motors::sanitize_commands;
use quad::{QuadParams, QuadState};

use crate::fixtures::sim;

#[test]
fn out_of_range_commands_are_clamped_and_non_finite_ones_stop_the_motor_each_counted() {
    let (clean, report) = sanitize_commands([f64::NAN, 1.5, -0.2, 0.4]);
    assert_eq!(clean, [0.0, 1.0, 0.0, 0.4]);
    assert_eq!((report.non_finite, report.clamped), (1, 2));
    let (clean, report) = sanitize_commands([-0.0, f64::INFINITY, f64::NEG_INFINITY, 1.0]);
    assert!(clean[0].is_sign_positive(), "a zero is +0");
    assert_eq!(clean, [0.0, 0.0, 0.0, 1.0]);
    assert_eq!((report.non_finite, report.clamped), (2, 0));

    let mut s = sim(QuadParams::default(), QuadState::resting_at(0.0, 0.0));
    assert!(s.set_commands([0.1, 0.2, 0.3, 0.4]).is_clean());
    s.set_commands([f64::NAN, 2.0, 0.5, 0.5]);
    s.set_commands([0.5, 0.5, -1.0, 0.5]);
    let stats = s.command_stats();
    assert_eq!((stats.commands, stats.clamped, stats.non_finite), (3, 2, 1));
    assert_eq!(s.commands(), [0.5, 0.5, 0.0, 0.5]);
}
