//! Import of a million ping lines, statistics of a million entries, the fit of 100,000 delays
//! (every kind, with its bootstrap: the defaults of `hilbench trace fit`).
//!
//! `cargo bench -p linkfit`

use criterion::{Criterion, criterion_group, criterion_main};
use delay::{DelayLine, Direction, DirectionProfile, Distribution};
use linkfit::{FitOptions, Format, ImportOptions, Kind, StatsOptions, fit, import, trace_stats};

/// `n` lines of Linux ping output, every 50th reply missing.
fn ping_text(n: u64) -> String {
    let mut s = String::with_capacity(70 * n as usize);
    s.push_str("PING 127.0.0.1 (127.0.0.1) 56(84) bytes of data.\n");
    for k in 1..=n {
        if k % 50 != 0 {
            s.push_str(&format!(
                "64 bytes from 127.0.0.1: icmp_seq={} ttl=64 time={:.3} ms\n",
                k % 65_536,
                10.0 + (k % 97) as f64 * 0.1
            ));
        }
    }
    s.push_str(&format!("{n} packets transmitted, {} received, 2% packet loss, time 1ms\n", n - n / 50));
    s
}

fn gamma(n: usize) -> Vec<f64> {
    let p = DirectionProfile::with_delay(Distribution::Gamma { shape: 12.0, scale_s: 0.015 }, 1);
    let mut line = DelayLine::new(Direction::ControllerToPlant, p).expect("profile");
    (0..n).map(|_| line.sample_delay_s()).collect()
}

fn benches(c: &mut Criterion) {
    let text = ping_text(1_000_000);
    let mut g = c.benchmark_group("linkfit");
    g.sample_size(10);
    g.bench_function("import_ping_1M_lines", |b| {
        b.iter(|| import(&text, &ImportOptions::new(Format::Ping)).expect("imported"))
    });
    let entries = import(&text, &ImportOptions::new(Format::Ping)).expect("imported").trace.delays_s;
    g.bench_function("stats_1M_entries", |b| {
        b.iter(|| trace_stats(&entries, &StatsOptions::default()).expect("stats"))
    });
    let x = gamma(100_000);
    g.bench_function("fit_100k_all_kinds", |b| b.iter(|| fit(&x, &FitOptions::default()).expect("fit")));
    let iid = FitOptions {
        kinds: vec![Kind::Gamma, Kind::Lognormal, Kind::Pareto, Kind::Weibull],
        ..FitOptions::default()
    };
    g.bench_function("fit_100k_iid_kinds", |b| b.iter(|| fit(&x, &iid).expect("fit")));
    let regime = FitOptions { kinds: vec![Kind::Regime], ..FitOptions::default() };
    g.bench_function("fit_100k_regime", |b| b.iter(|| fit(&x, &regime).expect("fit")));
    g.finish();
}

criterion_group!(linkfit_benches, benches);
criterion_main!(linkfit_benches);
