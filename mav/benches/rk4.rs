//! One RK4 step of the MAV model (the plant's truth integrator), 1 ms step.
//! Target (BENCHMARKS.md): at least 5 million steps per second on one core.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use mav::{Input, MavModel, State, rk4_step};
use std::hint::black_box;

fn rk4(c: &mut Criterion) {
    let model = MavModel::default();
    let u = Input::new(10.5, 0.05, -0.03);
    let mut group = c.benchmark_group("mav");
    group.throughput(Throughput::Elements(1));
    group.bench_function("rk4_step", |b| {
        // Chained steps (each uses the previous result), like the plant's integration loop.
        let mut x = State::from([0.0, 0.0, 1.0, 0.3, -0.2, 0.1, 0.05, -0.04]);
        b.iter(|| {
            x = rk4_step(black_box(&model), black_box(&x), black_box(&u), black_box(0.001));
        });
        black_box(x);
    });
    group.finish();
}

criterion_group!(benches, rk4);
criterion_main!(benches);
