//! The delay line against the laws it claims to draw from, and its reproducibility contract.

mod common;
use common::ks;
use delay::{DelayLine, Direction, DirectionProfile, Distribution, Fate, Ordering, Trace, preset};
use proptest::prelude::*;
use statrs::distribution::{Continuous, ContinuousCDF, Gamma, Normal};

fn line(d: Distribution, seed: u64) -> DelayLine {
    match DelayLine::new(Direction::ControllerToPlant, DirectionProfile::with_delay(d.clone(), seed)) {
        Ok(l) => l,
        Err(e) => panic!("valid profile {d:?} refused: {e}"),
    }
}

fn samples(d: Distribution, seed: u64, n: usize) -> Vec<f64> {
    let mut l = line(d, seed);
    (0..n).map(|_| l.sample_delay_s()).collect()
}

/// Critical value of the one-sample KS test at level 0.001 (asymptotic, n large).
fn ks_critical(n: usize) -> f64 {
    1.949 / (n as f64).sqrt()
}

#[test]
fn gamma_samples_pass_kolmogorov_smirnov_and_a_wrong_law_fails() {
    let n = 10_000;
    for (i, (shape, scale)) in
        [(12.0, 0.015), (6.0, 0.015), (1.0, 0.05), (0.5, 0.2), (40.0, 0.001)].into_iter().enumerate()
    {
        let xs = samples(Distribution::Gamma { shape, scale_s: scale }, 1000 + i as u64, n);
        let Ok(law) = Gamma::new(shape, 1.0 / scale) else { panic!("statrs gamma") };
        let d = ks(xs.clone(), |x| law.cdf(x));
        assert!(d < ks_critical(n), "Gamma({shape}, {scale}): KS D = {d} >= {}", ks_critical(n));
        // The test has power: the same samples against a Gamma with a 10% larger scale fail.
        let Ok(wrong) = Gamma::new(shape, 1.0 / (scale * 1.1)) else { panic!("statrs gamma") };
        let d_wrong = ks(xs, |x| wrong.cdf(x));
        assert!(d_wrong > ks_critical(n), "Gamma({shape}, {scale}) vs wrong scale: D = {d_wrong}");
    }
    // By moments: Gamma(mean 0.18, std 0.052) is Gamma(12, 0.015) up to rounding.
    let (mean, std) = (0.18, 0.18 / 12f64.sqrt());
    let xs = samples(Distribution::GammaMoments { mean_s: mean, std_s: std }, 5, n);
    let Ok(law) = Gamma::new(12.0, 1.0 / 0.015) else { panic!("statrs gamma") };
    assert!(ks(xs, |x| law.cdf(x)) < ks_critical(n));
}

fn mean_var(xs: &[f64]) -> (f64, f64) {
    let n = xs.len() as f64;
    let m = xs.iter().sum::<f64>() / n;
    (m, xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0))
}

#[test]
fn every_distribution_has_its_mean_and_variance() {
    let std_normal = Normal::standard();
    // Normal(0.01, 0.01) truncated at zero: mean mu + s*l, var s^2 (1 + a l - l^2).
    let (mu, s) = (0.01, 0.01);
    let a = -mu / s;
    let l = std_normal.pdf(a) / (1.0 - std_normal.cdf(a));
    let trunc_mean = mu + s * l;
    let trunc_var = s * s * (1.0 + a * l - l * l);
    let (lm, ls) = (-4.0f64, 0.5f64);
    let (pm, pa) = (0.01f64, 5.0f64);
    let cases: Vec<(Distribution, f64, f64)> = vec![
        (Distribution::Constant { delay_s: 0.02 }, 0.02, 0.0),
        (Distribution::Uniform { min_s: 0.01, max_s: 0.05 }, 0.03, 0.04f64.powi(2) / 12.0),
        (Distribution::Normal { mean_s: 0.05, std_s: 0.01 }, 0.05, 1e-4),
        (Distribution::Normal { mean_s: mu, std_s: s }, trunc_mean, trunc_var),
        (Distribution::Gamma { shape: 12.0, scale_s: 0.015 }, 0.18, 12.0 * 0.015f64.powi(2)),
        (Distribution::GammaMoments { mean_s: 0.1, std_s: 0.03 }, 0.1, 0.03f64.powi(2)),
        (
            Distribution::Lognormal { mu: lm, sigma: ls },
            (lm + ls * ls / 2.0).exp(),
            ((ls * ls).exp() - 1.0) * (2.0 * lm + ls * ls).exp(),
        ),
        (
            Distribution::Pareto { scale_s: pm, shape: pa },
            pa * pm / (pa - 1.0),
            pm * pm * pa / ((pa - 1.0).powi(2) * (pa - 2.0)),
        ),
    ];
    let n = 200_000;
    for (i, (d, mean, var)) in cases.into_iter().enumerate() {
        let xs = samples(d.clone(), 77 + i as u64, n);
        assert!(xs.iter().all(|x| *x >= 0.0), "{d:?} drew a negative delay");
        let (m, v) = mean_var(&xs);
        // Mean within 5 standard errors; variance within 5% (3% for the light-tailed laws).
        let se = (var / n as f64).sqrt();
        assert!((m - mean).abs() <= 5.0 * se + 1e-12, "{d:?}: mean {m} vs {mean}");
        let tol = if matches!(d, Distribution::Pareto { .. } | Distribution::Lognormal { .. }) {
            0.05
        } else {
            0.03
        };
        assert!((v - var).abs() <= tol * var + 1e-12, "{d:?}: variance {v} vs {var}");
    }
}

#[test]
fn trace_replay_reproduces_the_trace_exactly() -> Result<(), delay::TraceError> {
    let trace = delay::parse_trace("# recorded\n0.0125\n0.0031\n0.2\n0\n0.047\n")?;
    let mut p = DirectionProfile::with_delay(Distribution::Trace(Trace::looping(trace.clone())), 1);
    p.ordering = Ordering::Independent;
    let Ok(mut l) = DelayLine::new(Direction::PlantToController, p) else { panic!("valid trace refused") };
    for k in 0..3 * trace.len() {
        let send = k as u64 * 1_000_000;
        let d = l.send(send);
        let want = trace[k % trace.len()];
        assert_eq!(d.sampled_delay_s.to_bits(), want.to_bits());
        let r = d.releases().next().map(|r| r.release_time_ns);
        assert_eq!(r, Some(send + (want * 1e9).round() as u64));
    }
    Ok(())
}

#[test]
fn same_seed_gives_the_same_delays_bit_for_bit_and_directions_differ() {
    let Ok(p) = preset("paper", 42) else { panic!("paper preset") };
    let mut p = p.to_plant;
    p.loss_probability = 0.1;
    p.duplicate_probability = 0.1;
    let run = |dir| {
        let Ok(mut l) = DelayLine::new(dir, p.clone()) else { panic!("paper") };
        (0..5_000u64).map(|k| l.send(k * 50_000_000)).collect::<Vec<_>>()
    };
    let a = run(Direction::ControllerToPlant);
    let b = run(Direction::ControllerToPlant);
    assert_eq!(a, b);
    let bits = |v: &[delay::Decision]| v.iter().map(|d| d.sampled_delay_s.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a), bits(&b));
    assert_ne!(bits(&a), bits(&run(Direction::PlantToController)));
    // A reset line replays the same decisions.
    let Ok(mut l) = DelayLine::new(Direction::ControllerToPlant, p.clone()) else { panic!("paper") };
    let first: Vec<_> = (0..10u64).map(|k| l.send(k)).collect();
    l.reset();
    let again: Vec<_> = (0..10u64).map(|k| l.send(k)).collect();
    assert_eq!(first, again);
}

/// Pins the generator: the first paper-preset delays of seed 42. If this changes, every
/// recorded run of the bench changes with it (a `rand`, `rand_distr` or ChaCha change).
#[test]
fn paper_delays_of_seed_42_are_pinned() {
    let Ok(p) = preset("paper", 42) else { panic!("paper preset") };
    let Ok(mut l) = DelayLine::new(Direction::ControllerToPlant, p.to_plant) else { panic!("paper") };
    let got: Vec<u64> = (0..4).map(|_| l.sample_delay_s().to_bits()).collect();
    let want: Vec<u64> = PINNED.to_vec();
    assert_eq!(got, want, "as f64: {:?}", got.iter().map(|b| f64::from_bits(*b)).collect::<Vec<_>>());
}

const PINNED: [u64; 4] = [4598725846221011057, 4596865186719971591, 4594629538141744736, 4597836008234703831];

fn any_distribution() -> impl Strategy<Value = Distribution> {
    prop_oneof![
        (0.0..0.5f64).prop_map(|d| Distribution::Constant { delay_s: d }),
        (0.0..0.1f64, 0.0..0.4f64).prop_map(|(a, w)| Distribution::Uniform { min_s: a, max_s: a + w }),
        (0.0..0.2f64, 0.0..0.1f64).prop_map(|(m, s)| Distribution::Normal { mean_s: m, std_s: s }),
        (0.2..20.0f64, 0.001..0.05f64).prop_map(|(k, t)| Distribution::Gamma { shape: k, scale_s: t }),
        (-6.0..-1.0f64, 0.0..1.5f64).prop_map(|(m, s)| Distribution::Lognormal { mu: m, sigma: s }),
        (0.001..0.05f64, 0.5..5.0f64).prop_map(|(s, a)| Distribution::Pareto { scale_s: s, shape: a }),
        (proptest::collection::vec(0.0..0.3f64, 1..20), any::<bool>())
            .prop_map(|(v, l)| Distribution::Trace(if l { Trace::looping(v) } else { Trace::holding(v) })),
    ]
}

proptest! {
    #[test]
    fn fifo_never_reorders(
        d in any_distribution(),
        seed in any::<u64>(),
        dup in 0.0..1.0f64,
        gaps in proptest::collection::vec(0u64..50_000_000, 1..300),
    ) {
        let mut p = DirectionProfile::with_delay(d, seed);
        p.duplicate_probability = dup;
        let mut l = DelayLine::new(Direction::ControllerToPlant, p).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let mut t = 0u64;
        let mut last = 0u64;
        for g in gaps {
            t += g;
            let dec = l.send(t);
            for r in dec.releases() {
                prop_assert!(r.release_time_ns >= last, "released {} before an earlier {}", r.release_time_ns, last);
                prop_assert!(r.release_time_ns >= t + delay::delay_ns(r.sampled_delay_s));
                prop_assert_eq!(r.delay_ns, r.release_time_ns - t);
                last = r.release_time_ns;
            }
        }
    }

    #[test]
    fn zero_loss_loses_nothing(d in any_distribution(), seed in any::<u64>(), dup in 0.0..1.0f64, n in 1usize..500) {
        let mut p = DirectionProfile::with_delay(d, seed);
        p.duplicate_probability = dup;
        p.ordering = Ordering::Independent;
        let mut l = DelayLine::new(Direction::PlantToController, p).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let mut stats = delay::DirectionStats::default();
        for k in 0..n as u64 {
            let dec = l.send(k * 1_000);
            prop_assert!(dec.fate != Fate::Dropped);
            stats.record_decision(&dec);
            for r in dec.releases() { stats.record_delivered(r.delay_ns); }
        }
        prop_assert_eq!(stats.dropped, 0);
        prop_assert_eq!(stats.delivered, stats.sent + stats.duplicated);
    }

    #[test]
    fn the_delays_do_not_depend_on_loss_or_duplication(seed in any::<u64>(), loss in 0.0..1.0f64, dup in 0.0..1.0f64) {
        let base = DirectionProfile::with_delay(Distribution::Gamma { shape: 12.0, scale_s: 0.015 }, seed);
        let mut lossy = base.clone();
        lossy.loss_probability = loss;
        lossy.duplicate_probability = dup;
        let (Ok(mut a), Ok(mut b)) = (DelayLine::new(Direction::ControllerToPlant, base), DelayLine::new(Direction::ControllerToPlant, lossy)) else {
            return Err(TestCaseError::fail("profiles refused"));
        };
        for k in 0..200u64 {
            prop_assert_eq!(a.send(k).sampled_delay_s.to_bits(), b.send(k).sampled_delay_s.to_bits());
        }
    }
}
