//! Fixed problem instances shared by the crate's criterion benches and the `lab` crate's
//! profiling targets, so that a profile and a bench measure the same thing. Compiled always
//! (hidden from the docs), not behind a cargo feature: a package build and a workspace build
//! then resolve `mpc` alike.
use crate::{ControllerMode, Evaluator, Mpc, MpcSettings, ObstacleFormulation, OcpDefinition, SolveBudget};

/// The `cost_and_gradient` instance: a state between paper-2's cylinders at 1.5 m/s, equal
/// scenario weights, hover as the last input, fixed scaled inputs and no multipliers.
/// Returns the evaluator with the instance set, the scaled inputs `z`, the multipliers `y`
/// and a gradient buffer.
pub fn eval_case(def: &OcpDefinition) -> (Evaluator, Vec<f64>, Vec<f64>, Vec<f64>) {
    let mut ev = Evaluator::new(def);
    let m = def.num_scenarios();
    let weights = vec![1.0 / m as f64; m];
    let mut x0 = [0.0; 8];
    x0[..3].copy_from_slice(&[3.1, 1.2, 0.6]);
    x0[4] = 1.5;
    ev.set_instance(&x0, &[9.81, 0.0, 0.0], &weights);
    let n = ev.num_variables();
    let z: Vec<f64> = (0..n).map(|k| ((k * 7919) % 13) as f64 * 0.05 - 0.3).collect();
    let y = vec![0.0; def.num_constraints()];
    (ev, z, y, vec![0.0; n])
}

/// The QP fallback's scenario weights (M = 5).
pub const W5: [f64; 5] = [0.05, 0.15, 0.45, 0.30, 0.05];
/// The QP fallback's previous input (hover).
pub const U_PREV: [f64; 3] = [9.81, 0.0, 0.0];

/// One QP fallback problem: its name, the state and the nominal inputs.
pub struct QpCase {
    pub name: &'static str,
    pub x0: [f64; 8],
    pub nominal: Vec<f64>,
}

/// The QP fallback's problems: paper-2, multi-stage (M = 5, N = 40, three cylinders, margin
/// 0.1 m), at the start and at a state between the cylinders, each linearized around PANOC's
/// plan from there shifted by one step (the nominal as in the loop).
pub fn qp_cases() -> (OcpDefinition, Vec<QpCase>) {
    let scenario = mav::Scenario::paper_2();
    let def = OcpDefinition::from_scenario(
        &scenario,
        ControllerMode::Multistage,
        0.1,
        ObstacleFormulation::DistanceAlm,
    );
    let states = [("start", scenario.start), ("between_cylinders", [3.3, 2.2, 0.9, 0.0, 0.6, 0.1, 0.0, 0.0])];
    let cases = states
        .into_iter()
        .map(|(name, x0)| {
            let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
            mpc.solve(&x0, &U_PREV, &W5, &SolveBudget::default()).expect("valid");
            QpCase { name, x0, nominal: crate::shifted_plan(mpc.solution()) }
        })
        .collect();
    (def, cases)
}
