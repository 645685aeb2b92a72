//! Profiling target for the QP fallback: the two states of `benches/qp.rs`, solved repeatedly
//! (run under `perf stat -e instructions:u` or callgrind: instruction counts do not depend on
//! the load of the machine). Argument: solves per state (default 100). Settings to explore
//! from the environment: `QP_LAZY` (lazy_slack_m), `QP_UNBLOCKED`, `QP_BLOCK`, `QP_ROUNDS`
//! (max_lazy_rounds), `QP_REFINE` (1: iterative refinement on).
use mpc::{
    ControllerMode, Mpc, MpcSettings, ObstacleFormulation, OcpDefinition, QpBudget, QpFallback, QpSettings,
    SolveBudget,
};

const W5: [f64; 5] = [0.05, 0.15, 0.45, 0.30, 0.05];

fn main() {
    let reps: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(100);
    let scenario = mav::Scenario::paper_2();
    let def = OcpDefinition::from_scenario(
        &scenario,
        ControllerMode::Multistage,
        0.1,
        ObstacleFormulation::DistanceAlm,
    );
    let u_prev = [9.81, 0.0, 0.0];
    let cases = [("start", scenario.start), ("between_cylinders", [3.3, 2.2, 0.9, 0.0, 0.6, 0.1, 0.0, 0.0])];
    for (name, x0) in cases {
        let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
        mpc.solve(&x0, &u_prev, &W5, &SolveBudget::default()).expect("valid");
        let plan = mpc.solution().to_vec();
        let mut nominal = plan[3..].to_vec();
        nominal.extend_from_slice(&plan[plan.len() - 3..]);
        let envf = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<f64>().ok());
        let mut settings = QpSettings::default();
        if let Some(v) = envf("QP_LAZY") {
            settings.lazy_slack_m = v;
        }
        if let Some(v) = envf("QP_UNBLOCKED") {
            settings.unblocked_steps = v as usize;
        }
        if let Some(v) = envf("QP_REFINE") {
            settings.iterative_refinement = v > 0.0;
        }
        if let Some(v) = envf("QP_ROUNDS") {
            settings.max_lazy_rounds = v as usize;
        }
        if let Some(v) = envf("QP_BLOCK") {
            settings.block_steps = v as usize;
        }
        let mut qp = QpFallback::new(&def, settings).expect("valid");
        let t = std::time::Instant::now();
        let mut last = None;
        for _ in 0..reps {
            last = Some(qp.solve(&x0, &u_prev, &W5, Some(&nominal), &QpBudget::default()).expect("valid"));
        }
        let per = t.elapsed().as_secs_f64() * 1e3 / reps as f64;
        if let Some(r) = last {
            println!(
                "{name}: {per:.3} ms/solve, status {:?}, iterations {}, clarabel solves {}, rows {}, cost {:.4}, clearance {:.4}",
                r.status, r.iterations, r.clarabel_solves, r.num_clarabel_rows, r.cost, r.min_clearance_m
            );
        }
    }
}
