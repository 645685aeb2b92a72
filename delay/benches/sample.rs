//! Cost of deciding one message: drawing a delay, and a full `send` (delay, loss, duplicate,
//! FIFO), for the paper's Gamma, a 1000-delay trace (a scenario file's, ending the run at its
//! end) and a two-state regime. Target: at most 100 ns per delay and per `send` of a trace.

use criterion::{Criterion, criterion_group, criterion_main};
use delay::{DelayLine, Direction, DirectionProfile, Distribution, Dwell, RegimeState, Trace, preset};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let cases = [
        ("constant", Distribution::Constant { delay_s: 0.02 }),
        ("uniform", Distribution::Uniform { min_s: 0.01, max_s: 0.03 }),
        ("normal", Distribution::Normal { mean_s: 0.02, std_s: 0.005 }),
        ("gamma_12_0.015", Distribution::Gamma { shape: 12.0, scale_s: 0.015 }),
        ("lognormal", Distribution::Lognormal { mu: -4.0, sigma: 0.5 }),
        ("pareto", Distribution::Pareto { scale_s: 0.01, shape: 3.0 }),
    ];
    let mut g = c.benchmark_group("sample_delay");
    for (name, d) in cases {
        let Ok(mut line) = DelayLine::new(Direction::ControllerToPlant, DirectionProfile::with_delay(d, 42))
        else {
            continue;
        };
        g.bench_function(name, |b| b.iter(|| black_box(line.sample_delay_s())));
    }
    g.finish();
    let paper = preset("paper", 42).map(|p| p.to_plant).ok();
    // A trace as a scenario file gives it (stopping at its end), replayed from a fresh line for
    // every batch of 1000 messages so that no `send` runs past the end.
    let trace: Vec<f64> = (0..1000).map(|k| 0.02 + 0.001 * (k % 37) as f64).collect();
    let trace =
        DirectionProfile::with_delay(Distribution::Trace(Trace::from_file("bench.csv", trace, false)), 42);
    let regime = DirectionProfile::with_delay(
        Distribution::Regime {
            states: [
                RegimeState::new(Distribution::Lognormal { mu: -2.9, sigma: 0.3 }, Dwell::Messages(80.0)),
                RegimeState::new(Distribution::Uniform { min_s: 0.08, max_s: 0.33 }, Dwell::Seconds(1.0)),
            ]
            .into(),
        },
        42,
    );
    for (name, profile) in
        [("send_paper_fifo", paper), ("send_trace_fifo", Some(trace)), ("send_regime_fifo", Some(regime))]
    {
        let Some(profile) = profile else { continue };
        let Ok(fresh) = DelayLine::new(Direction::ControllerToPlant, profile) else { continue };
        c.bench_function(name, |b| {
            b.iter_batched_ref(
                || (fresh.clone(), 0u64),
                |(line, t)| {
                    for _ in 0..1000 {
                        *t += 50_000_000;
                        black_box(line.send(*t));
                    }
                },
                criterion::BatchSize::LargeInput,
            )
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
