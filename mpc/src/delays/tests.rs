use super::*;
use approx::assert_relative_eq;
use proptest::prelude::*;
use rand::SeedableRng;
use rand_distr::Distribution;

const TS: [f64; 5] = [0.05, 0.07, 0.1, 0.2, 0.33];

#[test]
fn moment_fit_recovers_a_known_gamma() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let dist = rand_distr::Gamma::new(12.0, 0.015).expect("valid");
    let mut w = DelayWindow::new(200_000);
    for _ in 0..200_000 {
        w.push(dist.sample(&mut rng));
    }
    let fit = w.fit(10).expect("fit");
    assert_relative_eq!(fit.shape, 12.0, max_relative = 0.02);
    assert_relative_eq!(fit.scale_s, 0.015, max_relative = 0.02);
}

#[test]
fn exact_moments_give_exact_parameters() {
    // A window holding {0.1, 0.3}: mean 0.2, population variance 0.01.
    let mut w = DelayWindow::new(50);
    w.push(0.1);
    w.push(0.3);
    let fit = w.fit(2).expect("fit");
    assert_relative_eq!(fit.shape, 4.0, max_relative = 1e-12);
    assert_relative_eq!(fit.scale_s, 0.05, max_relative = 1e-12);
}

#[test]
fn weights_of_the_paper_prior_match_the_gamma_cdf() {
    let g = GammaParams { shape: 12.0, scale_s: 0.015 };
    let mut w = [0.0; 5];
    assert!(weights_from_gamma(&g, &TS, &mut w));
    // The CDF of Gamma(k, theta) at t is the regularised lower incomplete gamma P(k, t/theta);
    // for integer k it is 1 - e^{-x} sum_{n<k} x^n / n!.
    let cdf = |t: f64| {
        let x = t / 0.015;
        let mut term = 1.0;
        let mut sum = 1.0;
        for n in 1..12 {
            term *= x / n as f64;
            sum += term;
        }
        1.0 - (-x).exp() * sum
    };
    assert_relative_eq!(w[0], cdf(0.05), max_relative = 1e-9);
    assert_relative_eq!(w[3], cdf(0.2) - cdf(0.1), max_relative = 1e-9);
    assert_relative_eq!(w.iter().sum::<f64>(), cdf(0.33), max_relative = 1e-9);
}

#[test]
fn prior_until_enough_samples_or_when_the_window_is_degenerate_then_the_fit() {
    let s = WeightSettings::default();
    let prior_weights = {
        let mut w = [0.0; 5];
        assert!(weights_from_gamma(&s.prior, &TS, &mut w));
        w
    };
    let mut sw = ScenarioWeights::new(s, &TS, None);
    assert_eq!(sw.source(), WeightSource::Prior(s.prior));
    for _ in 0..s.min_samples - 1 {
        sw.observe(0.18 + 0.01 * sw.window().len() as f64);
    }
    assert_eq!(sw.source(), WeightSource::Prior(s.prior));
    sw.observe(0.12);
    assert!(matches!(sw.source(), WeightSource::Fitted(_)), "{:?}", sw.source());
    // Zero variance (a constant delay) has no Gamma fit: back to the prior, whatever the delay.
    for delay_s in [0.05, 0.18, 0.5] {
        let mut constant = ScenarioWeights::new(s, &TS, None);
        for _ in 0..20 {
            constant.observe(delay_s);
        }
        assert_eq!(constant.window().len(), 20);
        assert_eq!(constant.source(), WeightSource::Prior(s.prior), "{delay_s}");
        assert_eq!(constant.weights(), &prior_weights, "{delay_s}");
        constant.observe(delay_s + 0.07);
        assert!(matches!(constant.source(), WeightSource::Fitted(_)), "{delay_s}");
    }
    // Moments that overflow (delays near f64::MAX) are not finite: the prior as well.
    let mut huge = ScenarioWeights::new(s, &TS, None);
    for k in 0..20 {
        huge.observe(if k % 2 == 0 { 1e300 } else { 1.7e308 });
    }
    assert_eq!(huge.source(), WeightSource::Prior(s.prior));
    sw.observe(f64::NAN); // ignored
    assert_eq!(sw.window().len(), s.min_samples);
    let fixed = ScenarioWeights::new(s, &TS, Some(&[0.05, 0.15, 0.45, 0.30, 0.05]));
    assert_eq!(fixed.weights(), &[0.05, 0.15, 0.45, 0.30, 0.05]);
}

#[test]
fn a_near_constant_link_slower_than_every_sampling_time_weighs_the_last_scenario() {
    // What ping reports on a saturated uplink (500/501 ms), and two delays 1 ms apart: the
    // fitted Gamma's CDF is 0 at every sampling time, so the paper's weights are all zero.
    for delays in [&[0.500, 0.501][..], &[0.4759, 0.4749]] {
        let mut sw = ScenarioWeights::new(WeightSettings::default(), &TS, None);
        for k in 0..60 {
            sw.observe(delays[k % delays.len()]);
        }
        assert!(matches!(sw.source(), WeightSource::Fitted(_)), "{:?}", sw.source());
        let w = sw.weights();
        assert_eq!(w[..4], [0.0; 4], "{w:?}");
        assert_relative_eq!(w[4], 1.0, max_relative = 1e-12);
    }
    // The paper's prior and a link within the sampling times keep the paper's weights.
    let g = GammaParams { shape: 12.0, scale_s: 0.015 };
    let mut w = [0.0; 5];
    assert!(weights_from_gamma(&g, &TS, &mut w));
    assert_relative_eq!(w.iter().sum::<f64>(), g.cdf(0.33).expect("valid"), max_relative = 1e-12);
}

proptest! {
    #[test]
    fn weights_are_non_negative_and_sum_to_the_cdf_at_the_last_time(
        shape in 0.2f64..200.0,
        scale in 1e-4f64..0.5,
    ) {
        let g = GammaParams { shape, scale_s: scale };
        let mut w = [0.0; 5];
        prop_assert!(weights_from_gamma(&g, &TS, &mut w));
        prop_assert!(w.iter().all(|v| *v >= 0.0));
        let total = g.cdf(0.33).expect("valid");
        if total >= MIN_MASS_WITHIN_SAMPLING_TIMES {
            // The paper's weights, as they are.
            prop_assert!((w.iter().sum::<f64>() - total).abs() < 1e-12);
        } else {
            // A link slower than every scenario: the mass beyond 0.33 s on the last one.
            prop_assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        }
    }

    /// Windows of any shape a link can produce (near-constant at any level, jittered by
    /// milliseconds or by rounding, spread, spiky): the weights are finite, non-negative, and
    /// carry weight, so every problem they make is one the solver accepts.
    #[test]
    fn the_weights_of_any_window_are_finite_non_negative_and_never_all_zero(
        level in 0.0f64..5.0,
        jitter in prop::sample::select(vec![0.0, 1e-15, 1e-12, 1e-9, 1e-6, 1e-3, 0.05, 1.0]),
        spikes in prop::collection::vec((0usize..50, 0.0f64..30.0), 0..5),
        pattern in prop::collection::vec(-1.0f64..1.0, 2..120),
    ) {
        let mut sw = ScenarioWeights::new(WeightSettings::default(), &TS, None);
        for (i, p) in pattern.iter().enumerate() {
            let spike = spikes.iter().find(|(at, _)| *at == i % 50).map_or(0.0, |(_, s)| *s);
            sw.observe((level + jitter * p + spike).max(0.0));
            let w = sw.weights();
            prop_assert!(w.iter().all(|v| v.is_finite() && *v >= 0.0), "{w:?}");
            prop_assert!(w.iter().sum::<f64>() >= MIN_MASS_WITHIN_SAMPLING_TIMES, "{w:?} after {i} delays");
            let accepted = crate::problem::validate_instance(5, &[0.0; 8], &[9.81, 0.0, 0.0], w);
            prop_assert!(accepted.is_ok(), "{accepted:?}");
        }
    }

    #[test]
    fn the_window_keeps_only_the_last_n(values in prop::collection::vec(0.0f64..1.0, 1..200)) {
        let mut w = DelayWindow::new(50);
        for v in &values { w.push(*v); }
        let tail = &values[values.len().saturating_sub(50)..];
        let mean = tail.iter().sum::<f64>() / tail.len() as f64;
        let (m, _) = w.moments().expect("non-empty");
        prop_assert!((m - mean).abs() < 1e-12);
        prop_assert_eq!(w.len(), tail.len());
    }
}
