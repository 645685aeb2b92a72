//! Profiling target for the QP fallback: the two problems of `benches/qp.rs`, solved
//! repeatedly, for instruction counts under callgrind (they do not depend on the load of the
//! machine, unlike wall times). Argument: solves per problem (default 100). Settings from the
//! environment (`benches/common/qp_env.rs`); `QP_ONLY` picks one problem.
use mpc::{QpBudget, QpFallback};

#[path = "../benches/common/qp_env.rs"]
mod qp_env;

#[path = "../benches/common/qp_cases.rs"]
mod qp_cases;
use qp_cases::{U_PREV, W5, qp_cases};

fn main() {
    let reps: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(100);
    let settings = qp_env::qp_settings_from_env();
    let (def, cases) = qp_cases();
    let only = std::env::var("QP_ONLY").ok();
    for case in cases.iter().filter(|c| only.as_ref().is_none_or(|o| o == c.name)) {
        let mut qp = QpFallback::new(&def, settings).expect("valid settings");
        let t = std::time::Instant::now();
        let mut last = None;
        for _ in 0..reps {
            last = Some(
                qp.solve(&case.x0, &U_PREV, &W5, Some(&case.nominal), &QpBudget::default()).expect("valid"),
            );
        }
        let per_ms = t.elapsed().as_secs_f64() * 1e3 / reps.max(1) as f64;
        if let Some(r) = last {
            println!(
                "{}: {per_ms:.3} ms/solve, status {:?}, iterations {}, clarabel solves {}, rows {}, cost {:.4}, clearance {:.4}",
                case.name,
                r.status,
                r.iterations,
                r.clarabel_solves,
                r.num_clarabel_rows,
                r.cost,
                r.min_clearance_m
            );
        }
    }
}
