//! The cost of the safety layer per control cycle: the whole in-process paper-2 closed loop
//! (multi-stage, 46 cycles) with the layer off, with the default QP schedule (every 5th cycle
//! and whenever PANOC's plan is rejected) and with the QP every cycle. Per-cycle cost = time /
//! cycles (printed once per variant).
use criterion::{Criterion, criterion_group, criterion_main};
use mpc::{ClosedLoopSettings, ControllerMode, QpSchedule, SafetySettings, run_closed_loop};
use std::hint::black_box;

fn closed_loop_per_cycle(c: &mut Criterion) {
    let scenario = mav::Scenario::paper_2();
    let variants: [(&str, Option<SafetySettings>); 3] = [
        ("safety_off", None),
        ("qp_every_5th", Some(SafetySettings::default())),
        (
            "qp_every_cycle",
            Some(SafetySettings { qp_schedule: QpSchedule::EveryCycle, ..Default::default() }),
        ),
    ];
    let mut group = c.benchmark_group("closed_loop/paper-2/multistage");
    group.sample_size(10);
    for (name, safety) in variants {
        let settings = ClosedLoopSettings { safety, ..ClosedLoopSettings::paper(ControllerMode::Multistage) };
        let (summary, _) = run_closed_loop(&scenario, &settings).expect("runs");
        eprintln!("{name}: {} cycles, decisions {:?}", summary.cycles, summary.decisions);
        group.bench_function(name, |b| {
            b.iter(|| black_box(run_closed_loop(black_box(&scenario), &settings).expect("runs").0.cycles))
        });
    }
    group.finish();
}

criterion_group!(benches, closed_loop_per_cycle);
criterion_main!(benches);
