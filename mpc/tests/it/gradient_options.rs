//! The adjoint gradient with the options beyond the paper: the floor constraint and dead-time
//! compensation, against central finite differences (the paper's problem is covered by the
//! unit tests of `mpc::problem`).

use mav::Scenario;
use mpc::problem::check_gradient;
use mpc::{ControllerMode, Evaluator, ObstacleFormulation, OcpDefinition};
use proptest::prelude::*;

fn definition(form: ObstacleFormulation, floor_m: f64, compensation: bool) -> OcpDefinition {
    let scenario =
        Scenario { min_altitude_m: Some(floor_m), delay_compensation: compensation, ..Scenario::paper_2() };
    OcpDefinition::from_scenario(&scenario, ControllerMode::Multistage, 0.1, form)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn gradient_matches_finite_differences_with_floor_and_compensation(
        z in prop::collection::vec(-1.0f64..1.0, 120),
        pz in 0.0f64..1.0, vz in -1.5f64..0.5, vy in 0.0f64..2.0,
        floor_m in 0.2f64..0.8,
        compensation in any::<bool>(),
        paper_form in any::<bool>(),
        c in prop::sample::select(vec![1e2, 1e4]),
        y_scale in 0.0f64..50.0,
    ) {
        let form = if paper_form { ObstacleFormulation::PaperPenalty } else { ObstacleFormulation::DistanceAlm };
        let def = definition(form, floor_m, compensation);
        let mut ev = Evaluator::new(&def);
        let x0 = [3.1, 1.0, pz, 0.1, vy, vz, 0.02, -0.03];
        ev.set_instance(&x0, &[9.0, 0.05, -0.05], &[0.05, 0.15, 0.45, 0.30, 0.05]);
        let nc = def.num_constraints();
        prop_assert_eq!(nc, 5 * 40 * 4, "three cylinders and the floor per point");
        let y: Vec<f64> = if paper_form { Vec::new() } else { (0..nc).map(|k| y_scale * ((k % 7) as f64) / 7.0).collect() };
        let r = check_gradient(&mut ev, &z, c, &y);
        prop_assert!(r.is_ok(), "{:?}", r);
    }
}

/// The floor is active in those tests (some predicted point is below it), and compensation
/// moves each scenario's first predicted point by one step of its own sampling time.
#[test]
fn the_floor_is_active_and_compensation_moves_the_prediction() {
    let x0 = [3.1, 1.0, 0.3, 0.1, 1.0, -1.0, 0.02, -0.03];
    let u_prev = [9.0, 0.05, -0.05];
    let w = [0.05, 0.15, 0.45, 0.30, 0.05];
    let z = vec![0.0; 120];
    let mut plain = Evaluator::new(&definition(ObstacleFormulation::DistanceAlm, 0.5, false));
    plain.set_instance(&x0, &u_prev, &w);
    let mut out = vec![0.0; 5 * 40 * 4];
    plain.constraints(&z, &mut out);
    let floor_values: Vec<f64> = out.iter().skip(3).step_by(4).copied().collect();
    assert!(floor_values.iter().any(|v| *v > 0.0), "some point below the floor");
    let mut compensated = Evaluator::new(&definition(ObstacleFormulation::DistanceAlm, 0.5, true));
    compensated.set_instance(&x0, &u_prev, &w);
    compensated.constraints(&z, &mut out);
    for (i, dt) in [0.05, 0.07, 0.1, 0.2, 0.33].iter().enumerate() {
        let start = compensated.predicted_states(i)[0];
        assert!((start[1] - (x0[1] + dt * x0[4])).abs() < 1e-12, "scenario {i}: y after the dead time");
        assert_eq!(plain.predicted_states(i)[0], x0);
    }
}
