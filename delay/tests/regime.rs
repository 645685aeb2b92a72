//! The regime (Markov-modulated) process against the laws it claims: mean dwell times in
//! messages and in seconds, uniform choice of the next state, each state's own delay law and
//! loss, and reproducibility from the seed.

mod common;
use common::ks;
use delay::{DelayLine, Direction, DirectionProfile, Distribution, Dwell, RegimeState};
use statrs::distribution::{ContinuousCDF, Gamma};

fn regime(states: Vec<(Distribution, Dwell)>) -> Distribution {
    Distribution::Regime {
        states: states.into_iter().map(|(delay, mean_dwell)| RegimeState::new(delay, mean_dwell)).collect(),
    }
}

fn line(d: Distribution, seed: u64) -> DelayLine {
    match DelayLine::new(Direction::ControllerToPlant, DirectionProfile::with_delay(d.clone(), seed)) {
        Ok(l) => l,
        Err(e) => panic!("valid profile {d:?} refused: {e}"),
    }
}

/// Delays of `n` messages sent every `gap_ns`.
fn delays(d: Distribution, seed: u64, n: u64, gap_ns: u64) -> Vec<f64> {
    let mut l = line(d, seed);
    (0..n).map(|k| l.send(k * gap_ns).sampled_delay_s).collect()
}

/// Runs of equal values: (value, length), in order.
fn runs(xs: &[f64]) -> Vec<(f64, usize)> {
    let mut out: Vec<(f64, usize)> = Vec::new();
    for &x in xs {
        match out.last_mut() {
            Some((v, n)) if *v == x => *n += 1,
            _ => out.push((x, 1)),
        }
    }
    out
}

/// Mean length of the runs of `value`, leaving out the first and last run (cut by the window).
fn mean_run(runs: &[(f64, usize)], value: f64) -> (f64, usize) {
    let inner = &runs[1..runs.len() - 1];
    let lens: Vec<f64> = inner.iter().filter(|(v, _)| *v == value).map(|(_, n)| *n as f64).collect();
    (lens.iter().sum::<f64>() / lens.len() as f64, lens.len())
}

fn constant(delay_s: f64) -> Distribution {
    Distribution::Constant { delay_s }
}

#[test]
fn dwell_in_messages_is_geometric_with_the_given_mean() {
    // Constant delays tell the states apart. Geometric dwell with mean m has std sqrt(m^2 - m).
    let d = regime(vec![(constant(0.01), Dwell::Messages(20.0)), (constant(0.5), Dwell::Messages(5.0))]);
    let xs = delays(d, 3, 400_000, 1_000_000);
    let r = runs(&xs);
    for (value, mean) in [(0.01, 20.0f64), (0.5, 5.0)] {
        let (got, n) = mean_run(&r, value);
        let se = (mean * mean - mean).sqrt() / (n as f64).sqrt();
        assert!(
            (got - mean).abs() < 5.0 * se,
            "state {value}: mean dwell {got} messages vs {mean} ({n} runs)"
        );
    }
    // Time shares follow the dwells: 20 / 25 of the messages in the first state.
    let share = xs.iter().filter(|x| **x == 0.01).count() as f64 / xs.len() as f64;
    assert!((share - 0.8).abs() < 0.01, "share {share}");
}

#[test]
fn dwell_in_seconds_is_exponential_with_the_given_mean() {
    // Messages every 1 ms: a run of k messages lasts k ms, the dwell up to 1 ms more; the
    // exponential's std equals its mean.
    let gap_ns = 1_000_000;
    let d = regime(vec![(constant(0.01), Dwell::Seconds(0.5)), (constant(0.5), Dwell::Seconds(0.2))]);
    let xs = delays(d, 11, 2_000_000, gap_ns);
    let r = runs(&xs);
    for (value, mean_s) in [(0.01, 0.5f64), (0.5, 0.2)] {
        let (got_messages, n) = mean_run(&r, value);
        let got_s = got_messages * gap_ns as f64 / 1e9;
        let se = mean_s / (n as f64).sqrt();
        assert!(
            (got_s - mean_s).abs() < 5.0 * se + 1e-3,
            "state {value}: mean dwell {got_s} s vs {mean_s} ({n} runs)"
        );
    }
}

#[test]
fn mixed_dwells_and_the_next_state_is_uniform_among_the_others() {
    let d = regime(vec![
        (constant(0.01), Dwell::Messages(10.0)),
        (constant(0.02), Dwell::Seconds(0.1)),
        (constant(0.03), Dwell::Messages(4.0)),
    ]);
    let xs = delays(d, 5, 300_000, 1_000_000);
    let r = runs(&xs);
    // From the first state, half the changes go to each of the two others (the seconds
    // state lasts long against the 1 ms between messages, so it is seldom skipped unseen).
    let next: Vec<f64> = r.windows(2).filter(|w| w[0].0 == 0.01).map(|w| w[1].0).collect();
    let to_second = next.iter().filter(|v| **v == 0.02).count() as f64 / next.len() as f64;
    let se = (0.25 / next.len() as f64).sqrt();
    assert!((to_second - 0.5).abs() < 5.0 * se, "{to_second} of {} changes", next.len());
    assert!(r.windows(2).all(|w| w[0].0 != w[1].0), "a change always goes to another state");
    let (got, n) = mean_run(&r, 0.03);
    let se = (16.0f64 - 4.0).sqrt() / (n as f64).sqrt();
    assert!((got - 4.0).abs() < 5.0 * se, "{got}");
}

#[test]
fn each_state_draws_from_its_own_law() {
    // Gamma(12, 2 ms) stays far below 0.2 s, the uniform on [0.2, 0.4] above: the value tells
    // the state, and within a state the delays are independent draws of its law.
    let d = regime(vec![
        (Distribution::Gamma { shape: 12.0, scale_s: 0.002 }, Dwell::Messages(30.0)),
        (Distribution::Uniform { min_s: 0.2, max_s: 0.4 }, Dwell::Seconds(0.05)),
    ]);
    let xs = delays(d, 21, 100_000, 1_000_000);
    let (low, high): (Vec<f64>, Vec<f64>) = xs.iter().partition(|x| **x < 0.2);
    assert!(low.len() > 10_000 && high.len() > 10_000, "{} / {}", low.len(), high.len());
    let Ok(gamma) = Gamma::new(12.0, 1.0 / 0.002) else { panic!("statrs gamma") };
    let critical = |n: usize| 1.949 / (n as f64).sqrt();
    let d_low = ks(low.clone(), |x| gamma.cdf(x));
    assert!(d_low < critical(low.len()), "gamma state: KS D = {d_low}");
    let d_high = ks(high.clone(), |x| ((x - 0.2) / 0.2).clamp(0.0, 1.0));
    assert!(d_high < critical(high.len()), "uniform state: KS D = {d_high}");
}

#[test]
fn the_same_seed_gives_the_same_states_and_delays_and_another_seed_does_not() {
    let d = regime(vec![
        (Distribution::Gamma { shape: 4.0, scale_s: 0.01 }, Dwell::Messages(8.0)),
        (Distribution::LognormalMoments { mean_s: 0.2, std_s: 0.1 }, Dwell::Seconds(0.3)),
    ]);
    let bits =
        |seed| delays(d.clone(), seed, 5_000, 7_000_000).iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(9), bits(9));
    assert_ne!(bits(9), bits(10));
    let mut l = line(d, 9);
    let first: Vec<_> = (0..500u64).map(|k| l.send(k * 7_000_000)).collect();
    l.reset();
    let again: Vec<_> = (0..500u64).map(|k| l.send(k * 7_000_000)).collect();
    assert_eq!(first, again, "a reset replays the regime");
}

#[test]
fn a_one_state_regime_draws_exactly_its_states_delays() {
    let gamma = Distribution::Gamma { shape: 12.0, scale_s: 0.015 };
    let plain = delays(gamma.clone(), 42, 1_000, 50_000_000);
    for dwell in [Dwell::Messages(3.0), Dwell::Seconds(0.1)] {
        let one = delays(regime(vec![(gamma.clone(), dwell)]), 42, 1_000, 50_000_000);
        assert_eq!(
            one.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            plain.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
        );
    }
}

#[test]
fn lognormal_by_moments_has_the_mean_and_std_it_was_given() {
    let (mean, std) = (0.12, 0.05);
    let xs = delays(Distribution::LognormalMoments { mean_s: mean, std_s: std }, 4, 400_000, 1);
    let n = xs.len() as f64;
    let m = xs.iter().sum::<f64>() / n;
    let s = (xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    assert!((m - mean).abs() < 5.0 * std / n.sqrt(), "mean {m}");
    assert!((s - std).abs() < 0.02 * std, "std {s}");
    let (mu, sigma) = Distribution::lognormal_from_moments(mean, std);
    assert!((mu - (mean.ln() - sigma * sigma / 2.0)).abs() < 1e-15);
}

/// Per state (told apart by its constant delay): messages sent in it, and how many were lost.
fn losses_by_state(states: Vec<RegimeState>, direction_loss: f64, n: u64) -> Vec<(f64, u64, u64)> {
    let mut profile = DirectionProfile::with_delay(Distribution::Regime { states: states.into() }, 11);
    profile.loss_probability = direction_loss;
    let mut l = DelayLine::new(Direction::ControllerToPlant, profile).expect("a valid profile");
    let mut out: Vec<(f64, u64, u64)> = Vec::new();
    for k in 0..n {
        let d = l.send(k * 1_000_000);
        let lost = u64::from(matches!(d.fate, delay::Fate::Dropped));
        match out.iter_mut().find(|(v, _, _)| *v == d.sampled_delay_s) {
            Some((_, sent, dropped)) => (*sent, *dropped) = (*sent + 1, *dropped + lost),
            None => out.push((d.sampled_delay_s, 1, lost)),
        }
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    out
}

#[test]
fn a_state_with_a_loss_of_its_own_loses_at_its_rate_and_the_others_at_the_directions() {
    // 0.01 s: no loss at all; 0.5 s: a quarter; 0.2 s: none of its own, the direction's 5 %.
    let states = |spike_loss: Option<f64>| {
        vec![
            RegimeState {
                loss_probability: Some(0.0),
                ..RegimeState::new(constant(0.01), Dwell::Messages(20.0))
            },
            RegimeState {
                loss_probability: spike_loss,
                ..RegimeState::new(constant(0.5), Dwell::Messages(5.0))
            },
            RegimeState::new(constant(0.2), Dwell::Messages(10.0)),
        ]
    };
    let n = 300_000;
    let by_state = losses_by_state(states(Some(0.25)), 0.05, n);
    assert_eq!(by_state.iter().map(|s| s.0).collect::<Vec<_>>(), [0.01, 0.2, 0.5]);
    assert_eq!(by_state[0].2, 0, "the loss-free state lost messages");
    for ((_, sent, lost), p) in [(by_state[1], 0.05), (by_state[2], 0.25)] {
        let rate = lost as f64 / sent as f64;
        let se = (p * (1.0 - p) / sent as f64).sqrt();
        assert!((rate - p).abs() < 4.0 * se, "loss {rate} where {p} was asked ({sent} sent)");
    }
    // The one loss draw a message: giving the spikes their loss changes no other state's fate.
    let without = losses_by_state(states(None), 0.05, n);
    assert_eq!((without[0], without[1]), (by_state[0], by_state[1]));
    assert_ne!(without[2], by_state[2]);
}

#[test]
fn a_states_loss_outside_zero_to_one_is_refused_naming_the_state() {
    for p in [-0.1, 1.5, f64::NAN, f64::INFINITY] {
        let d = Distribution::Regime {
            states: vec![
                RegimeState::new(constant(0.01), Dwell::Messages(20.0)),
                RegimeState {
                    loss_probability: Some(p),
                    ..RegimeState::new(constant(0.5), Dwell::Messages(5.0))
                },
            ]
            .into(),
        };
        let e = DirectionProfile::with_delay(d, 1).validate().expect_err("refused");
        assert_eq!(e.field, "delay.regime.states[1].loss_probability", "{e}");
    }
}
