//! Robustness survey: paper-2 with the multi-stage controller under many random delay traces
//! (uniform, Gamma, bursts in [0, 0.33] s), counting collisions and misses. Settings from the
//! environment: MARGIN (m), FLOOR (m), COMP (dead-time compensation), NOSAFETY, CASES.
use mpc::{ClosedLoopSettings, ControllerMode, DelaySource, run_closed_loop};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Gamma};

fn main() {
    let cases: u64 = std::env::var("CASES").ok().and_then(|c| c.parse().ok()).unwrap_or(20);
    let mut scenario = mav::Scenario::paper_2();
    scenario.delay_compensation = std::env::var("COMP").is_ok();
    scenario.min_altitude_m = std::env::var("FLOOR").ok().and_then(|z| z.parse().ok());
    let mut settings = ClosedLoopSettings::paper(ControllerMode::Multistage);
    if let Some(m) = std::env::var("MARGIN").ok().and_then(|m| m.parse().ok()) {
        settings.mpc.obstacle_margin_m = m;
    }
    if std::env::var("NOSAFETY").is_ok() {
        settings.safety = None;
    }
    // Width of the i.i.d. uniform jitter, s: delays uniform in [a, a + width], a random.
    let width: f64 = std::env::var("WIDTH").ok().and_then(|w| w.parse().ok()).unwrap_or(0.33);
    for kind in ["uniform", "gamma", "bursts"] {
        let (mut collided, mut missed, mut fallbacks) = (0, 0, 0);
        for seed in 0..cases {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed * 7919 + kind.len() as u64);
            let len = rng.random_range(20..200);
            let trace: Vec<f64> = match kind {
                "uniform" => {
                    let low = rng.random_range(0.0..=0.33 - width);
                    (0..len).map(|_| rng.random_range(low..=low + width)).collect()
                }
                "gamma" => {
                    let g: Gamma<f64> =
                        Gamma::new(rng.random_range(1.0..30.0), rng.random_range(0.002..0.04))
                            .expect("gamma");
                    (0..len).map(|_| g.sample(&mut rng).min(0.33)).collect()
                }
                _ => {
                    let base = rng.random_range(0.0..0.06);
                    let mut t = vec![base; len];
                    let mut at = 0;
                    for _ in 0..rng.random_range(1..6) {
                        at += rng.random_range(0..30);
                        let (w, level) = (rng.random_range(1..15), rng.random_range(0.15..=0.33));
                        for d in t.iter_mut().skip(at).take(w) {
                            *d = level;
                        }
                        at += w;
                    }
                    t
                }
            };
            // ONLY=kind:seed runs one trace and prints its cycles (what the controller decided).
            let only = std::env::var("ONLY").ok();
            if only.as_ref().is_some_and(|o| *o != format!("{kind}:{seed}")) {
                continue;
            }
            settings.delays = Some(DelaySource::Trace(trace));
            let (s, records) = run_closed_loop(&scenario, &settings).expect("run");
            if only.is_some() {
                for r in &records {
                    let p = &r.state;
                    let reason = r.selection.as_ref().map(|s| s.reason()).unwrap_or_default();
                    println!(
                        "{:4} t={:6.2} p=[{:5.2},{:5.2},{:5.2}] d={:.3} {reason}",
                        r.cycle, r.t_s, p[0], p[1], p[2], r.delay_s
                    );
                }
            }
            if s.collided || !s.reached {
                let mean = trace_mean(settings.delays.as_ref());
                println!(
                    "  {kind} seed {seed}: collided {} reached {} clearance {:.3} mean delay {mean:.3}",
                    s.collided, s.reached, s.min_clearance_m
                );
            }
            collided += usize::from(s.collided);
            missed += usize::from(!s.reached);
            fallbacks += s.fallbacks;
        }
        println!(
            "{kind}: {cases} traces, {collided} collided, {missed} missed the goal, {fallbacks} fallback cycles"
        );
    }
}

fn trace_mean(d: Option<&DelaySource>) -> f64 {
    match d {
        Some(DelaySource::Trace(t)) => t.iter().sum::<f64>() / t.len() as f64,
        _ => f64::NAN,
    }
}
