//! The cost of the safety layer per control cycle: the whole in-process paper-2 closed loop
//! (multi-stage, 46 cycles) with the layer off, with the default QP schedule (every 5th cycle
//! and whenever PANOC's plan is rejected), with the QP every cycle, and with the default
//! schedule and the fail-safe check. Per-cycle cost = time / cycles (printed once per
//! variant). Also one fail-safe check (`FailSafe::envelope`) alone, between the cylinders.
use criterion::{Criterion, criterion_group, criterion_main};
use mpc::{
    BrakingCheck, ClosedLoopSettings, ControllerMode, FailSafe, InFlight, QpSchedule, SafetySettings,
    run_closed_loop,
};
use std::hint::black_box;

fn closed_loop_per_cycle(c: &mut Criterion) {
    let scenario = mav::Scenario::paper_2();
    let variants: [(&str, Option<SafetySettings>); 4] = [
        ("safety_off", None),
        ("qp_every_5th", Some(SafetySettings::default())),
        (
            "qp_every_cycle",
            Some(SafetySettings { qp_schedule: QpSchedule::EveryCycle, ..Default::default() }),
        ),
        (
            "fail_safe_check",
            Some(SafetySettings { braking_check: Some(BrakingCheck::default()), ..Default::default() }),
        ),
    ];
    let mut group = c.benchmark_group("closed_loop/paper-2/multistage");
    group.sample_size(10);
    for (name, safety) in variants {
        let mut settings = ClosedLoopSettings::paper(ControllerMode::Multistage);
        settings.episode.safety = safety;
        let (summary, _) = run_closed_loop(&scenario, &settings).expect("runs");
        eprintln!("{name}: {} cycles, decisions {:?}", summary.cycles, summary.decisions);
        group.bench_function(name, |b| {
            b.iter(|| black_box(run_closed_loop(black_box(&scenario), &settings).expect("runs").0.cycles))
        });
    }
    group.finish();
}

fn fail_safe_envelope(c: &mut Criterion) {
    let s = mav::Scenario::paper_2();
    let fs = FailSafe::new(BrakingCheck::default(), s.model, s.bounds, s.obstacles.clone(), 1.0);
    // Between the first two cylinders at 1.5 m/s, tilted, the previous command a climb.
    let x0 = [3.1, 1.2, 0.6, 0.1, 1.5, 0.2, 0.05, -0.02];
    let (u_prev, u) = ([10.5, 0.05, -0.02], [10.0, 0.1, 0.0]);
    let e = fs.envelope(&x0, &u_prev, &u);
    eprintln!("envelope: clearance {:.3} m, altitude {:.3} m", e.min_clearance_m, e.min_altitude_m);
    c.bench_function("fail_safe/envelope/paper-2", |b| {
        b.iter(|| black_box(fs.envelope(black_box(&x0), &u_prev, &u)))
    });
    // Real time: the same with the last three commands still in flight.
    let in_flight: Vec<InFlight> =
        [0.15, 0.1, 0.05].iter().map(|&sent_ago_s| InFlight { sent_ago_s, command: u_prev }).collect();
    let e = fs.envelope_real_time(&x0, &u_prev, &in_flight, &u);
    eprintln!("real time: clearance {:.3} m, altitude {:.3} m", e.min_clearance_m, e.min_altitude_m);
    c.bench_function("fail_safe/envelope_real_time/paper-2", |b| {
        b.iter(|| black_box(fs.envelope_real_time(black_box(&x0), &u_prev, &in_flight, &u)))
    });
}

criterion_group!(benches, closed_loop_per_cycle, fail_safe_envelope);
criterion_main!(benches);
