//! Cost of deciding one message: drawing a delay, and a full `send` (delay, loss, duplicate,
//! FIFO). Target: at most 100 ns per delay.

use criterion::{Criterion, criterion_group, criterion_main};
use delay::{DelayLine, Direction, DirectionProfile, Distribution, preset};
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
    if let Some(mut line) =
        preset("paper", 42).ok().and_then(|p| DelayLine::new(Direction::ControllerToPlant, p.to_plant).ok())
    {
        let mut t = 0u64;
        c.bench_function("send_paper_fifo", |b| {
            b.iter(|| {
                t += 1_000_000;
                black_box(line.send(t))
            })
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
