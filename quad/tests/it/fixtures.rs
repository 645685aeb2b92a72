//! Simulations the tests start from.

use nalgebra::Vector3;
use quad::{QuadParams, QuadSim, QuadState, SimSettings};

/// The default quadrotor without drag of either kind, so motion has closed forms.
pub fn dragless() -> QuadParams {
    QuadParams {
        drag_coefficient_n_s_per_m: 0.0,
        rotational_drag_n_m_s_per_rad: 0.0,
        ..QuadParams::default()
    }
}

pub fn sim(params: QuadParams, initial: QuadState) -> QuadSim {
    match QuadSim::new(params, SimSettings::default(), initial) {
        Ok(sim) => sim,
        Err(e) => panic!("a valid simulation: {e}"),
    }
}

/// Hovering at `z_m`, every motor at the speed `commands` hold (so nothing spins up), those
/// commands set.
pub fn flying_at(params: QuadParams, z_m: f64, commands: [f64; 4]) -> QuadSim {
    let mut initial = QuadState::hovering_at(&params, Vector3::new(0.0, 0.0, z_m));
    initial.motor_speed_rad_s = commands.map(|c| c * params.max_motor_speed_rad_s);
    let mut s = sim(params, initial);
    assert!(s.set_commands(commands).is_clean());
    s
}

pub fn advance(sim: &mut QuadSim, time_ns: u64) {
    if let Err(e) = sim.advance_to(time_ns) {
        panic!("advance to {time_ns} ns: {e}");
    }
}

pub const SECOND_NS: u64 = 1_000_000_000;
