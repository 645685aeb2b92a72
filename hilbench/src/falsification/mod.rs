//! `hilbench falsify FILE`: search the file's `[falsify]` spaces for a run that fails its
//! property, with the `falsify` crate's optimiser (CMA-ES, or random search as the baseline),
//! each run flown the way `hilbench run` flies one (`fly::fly_one`, so in process, over gRPC or
//! with an external controller alike), a batch's runs on `--jobs` threads; the worst run's
//! trace shrunk (`crate::shrink`) and written for `hilbench run --delay-trace` ([`output`]).
//!
//! A search is `falsify::Search` (ask a batch, fly it, tell its scores): **the same seed gives
//! the same search, bit for bit, whatever `--jobs`**, since the points of a batch do not
//! depend on the order its runs finish in.

pub mod journal;
pub mod output;

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use falsify::{Dim, Method, Property, RunFacts, Search, SearchResult, SearchSettings, Space};
use mav::Scenario;

use crate::drive::Driver;
use crate::fly::{Flight, RunFate, fly_one, watch_ctrl_c};
use crate::run::{Controller, Job, RunErrorKind, Verdict};
use crate::shrink::{self, FailureTrace, Rerun};

/// Everything a falsification needs, flags applied.
#[derive(Debug, Clone)]
pub struct Falsification {
    /// The scenario file (named in the outputs and in the replay command).
    pub file: PathBuf,
    pub scenario: Scenario,
    /// The spaces searched, one search per space and method.
    pub spaces: Vec<Space>,
    pub methods: Vec<Method>,
    pub property: Property,
    /// Runs per search.
    pub budget: u64,
    /// Seed of every search (and of the families' delay processes).
    pub seed: u64,
    /// Search on after the first failure, to the budget.
    pub whole_budget: bool,
    /// CMA-ES's first population (and random search's batch), and first step.
    pub population: Option<usize>,
    pub sigma0: f64,
    /// CMA-ES's warm-up: random points flown before its first generation.
    pub warmup: usize,
    pub controller: Controller,
    pub jobs: usize,
    pub driver: Driver,
    pub run_timeout: Duration,
    /// Reruns to shrink the worst run's trace (0: not shrunk).
    pub shrink_runs: u64,
    /// Where each run goes as it finishes, and the runs of an earlier try (`--resume`).
    pub journal: Option<Arc<journal::Journal>>,
}

/// One run of a search.
#[derive(Debug, Clone)]
pub struct Evaluation {
    /// From 1, in the order the search asked for it.
    pub run: u64,
    /// In the space's units, one value per dim.
    pub point: Vec<f64>,
    /// The robustness (m, `< 0`: the property fails); `-inf` for a run the controller
    /// stopped or that timed out (a failure of the property outright); NaN for one the bench
    /// could not fly (an error of its own: not evaluated).
    pub score: f64,
    pub outcome: Verdict,
    /// Why a run did not finish (its error), else empty.
    pub error: String,
    pub cycles: u64,
    pub min_clearance_m: Option<f64>,
    pub end_time_s: Option<f64>,
    pub wall_s: f64,
}

/// The run with the lowest score, and its trace (shrunk when it fails and shrinking is on).
#[derive(Debug, Clone)]
pub struct Worst {
    pub run: u64,
    pub score: f64,
    pub trace: FailureTrace,
}

/// One search: a space, a method, what it flew and found.
#[derive(Debug, Clone)]
pub struct SearchRecord {
    pub space: String,
    pub dims: Vec<Dim>,
    pub method: Method,
    pub result: SearchResult,
    /// Every run flown, in run order (those of a batch cut by Ctrl-C included).
    pub evaluations: Vec<Evaluation>,
    pub worst: Option<Worst>,
    pub interrupted: bool,
    pub wall_time_s: f64,
    /// Of `evaluations`, those taken from the journal of an earlier try (`--resume`).
    pub resumed_runs: usize,
}

impl SearchRecord {
    /// Runs the bench could not fly (its own errors): not evaluated, ranked last.
    pub fn errors(&self) -> usize {
        self.evaluations.iter().filter(|e| e.score.is_nan()).count()
    }

    /// The first run that failed the property, among all runs flown.
    pub fn first_failure(&self) -> Option<&Evaluation> {
        self.evaluations.iter().find(|e| e.score < 0.0)
    }
}

/// What a falsification gives back.
#[derive(Debug, Clone)]
pub struct FalsifyResult {
    pub searches: Vec<SearchRecord>,
    pub interrupted: bool,
    pub wall_time_s: f64,
}

impl FalsifyResult {
    /// Whether some search found a run that fails the property.
    pub fn found(&self) -> bool {
        self.searches.iter().any(|s| s.first_failure().is_some())
    }

    /// Runs that were evaluated (flown to an outcome, a controller's stop and a time-out
    /// included), over every search.
    pub fn evaluated(&self) -> usize {
        self.searches.iter().map(|s| s.evaluations.len() - s.errors()).sum()
    }
}

/// A point flown: its evaluation, and its delays and flight (kept for the worst run's trace).
struct PointRun {
    evaluation: Evaluation,
    delays_s: Vec<f64>,
    flight: Option<Box<Flight>>,
    interrupted: bool,
    /// Taken from the journal of an earlier try, not flown: no delays, no flight.
    journaled: bool,
}

impl Falsification {
    fn settings(&self, method: Method) -> SearchSettings {
        SearchSettings {
            stop_at_failure: !self.whole_budget,
            population: self.population,
            sigma0: self.sigma0,
            warmup: self.warmup,
            ..SearchSettings::new(method, self.budget, self.seed)
        }
    }

    fn rerun<'a>(&'a self, space: &Space, stop: &'a AtomicBool) -> Rerun<'a> {
        Rerun {
            stop,
            scenario: &self.scenario,
            trace_name: format!("falsify-{}", space.name),
            controller: &self.controller,
            driver: &self.driver,
            timeout: self.run_timeout,
            deadline: None,
        }
    }

    /// The score of a flown run.
    pub fn score(&self, flight: &Flight) -> f64 {
        self.property.robustness(&RunFacts::of(&flight.summary, &self.scenario))
    }

    /// Flies `point` of `space` as run `run`.
    fn fly_point(&self, space: &Space, run: u64, point: &[f64], stop: &AtomicBool) -> PointRun {
        let started = Instant::now();
        let mut evaluation = Evaluation {
            run,
            point: point.to_vec(),
            score: f64::NAN,
            outcome: Verdict::Failed(RunErrorKind::Bench),
            error: String::new(),
            cycles: 0,
            min_clearance_m: None,
            end_time_s: None,
            wall_s: 0.0,
        };
        let delays_s = match space.delays(point, &self.scenario) {
            Ok(d) => d,
            Err(e) => {
                evaluation.error = e;
                return PointRun {
                    evaluation,
                    delays_s: Vec::new(),
                    flight: None,
                    interrupted: false,
                    journaled: false,
                };
            }
        };
        let job = Job {
            scenario: self.rerun(space, stop).scenario_with(delays_s.clone()),
            controller: self.controller.clone(),
        };
        let fate = fly_one(&job, &self.driver, self.run_timeout);
        evaluation.wall_s = started.elapsed().as_secs_f64();
        let mut flight = None;
        let mut interrupted = false;
        match fate {
            RunFate::Flown(f) => {
                let s = &f.summary;
                evaluation.score = self.score(&f);
                evaluation.outcome = s.outcome().into();
                evaluation.cycles = s.cycles;
                evaluation.min_clearance_m = Some(s.min_clearance_m);
                evaluation.end_time_s = Some(s.end_time_s);
                flight = Some(f);
            }
            // The controller stopping the run fails the property outright; the bench's own
            // error leaves the point unevaluated.
            RunFate::Failed(e) => {
                evaluation.outcome = Verdict::Failed(e.kind);
                if e.is_controllers() {
                    evaluation.score = f64::NEG_INFINITY;
                }
                evaluation.error = e.message;
            }
            RunFate::TimedOut(limit) => {
                evaluation.outcome = Verdict::TimedOut;
                evaluation.score = f64::NEG_INFINITY;
                evaluation.error =
                    format!("the run took longer than the per-run time limit of {} s", limit.as_secs_f64());
            }
            RunFate::Interrupted => interrupted = true,
        }
        PointRun { evaluation, delays_s, flight, interrupted, journaled: false }
    }
}

/// Runs every search (each space, each method) in turn; `progress` sees each search's batches
/// (`space`, `method`, the batch's generation).
pub fn execute(
    f: &Falsification,
    progress: &mut dyn FnMut(&str, Method, &falsify::Generation),
) -> FalsifyResult {
    let started = Instant::now();
    let stop = Arc::new(AtomicBool::new(false));
    watch_ctrl_c(Arc::clone(&stop), "hilbench-falsify-ctrl-c");
    let mut searches = Vec::new();
    let mut interrupted = false;
    'spaces: for space in &f.spaces {
        for &method in &f.methods {
            let record = search_one(f, space, method, &stop, progress);
            interrupted |= record.interrupted;
            searches.push(record);
            if interrupted {
                break 'spaces;
            }
        }
    }
    FalsifyResult { searches, interrupted, wall_time_s: started.elapsed().as_secs_f64() }
}

/// The worst run of a search so far.
struct WorstSoFar {
    score: f64,
    run: u64,
    point: Vec<f64>,
    delays_s: Vec<f64>,
    /// None for a run the controller stopped or that timed out, or one taken from the journal.
    flight: Option<Box<Flight>>,
    journaled: bool,
}

/// One search of `space` with `method`, to its budget, its first failure or Ctrl-C; then the
/// worst run's trace.
fn search_one(
    f: &Falsification,
    space: &Space,
    method: Method,
    stop: &AtomicBool,
    progress: &mut dyn FnMut(&str, Method, &falsify::Generation),
) -> SearchRecord {
    let started = Instant::now();
    let mut search = Search::new(&space.dims, &f.settings(method));
    let mut evaluations: Vec<Evaluation> = Vec::new();
    // The worst run so far: its evaluation's score, run, delays and flight (none for a run the
    // controller stopped or that timed out).
    let mut worst: Option<WorstSoFar> = None;
    let mut interrupted = false;
    let mut resumed_runs = 0;
    while !search.done() {
        if stop.load(Ordering::Relaxed) {
            interrupted = true;
            break;
        }
        let batch = search.ask();
        let first = evaluations.len() as u64 + 1;
        let numbered: Vec<(u64, Vec<f64>)> = (first..).zip(batch).collect();
        let flown = falsify::in_process::par_map(&numbered, f.jobs, |(run, point)| {
            if stop.load(Ordering::Relaxed) {
                return None;
            }
            if let Some(evaluation) =
                f.journal.as_ref().and_then(|j| j.finished(&space.name, method, *run, point))
            {
                let p = PointRun {
                    evaluation,
                    delays_s: Vec::new(),
                    flight: None,
                    interrupted: false,
                    journaled: true,
                };
                return Some(p);
            }
            let p = f.fly_point(space, *run, point, stop);
            if let (Some(journal), false) = (&f.journal, p.interrupted) {
                journal.record(&space.name, method, &p.evaluation);
            }
            Some(p)
        });
        let cut = flown.iter().any(|p| p.as_ref().is_none_or(|p| p.interrupted));
        let mut scores = Vec::with_capacity(flown.len());
        for p in flown.into_iter().flatten().filter(|p| !p.interrupted) {
            let score = p.evaluation.score;
            scores.push(score);
            resumed_runs += usize::from(p.journaled);
            let flew = p.flight.is_some() || score == f64::NEG_INFINITY || (p.journaled && !score.is_nan());
            if flew && worst.as_ref().is_none_or(|w| score < w.score) {
                worst = Some(WorstSoFar {
                    score,
                    run: p.evaluation.run,
                    point: p.evaluation.point.clone(),
                    delays_s: p.delays_s,
                    flight: p.flight,
                    journaled: p.journaled,
                });
            }
            evaluations.push(p.evaluation);
        }
        if cut {
            // The batch's finished runs are kept; the optimiser is not told a partial batch.
            interrupted = true;
            break;
        }
        progress(&space.name, method, search.tell(&scores));
    }
    let worst = worst.map(|w| {
        let WorstSoFar { score, run, mut delays_s, mut flight, .. } = w;
        if w.journaled {
            // Flown by an earlier try: its delays again, and (lockstep: the same flight) its
            // flight for the trace, unless the controller stopped it or it timed out.
            if score.is_finite() {
                let again = f.fly_point(space, run, &w.point, stop);
                (delays_s, flight) = (again.delays_s, again.flight);
            } else {
                delays_s = space.delays(&w.point, &f.scenario).unwrap_or_default();
            }
        }
        let trace = match flight {
            Some(flight) if score < 0.0 && f.shrink_runs > 0 => {
                let fails = |flight: &Flight| f.score(flight) < 0.0;
                let failure = FailureTrace::unshrunk(&delays_s, &flight);
                shrink::shrink(&f.rerun(space, stop), f.shrink_runs, failure, shrink::Passes::All, &fails)
            }
            Some(flight) => FailureTrace::unshrunk(&delays_s, &flight),
            // Stopped by the controller or timed out: every delay the point drew, unshrunk.
            None => FailureTrace::whole(&delays_s),
        };
        Worst { run, score, trace }
    });
    SearchRecord {
        space: space.name.clone(),
        dims: space.dims.clone(),
        method,
        result: search.finish(),
        evaluations,
        worst,
        interrupted,
        wall_time_s: started.elapsed().as_secs_f64(),
        resumed_runs,
    }
}
