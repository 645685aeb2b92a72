//! QP-linearized fallback: linearize + condense + clarabel solve for paper-2,
//! multi-stage (M = 5, N = 40, three cylinders). Target: median at most 3 ms. The default
//! settings against the full QP (no move blocking, every row from the start).
use criterion::{Criterion, criterion_group, criterion_main};
use mpc::{QpBudget, QpFallback, QpSettings};
use std::hint::black_box;

use mpc::fixtures::{U_PREV, W5, qp_cases};

fn qp_build_and_solve(c: &mut Criterion) {
    let (def, cases) = qp_cases();
    for case in &cases {
        let (x0, nominal) = (case.x0, Some(&case.nominal[..]));
        // The default (move-blocked corrections, lazy rows) and the full QP in all 120 inputs
        // with every row from the start (the fallback without move blocking or lazy rows).
        let full = QpSettings { block_steps: 1, lazy_slack_m: f64::INFINITY, ..Default::default() };
        for (variant, settings) in [("default", QpSettings::default()), ("full", full)] {
            let mut qp = QpFallback::new(&def, settings).expect("valid");
            let r = qp.solve(&x0, &U_PREV, &W5, nominal, &QpBudget::default()).expect("valid");
            eprintln!("qp/{}/{variant}: {} QP variables, {r:?}", case.name, qp.num_qp_variables());
            c.bench_function(
                &format!("qp_build_and_solve/paper-2/multistage/{}/{variant}", case.name),
                |b| {
                    b.iter(|| {
                        let r = qp
                            .solve(black_box(&x0), &U_PREV, &W5, nominal, &QpBudget::default())
                            .expect("valid");
                        black_box(r.status)
                    })
                },
            );
        }
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30);
    targets = qp_build_and_solve
}
criterion_main!(benches);
