//! CMA-ES (Hansen, "The CMA Evolution Strategy: A Tutorial", 2016: the default parameters of
//! its table 1, cumulative step-size adaptation, rank-one and rank-mu updates) over the unit
//! cube, with IPOP restarts, as an ask/tell optimiser.
//!
//! Bounds: the distribution lives in unbounded space and each sample is folded into `[0, 1]`
//! by reflection at the faces (`x mod 2`, mirrored), the point evaluated; the update uses the
//! unfolded samples (pycma's `BoundTransform` does the same with a smoothed fold). A box's
//! corner is then as reachable as its centre, and no evaluation is spent outside it.
//!
//! Restarts (IPOP, Auger and Hansen 2005): a run stops when its step is below `tol_x` in every
//! coordinate, when its best scores of the last `10 + 30 n / lambda` generations and of this
//! one are within `tol_fun`, when every score of a generation is equal, or when the covariance's
//! condition number passes 1e14; the next run starts at a point drawn uniformly in the cube
//! with the first step and twice the population.
//!
//! ## Determinism
//! Every draw comes from one ChaCha8 generator seeded with the seed, and the arithmetic is
//! plain `f64` in a fixed order: the same seed and the same scores give the same points, bit
//! for bit.

use nalgebra::{DMatrix, DVector};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Settings of [`Cmaes`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CmaesSettings {
    /// Population of the first run (default `4 + floor(3 ln n)`); each restart doubles it.
    pub population: Option<usize>,
    /// First step, in the unit cube.
    pub sigma0: f64,
    /// A run stops when `sigma * sqrt(C_ii) < tol_x` for every `i` (default 1e-11, pycma's).
    pub tol_x: f64,
    /// A run stops when its recent best scores lie within this (default 1e-12).
    pub tol_fun: f64,
    /// The first run's mean: the centre of the cube (else a uniform draw, as every restart).
    pub start_at_centre: bool,
}

impl Default for CmaesSettings {
    fn default() -> Self {
        Self {
            population: None,
            sigma0: crate::table::DEFAULT_SIGMA0,
            tol_x: 1e-11,
            tol_fun: 1e-12,
            start_at_centre: false,
        }
    }
}

/// The strategy's parameters for dimension `n` and population `lambda` (tutorial, table 1).
#[derive(Debug, Clone)]
struct Params {
    lambda: usize,
    mu: usize,
    weights: Vec<f64>,
    mu_eff: f64,
    c_sigma: f64,
    d_sigma: f64,
    c_c: f64,
    c_1: f64,
    c_mu: f64,
    chi_n: f64,
}

impl Params {
    fn new(n: usize, lambda: usize) -> Self {
        let nf = n as f64;
        let mu = lambda / 2;
        let raw: Vec<f64> = (1..=mu).map(|i| ((lambda as f64 + 1.0) / 2.0).ln() - (i as f64).ln()).collect();
        let sum: f64 = raw.iter().sum();
        let weights: Vec<f64> = raw.iter().map(|w| w / sum).collect();
        let mu_eff = 1.0 / weights.iter().map(|w| w * w).sum::<f64>();
        let c_sigma = (mu_eff + 2.0) / (nf + mu_eff + 5.0);
        let d_sigma = 1.0 + 2.0 * (((mu_eff - 1.0) / (nf + 1.0)).sqrt() - 1.0).max(0.0) + c_sigma;
        let c_c = (4.0 + mu_eff / nf) / (nf + 4.0 + 2.0 * mu_eff / nf);
        let c_1 = 2.0 / ((nf + 1.3).powi(2) + mu_eff);
        let c_mu = (1.0 - c_1).min(2.0 * (mu_eff - 2.0 + 1.0 / mu_eff) / ((nf + 2.0).powi(2) + mu_eff));
        let chi_n = nf.sqrt() * (1.0 - 1.0 / (4.0 * nf) + 1.0 / (21.0 * nf * nf));
        Self { lambda, mu, weights, mu_eff, c_sigma, d_sigma, c_c, c_1, c_mu, chi_n }
    }
}

/// The default population for dimension `n`.
pub fn default_population(n: usize) -> usize {
    4 + (3.0 * (n.max(1) as f64).ln()).floor() as usize
}

/// One run's state.
#[derive(Debug, Clone)]
struct Run {
    p: Params,
    mean: DVector<f64>,
    sigma: f64,
    c: DMatrix<f64>,
    /// Eigenvectors of `c` (columns) and the square roots of its eigenvalues.
    b: DMatrix<f64>,
    d: DVector<f64>,
    p_sigma: DVector<f64>,
    p_c: DVector<f64>,
    generation: u64,
    /// The best score of each generation.
    history: Vec<f64>,
}

impl Run {
    fn new(mean: DVector<f64>, sigma: f64, lambda: usize) -> Self {
        let n = mean.len();
        Self {
            p: Params::new(n, lambda),
            mean,
            sigma,
            c: DMatrix::identity(n, n),
            b: DMatrix::identity(n, n),
            d: DVector::from_element(n, 1.0),
            p_sigma: DVector::zeros(n),
            p_c: DVector::zeros(n),
            generation: 0,
            history: Vec::new(),
        }
    }
}

/// Why a run of CMA-ES ended (the next one starts with twice the population).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stop {
    TolX,
    TolFun,
    FlatScores,
    Condition,
}

/// CMA-ES with IPOP restarts in `[0, 1]^n`, ask/tell.
#[derive(Debug, Clone)]
pub struct Cmaes {
    n: usize,
    settings: CmaesSettings,
    rng: ChaCha8Rng,
    run: Run,
    /// The unfolded samples of the generation asked and not yet told.
    asked: Vec<DVector<f64>>,
    restarts: u32,
    last_stop: Option<Stop>,
}

/// Folds `x` into `[0, 1]` by reflection at the faces.
pub fn fold(x: f64) -> f64 {
    let y = x.rem_euclid(2.0);
    if y > 1.0 { 2.0 - y } else { y }
}

impl Cmaes {
    /// A search of `[0, 1]^n` (`n >= 1`) seeded with `seed`.
    pub fn new(n: usize, settings: CmaesSettings, seed: u64) -> Self {
        let n = n.max(1);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mean = if settings.start_at_centre {
            DVector::from_element(n, 0.5)
        } else {
            DVector::from_fn(n, |_, _| rng.random::<f64>())
        };
        let lambda = settings.population.unwrap_or_else(|| default_population(n)).max(2);
        let run = Run::new(mean, settings.sigma0, lambda);
        Self { n, settings, rng, run, asked: Vec::new(), restarts: 0, last_stop: None }
    }

    /// A search of `[0, 1]^n` whose first run's mean is `mean` (e.g. the best of a warm-up of
    /// random points), seeded with `seed`.
    pub fn new_at(mean: &[f64], settings: CmaesSettings, seed: u64) -> Self {
        let n = mean.len().max(1);
        let rng = ChaCha8Rng::seed_from_u64(seed);
        let mean = DVector::from_fn(n, |i, _| mean.get(i).copied().unwrap_or(0.5).clamp(0.0, 1.0));
        let lambda = settings.population.unwrap_or_else(|| default_population(n)).max(2);
        let run = Run::new(mean, settings.sigma0, lambda);
        Self { n, settings, rng, run, asked: Vec::new(), restarts: 0, last_stop: None }
    }

    /// The population of the current run.
    pub fn population(&self) -> usize {
        self.run.p.lambda
    }

    /// Restarts so far.
    pub fn restarts(&self) -> u32 {
        self.restarts
    }

    /// Why the last run ended, if one has.
    pub fn last_stop(&self) -> Option<Stop> {
        self.last_stop
    }

    /// The current step (unit cube), times the largest standard deviation of the covariance.
    pub fn step(&self) -> f64 {
        self.run.sigma * self.run.d.max()
    }

    /// The next generation's points, each in `[0, 1]^n`.
    pub fn ask(&mut self) -> Vec<Vec<f64>> {
        let run = &self.run;
        self.asked = (0..run.p.lambda)
            .map(|_| {
                let z = DVector::from_fn(self.n, |_, _| self.rng.sample::<f64, _>(StandardNormal));
                &run.mean + run.sigma * (&run.b * run.d.component_mul(&z))
            })
            .collect();
        self.asked.iter().map(|x| x.iter().map(|&v| fold(v)).collect()).collect()
    }

    /// The scores of the points of the last [`Cmaes::ask`], in order (lower is better; NaN
    /// ranks last). Updates the distribution, or restarts.
    pub fn tell(&mut self, scores: &[f64]) {
        assert_eq!(scores.len(), self.asked.len(), "tell needs a score for every point asked");
        let mut order: Vec<usize> = (0..scores.len()).collect();
        let key = |s: f64| if s.is_nan() { f64::INFINITY } else { s };
        order.sort_by(|&a, &b| key(scores[a]).total_cmp(&key(scores[b])).then(a.cmp(&b)));
        let run = &mut self.run;
        let p = run.p.clone();
        let n = self.n as f64;
        let ys: Vec<DVector<f64>> =
            order[..p.mu].iter().map(|&i| (&self.asked[i] - &run.mean) / run.sigma).collect();
        let mut y_w = DVector::zeros(self.n);
        for (w, y) in p.weights.iter().zip(&ys) {
            y_w += *w * y;
        }
        run.mean += run.sigma * &y_w;
        // C^{-1/2} y_w = B D^{-1} B^T y_w.
        let c_inv_sqrt_yw = &run.b * (run.b.transpose() * &y_w).component_div(&run.d);
        run.p_sigma = (1.0 - p.c_sigma) * &run.p_sigma
            + (p.c_sigma * (2.0 - p.c_sigma) * p.mu_eff).sqrt() * c_inv_sqrt_yw;
        run.generation += 1;
        let ps_norm = run.p_sigma.norm();
        let h_sigma = ps_norm / (1.0 - (1.0 - p.c_sigma).powi(2 * run.generation as i32)).sqrt()
            < (1.4 + 2.0 / (n + 1.0)) * p.chi_n;
        let h = if h_sigma { 1.0 } else { 0.0 };
        run.p_c = (1.0 - p.c_c) * &run.p_c + h * (p.c_c * (2.0 - p.c_c) * p.mu_eff).sqrt() * &y_w;
        let delta_h = (1.0 - h) * p.c_c * (2.0 - p.c_c);
        let mut rank_mu = DMatrix::zeros(self.n, self.n);
        for (w, y) in p.weights.iter().zip(&ys) {
            rank_mu += *w * (y * y.transpose());
        }
        run.c = (1.0 - p.c_1 - p.c_mu) * &run.c
            + p.c_1 * (&run.p_c * run.p_c.transpose() + delta_h * &run.c)
            + p.c_mu * rank_mu;
        run.sigma *= ((p.c_sigma / p.d_sigma) * (ps_norm / p.chi_n - 1.0)).exp();
        // Symmetric by construction up to rounding; make it exactly so for the decomposition.
        run.c = (&run.c + run.c.transpose()) * 0.5;
        let eigen = run.c.clone().symmetric_eigen();
        let min_ev = eigen.eigenvalues.min();
        run.b = eigen.eigenvectors;
        run.d = eigen.eigenvalues.map(|v| v.max(1e-300).sqrt());
        run.history.push(key(scores[order[0]]));
        if let Some(stop) = self.stop(min_ev, key(scores[order[0]]), key(scores[order[order.len() - 1]])) {
            self.restart(stop);
        }
        self.asked.clear();
    }

    fn stop(&self, min_ev: f64, best: f64, worst: f64) -> Option<Stop> {
        let run = &self.run;
        if best == worst && best.is_finite() {
            return Some(Stop::FlatScores);
        }
        if (0..self.n).all(|i| run.sigma * run.c[(i, i)].sqrt() < self.settings.tol_x) {
            return Some(Stop::TolX);
        }
        let max_ev = run.d.max().powi(2);
        if min_ev <= 0.0 || max_ev / min_ev > 1e14 {
            return Some(Stop::Condition);
        }
        let window = 10 + (30.0 * self.n as f64 / run.p.lambda as f64).ceil() as usize;
        if run.history.len() > window {
            let recent = &run.history[run.history.len() - window - 1..];
            let hi = recent.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let lo = recent.iter().copied().fold(f64::INFINITY, f64::min);
            if hi - lo < self.settings.tol_fun {
                return Some(Stop::TolFun);
            }
        }
        None
    }

    fn restart(&mut self, stop: Stop) {
        let lambda = (self.run.p.lambda * 2).min(100_000);
        let mean = DVector::from_fn(self.n, |_, _| self.rng.random::<f64>());
        self.run = Run::new(mean, self.settings.sigma0, lambda);
        self.restarts += 1;
        self.last_stop = Some(stop);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fold_reflects_at_the_faces() {
        for (x, y) in [(0.3, 0.3), (1.2, 0.8), (-0.25, 0.25), (2.1, 0.1), (-1.5, 0.5), (1.0, 1.0), (0.0, 0.0)]
        {
            assert!((fold(x) - y).abs() < 1e-12, "fold({x}) = {}, not {y}", fold(x));
        }
    }

    #[test]
    fn default_parameters_are_the_tutorials() {
        // n = 10: lambda = 10, mu = 5, mu_eff ~ 3.17 (Hansen's tutorial, table 1).
        let p = Params::new(10, default_population(10));
        assert_eq!((p.lambda, p.mu), (10, 5));
        assert!((p.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!((p.mu_eff - 3.1672).abs() < 1e-3, "{}", p.mu_eff);
        assert!((p.chi_n - 3.0847).abs() < 1e-3, "{}", p.chi_n);
    }
}
