//! Import of a million ping lines, statistics of a million entries, the fit of 100,000 delays
//! (every kind, with its bootstrap: the defaults of `hilbench trace fit`).
//!
//! `cargo bench -p linkfit`

use criterion::{Criterion, criterion_group, criterion_main};
use delay::{DelayLine, Direction, DirectionProfile, Distribution, Dwell, Fate, LOST_S, RegimeState};
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

/// `n` entries of a two-state regime that loses 8 % of its spikes and 0.2 % otherwise: the
/// regime is fitted twice (one loss share, a share per state).
fn lossy_regime(n: usize) -> Vec<f64> {
    let state = |mu, sigma, dwell, loss| RegimeState {
        loss_probability: Some(loss),
        ..RegimeState::new(Distribution::Lognormal { mu, sigma }, Dwell::Messages(dwell))
    };
    let d = Distribution::Regime {
        states: vec![state(-3.5, 0.2, 100.0, 0.002), state(-1.9, 0.3, 20.0, 0.08)].into(),
    };
    let mut line =
        DelayLine::new(Direction::ControllerToPlant, DirectionProfile::with_delay(d, 1)).expect("profile");
    (0..n as u64)
        .map(|k| {
            let decision = line.send(k * 50_000_000);
            if matches!(decision.fate, Fate::Dropped) { LOST_S } else { decision.sampled_delay_s }
        })
        .collect()
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
    let lossy = lossy_regime(100_000);
    g.bench_function("fit_100k_lossy_regime", |b| b.iter(|| fit(&lossy, &regime).expect("fit")));
    g.finish();
}

criterion_group!(linkfit_benches, benches);
criterion_main!(linkfit_benches);
