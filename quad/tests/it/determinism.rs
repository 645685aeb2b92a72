//! Bit-determinism: the same commands at the same plant times give the same bits, however
//! the advances were split on the grid.

use nalgebra::{UnitQuaternion, Vector3};
use quad::{QuadParams, QuadSim, QuadState, SimError};

use crate::fixtures::{SECOND_NS, advance, sim};

fn initial() -> QuadState {
    let p = QuadParams::default();
    QuadState {
        attitude: UnitQuaternion::from_euler_angles(0.1, -0.05, 0.7),
        angular_velocity_rad_s: Vector3::new(0.3, -0.2, 0.1),
        ..QuadState::hovering_at(&p, Vector3::new(1.0, 2.0, 3.0))
    }
}

/// Commands changing every 20 ms (off the 1 ms grid at 20.5 ms), flown to 2 s with
/// `advance` called at every multiple of `stride_ns` in between (a multiple of the step: a
/// stop off the grid adds a step boundary, which changes the bits, as documented).
fn fly(stride_ns: u64) -> Vec<u64> {
    let mut s: QuadSim = sim(QuadParams::default(), initial());
    let mut t = 0;
    for k in 0..100u64 {
        let c = 0.55 + 0.05 * ((k as f64) * 0.7).sin();
        s.set_commands([c, 1.1 - c, c, 1.1 - c]);
        let end = k * 20_000_000 + 20_500_000;
        // Stops at the multiples of the stride (on the grid) before the command's end.
        while (t / stride_ns + 1).saturating_mul(stride_ns) < end {
            t = (t / stride_ns + 1) * stride_ns;
            advance(&mut s, t);
        }
        t = end;
        advance(&mut s, t);
    }
    advance(&mut s, 2 * SECOND_NS + 500_000);
    s.state().to_vector().iter().map(|v| v.to_bits()).collect()
}

#[test]
fn two_runs_split_differently_on_the_grid_are_bit_identical() {
    let once = fly(u64::MAX / 4);
    assert_eq!(once, fly(u64::MAX / 4));
    assert_eq!(once, fly(1_000_000));
    assert_eq!(once, fly(5_000_000));
}

#[test]
fn time_never_runs_backwards() {
    let mut s = sim(QuadParams::default(), initial());
    advance(&mut s, 10_000_000);
    assert_eq!(
        s.advance_to(9_999_999),
        Err(SimError::TimeBackwards { now_ns: 10_000_000, asked_ns: 9_999_999 })
    );
    assert!(s.advance_to(10_000_000).is_ok());
    s.step();
    assert_eq!(s.time_ns(), 11_000_000);
}
