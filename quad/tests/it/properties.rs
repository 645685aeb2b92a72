//! Properties over random attitudes, rates and commands.

use mav::rk4_step;
use nalgebra::{UnitQuaternion, Vector3};
use proptest::prelude::*;
use quad::{QuadModel, QuadParams, QuadState};

use crate::fixtures::sim;

fn state(roll: f64, pitch: f64, yaw: f64, rates: [f64; 3]) -> QuadState {
    QuadState {
        attitude: UnitQuaternion::from_euler_angles(roll, pitch, yaw),
        angular_velocity_rad_s: Vector3::from(rates),
        ..QuadState::hovering_at(&QuadParams::default(), Vector3::new(0.0, 0.0, 50.0))
    }
}

proptest! {
    #[test]
    fn one_rk4_step_keeps_the_quaternion_norm_and_the_simulation_keeps_it_unit(
        roll in -3.1..3.1f64, pitch in -1.5..1.5f64, yaw in -3.1..3.1f64,
        rates in proptest::array::uniform3(-10.0..10.0f64),
        commands in proptest::array::uniform4(0.0..=1.0f64),
    ) {
        let params = QuadParams::default();
        let Ok(model) = QuadModel::new(params) else { panic!("valid") };
        let x0 = state(roll, pitch, yaw, rates);
        // Before normalisation: the step itself keeps the norm to RK4's error.
        let x1 = rk4_step(&model, &x0.to_vector(), &model.commanded_speeds(&commands), 1e-3);
        let norm = x1.fixed_rows::<4>(quad::model::idx::ATTITUDE).norm();
        prop_assert!((norm - 1.0).abs() < 1e-9, "norm {}", norm);

        let mut s = sim(params, x0);
        s.set_commands(commands);
        for _ in 0..300 {
            s.step();
        }
        let x = s.state();
        prop_assert!(x.is_finite());
        prop_assert!((x.attitude.quaternion().norm() - 1.0).abs() < 1e-12);
        prop_assert!(x.motor_speed_rad_s.iter().all(|w| (0.0..=params.max_motor_speed_rad_s).contains(w)));
    }
}
