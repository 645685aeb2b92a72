//! The survey's random delay traces (`delay_robustness`, `delay_diagnose`): trace `seed` of
//! each kind is the same in both, so that a trace the survey reports can be looked at; and
//! the fail-safe check both take from the environment.
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Gamma};

/// Trace `seed` of `kind` (`uniform`, `gamma`, `bursts`), delays in `[0, 0.33]` s; `uniform`
/// draws i.i.d. delays in `[a, a + width_s]` with `a` random.
pub fn trace(kind: &str, seed: u64, width_s: f64) -> Vec<f64> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed * 7919 + kind.len() as u64);
    let len = rng.random_range(20..200);
    match kind {
        "uniform" => {
            let low = rng.random_range(0.0..=0.33 - width_s);
            (0..len).map(|_| rng.random_range(low..=low + width_s)).collect()
        }
        "gamma" => {
            let g: Gamma<f64> =
                Gamma::new(rng.random_range(1.0..30.0), rng.random_range(0.002..0.04)).expect("gamma");
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
    }
}

/// Width of the survey's i.i.d. uniform jitter from `WIDTH` (s; default 0.33, the whole range):
/// delays uniform in `[a, a + width]`, `a` random.
pub fn width_from_env() -> f64 {
    std::env::var("WIDTH").ok().and_then(|w| w.parse().ok()).unwrap_or(0.33)
}

/// paper-2 and the multi-stage controller as the environment asks: `COMP` (dead-time
/// compensation), `FLOOR` (m), `MARGIN` (m), `NOSAFETY` (no safety layer), `FAILSAFE=1` (the
/// fail-safe check: first input, then braking, under every delay up to `DMAX` s, `SAMPLES`
/// delays per cycle).
pub fn setup_from_env() -> (mav::Scenario, mpc::ClosedLoopSettings) {
    let mut scenario = mav::Scenario::paper_2();
    scenario.delay_compensation = std::env::var("COMP").is_ok();
    scenario.min_altitude_m = std::env::var("FLOOR").ok().and_then(|z| z.parse().ok());
    let mut settings = mpc::ClosedLoopSettings::paper(mpc::ControllerMode::Multistage);
    if let Some(m) = std::env::var("MARGIN").ok().and_then(|m| m.parse().ok()) {
        settings.mpc.obstacle_margin_m = m;
    }
    if std::env::var("NOSAFETY").is_ok() {
        settings.safety = None;
    }
    if std::env::var("FAILSAFE").is_ok()
        && let Some(safety) = settings.safety.as_mut()
    {
        let mut check = mpc::BrakingCheck::default();
        if let Some(d) = std::env::var("DMAX").ok().and_then(|d| d.parse().ok()) {
            check.max_delay_s = d;
        }
        if let Some(n) = std::env::var("SAMPLES").ok().and_then(|n| n.parse().ok()) {
            check.delay_samples = n;
        }
        safety.braking_check = Some(check);
    }
    (scenario, settings)
}
