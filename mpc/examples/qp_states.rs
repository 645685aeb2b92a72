//! The QP fallback on the problems of the paper closed loops (multi-stage, M = 5, N = 40):
//! for every cycle of paper-1/2/3, the QP the safety layer would solve there (the cycle's state,
//! the previous command, the cycle's weights, the previous plan shifted as nominal), timed as
//! build + clarabel solve. Prints the distribution per scenario. Argument: repetitions per
//! problem (the fastest counts; default 3).
use mpc::{
    ClosedLoopSettings, ControllerMode, ObstacleFormulation, OcpDefinition, QpBudget, QpFallback, QpSettings,
    run_closed_loop,
};
use std::time::Instant;

fn main() {
    let reps: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(3).max(1);
    let mut all = Vec::new();
    for scenario in [mav::Scenario::paper_1(), mav::Scenario::paper_2(), mav::Scenario::paper_3()] {
        let settings = ClosedLoopSettings::paper(ControllerMode::Multistage);
        let (_, records) = run_closed_loop(&scenario, &settings).expect("run");
        let def = OcpDefinition::from_scenario(
            &scenario,
            ControllerMode::Multistage,
            settings.mpc.obstacle_margin_m,
            ObstacleFormulation::DistanceAlm,
        );
        let mut qp = QpFallback::new(&def, QpSettings::default()).expect("valid");
        let mut times = Vec::new();
        let (mut iterations, mut solves, mut rows, mut solved) = (0u64, 0u64, 0u64, 0usize);
        for pair in records.windows(2) {
            let (prev, cur) = (&pair[0], &pair[1]);
            let mut nominal = prev.plan[3..].to_vec();
            nominal.extend_from_slice(&prev.plan[prev.plan.len() - 3..]);
            let mut best = f64::INFINITY;
            let mut last = None;
            for _ in 0..reps {
                let t = Instant::now();
                let r = qp
                    .solve(&cur.state, &prev.command, &cur.weights_used, Some(&nominal), &QpBudget::default())
                    .expect("valid");
                best = best.min(t.elapsed().as_secs_f64() * 1e3);
                last = Some(r);
            }
            // Deterministic: every repetition reports the same.
            if let Some(r) = last {
                iterations += u64::from(r.iterations);
                solves += r.clarabel_solves as u64;
                rows += r.num_clarabel_rows as u64;
                solved += usize::from(r.status.has_solution());
            }
            times.push(best);
        }
        let n = times.len();
        print_distribution(&scenario.name, &mut times.clone());
        println!(
            "    {n} problems, solved {solved}, mean clarabel iterations {:.1}, solves {:.2}, rows {:.0}",
            iterations as f64 / n as f64,
            solves as f64 / n as f64,
            rows as f64 / n as f64
        );
        all.extend(times);
    }
    print_distribution("all", &mut all);
}

fn print_distribution(name: &str, t: &mut [f64]) {
    t.sort_by(f64::total_cmp);
    let q = |p: f64| t[((t.len() - 1) as f64 * p).round() as usize];
    println!("{name}: median {:.3} ms, p95 {:.3} ms, max {:.3} ms", q(0.5), q(0.95), q(1.0));
}
