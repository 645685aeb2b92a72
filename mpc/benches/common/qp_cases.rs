//! The QP fallback's benchmark problems, shared by `benches/qp.rs` and `examples/profile_qp.rs`:
//! paper-2, multi-stage (M = 5, N = 40, three cylinders, margin 0.1 m), at the start and at a
//! state between the cylinders, each linearized around PANOC's plan from there shifted by one
//! step (the nominal as in the loop).
use mpc::{ControllerMode, Mpc, MpcSettings, ObstacleFormulation, OcpDefinition, SolveBudget};

pub const W5: [f64; 5] = [0.05, 0.15, 0.45, 0.30, 0.05];
pub const U_PREV: [f64; 3] = [9.81, 0.0, 0.0];

/// One problem: its name, the state and the nominal inputs.
pub struct QpCase {
    pub name: &'static str,
    pub x0: [f64; 8],
    pub nominal: Vec<f64>,
}

/// The definition and the two cases.
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
            QpCase { name, x0, nominal: mpc::shifted_plan(mpc.solution()) }
        })
        .collect();
    (def, cases)
}
