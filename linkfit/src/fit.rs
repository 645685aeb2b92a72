//! Maximum-likelihood fits of a trace's delays, ranked, with 95 % intervals, and the tables a
//! scenario and a sweep take.
//!
//! Candidates: Gamma, lognormal, Pareto (type I), Weibull, and a two-state regime (a hidden
//! Markov model whose states have lognormal delays: the bench's `regime` kind with two
//! `lognormal` states and a mean dwell in messages, or in seconds when the probe rate is
//! known). They are ranked by AIC (`2 k - 2 ln L`, the regime's `L` is the likelihood of the
//! sequence, so a bursty link's dependence counts) and, beside it, by the Kolmogorov–Smirnov
//! distance of the marginal law (the regime's: the stationary mixture of its states). The
//! best by AIC that the bench can replay (every kind but Weibull, which `delay` does not
//! have) becomes the `[scenario.delays]` table ([`FitReport::scenario_toml`]) and a
//! `[[sweep.families]]` table whose ranges are the intervals ([`FitReport::sweep_toml`]).
//!
//! What is written by hand, and why:
//! - the MLEs: statrs has distributions but no fitting. Lognormal and Pareto are closed forms
//!   (`mu`, `sigma` the mean and the `1/n` standard deviation of `ln x`; `x_m = min x`,
//!   `alpha = n / sum ln(x / x_m)`). Gamma's shape solves `ln k - digamma(k) = ln(mean x) -
//!   mean(ln x)` by Newton from the Choi–Wette start (statrs' `digamma`, and [`trigamma`]
//!   here, which statrs lacks). Weibull's shape solves the profile equation `sum x^k ln x /
//!   sum x^k - 1/k = mean(ln x)` by Newton, safeguarded by bisection (its left side grows
//!   with `k`, so the root is unique); the sums are taken on `ln x` centred and shifted by its
//!   maximum, so `x^k` never overflows.
//! - the log-likelihoods from the sufficient statistics (one pass over the data, not `n`
//!   calls of statrs' `ln_pdf`; a test checks them against statrs);
//! - the regime's EM (Baum–Welch with scaled forward–backward): a lost entry is an emission
//!   of its own, with its state's loss share, so the chain still steps over it. A trace with
//!   losses is fitted with the trace's one share for both states and with a share each (a
//!   link that loses 8 % in its spikes and 0.2 % otherwise), the second kept where AIC
//!   prefers it; the likelihood is that of the delays and the losses, less the Bernoulli
//!   likelihood of the losses at the trace's one share, which the i.i.d. kinds carry as a
//!   common term and AIC drops. Its states are ordered by `mu` (the faster state first; the
//!   bench's regime starts in its first state).
//!
//! Intervals (95 %, seeded ChaCha8, deterministic):
//! - Gamma, lognormal, Weibull: the percentile bootstrap, [`FitOptions::replicates`]
//!   resamples of `m = min(n, FitOptions::bootstrap_size)` delays with replacement; with
//!   `m < n` (an m-out-of-n bootstrap, which keeps 100,000 delays under a second) the
//!   replicates' spread about the estimate is scaled by `sqrt(m / n)`, the rate at which
//!   these estimators' spread shrinks.
//! - Pareto: exact, because the bootstrap fails for a minimum (the true `x_m` lies below
//!   every resample's minimum): `n alpha / alpha_hat ~ Gamma(n - 1, 1)` and `min x / x_m ~
//!   Pareto(1, n alpha)` (`x_m`'s interval is one-sided, up to `min x`).
//! - Regime: a parametric bootstrap, [`FitOptions::regime_replicates`] sequences of
//!   `min(entries, FitOptions::regime_bootstrap_size)` entries drawn from the fitted model
//!   (losses drawn at each state's share, or where the trace's are), each refitted by at most 25 EM iterations from the fit,
//!   percentile intervals scaled as above. Fewer and shorter replicates than for the i.i.d.
//!   kinds (each is an EM), so its intervals' ends are coarser. A trace longer than 10,000
//!   entries is fitted on its first 10,000, then polished by EM on the whole.

use delay::is_lost;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use statrs::distribution::{ContinuousCDF, Gamma, LogNormal, Pareto, Weibull};
use statrs::function::gamma::{digamma, ln_gamma};

/// A candidate law.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    Gamma,
    Lognormal,
    Pareto,
    Weibull,
    Regime,
}

impl Kind {
    pub const ALL: [Kind; 5] = [Kind::Gamma, Kind::Lognormal, Kind::Pareto, Kind::Weibull, Kind::Regime];

    /// The name (the `[scenario.delays]` kind, `weibull` aside).
    pub fn name(self) -> &'static str {
        match self {
            Kind::Gamma => "gamma",
            Kind::Lognormal => "lognormal",
            Kind::Pareto => "pareto",
            Kind::Weibull => "weibull",
            Kind::Regime => "regime",
        }
    }

    /// The bench can replay it (`delay` has the kind).
    pub fn replayable(self) -> bool {
        self != Kind::Weibull
    }
}

/// A fitted law's parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Model {
    Gamma { shape: f64, scale_s: f64 },
    Lognormal { mu: f64, sigma: f64 },
    Pareto { scale_s: f64, shape: f64 },
    Weibull { shape: f64, scale_s: f64 },
    Regime(RegimeModel),
}

/// Two states with lognormal delays; after each message the chain leaves state `i` with
/// probability `leave[i]`; a probe sent in state `i` is lost with probability `loss[i]`, or,
/// with `loss` `None`, at the trace's one share (`FitReport::loss_probability`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RegimeModel {
    pub mu: [f64; 2],
    pub sigma: [f64; 2],
    pub leave: [f64; 2],
    pub loss: Option<[f64; 2]>,
}

impl RegimeModel {
    /// Whether the states have loss shares of their own.
    pub fn loses(&self) -> bool {
        self.loss.is_some()
    }

    /// Mean dwell of each state, messages (`1 / leave`, at most `delay::MAX_MEAN_DWELL`).
    pub fn mean_dwell_messages(&self) -> [f64; 2] {
        self.leave.map(|p| (1.0 / p).min(delay::MAX_MEAN_DWELL))
    }

    /// The stationary share of time in each state.
    pub fn stationary(&self) -> [f64; 2] {
        let s = self.leave[0] + self.leave[1];
        if s > 0.0 { [self.leave[1] / s, self.leave[0] / s] } else { [1.0, 0.0] }
    }
}

impl Model {
    pub fn kind(&self) -> Kind {
        match self {
            Model::Gamma { .. } => Kind::Gamma,
            Model::Lognormal { .. } => Kind::Lognormal,
            Model::Pareto { .. } => Kind::Pareto,
            Model::Weibull { .. } => Kind::Weibull,
            Model::Regime(_) => Kind::Regime,
        }
    }

    /// The marginal CDF at `x_s` (the regime's: its stationary mixture).
    pub fn cdf(&self, x_s: f64) -> f64 {
        match *self {
            Model::Gamma { shape, scale_s } => {
                Gamma::new(shape, 1.0 / scale_s).map_or(f64::NAN, |g| g.cdf(x_s))
            }
            Model::Lognormal { mu, sigma } => LogNormal::new(mu, sigma).map_or(f64::NAN, |l| l.cdf(x_s)),
            Model::Pareto { scale_s, shape } => Pareto::new(scale_s, shape).map_or(f64::NAN, |p| p.cdf(x_s)),
            Model::Weibull { shape, scale_s } => {
                Weibull::new(shape, scale_s).map_or(f64::NAN, |w| w.cdf(x_s))
            }
            Model::Regime(r) => {
                let w = r.stationary();
                (0..2)
                    .map(|i| w[i] * LogNormal::new(r.mu[i], r.sigma[i]).map_or(f64::NAN, |l| l.cdf(x_s)))
                    .sum()
            }
        }
    }

    /// The marginal density at `x_s`, 1/s (for plots).
    pub fn pdf(&self, x_s: f64) -> f64 {
        use statrs::distribution::Continuous;
        match *self {
            Model::Gamma { shape, scale_s } => {
                Gamma::new(shape, 1.0 / scale_s).map_or(f64::NAN, |g| g.pdf(x_s))
            }
            Model::Lognormal { mu, sigma } => LogNormal::new(mu, sigma).map_or(f64::NAN, |l| l.pdf(x_s)),
            Model::Pareto { scale_s, shape } => Pareto::new(scale_s, shape).map_or(f64::NAN, |p| p.pdf(x_s)),
            Model::Weibull { shape, scale_s } => {
                Weibull::new(shape, scale_s).map_or(f64::NAN, |w| w.pdf(x_s))
            }
            Model::Regime(r) => {
                let w = r.stationary();
                (0..2)
                    .map(|i| w[i] * LogNormal::new(r.mu[i], r.sigma[i]).map_or(f64::NAN, |l| l.pdf(x_s)))
                    .sum()
            }
        }
    }

    /// The parameters as `(key, value)`, keys as in `[scenario.delays]` (a regime's as
    /// `states[i].key`; Weibull's as its own).
    pub fn params(&self) -> Vec<(String, f64)> {
        let p = |k: &str, v: f64| (k.to_string(), v);
        match *self {
            Model::Gamma { shape, scale_s } => vec![p("shape", shape), p("scale_s", scale_s)],
            Model::Lognormal { mu, sigma } => vec![p("mu", mu), p("sigma", sigma)],
            Model::Pareto { scale_s, shape } => vec![p("scale_s", scale_s), p("shape", shape)],
            Model::Weibull { shape, scale_s } => vec![p("shape", shape), p("scale_s", scale_s)],
            Model::Regime(r) => {
                let dwell = r.mean_dwell_messages();
                let mut params = Vec::new();
                for i in 0..2 {
                    params.push(p(&format!("states[{i}].mu"), r.mu[i]));
                    params.push(p(&format!("states[{i}].sigma"), r.sigma[i]));
                    params.push(p(&format!("states[{i}].mean_dwell_messages"), dwell[i]));
                    if let Some(loss) = r.loss {
                        params.push(p(&format!("states[{i}].loss_probability"), loss[i]));
                    }
                }
                params
            }
        }
    }

    /// Number of free parameters (AIC's `k`): two for each i.i.d. law, seven for the regime
    /// (two states' `mu` and `sigma`, two leave probabilities, the initial state), and one
    /// more for a regime whose states have loss shares of their own (two where every other
    /// kind has the trace's one, which each of them shares and AIC leaves out).
    pub fn free_parameters(&self) -> usize {
        match self {
            Model::Regime(r) => 7 + usize::from(r.loses()),
            _ => 2,
        }
    }
}

/// A parameter with its 95 % interval.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Param {
    /// Its key (see [`Model::params`]).
    pub name: String,
    pub value: f64,
    pub lower: f64,
    pub upper: f64,
}

/// One fitted candidate.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Candidate {
    pub model: Model,
    pub params: Vec<Param>,
    pub log_likelihood: f64,
    pub aic: f64,
    /// Kolmogorov–Smirnov distance between the delays' ECDF and the marginal CDF.
    pub ks: f64,
}

impl Candidate {
    pub fn kind(&self) -> Kind {
        self.model.kind()
    }
}

/// How to fit.
#[derive(Debug, Clone, PartialEq)]
pub struct FitOptions {
    /// Seed of the bootstrap.
    pub seed: u64,
    /// Bootstrap resamples for Gamma, lognormal and Weibull.
    pub replicates: usize,
    /// Parametric bootstrap sequences for the regime.
    pub regime_replicates: usize,
    /// At most this many delays per resample (`m` of the m-out-of-n bootstrap).
    pub bootstrap_size: usize,
    /// At most this many entries per regime sequence (its `m`).
    pub regime_bootstrap_size: usize,
    /// Probes per second: the regime's dwell is then written in seconds too.
    pub rate_hz: Option<f64>,
    /// The kinds to fit (all by default).
    pub kinds: Vec<Kind>,
}

impl Default for FitOptions {
    /// Seed 1, 200 resamples of at most 10,000 delays, 30 regime sequences of at most 5,000
    /// entries, every kind.
    fn default() -> Self {
        Self {
            seed: 1,
            replicates: 200,
            regime_replicates: 30,
            bootstrap_size: 10_000,
            regime_bootstrap_size: 5_000,
            rate_hz: None,
            kinds: Kind::ALL.to_vec(),
        }
    }
}

/// Least variance of a trace, relative to its mean squared, that the fits take as a spread:
/// below it the delays are one value up to rounding. The controller's delay fit draws the same
/// line (`mpc::delays`, `GammaParams::from_moments`).
pub const MIN_RELATIVE_VARIANCE: f64 = 1e-12;

/// Why a trace cannot be fitted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FitError {
    #[error("{0} delivered delays: a fit needs at least 10")]
    TooFew(usize),
    #[error("entry {index}: {value} is not a delay > 0 (the laws fitted have no mass at 0)")]
    NotPositive { index: usize, value: f64 },
    #[error("every delay is {0} s: no law with a spread fits a constant")]
    Constant(f64),
    /// A spread too small for any law with one: its fit would be a point mass in disguise (a
    /// Gamma of shape 1e13, whose CDF alone takes minutes).
    #[error(
        "the delays are constant but for rounding (mean {mean_s} s, variance {relative_variance:e} of the mean squared, \
         below {MIN_RELATIVE_VARIANCE:e}): no law with a spread fits them; replay the trace, or a constant delay"
    )]
    NearlyConstant { mean_s: f64, relative_variance: f64 },
    #[error("{0}")]
    Option(String),
}

/// The fits of a trace, best first.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FitReport {
    /// By AIC, best first (kinds that could not be fitted are left out).
    pub candidates: Vec<Candidate>,
    /// The kinds by KS distance, best first.
    pub by_ks: Vec<Kind>,
    /// Entries, and delivered delays fitted.
    pub entries: usize,
    pub delivered: usize,
    /// `losses / entries`: the table's `loss_probability`.
    pub loss_probability: f64,
    pub rate_hz: Option<f64>,
}

/// Sufficient statistics and the sample.
struct Sample {
    x: Vec<f64>,
    ln_x: Vec<f64>,
}

impl Sample {
    fn sums(&self, idx: Option<&[u32]>) -> Sums {
        let mut s = Sums { n: 0.0, sum: 0.0, sum_ln: 0.0, sum_ln2: 0.0, min: f64::INFINITY };
        let mut add = |x: f64, l: f64| {
            s.n += 1.0;
            s.sum += x;
            s.sum_ln += l;
            s.sum_ln2 += l * l;
            s.min = s.min.min(x);
        };
        match idx {
            None => self.x.iter().zip(&self.ln_x).for_each(|(x, l)| add(*x, *l)),
            Some(idx) => idx.iter().for_each(|&i| add(self.x[i as usize], self.ln_x[i as usize])),
        }
        s
    }
}

#[derive(Debug, Clone, Copy)]
struct Sums {
    n: f64,
    sum: f64,
    sum_ln: f64,
    sum_ln2: f64,
    min: f64,
}

/// Trigamma `psi'(x)`, `x > 0`: the recurrence `psi'(x) = psi'(x + 1) + 1/x^2` up to `x >= 10`,
/// then the asymptotic series `1/x + 1/(2x^2) + sum B_2k / x^(2k+1)` to `B_10` (its next term
/// is below 1e-14 there). statrs has digamma only.
pub fn trigamma(mut x: f64) -> f64 {
    let mut acc = 0.0;
    while x < 10.0 {
        acc += 1.0 / (x * x);
        x += 1.0;
    }
    let r = 1.0 / x;
    let r2 = r * r;
    let tail = 1.0 / 6.0 - r2 * (1.0 / 30.0 - r2 * (1.0 / 42.0 - r2 * (1.0 / 30.0 - r2 * 5.0 / 66.0)));
    acc + r + r2 / 2.0 + r * r2 * tail
}

/// Gamma MLE `(shape, scale_s)` from the sums.
fn gamma_mle(s: &Sums) -> Option<(f64, f64)> {
    let mean = s.sum / s.n;
    let d = mean.ln() - s.sum_ln / s.n;
    if !(d > 0.0 && d.is_finite()) {
        return None;
    }
    // Choi and Wette's start, then Newton on ln k - digamma(k) = d.
    let mut k = (3.0 - d + ((d - 3.0).powi(2) + 24.0 * d).sqrt()) / (12.0 * d);
    for _ in 0..50 {
        let f = k.ln() - digamma(k) - d;
        let df = 1.0 / k - trigamma(k);
        let next = k - f / df;
        let next = if next > 0.0 { next } else { k / 2.0 };
        let done = (next - k).abs() <= 1e-13 * k;
        k = next;
        if done {
            break;
        }
    }
    (k.is_finite() && k > 0.0).then_some((k, mean / k))
}

fn gamma_ll(s: &Sums, shape: f64, scale: f64) -> f64 {
    (shape - 1.0) * s.sum_ln - s.sum / scale - s.n * (ln_gamma(shape) + shape * scale.ln())
}

fn lognormal_mle(s: &Sums) -> Option<(f64, f64)> {
    let mu = s.sum_ln / s.n;
    let var = (s.sum_ln2 / s.n - mu * mu).max(0.0);
    (var > 0.0).then(|| (mu, var.sqrt()))
}

fn lognormal_ll(s: &Sums, mu: f64, sigma: f64) -> f64 {
    let sq = s.sum_ln2 - 2.0 * mu * s.sum_ln + s.n * mu * mu;
    -s.sum_ln - s.n * (sigma.ln() + 0.5 * (2.0 * std::f64::consts::PI).ln()) - sq / (2.0 * sigma * sigma)
}

fn pareto_mle(s: &Sums) -> Option<(f64, f64)> {
    let denom = s.sum_ln - s.n * s.min.ln();
    (denom > 0.0).then(|| (s.min, s.n / denom))
}

fn pareto_ll(s: &Sums, scale: f64, shape: f64) -> f64 {
    s.n * shape.ln() + s.n * shape * scale.ln() - (shape + 1.0) * s.sum_ln
}

/// Weibull MLE `(shape, scale_s)` of the logs `ln_x`.
fn weibull_mle(ln_x: &[f64]) -> Option<(f64, f64)> {
    let n = ln_x.len() as f64;
    let c = ln_x.iter().sum::<f64>() / n;
    let zmax = ln_x.iter().fold(f64::NEG_INFINITY, |m, l| m.max(l - c));
    // g(k) = E_w[z] - 1/k with weights e^{k z}, z = ln x - c (so mean z = 0); g' = Var_w[z] + 1/k^2.
    let g = |k: f64| {
        let (mut s0, mut s1, mut s2) = (0.0, 0.0, 0.0);
        for l in ln_x {
            let z = l - c;
            let w = (k * (z - zmax)).exp();
            s0 += w;
            s1 += w * z;
            s2 += w * z * z;
        }
        let m1 = s1 / s0;
        (m1 - 1.0 / k, s2 / s0 - m1 * m1 + 1.0 / (k * k), s0)
    };
    let var = ln_x.iter().map(|l| (l - c) * (l - c)).sum::<f64>() / n;
    if var <= 0.0 {
        return None;
    }
    // Start: Var(ln x) = pi^2 / (6 k^2) for a Weibull.
    let mut k = std::f64::consts::PI / (6.0 * var).sqrt();
    let (mut lo, mut hi) = (0.0_f64, f64::INFINITY);
    for _ in 0..100 {
        let (f, df, _) = g(k);
        if f > 0.0 {
            hi = hi.min(k);
        } else {
            lo = lo.max(k);
        }
        let mut next = k - f / df;
        if !(next > lo && next < hi && next.is_finite()) {
            next = if hi.is_finite() { (lo + hi) / 2.0 } else { k * 2.0 };
        }
        let done = (next - k).abs() <= 1e-12 * k;
        k = next;
        if done {
            break;
        }
    }
    let (_, _, s0) = g(k);
    // scale^k = mean x^k = e^{k (c + zmax)} * s0 / n.
    let scale = (c + zmax + (s0 / n).ln() / k).exp();
    (k.is_finite() && k > 0.0 && scale.is_finite()).then_some((k, scale))
}

fn weibull_ll(s: &Sums, ln_x: &[f64], shape: f64, scale: f64) -> f64 {
    let ln_scale = scale.ln();
    let sum_pow: f64 = ln_x.iter().map(|l| (shape * (l - ln_scale)).exp()).sum();
    s.n * (shape.ln() - shape * ln_scale) + (shape - 1.0) * s.sum_ln - sum_pow
}

/// Kolmogorov–Smirnov distance of the sorted sample `sorted` from `cdf` (also what the tests
/// of other crates measure a delay sample against a law with).
pub fn ks_distance(sorted: &[f64], cdf: impl Fn(f64) -> f64) -> f64 {
    let n = sorted.len() as f64;
    let mut d: f64 = 0.0;
    for (i, &x) in sorted.iter().enumerate() {
        let f = cdf(x);
        d = d.max((i + 1) as f64 / n - f).max(f - i as f64 / n);
    }
    d
}

/// The Kolmogorov–Smirnov distance beyond which a sample of `n` values is not drawn from a
/// given law at the 95 % level (asymptotic, `1.358 / sqrt(n)`). For a law whose parameters
/// were fitted to the same sample the test is conservative (Lilliefors' limits are lower):
/// a fit beyond it is a poor fit.
pub fn ks_limit_95(n: usize) -> f64 {
    1.358 / (n.max(1) as f64).sqrt()
}

/// The percentile interval of `reps` about `estimate`, the spread scaled by `scale`.
fn percentile_interval(estimate: f64, reps: &mut Vec<f64>, scale: f64) -> (f64, f64) {
    reps.retain(|v| v.is_finite());
    if reps.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    reps.sort_unstable_by(f64::total_cmp);
    let lo = crate::stats::quantile(reps, 0.025);
    let hi = crate::stats::quantile(reps, 0.975);
    (estimate + scale * (lo - estimate), estimate + scale * (hi - estimate))
}

/// Fits every kind of `options.kinds` to the entries `delays_s` (delays, s, and
/// [`delay::LOST_S`]; the i.i.d. laws see the delivered delays, the regime the sequence).
pub fn fit(delays_s: &[f64], options: &FitOptions) -> Result<FitReport, FitError> {
    if options.replicates < 2
        || options.regime_replicates < 2
        || options.bootstrap_size < 10
        || options.regime_bootstrap_size < 10
    {
        return Err(FitError::Option(
            "replicates and regime_replicates >= 2, bootstrap_size and regime_bootstrap_size >= 10".into(),
        ));
    }
    if let Some(r) = options.rate_hz
        && !(r.is_finite() && r > 0.0)
    {
        return Err(FitError::Option(format!("rate_hz must be finite and > 0, got {r}")));
    }
    let mut x = Vec::with_capacity(delays_s.len());
    for (index, &d) in delays_s.iter().enumerate() {
        if is_lost(d) {
            continue;
        }
        if !(d.is_finite() && d > 0.0) {
            return Err(FitError::NotPositive { index, value: d });
        }
        x.push(d);
    }
    if x.len() < 10 {
        return Err(FitError::TooFew(x.len()));
    }
    if x.iter().all(|v| *v == x[0]) {
        return Err(FitError::Constant(x[0]));
    }
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    let relative_variance =
        x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / x.len() as f64 / (mean * mean);
    if relative_variance < MIN_RELATIVE_VARIANCE {
        return Err(FitError::NearlyConstant { mean_s: mean, relative_variance });
    }
    let ln_x: Vec<f64> = x.iter().map(|v| v.ln()).collect();
    let sample = Sample { x, ln_x };
    let n = sample.x.len();
    let sums = sample.sums(None);
    let mut sorted = sample.x.clone();
    sorted.sort_unstable_by(f64::total_cmp);

    let wants = |k: Kind| options.kinds.contains(&k);
    let mut models: Vec<(Model, f64)> = Vec::new();
    if wants(Kind::Gamma)
        && let Some((k, th)) = gamma_mle(&sums)
    {
        models.push((Model::Gamma { shape: k, scale_s: th }, gamma_ll(&sums, k, th)));
    }
    if wants(Kind::Lognormal)
        && let Some((mu, sigma)) = lognormal_mle(&sums)
    {
        models.push((Model::Lognormal { mu, sigma }, lognormal_ll(&sums, mu, sigma)));
    }
    if wants(Kind::Pareto)
        && let Some((xm, a)) = pareto_mle(&sums)
    {
        models.push((Model::Pareto { scale_s: xm, shape: a }, pareto_ll(&sums, xm, a)));
    }
    if wants(Kind::Weibull)
        && let Some((k, l)) = weibull_mle(&sample.ln_x)
    {
        models.push((Model::Weibull { shape: k, scale_s: l }, weibull_ll(&sums, &sample.ln_x, k, l)));
    }
    let regime = if wants(Kind::Regime) { regime::fit(delays_s) } else { None };
    if let Some((r, ll)) = regime {
        models.push((Model::Regime(r), ll));
    }

    // The i.i.d. kinds' bootstrap: one resample serves every kind.
    let m = n.min(options.bootstrap_size);
    let scale = (m as f64 / n as f64).sqrt();
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let iid: Vec<usize> = (0..models.len())
        .filter(|i| matches!(models[*i].0.kind(), Kind::Gamma | Kind::Lognormal | Kind::Weibull))
        .collect();
    let mut reps: Vec<Vec<Vec<f64>>> =
        models.iter().map(|(m, _)| vec![Vec::new(); m.params().len()]).collect();
    if !iid.is_empty() {
        let mut idx = vec![0u32; m];
        let mut ln_buf = vec![0.0; m];
        for _ in 0..options.replicates {
            for i in idx.iter_mut() {
                *i = rng.random_range(0..n as u32);
            }
            let s = sample.sums(Some(&idx));
            for &c in &iid {
                let fitted = match models[c].0.kind() {
                    Kind::Gamma => gamma_mle(&s).map(|(a, b)| [a, b]),
                    Kind::Lognormal => lognormal_mle(&s).map(|(a, b)| [a, b]),
                    _ => {
                        for (b, &i) in ln_buf.iter_mut().zip(&idx) {
                            *b = sample.ln_x[i as usize];
                        }
                        weibull_mle(&ln_buf).map(|(a, b)| [a, b])
                    }
                };
                for (j, v) in fitted.unwrap_or([f64::NAN; 2]).into_iter().enumerate() {
                    reps[c][j].push(v);
                }
            }
        }
    }
    let mut regime_scale = 1.0;
    if let Some(c) = models.iter().position(|(m, _)| m.kind() == Kind::Regime)
        && let Model::Regime(r) = models[c].0
    {
        let len = delays_s.len().min(options.regime_bootstrap_size);
        reps[c] = regime::bootstrap(&r, delays_s, len, options.regime_replicates, options.seed);
        regime_scale = (len as f64 / delays_s.len() as f64).sqrt();
    }

    let mut candidates: Vec<Candidate> = Vec::with_capacity(models.len());
    for (c, (model, ll)) in models.into_iter().enumerate() {
        let params = match model {
            Model::Pareto { scale_s, shape } => pareto_intervals(n, scale_s, shape),
            _ => model
                .params()
                .into_iter()
                .zip(reps[c].iter_mut())
                .map(|((name, value), r)| {
                    let s = if matches!(model, Model::Regime(_)) { regime_scale } else { scale };
                    let (lower, upper) = percentile_interval(value, r, s);
                    Param { name, value, lower, upper }
                })
                .collect(),
        };
        let ks = ks_distance(&sorted, |v| model.cdf(v));
        let aic = 2.0 * model.free_parameters() as f64 - 2.0 * ll;
        candidates.push(Candidate { model, params, log_likelihood: ll, aic, ks });
    }
    candidates.sort_by(|a, b| a.aic.total_cmp(&b.aic));
    let mut by_ks: Vec<(Kind, f64)> = candidates.iter().map(|c| (c.kind(), c.ks)).collect();
    by_ks.sort_by(|a, b| a.1.total_cmp(&b.1));
    Ok(FitReport {
        candidates,
        by_ks: by_ks.into_iter().map(|(k, _)| k).collect(),
        entries: delays_s.len(),
        delivered: n,
        loss_probability: (delays_s.len() - n) as f64 / delays_s.len() as f64,
        rate_hz: options.rate_hz,
    })
}

/// Pareto's exact 95 % intervals: `n alpha / alpha_hat ~ Gamma(n - 1, 1)`, and
/// `P(min x / x_m > t) = t^(-n alpha)` (at `alpha_hat`). `x_m <= min x` always, so its interval
/// is one-sided: `[min x * 0.05^(1 / (n alpha)), min x]`, the estimate its upper end.
fn pareto_intervals(n: usize, scale_s: f64, shape: f64) -> Vec<Param> {
    let nf = n as f64;
    let g = Gamma::new(nf - 1.0, 1.0).ok();
    let q = |p: f64| g.as_ref().map_or(f64::NAN, |g| g.inverse_cdf(p));
    let (a_lo, a_hi) = (shape * q(0.025) / nf, shape * q(0.975) / nf);
    let x_lo = scale_s * 0.05_f64.powf(1.0 / (nf * shape));
    vec![
        Param { name: "scale_s".into(), value: scale_s, lower: x_lo, upper: scale_s },
        Param { name: "shape".into(), value: shape, lower: a_lo, upper: a_hi },
    ]
}

pub mod regime;

mod tables;
pub use tables::{MAX_WIDEN, TableError};

#[cfg(test)]
mod tests;
