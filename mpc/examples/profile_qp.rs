//! Profiling target for the QP fallback: the two problems of `benches/qp.rs`, solved
//! repeatedly, for instruction counts under callgrind (they do not depend on the load of the
//! machine, unlike wall times). Argument: solves per problem (default 100). Settings to
//! explore from the environment: `QP_LAZY` (lazy_slack_m), `QP_UNBLOCKED`, `QP_BLOCK`,
//! `QP_ROUNDS` (max_lazy_rounds), `QP_REFINE` (1: iterative refinement on), `QP_ELASTIC`
//! (elastic_penalty_per_m).
use mpc::{QpBudget, QpFallback, QpSettings};

#[path = "../benches/common/qp_cases.rs"]
mod qp_cases;
use qp_cases::{U_PREV, W5, qp_cases};

fn main() {
    let reps: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(100);
    let env = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<f64>().ok());
    let mut settings = QpSettings::default();
    if let Some(v) = env("QP_LAZY") {
        settings.lazy_slack_m = v;
    }
    if let Some(v) = env("QP_UNBLOCKED") {
        settings.unblocked_steps = v as usize;
    }
    if let Some(v) = env("QP_BLOCK") {
        settings.block_steps = v as usize;
    }
    if let Some(v) = env("QP_ROUNDS") {
        settings.max_lazy_rounds = v as usize;
    }
    if let Some(v) = env("QP_REFINE") {
        settings.iterative_refinement = v > 0.0;
    }
    settings.elastic_penalty_per_m = env("QP_ELASTIC");
    if let Some(v) = env("QP_SCREEN") {
        settings.screen_runs = v > 0.0;
    }
    if let Some(v) = env("QP_ADD") {
        settings.lazy_add_margin_m = v;
    }
    if let Some(v) = env("QP_GAP") {
        settings.gap_tolerance = v;
    }
    if let Some(v) = env("QP_FEAS") {
        settings.feasibility_tolerance = v;
    }
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
