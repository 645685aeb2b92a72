//! The survey's random delay traces (`delay-robustness`, `delay-diagnose`): trace `seed` of
//! each kind is the same in both, so that a trace the survey reports can be looked at.
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Gamma};

/// The kinds of trace, in the survey's order.
pub const KINDS: [&str; 3] = ["uniform", "gamma", "bursts"];

/// One trace of the survey: `kind:seed` on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TraceId {
    pub kind: &'static str,
    pub seed: u64,
}

impl std::str::FromStr for TraceId {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let (kind, seed) = s.split_once(':').ok_or("`kind:seed`, e.g. uniform:29")?;
        let kind =
            KINDS.into_iter().find(|k| *k == kind).ok_or(format!("kind `{kind}`: one of {KINDS:?}"))?;
        let seed = seed.parse().map_err(|e| format!("seed `{seed}`: {e}"))?;
        Ok(Self { kind, seed })
    }
}

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
