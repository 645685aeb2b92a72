//! QP-linearized fallback (issue 5): linearize + condense + clarabel solve for paper-2,
//! multi-stage (M = 5, N = 40, three cylinders). Target: median at most 3 ms. The default
//! settings against the full QP (no move blocking, every row from the start).
use criterion::{Criterion, criterion_group, criterion_main};
use mpc::{
    ControllerMode, Mpc, MpcSettings, ObstacleFormulation, OcpDefinition, QpBudget, QpFallback, QpSettings,
    SolveBudget,
};
use std::hint::black_box;

const W5: [f64; 5] = [0.05, 0.15, 0.45, 0.30, 0.05];

fn qp_build_and_solve(c: &mut Criterion) {
    let scenario = mav::Scenario::paper_2();
    let def = OcpDefinition::from_scenario(
        &scenario,
        ControllerMode::Multistage,
        0.1,
        ObstacleFormulation::DistanceAlm,
    );
    let u_prev = [9.81, 0.0, 0.0];
    // (name, state): the start, and a state between the cylinders on the way to the goal.
    let cases = [("start", scenario.start), ("between_cylinders", [3.3, 2.2, 0.9, 0.0, 0.6, 0.1, 0.0, 0.0])];
    for (name, x0) in cases {
        // Nominal as in the loop: a previous plan (PANOC's, here) shifted by one step.
        let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
        mpc.solve(&x0, &u_prev, &W5, &SolveBudget::default()).expect("valid");
        let plan = mpc.solution().to_vec();
        let mut nominal = plan[3..].to_vec();
        nominal.extend_from_slice(&plan[plan.len() - 3..]);
        // The default (move-blocked corrections, lazy rows) and the full QP in all 120 inputs
        // with every row from the start (the fallback before issue 5's speed-up).
        let full = QpSettings { block_steps: 1, lazy_slack_m: f64::INFINITY, ..Default::default() };
        for (variant, settings) in [("default", QpSettings::default()), ("full", full)] {
            let mut qp = QpFallback::new(&def, settings).expect("valid");
            let r = qp.solve(&x0, &u_prev, &W5, Some(&nominal), &QpBudget::default()).expect("valid");
            eprintln!("qp/{name}/{variant}: {} QP variables, {r:?}", qp.num_qp_variables());
            c.bench_function(&format!("qp_build_and_solve/paper-2/multistage/{name}/{variant}"), |b| {
                b.iter(|| {
                    let r = qp
                        .solve(black_box(&x0), &u_prev, &W5, Some(&nominal), &QpBudget::default())
                        .expect("valid");
                    black_box(r.status)
                })
            });
        }
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30);
    targets = qp_build_and_solve
}
criterion_main!(benches);
