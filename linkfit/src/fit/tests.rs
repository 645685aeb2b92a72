use super::*;
use approx::assert_relative_eq;
use delay::{DelayLine, Direction, DirectionProfile, Distribution, Dwell, RegimeState};
use statrs::distribution::Continuous;

/// `n` delays drawn by the bench's own delay line (what a sweep would replay).
fn draws(d: Distribution, n: usize, seed: u64) -> Vec<f64> {
    let mut line = DelayLine::new(Direction::ControllerToPlant, DirectionProfile::with_delay(d, seed))
        .expect("a valid profile");
    (0..n).map(|k| line.sample_delay_at(k as u64 * 50_000_000)).collect()
}

fn ll_by_statrs(x: &[f64], pdf: impl Fn(f64) -> f64) -> f64 {
    x.iter().map(|v| pdf(*v).ln()).sum()
}

fn opts() -> FitOptions {
    FitOptions { seed: 7, ..FitOptions::default() }
}

/// The fit picks `kind` first and every true parameter lies in its interval. A 95 % interval
/// misses one time in twenty: each test's seed is fixed (it is deterministic) and one where
/// they all cover; that they cover about 95 % of the time is
/// `intervals_cover_the_truth_in_at_least_85_percent_of_200_data_sets`'s.
fn check(delays: &[f64], kind: Kind, truth: &[(&str, f64)]) -> FitReport {
    let report = fit(delays, &opts()).expect("a fit");
    let ranking: Vec<_> = report.candidates.iter().map(|c| (c.kind(), c.aic, c.ks)).collect();
    assert_eq!(report.best().map(Candidate::kind), Some(kind), "ranking by AIC: {ranking:?}");
    let c = report.candidate(kind).expect("fitted");
    for (name, value) in truth {
        let p =
            c.params.iter().find(|p| p.name == *name).unwrap_or_else(|| panic!("{name} in {:?}", c.params));
        assert!(p.lower <= *value && *value <= p.upper, "{kind:?} {name}: {value} not in {p:?}");
        assert!(p.lower <= p.value && p.value <= p.upper, "{p:?}");
    }
    report
}

#[test]
fn trigamma_matches_known_values() {
    let pi2 = std::f64::consts::PI.powi(2);
    assert_relative_eq!(trigamma(1.0), pi2 / 6.0, max_relative = 1e-12);
    assert_relative_eq!(trigamma(0.5), pi2 / 2.0, max_relative = 1e-12);
    // psi'(10) = pi^2/6 - sum_{k=1}^{9} 1/k^2
    let want = pi2 / 6.0 - (1..10).map(|k| 1.0 / (k * k) as f64).sum::<f64>();
    assert_relative_eq!(trigamma(10.0), want, max_relative = 1e-12);
}

#[test]
fn lognormal_and_pareto_mles_match_their_closed_forms() {
    let e = std::f64::consts::E;
    let s = Sample { x: vec![1.0, e, e * e], ln_x: vec![0.0, 1.0, 2.0] }.sums(None);
    let (mu, sigma) = lognormal_mle(&s).expect("mle");
    assert_relative_eq!(mu, 1.0, epsilon = 1e-15);
    assert_relative_eq!(sigma, (2.0f64 / 3.0).sqrt(), epsilon = 1e-15);
    let x = [1.0f64, 2.0, 4.0];
    let s = Sample { x: x.to_vec(), ln_x: x.iter().map(|v| v.ln()).collect() }.sums(None);
    let (xm, alpha) = pareto_mle(&s).expect("mle");
    assert_eq!(xm, 1.0);
    assert_relative_eq!(alpha, 1.0 / 2f64.ln(), max_relative = 1e-14);
}

#[test]
fn each_mle_maximises_statrs_likelihood_and_our_log_likelihood_is_statrs() {
    let x = draws(Distribution::Gamma { shape: 3.0, scale_s: 0.01 }, 2000, 3);
    let sample = Sample { ln_x: x.iter().map(|v| v.ln()).collect(), x: x.clone() };
    let s = sample.sums(None);
    let (k, th) = gamma_mle(&s).expect("gamma");
    let (l, w) = weibull_mle(&sample.ln_x).expect("weibull");
    let (mu, sg) = lognormal_mle(&s).expect("lognormal");
    type Ll = Box<dyn Fn(f64, f64) -> f64>;
    let xs = x.clone();
    let gamma: Ll = Box::new(move |a, b| ll_by_statrs(&xs, |v| Gamma::new(a, 1.0 / b).expect("g").pdf(v)));
    let xs = x.clone();
    let weib: Ll = Box::new(move |a, b| ll_by_statrs(&xs, |v| Weibull::new(a, b).expect("w").pdf(v)));
    let xs = x.clone();
    let logn: Ll = Box::new(move |a, b| ll_by_statrs(&xs, |v| LogNormal::new(a, b).expect("l").pdf(v)));
    for (name, f, a, b, ours) in [
        ("gamma", &gamma, k, th, gamma_ll(&s, k, th)),
        ("weibull", &weib, l, w, weibull_ll(&s, &sample.ln_x, l, w)),
        ("lognormal", &logn, mu, sg, lognormal_ll(&s, mu, sg)),
    ] {
        let at = f(a, b);
        assert_relative_eq!(ours, at, max_relative = 1e-10);
        for (da, db) in [(1.001, 1.0), (0.999, 1.0), (1.0, 1.001), (1.0, 0.999)] {
            let (pa, pb) = if name == "lognormal" { (a + (da - 1.0), b * db) } else { (a * da, b * db) };
            assert!(f(pa, pb) < at, "{name}: ({pa}, {pb}) beats the MLE ({a}, {b})");
        }
    }
    let p = Pareto::new(0.005, 2.0).expect("p");
    let s = Sample { ln_x: x.iter().map(|v| v.ln()).collect(), x: x.clone() }.sums(None);
    let (xm, al) = pareto_mle(&s).expect("pareto");
    assert_relative_eq!(
        pareto_ll(&s, xm, al),
        ll_by_statrs(&x, |v| Pareto::new(xm, al).expect("p").pdf(v)),
        max_relative = 1e-10
    );
    assert!(p.pdf(0.01) > 0.0);
}

#[test]
fn gamma_draws_fit_gamma_with_the_truth_inside_the_intervals() {
    let x = draws(Distribution::Gamma { shape: 12.0, scale_s: 0.015 }, 20_000, 11);
    check(&x, Kind::Gamma, &[("shape", 12.0), ("scale_s", 0.015)]);
}

#[test]
fn lognormal_draws_fit_lognormal_with_the_truth_inside_the_intervals() {
    let x = draws(Distribution::Lognormal { mu: -3.0, sigma: 0.5 }, 20_000, 12);
    check(&x, Kind::Lognormal, &[("mu", -3.0), ("sigma", 0.5)]);
}

#[test]
fn pareto_draws_fit_pareto_with_the_truth_inside_the_intervals() {
    let x = draws(Distribution::Pareto { scale_s: 0.02, shape: 3.0 }, 20_000, 13);
    check(&x, Kind::Pareto, &[("scale_s", 0.02), ("shape", 3.0)]);
}

#[test]
fn weibull_draws_fit_weibull_and_the_table_is_the_best_replayable_kind() {
    use rand_distr::Distribution as _;
    let mut rng = ChaCha8Rng::seed_from_u64(19);
    let w = rand_distr::Weibull::new(0.05, 1.6).expect("weibull"); // scale, shape
    let x: Vec<f64> = (0..20_000).map(|_| w.sample(&mut rng)).collect();
    let report = check(&x, Kind::Weibull, &[("shape", 1.6), ("scale_s", 0.05)]);
    let replayable = report.best_replayable().expect("one").kind();
    assert_ne!(replayable, Kind::Weibull);
    assert!(report.scenario_toml().expect("toml").contains("cannot replay"));
}

fn regime_truth() -> Distribution {
    let state = |mu: f64, sigma: f64, dwell: f64| {
        RegimeState::new(Distribution::Lognormal { mu, sigma }, Dwell::Messages(dwell))
    };
    Distribution::Regime { states: vec![state(-3.5, 0.2, 100.0), state(-1.9, 0.3, 20.0)].into() }
}

#[test]
fn regime_draws_fit_the_regime_with_the_truth_inside_the_intervals() {
    let x = draws(regime_truth(), 20_000, 15);
    check(
        &x,
        Kind::Regime,
        &[
            ("states[0].mu", -3.5),
            ("states[0].sigma", 0.2),
            ("states[0].mean_dwell_messages", 100.0),
            ("states[1].mu", -1.9),
            ("states[1].sigma", 0.3),
            ("states[1].mean_dwell_messages", 20.0),
        ],
    );
}

#[test]
fn losses_the_states_share_are_one_share_the_tables_loss_probability() {
    // Every 50th entry lost, whatever the state: a share each does not pay for itself.
    let mut x = draws(regime_truth(), 20_000, 16);
    for k in (0..x.len()).step_by(50) {
        x[k] = delay::LOST_S;
    }
    let report = fit(&x, &opts()).expect("a fit");
    assert_eq!(report.best().map(Candidate::kind), Some(Kind::Regime));
    assert_relative_eq!(report.loss_probability, 400.0 / 20_000.0);
    let Model::Regime(r) = report.best().expect("best").model else { panic!("a regime") };
    assert_eq!(r.loss, None);
    let table = report.delays_table(report.best().expect("best")).expect("a table");
    assert_eq!(table.loss_probability, Some(0.02));
    let states = table.states.expect("states");
    assert!(states.iter().all(|s| s.loss_probability.is_none()), "{states:?}");
}

/// `n` entries of the bench's delay line, a lost message as `LOST_S`.
fn entries(d: Distribution, n: usize, seed: u64) -> Vec<f64> {
    let mut line = DelayLine::new(Direction::ControllerToPlant, DirectionProfile::with_delay(d, seed))
        .expect("a valid profile");
    (0..n)
        .map(|k| {
            let decision = line.send(k as u64 * 50_000_000);
            if matches!(decision.fate, delay::Fate::Dropped) {
                delay::LOST_S
            } else {
                decision.sampled_delay_s
            }
        })
        .collect()
}

#[test]
fn a_link_losing_in_its_spikes_fits_each_states_loss_with_the_truth_inside_the_intervals() {
    // The newcomer's link: 8 % lost in its spikes, 0.2 % otherwise.
    let state = |mu: f64, sigma: f64, dwell: f64, loss: f64| RegimeState {
        loss_probability: Some(loss),
        ..RegimeState::new(Distribution::Lognormal { mu, sigma }, Dwell::Messages(dwell))
    };
    let truth = Distribution::Regime {
        states: vec![state(-3.5, 0.2, 100.0, 0.002), state(-1.9, 0.3, 20.0, 0.08)].into(),
    };
    let x = entries(truth, 40_000, 22);
    let report = check(
        &x,
        Kind::Regime,
        &[
            ("states[0].mu", -3.5),
            ("states[0].mean_dwell_messages", 100.0),
            ("states[0].loss_probability", 0.002),
            ("states[1].mu", -1.9),
            ("states[1].loss_probability", 0.08),
        ],
    );
    let c = report.best().expect("best");
    assert_eq!(c.model.free_parameters(), 8);
    // A share each, not the trace's one: AIC preferred the eighth parameter.
    let Model::Regime(r) = c.model else { panic!("a regime") };
    let loss = r.loss.expect("a share per state");
    assert!(loss[1] > 10.0 * loss[0], "{loss:?}");
    let table = report.delays_table(c).expect("a table");
    assert_eq!(table.loss_probability, None, "the states carry the losses");
    let shares: Vec<_> = table.states.expect("states").iter().map(|s| s.loss_probability).collect();
    assert_eq!(shares, loss.map(Some));
    // The sweep family ranges each state's loss over its interval (widened by 2, below 1).
    let family = report.sweep_toml_widened(2.0).expect("a family");
    assert!(family.contains("its share's 95 % interval, widened to a factor of 2 either side"), "{family}");
    let doc: toml::Table = toml::from_str(&family).expect("TOML");
    let states = doc["sweep"]["families"][0]["states"].as_array().expect("states");
    for (i, s) in states.iter().enumerate() {
        let range: Vec<f64> =
            s["loss"].as_array().expect("a range").iter().filter_map(toml::Value::as_float).collect();
        let p = c.params.iter().find(|p| p.name == format!("states[{i}].loss_probability")).expect("a share");
        assert!(
            range[0] <= p.value / 2.0 && range[1] >= (p.value * 2.0).min(0.5) && range[1] < 1.0,
            "{range:?}"
        );
    }
    assert!(doc["sweep"]["families"][0].get("loss").is_none(), "{family}");
}

#[test]
fn the_fit_is_deterministic_for_a_seed_and_moves_with_it() {
    let x = draws(Distribution::Gamma { shape: 4.0, scale_s: 0.01 }, 3000, 17);
    let a = fit(&x, &opts()).expect("fit");
    assert_eq!(a, fit(&x, &opts()).expect("fit"));
    let b = fit(&x, &FitOptions { seed: 8, ..opts() }).expect("fit");
    assert_eq!(a.candidates[0].model, b.candidates[0].model, "the estimate does not depend on the seed");
    assert_ne!(a.candidates[0].params, b.candidates[0].params, "the intervals do");
}

#[test]
fn too_few_zero_constant_or_constant_but_for_rounding_delays_are_refused() {
    assert_eq!(fit(&[0.1; 5], &opts()), Err(FitError::TooFew(5)));
    assert_eq!(fit(&[0.1; 20], &opts()), Err(FitError::Constant(0.1)));
    // Constant but for rounding (the probe's: 1,000 x 0.05 s and one 0.0500001 s, or 0.05 +
    // 1e-12): refused at once, not fitted for minutes with a Gamma of shape 1e13.
    for odd in [0.050_000_1, 0.05 + 1e-12] {
        let mut x = vec![0.05; 1000];
        x[500] = odd;
        let e = fit(&x, &opts()).expect_err("near-constant");
        assert!(matches!(e, FitError::NearlyConstant { .. }), "{e:?}");
        assert!(e.to_string().contains("constant but for rounding"), "{e}");
    }
    let mut z = vec![0.1; 20];
    z[3] = 0.0;
    assert_eq!(fit(&z, &opts()), Err(FitError::NotPositive { index: 3, value: 0.0 }));
}

#[test]
fn intervals_cover_the_truth_in_at_least_85_percent_of_200_data_sets() {
    use rand_distr::Distribution as _;
    // 200 data sets of 1000 delays each, the intervals' coverage counted per parameter.
    let mut covered = std::collections::BTreeMap::<String, usize>::new();
    for seed in 0..200u64 {
        let gamma = draws(Distribution::Gamma { shape: 4.0, scale_s: 0.01 }, 1000, 100 + seed);
        let mut rng = ChaCha8Rng::seed_from_u64(200 + seed);
        let w = rand_distr::Weibull::new(0.05, 1.6).expect("weibull");
        let weibull: Vec<f64> = (0..1000).map(|_| w.sample(&mut rng)).collect();
        let pareto = draws(Distribution::Pareto { scale_s: 0.02, shape: 3.0 }, 1000, 300 + seed);
        for (x, kind, truth) in [
            (gamma, Kind::Gamma, [4.0, 0.01]),
            (weibull, Kind::Weibull, [1.6, 0.05]),
            (pareto, Kind::Pareto, [0.02, 3.0]),
        ] {
            let o = FitOptions { seed, kinds: vec![kind], ..FitOptions::default() };
            let report = fit(&x, &o).expect("a fit");
            let c = report.candidate(kind).expect("fitted");
            let want = match kind {
                Kind::Pareto => [("scale_s", truth[0]), ("shape", truth[1])],
                Kind::Weibull => [("shape", truth[0]), ("scale_s", truth[1])],
                _ => [("shape", truth[0]), ("scale_s", truth[1])],
            };
            for (name, v) in want {
                let p = c.params.iter().find(|p| p.name == name).expect("the parameter");
                *covered.entry(format!("{} {name}", kind.name())).or_default() +=
                    usize::from(p.lower <= v && v <= p.upper);
            }
        }
    }
    // Measured: 180 to 188 of 200 (the percentile bootstrap undercovers a little at n = 1000:
    // gamma's shape, whose estimate is biased up by about 3 / n of itself, the most).
    assert!(covered.values().all(|n| *n >= 170), "covered of 200: {covered:?}");
    assert!(covered.values().all(|n| *n < 200), "an interval that always covers is too wide: {covered:?}");
}

#[test]
fn a_fits_scenario_table_says_a_dwell_without_a_probe_rate_is_in_probes_and_gives_the_gamma_prior() {
    let x = draws(regime_truth(), 5_000, 23);
    let report = fit(&x, &opts()).expect("a fit");
    assert_eq!(report.best().map(Candidate::kind), Some(Kind::Regime));
    assert!(report.scenario_toml().expect("toml").contains("The dwells are in probes"));
    let Some(Model::Gamma { shape, scale_s }) = report.candidate(Kind::Gamma).map(|c| c.model) else {
        panic!("a Gamma candidate")
    };
    let prior = format!("prior_gamma = [{shape:.4}, {scale_s:.6}]");
    assert!(report.scenario_toml().expect("toml").contains(&prior), "the Gamma prior to give the controller");
    let timed = fit(&x, &FitOptions { rate_hz: Some(20.0), ..opts() }).expect("a fit");
    assert!(!timed.scenario_toml().expect("toml").contains("in probes"));
}
