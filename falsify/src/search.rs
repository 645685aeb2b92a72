//! The search: an optimiser over a space's unit cube behind one ask/tell driver, and the loop
//! that runs it against an evaluation.
//!
//! [`Search`] hands out batches of points (a CMA-ES generation, or a batch of random points)
//! in the space's own units and takes their scores back, so that the caller evaluates a batch
//! however it likes (in parallel threads, over gRPC). [`search`] is that loop for a closure.
//! A search flies at most `budget` runs: the generation that would pass it is cut short (its
//! points are flown, the optimiser is not told). With `stop_at_failure` it ends after the
//! batch that holds its first failure.
//!
//! **The same seed and the same scores give the same points, bit for bit**, whatever the
//! evaluation's parallelism: every draw comes from the optimiser's own ChaCha8 generator, and
//! random search draws point `i` from the same stream whatever the batch size.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::cmaes::{Cmaes, CmaesSettings, default_population};
use crate::space::Dim;
use crate::table::Method;

/// How a search runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchSettings {
    pub method: Method,
    /// Most runs flown.
    pub budget: u64,
    pub seed: u64,
    /// End after the batch that holds the first failure (score < 0).
    pub stop_at_failure: bool,
    /// CMA-ES's first population (each restart doubles it), and random search's batch
    /// (default `4 + floor(3 ln n)`, CMA-ES's).
    pub population: Option<usize>,
    /// CMA-ES's first step, a fraction of each range.
    pub sigma0: f64,
    /// CMA-ES restarts when its step is below this in every coordinate (a fraction of each
    /// range): default 1e-4, finer than a falsifier needs to tell two runs apart.
    pub tol_x: f64,
    /// CMA-ES restarts when its recent best scores lie within this (the score's units, m):
    /// default 1e-6.
    pub tol_fun: f64,
    /// CMA-ES first flies this many uniformly drawn points (random search's first points, for
    /// the same seed) and starts its first run at the best of them; 0: at a uniformly drawn
    /// point, unflown.
    pub warmup: usize,
}

impl SearchSettings {
    pub fn new(method: Method, budget: u64, seed: u64) -> Self {
        Self {
            method,
            budget,
            seed,
            stop_at_failure: true,
            population: None,
            sigma0: crate::table::DEFAULT_SIGMA0,
            tol_x: 1e-4,
            tol_fun: 1e-6,
            warmup: 0,
        }
    }
}

/// One flown point.
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluated {
    /// Which run of the search it was, from 1.
    pub run: u64,
    /// In the space's units, one value per dim.
    pub point: Vec<f64>,
    pub score: f64,
}

/// What a batch left: a point of the convergence plot (best score against runs).
#[derive(Debug, Clone, PartialEq)]
pub struct Generation {
    /// From 0.
    pub index: u64,
    /// Runs flown so far, this batch's included.
    pub runs: u64,
    /// The best score of this batch.
    pub batch_best: f64,
    /// The best score so far.
    pub best: f64,
    /// CMA-ES: its step after this generation (unit cube, largest axis), its population and
    /// restarts so far.
    pub step: Option<f64>,
    pub population: usize,
    pub restarts: u32,
}

/// What a search found.
#[derive(Debug, Clone, PartialEq)]
pub struct SearchResult {
    pub method: Method,
    pub runs: u64,
    /// The lowest score (the first such run on ties); `None` only when no run was flown.
    pub best: Option<Evaluated>,
    pub first_failure: Option<Evaluated>,
    pub generations: Vec<Generation>,
    pub restarts: u32,
}

impl SearchResult {
    /// Runs to the first failure (its run number), if any.
    pub fn runs_to_failure(&self) -> Option<u64> {
        self.first_failure.as_ref().map(|e| e.run)
    }
}

#[derive(Debug, Clone)]
enum Optimiser {
    Cmaes(Box<Cmaes>),
    /// CMA-ES's warm-up: random points until `left` is 0, then CMA-ES at the best of them.
    WarmUp {
        rng: Box<ChaCha8Rng>,
        batch: usize,
        left: usize,
        best: Option<(f64, Vec<f64>)>,
    },
    Random {
        rng: Box<ChaCha8Rng>,
        batch: usize,
    },
}

/// A search in progress (ask/tell).
#[derive(Debug, Clone)]
pub struct Search {
    dims: Vec<Dim>,
    settings: SearchSettings,
    optimiser: Optimiser,
    /// The unit-cube points of the batch asked, as many as will be flown.
    asked: Vec<Vec<f64>>,
    /// The optimiser's batch was cut to the budget.
    cut: bool,
    result: SearchResult,
}

impl Search {
    /// A search of the box `dims` (an empty box has one point).
    pub fn new(dims: &[Dim], settings: &SearchSettings) -> Self {
        let n = dims.len().max(1);
        let batch = settings.population.unwrap_or_else(|| default_population(n)).max(1);
        let optimiser = match settings.method {
            Method::Cmaes if settings.warmup > 0 => Optimiser::WarmUp {
                rng: Box::new(ChaCha8Rng::seed_from_u64(settings.seed)),
                batch,
                left: settings.warmup,
                best: None,
            },
            Method::Cmaes => {
                Optimiser::Cmaes(Box::new(Cmaes::new(n, cmaes_settings(settings), settings.seed)))
            }
            Method::Random => {
                Optimiser::Random { rng: Box::new(ChaCha8Rng::seed_from_u64(settings.seed)), batch }
            }
        };
        Self {
            dims: dims.to_vec(),
            settings: *settings,
            optimiser,
            asked: Vec::new(),
            cut: false,
            result: SearchResult {
                method: settings.method,
                runs: 0,
                best: None,
                first_failure: None,
                generations: Vec::new(),
                restarts: 0,
            },
        }
    }

    /// Whether the search is over (budget spent, or a failure found with `stop_at_failure`).
    pub fn done(&self) -> bool {
        self.result.runs >= self.settings.budget
            || (self.settings.stop_at_failure && self.result.first_failure.is_some())
    }

    /// The next batch to fly, in the space's units (empty when [`Search::done`]). Each batch
    /// must be told before the next is asked.
    pub fn ask(&mut self) -> Vec<Vec<f64>> {
        assert!(self.asked.is_empty(), "the last batch was not told");
        if self.done() {
            return Vec::new();
        }
        let left = usize::try_from(self.settings.budget - self.result.runs).unwrap_or(usize::MAX);
        let n = self.dims.len().max(1);
        let mut batch = match &mut self.optimiser {
            Optimiser::Cmaes(c) => c.ask(),
            Optimiser::WarmUp { rng, batch, left: warm, .. } => {
                let k = (*batch).min(*warm).min(left);
                (0..k).map(|_| (0..n).map(|_| rng.random::<f64>()).collect()).collect()
            }
            Optimiser::Random { rng, batch } => {
                (0..(*batch).min(left)).map(|_| (0..n).map(|_| rng.random::<f64>()).collect()).collect()
            }
        };
        self.cut = batch.len() > left;
        batch.truncate(left);
        self.asked = batch;
        self.asked.iter().map(|u| self.to_space(u)).collect()
    }

    fn to_space(&self, unit: &[f64]) -> Vec<f64> {
        self.dims
            .iter()
            .zip(unit)
            .map(|(d, u)| if d.hi > d.lo { d.lo + (d.hi - d.lo) * u } else { d.lo })
            .collect()
    }

    /// The scores of the last batch asked, in order (lower is better, `< 0` a failure; NaN
    /// counts as the worst).
    pub fn tell(&mut self, scores: &[f64]) -> &Generation {
        assert_eq!(scores.len(), self.asked.len(), "tell needs a score for every point asked");
        let asked = std::mem::take(&mut self.asked);
        let key = |s: f64| if s.is_nan() { f64::INFINITY } else { s };
        let mut batch_best = f64::INFINITY;
        for (u, &score) in asked.iter().zip(scores) {
            self.result.runs += 1;
            let evaluated = Evaluated { run: self.result.runs, point: self.to_space(u), score };
            batch_best = batch_best.min(key(score));
            if self.result.best.as_ref().is_none_or(|b| key(score) < key(b.score)) {
                self.result.best = Some(evaluated.clone());
            }
            if score < 0.0 && self.result.first_failure.is_none() {
                self.result.first_failure = Some(evaluated);
            }
        }
        let (step, population) = match &mut self.optimiser {
            Optimiser::Cmaes(c) => {
                if !self.cut {
                    c.tell(scores);
                    self.result.restarts = c.restarts();
                }
                (Some(c.step()), c.population())
            }
            Optimiser::WarmUp { batch, left, best, .. } => {
                let population = *batch;
                for (u, &score) in asked.iter().zip(scores) {
                    if best.as_ref().is_none_or(|(b, _)| key(score) < *b) {
                        *best = Some((key(score), u.clone()));
                    }
                }
                *left = left.saturating_sub(asked.len());
                if *left == 0 {
                    let start = best.take().map_or_else(|| vec![0.5; self.dims.len().max(1)], |(_, u)| u);
                    let cmaes = Cmaes::new_at(&start, cmaes_settings(&self.settings), self.settings.seed);
                    self.optimiser = Optimiser::Cmaes(Box::new(cmaes));
                }
                (None, population)
            }
            Optimiser::Random { batch, .. } => (None, *batch),
        };
        let best = self.result.best.as_ref().map_or(f64::INFINITY, |b| key(b.score));
        self.result.generations.push(Generation {
            index: self.result.generations.len() as u64,
            runs: self.result.runs,
            batch_best,
            best,
            step,
            population,
            restarts: self.result.restarts,
        });
        self.result.generations.last().expect("just pushed")
    }

    /// The result so far.
    pub fn result(&self) -> &SearchResult {
        &self.result
    }

    /// The result.
    pub fn finish(self) -> SearchResult {
        self.result
    }
}

/// CMA-ES's settings of a search's.
fn cmaes_settings(settings: &SearchSettings) -> CmaesSettings {
    CmaesSettings {
        population: settings.population,
        sigma0: settings.sigma0,
        tol_x: settings.tol_x,
        tol_fun: settings.tol_fun,
        ..CmaesSettings::default()
    }
}

/// Searches the box `dims` with `settings`: `evaluate` scores each batch (points in the space's
/// units, one score each, in order), `progress` sees every batch's [`Generation`].
pub fn search(
    dims: &[Dim],
    settings: &SearchSettings,
    mut evaluate: impl FnMut(&[Vec<f64>]) -> Vec<f64>,
    mut progress: impl FnMut(&Generation),
) -> SearchResult {
    let mut s = Search::new(dims, settings);
    while !s.done() {
        let batch = s.ask();
        let scores = evaluate(&batch);
        progress(s.tell(&scores));
    }
    s.finish()
}
