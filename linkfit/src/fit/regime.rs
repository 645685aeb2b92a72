//! The two-state regime: a hidden Markov model with lognormal delays per state, fitted by EM
//! (Baum–Welch, scaled forward–backward), and its parametric bootstrap.
//!
//! The chain steps once per entry, lost or not (the bench's regime draws its state for every
//! message, lost ones too); a lost entry is an observation of its own, emitted by state `i`
//! with its loss share `loss[i]` (a delivered delay with `1 - loss[i]` times its density), so
//! that a link losing probes in its spikes fits a loss per state. Emissions are evaluated on
//! `y = ln x` in log space and rescaled by their larger value at each step, so that a delay
//! far from both states underflows neither; `sigma` is kept at 1e-3 or more (a state of one
//! repeated value would otherwise collapse to a spike of infinite likelihood).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution as _, Normal};

use super::RegimeModel;
use delay::is_lost;

const MIN_SIGMA: f64 = 1e-3;
/// Least and (one less) most loss share of a state of a trace with losses.
const MIN_SHARE: f64 = 1e-12;
/// EM iterations at most: of the fit (on at most [`PREFIX`] entries), of its polish on the
/// whole trace, and of a bootstrap replicate (which starts at the fit).
const MAX_ITER: usize = 200;
const MAX_ITER_POLISH: usize = 10;
const MAX_ITER_REPLICATE: usize = 25;
/// A longer trace is fitted on its first `PREFIX` entries, then polished on the whole: the
/// many iterations EM may take where the likelihood is flat (a link with no regimes) cost
/// `PREFIX` entries each, not the whole trace's.
const PREFIX: usize = 10_000;
const HALF_LN_2PI: f64 = 0.918_938_533_204_672_8;

/// The log-likelihood's change per delay under which EM stops.
const TOL: f64 = 1e-7;

/// EM fit of the entries (delays and `LOST_S`), from a split at the p80 of the delivered
/// delays: the model and its log-likelihood (of the delays, s, and of the losses, less their
/// Bernoulli log-likelihood at the trace's one loss share: the i.i.d. kinds' common term);
/// `None` with fewer than 10 delivered delays or when EM breaks down. A trace with losses is
/// fitted twice, with the trace's one share for both states and with a share each, and the
/// second kept only where its one more parameter pays for itself (AIC): five losses in 199
/// probes do not tell two shares apart, 3,000 in 40,000 do.
pub fn fit(delays_s: &[f64]) -> Option<(RegimeModel, f64)> {
    let y: Vec<f64> = delays_s.iter().map(|d| if is_lost(*d) { f64::NAN } else { d.ln() }).collect();
    let shared = fit_prefix_then_whole(&y, None, false)?;
    if !y.iter().any(|v| v.is_nan()) {
        return Some(shared);
    }
    match fit_prefix_then_whole(&y, Some(shared.0), true) {
        // AIC: 2 (k + 1) - 2 ln L' < 2 k - 2 ln L.
        Some(own) if own.1 - shared.1 > 1.0 => Some(own),
        _ => Some(shared),
    }
}

/// [`fit_logs`] on the first [`PREFIX`] entries, then polished on the whole.
fn fit_prefix_then_whole(
    y: &[f64],
    start: Option<RegimeModel>,
    own_loss: bool,
) -> Option<(RegimeModel, f64)> {
    if y.len() <= PREFIX {
        return fit_logs(y, start, MAX_ITER, own_loss);
    }
    let first = fit_logs(&y[..PREFIX], start, MAX_ITER, own_loss).map(|(m, _)| m);
    fit_logs(y, first.or(start), if first.is_some() { MAX_ITER_POLISH } else { MAX_ITER }, own_loss)
}

/// The EM on `y = ln x` (NaN: lost); with `own_loss`, a loss share for each state (else the
/// trace's one share for both, `RegimeModel::loss` `None`).
fn fit_logs(
    y: &[f64],
    start: Option<RegimeModel>,
    max_iter: usize,
    own_loss: bool,
) -> Option<(RegimeModel, f64)> {
    let t_len = y.len();
    let mut obs: Vec<f64> = y.iter().copied().filter(|v| v.is_finite()).collect();
    if obs.len() < 10 {
        return None;
    }
    let sum_y: f64 = obs.iter().sum();
    let lost = t_len - obs.len();
    let share = lost as f64 / t_len as f64;
    // The losses' Bernoulli log-likelihood at one share (0 ln 0 = 0).
    let one_share_ll =
        if lost == 0 { 0.0 } else { lost as f64 * share.ln() + obs.len() as f64 * (-share).ln_1p() };
    let mut model = match start {
        Some(m) => m,
        None => {
            obs.sort_unstable_by(f64::total_cmp);
            let cut = (obs.len() * 4 / 5).clamp(1, obs.len() - 1);
            let stats = |v: &[f64]| {
                let m = v.iter().sum::<f64>() / v.len() as f64;
                let s = (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / v.len() as f64).sqrt();
                (m, s.max(MIN_SIGMA))
            };
            let (m0, s0) = stats(&obs[..cut]);
            let (m1, s1) = stats(&obs[cut..]);
            RegimeModel { mu: [m0, m1], sigma: [s0, s1], leave: [0.05, 0.2], loss: None }
        }
    };
    // Each state's share: the trace's one unless fitted per state (from the start's own, or
    // the trace's share); kept off 0 and 1 where there are losses (a state that could lose
    // nothing would make a lost entry impossible, and ln(1 - 1) a delivered one).
    let own_loss = own_loss && lost > 0;
    let mut loss = match model.loss {
        Some(l) if own_loss => l.map(|p| p.clamp(MIN_SHARE, 1.0 - MIN_SHARE)),
        _ => [share; 2],
    };
    let mut pi = model.stationary();
    let mut e = vec![[0.0f64; 2]; t_len]; // scaled emissions
    let mut shift = vec![0.0f64; t_len]; // their log scale
    let mut alpha = vec![[0.0f64; 2]; t_len];
    let mut inv_c = vec![0.0f64; t_len];
    let mut last_ll = f64::NEG_INFINITY;
    let mut ll = f64::NEG_INFINITY;
    for _ in 0..max_iter {
        // Emissions.
        let inv = model.sigma.map(|s| 1.0 / s);
        let norm = [0, 1].map(|j| -model.sigma[j].ln() - HALF_LN_2PI + (-loss[j]).ln_1p());
        for t in 0..t_len {
            if y[t].is_nan() {
                e[t] = loss;
                shift[t] = 0.0;
                continue;
            }
            let l = [0, 1].map(|j| {
                let z = (y[t] - model.mu[j]) * inv[j];
                norm[j] - 0.5 * z * z
            });
            // The larger is 1, the other its ratio: one exp per entry.
            if l[0] >= l[1] {
                e[t] = [1.0, (l[1] - l[0]).exp()];
                shift[t] = l[0];
            } else {
                e[t] = [(l[0] - l[1]).exp(), 1.0];
                shift[t] = l[1];
            }
        }
        let a = [[1.0 - model.leave[0], model.leave[0]], [model.leave[1], 1.0 - model.leave[1]]];
        // Forward: alpha normalised at each step, `inv_c` the inverse of its scale; the
        // log-likelihood from a running product of the scales (a log per underflow, not per
        // entry).
        let (mut log_c, mut prod) = (0.0, 1.0f64);
        for t in 0..t_len {
            let prior = if t == 0 {
                pi
            } else {
                let p = alpha[t - 1];
                [p[0] * a[0][0] + p[1] * a[1][0], p[0] * a[0][1] + p[1] * a[1][1]]
            };
            let f = [prior[0] * e[t][0], prior[1] * e[t][1]];
            let s = f[0] + f[1];
            if !(s > 0.0 && s.is_finite()) {
                return None;
            }
            let inv = 1.0 / s;
            inv_c[t] = inv;
            alpha[t] = [f[0] * inv, f[1] * inv];
            log_c += shift[t];
            prod *= s;
            if !(1e-150..=1e150).contains(&prod) {
                log_c += prod.ln();
                prod = 1.0;
            }
        }
        ll = log_c + prod.ln();
        // Backward, with the M-step's sums on the way (gamma_t = alpha_t beta_t; the expected
        // switches from alpha_t, A, e_{t+1}, beta_{t+1}).
        let (mut g_sum, mut g_y, mut g_y2) = ([0.0f64; 2], [0.0f64; 2], [0.0f64; 2]);
        let (mut g_all, mut g_lost) = ([0.0f64; 2], [0.0f64; 2]);
        let (mut from, mut switch) = ([0.0f64; 2], [0.0f64; 2]);
        let mut beta = [1.0f64, 1.0];
        for t in (0..t_len).rev() {
            if t + 1 < t_len {
                let nb = [e[t + 1][0] * beta[0], e[t + 1][1] * beta[1]];
                let ic = inv_c[t + 1];
                for i in 0..2 {
                    switch[i] += alpha[t][i] * a[i][1 - i] * nb[1 - i] * ic;
                }
                beta = [0, 1].map(|i| (a[i][0] * nb[0] + a[i][1] * nb[1]) * ic);
            }
            let g = [alpha[t][0] * beta[0], alpha[t][1] * beta[1]];
            let inv = 1.0 / (g[0] + g[1]);
            let g = [g[0] * inv, g[1] * inv];
            for j in 0..2 {
                g_all[j] += g[j];
            }
            if y[t].is_nan() {
                for j in 0..2 {
                    g_lost[j] += g[j];
                }
            } else {
                for j in 0..2 {
                    g_sum[j] += g[j];
                    g_y[j] += g[j] * y[t];
                    g_y2[j] += g[j] * y[t] * y[t];
                }
            }
            if t + 1 < t_len {
                for i in 0..2 {
                    from[i] += g[i];
                }
            }
            if t == 0 {
                pi = g;
            }
        }
        for j in 0..2 {
            if g_sum[j] > 1e-9 {
                let mu = g_y[j] / g_sum[j];
                let var = (g_y2[j] / g_sum[j] - mu * mu).max(0.0);
                model.mu[j] = mu;
                model.sigma[j] = var.sqrt().max(MIN_SIGMA);
            }
            if from[j] > 0.0 {
                model.leave[j] = (switch[j] / from[j]).clamp(1e-12, 1.0);
            }
            if own_loss && g_all[j] > 0.0 {
                loss[j] = (g_lost[j] / g_all[j]).clamp(MIN_SHARE, 1.0 - MIN_SHARE);
            }
        }
        if (ll - last_ll).abs() <= TOL * obs.len() as f64 {
            break;
        }
        last_ll = ll;
    }
    model.loss = own_loss.then_some(loss);
    if model.mu[0] > model.mu[1] {
        model = RegimeModel {
            mu: [model.mu[1], model.mu[0]],
            sigma: [model.sigma[1], model.sigma[0]],
            leave: [model.leave[1], model.leave[0]],
            loss: model.loss.map(|l| [l[1], l[0]]),
        };
    }
    // The density of x is that of y = ln x times 1/x.
    Some((model, ll - sum_y - one_share_ll))
}

/// Parametric bootstrap: `replicates` sequences of `min(entries, size)` entries drawn from
/// `model` (a probe lost at its state's share when the states have their own, else where the
/// trace's first entries lost one), each refitted from `model`
/// (at most 25 EM iterations: from the fit, EM moves most in its first steps, and each
/// replicate's spread is what the intervals need); the replicates of each parameter, in
/// [`super::Model::params`]' order.
pub fn bootstrap(
    model: &RegimeModel,
    delays_s: &[f64],
    size: usize,
    replicates: usize,
    seed: u64,
) -> Vec<Vec<f64>> {
    let len = delays_s.len().min(size.max(10));
    let per_state = if model.loses() { 4 } else { 3 };
    let mut out: Vec<Vec<f64>> = (0..2 * per_state).map(|_| Vec::with_capacity(replicates)).collect();
    let normals = [0, 1].map(|j| Normal::new(model.mu[j], model.sigma[j]).ok());
    let mut y = vec![0.0; len];
    for r in 0..replicates {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(1 + r as u64);
        let w = model.stationary();
        let mut s = usize::from(rng.random::<f64>() >= w[0]);
        for (t, v) in y.iter_mut().enumerate() {
            let lost = match model.loss {
                Some(share) => rng.random::<f64>() < share[s],
                None => is_lost(delays_s[t]),
            };
            *v = match &normals[s] {
                _ if lost => f64::NAN,
                Some(n) => n.sample(&mut rng),
                None => model.mu[s],
            };
            if rng.random::<f64>() < model.leave[s] {
                s = 1 - s;
            }
        }
        let fitted = fit_logs(&y, Some(*model), MAX_ITER_REPLICATE, model.loses()).map(|(m, _)| m);
        // In `Model::params`' order (a replicate that happened to lose nothing: shares 0).
        let values: Vec<f64> = match fitted {
            Some(m) => {
                let d = m.mean_dwell_messages();
                let l = m.loss.unwrap_or([0.0; 2]);
                (0..2).flat_map(|i| [m.mu[i], m.sigma[i], d[i], l[i]].into_iter().take(per_state)).collect()
            }
            None => vec![f64::NAN; 2 * per_state],
        };
        for (slot, v) in out.iter_mut().zip(values) {
            slot.push(v);
        }
    }
    out
}
