//! `hilbench sweep FILE`: N closed-loop runs of a scenario file, each under a delay process
//! drawn from the file's `[sweep]` table ([`draw`]), flown in lockstep the way `hilbench run`
//! flies a run (`fly::fly_one`, `fly::fly_all` with one job, so whatever driver `run` gains, a
//! sweep gains), on worker threads; outcomes as distributions ([`stats`]), failures written as
//! replayable traces and optionally shrunk (`crate::shrink`), sharded and merged
//! ([`stats::merge`]).
//!
//! Scheduling is the simplest that fills the cores: `--jobs` threads take the next (run,
//! controller) pair from a shared counter; each run is independent, so the order in which they
//! finish changes nothing in the outputs (rows are sorted by run).

pub mod draw;
pub mod journal;
pub mod output;
pub mod plots;
pub mod shard;
pub mod stats;
pub mod until;

use std::ops::Range;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, mpsc};
use std::time::{Duration, Instant};

use hilbench_scenario_file::sweep_table::SweepSection;
use mav::Scenario;

use crate::drive::Driver;
use crate::fly::{RunFate, fly_one, watch_ctrl_c};
use crate::run::{Controller, Job, RunErrorKind, Verdict};
use crate::shrink::{self, Rerun};
use draw::RunPlan;
use stats::RunRow;

/// How often a sweep without a terminal says how far it is.
const PROGRESS_LINE: Duration = Duration::from_secs(10);

/// Everything a sweep needs, flags applied.
#[derive(Debug, Clone)]
pub struct Sweep {
    /// The scenario file (named in the outputs).
    pub file: PathBuf,
    pub scenario: Scenario,
    pub table: SweepSection,
    /// Seed of the draws.
    pub seed: u64,
    /// Runs of the whole sweep (all shards).
    pub runs: u64,
    /// The controllers each run is flown with, in this order.
    pub controllers: Vec<Controller>,
    /// The i-th of k slices of the runs, and where that came from.
    pub shard: Option<shard::Shard>,
    pub jobs: usize,
    pub driver: Driver,
    pub run_timeout: Duration,
    pub shrink: bool,
    /// Reruns one failure's shrinking may spend.
    pub shrink_runs: u64,
    /// Reruns the shrinking of all the failures may spend, shared out in run order.
    pub shrink_total_runs: u64,
    /// Wall time the shrinking of all the failures may take.
    pub shrink_wall: Option<Duration>,
    /// Fly these runs instead of the shard's (a batch of `--until-bound`, [`until`]).
    pub batch: Option<Range<u64>>,
    /// Where each finished run is kept as it finishes (a killed sweep can be resumed).
    pub journal: Option<Arc<journal::Journal>>,
    /// Runs finished before (`--resume`): taken as they are, not flown again.
    pub finished: Arc<journal::Finished>,
}

/// FNV-1a, 64 bits: a fingerprint of a file or of a scenario's contents (not a defence against
/// a forger, only a check that they did not change).
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3))
}

impl Sweep {
    /// The fingerprint of the scenario and `[sweep]` table as this sweep flies them (every
    /// trace inline), as 16 hex digits: what `sweep-merge` compares between shards, so that
    /// shards of a file edited in between (an obstacle moved, a range changed) are not merged.
    pub fn scenario_fingerprint(&self) -> String {
        let json = serde_json::to_vec(&(&self.scenario, &self.table)).unwrap_or_default();
        format!("{:016x}", fnv1a64(&json))
    }

    /// The run indices of this shard: the i-th of k contiguous slices of `0..runs`.
    pub fn indices(&self) -> Range<u64> {
        if let Some(batch) = &self.batch {
            return batch.clone();
        }
        match self.shard {
            None => 0..self.runs,
            Some(shard::Shard { index, count, .. }) => {
                let at = |j: u64| (u128::from(self.runs) * u128::from(j) / u128::from(count)) as u64;
                at(index)..at(index + 1)
            }
        }
    }

    /// The controllers flown, as the outputs name them (in order).
    pub fn controller_names(&self) -> Vec<String> {
        self.controllers.iter().map(|c| c.name().to_string()).collect()
    }

    /// The external controller's command line, when the sweep flies one.
    pub fn controller_cmd(&self) -> Option<&str> {
        self.controllers.iter().find_map(Controller::command)
    }

    /// Run `index`'s delays.
    pub fn plan(&self, index: u64) -> Result<RunPlan, String> {
        draw::plan(&self.table, &self.scenario, self.seed, index)
    }
}

/// One finished (run, controller): its row, and the trace written for a failure.
#[derive(Debug, Clone)]
pub struct Done {
    pub row: RunRow,
    /// A failure's delays (shrunk with `--shrink`), and how the shrink went.
    pub failure: Option<shrink::FailureTrace>,
}

/// What a sweep gives back.
#[derive(Debug, Clone)]
pub struct SweepResult {
    /// Sorted by run, then controller (in `controllers` order).
    pub done: Vec<Done>,
    pub interrupted: bool,
    pub wall_time_s: f64,
    /// `--until-bound`: the rule, how many runs it took and why it stopped (sweep.json's
    /// `until_bound`).
    pub until_bound: Option<serde_json::Value>,
    /// `--shrink`: what shrinking the failures spent ([`shrink_failures`]).
    pub shrinking: Option<ShrinkSpent>,
}

/// Flies every run of the shard on `sweep.jobs` threads. `bar` counts finished runs.
pub fn execute(sweep: &Sweep, bar: &indicatif::ProgressBar, show: bool) -> SweepResult {
    let started = Instant::now();
    // The (run, controller) pairs, by their number: nothing is allocated per run up front.
    let (runs, per_run) = (sweep.indices(), sweep.controllers.len().max(1));
    let total = usize::try_from(runs.end - runs.start).unwrap_or(usize::MAX).saturating_mul(per_run);
    let item = |k: usize| -> Option<(u64, &Controller)> {
        let controller = sweep.controllers.get(k % per_run)?;
        (k < total).then(|| (runs.start + (k / per_run) as u64, controller))
    };
    let stop = Arc::new(AtomicBool::new(false));
    watch_ctrl_c(Arc::clone(&stop), "hilbench-sweep-ctrl-c");
    let next = AtomicUsize::new(0);
    let (tx, rx) = mpsc::channel::<Option<Done>>();
    let mut done = Vec::with_capacity(total.min(4096));
    let mut interrupted = false;
    std::thread::scope(|s| {
        for _ in 0..sweep.jobs.max(1) {
            let tx = tx.clone();
            let (item, next, stop) = (&item, &next, &stop);
            s.spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    let Some((index, controller)) = item(next.fetch_add(1, Ordering::Relaxed)) else { break };
                    let key = (index, controller.name().to_string());
                    let result = match sweep.finished.get(&key) {
                        Some(done) => Some(done.clone()),
                        None => {
                            let result = one(sweep, index, controller);
                            if let (Some(done), Some(journal)) = (&result, &sweep.journal) {
                                journal.record(done);
                            }
                            result
                        }
                    };
                    if result.is_none() {
                        stop.store(true, Ordering::Relaxed);
                    }
                    if tx.send(result).is_err() {
                        break;
                    }
                }
            });
        }
        drop(tx);
        // Without a terminal (a log, CI) a line every few seconds says how far the sweep is.
        let mut said = Instant::now();
        loop {
            let result = match rx.recv_timeout(Duration::from_millis(500)) {
                Ok(result) => result,
                Err(mpsc::RecvTimeoutError::Timeout) => continue,
                Err(mpsc::RecvTimeoutError::Disconnected) => break,
            };
            if show && bar.is_hidden() && said.elapsed() >= PROGRESS_LINE {
                said = Instant::now();
                let elapsed = started.elapsed().as_secs_f64();
                eprintln!(
                    "  sweep: {} of {} runs in {elapsed:.0} s ({:.1} runs/s)",
                    done.len(),
                    total,
                    done.len() as f64 / elapsed.max(1e-9)
                );
            }
            match result {
                Some(d) => {
                    if d.row.failed() {
                        let text = format!(
                            "  run {} {}: {} ({})",
                            d.row.run, d.row.controller, d.row.outcome, d.row.what
                        );
                        crate::progress::line(bar, show && !bar.is_hidden(), &text);
                    }
                    done.push(d);
                    bar.inc(1);
                }
                None => interrupted = true,
            }
        }
    });
    interrupted |= stop.load(Ordering::Relaxed) && done.len() < total;
    let order = |m: &str| sweep.controllers.iter().position(|c| c.name() == m).unwrap_or(usize::MAX);
    done.sort_by_key(|a| (a.row.run, order(&a.row.controller)));
    SweepResult {
        done,
        interrupted,
        wall_time_s: started.elapsed().as_secs_f64(),
        until_bound: None,
        shrinking: None,
    }
}

/// Run `index` with `controller`: drawn, flown, its row, its failure's trace. `None`: Ctrl-C.
fn one(sweep: &Sweep, index: u64, controller: &Controller) -> Option<Done> {
    let started = Instant::now();
    let job_controller = controller.clone();
    let controller = controller.name();
    let plan = match sweep.plan(index) {
        Ok(plan) => plan,
        Err(e) => {
            let row =
                RunRow::of_error(index, controller, "", "", Verdict::Failed(RunErrorKind::Bench), &e, 0.0);
            return Some(Done { row, failure: None });
        }
    };
    let job = Job { scenario: plan.scenario(&sweep.scenario), controller: job_controller };
    let flight = fly_one(&job, &sweep.driver, sweep.run_timeout);
    let wall_s = started.elapsed().as_secs_f64();
    let row = match &flight {
        RunFate::Interrupted => return None,
        RunFate::Flown(f) => RunRow::of_flight(index, controller, &plan, f, wall_s),
        // The controller stopping the run is a failure of it, with its own outcome; the
        // bench's own errors are not outcomes.
        RunFate::Failed(e) => RunRow::of_error(
            index,
            controller,
            &plan.family,
            &plan.params_text(),
            Verdict::Failed(e.kind),
            &e.message,
            wall_s,
        ),
        RunFate::TimedOut(limit) => {
            let e = format!("the run took longer than the per-run time limit of {} s", limit.as_secs_f64());
            RunRow::of_error(
                index,
                controller,
                &plan.family,
                &plan.params_text(),
                Verdict::TimedOut,
                &e,
                wall_s,
            )
        }
    };
    let failure = match &flight {
        _ if row.outcome.is_reached() => None,
        RunFate::Flown(f) => Some(shrink::FailureTrace::unshrunk(&plan.delays_s, f)),
        _ => Some(shrink::FailureTrace::whole(&plan.delays_s)),
    };
    Some(Done { row, failure })
}

/// What shrinking the failures of a sweep spent (sweep.json's `shrinking`).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ShrinkSpent {
    /// Failures whose run flew to an end and so could be shrunk.
    pub failures: usize,
    /// Of them, those given a budget (the total ran out for the rest).
    pub shrunk: usize,
    pub reruns: u64,
    pub per_failure_budget: u64,
    pub total_budget: u64,
    pub wall_time_s: f64,
    pub interrupted: bool,
}

/// The reruns each of `n` failures may spend, in run order: an even share of `total`, at most
/// `per_failure` each (the first `total % n` get one more); independent of how many threads
/// shrink, so a sweep's traces do not depend on `--jobs`.
pub fn shrink_budgets(n: usize, per_failure: u64, total: u64) -> Vec<u64> {
    let n64 = n.max(1) as u64;
    (0..n as u64).map(|i| (total / n64 + u64::from(i < total % n64)).min(per_failure)).collect()
}

/// After the runs: shrinks each failure of `result` that flew to its end (a collision, or a
/// goal missed), in run order, within [`shrink_budgets`], on `sweep.jobs` threads. Says first
/// what it may cost; Ctrl-C ends it within a run, keeping what was shrunk.
pub fn shrink_failures(sweep: &Sweep, result: &mut SweepResult, show: bool) -> ShrinkSpent {
    let started = Instant::now();
    let todo: Vec<usize> = (0..result.done.len())
        .filter(|&i| {
            let d = &result.done[i];
            d.failure.as_ref().is_some_and(|f| f.replay.is_some())
        })
        .collect();
    let budgets = shrink_budgets(todo.len(), sweep.shrink_runs, sweep.shrink_total_runs);
    let planned: u64 = budgets.iter().sum();
    let shrunk = budgets.iter().filter(|b| **b > 0).count();
    if show && !todo.is_empty() {
        let walls: Vec<f64> = todo.iter().map(|&i| result.done[i].row.wall_s).collect();
        let run_s = walls.iter().sum::<f64>() / walls.len() as f64;
        let jobs = sweep.jobs.clamp(1, todo.len());
        let wall = sweep
            .shrink_wall
            .map(|w| format!(", stopping after {}", crate::progress::duration_text(w.as_secs_f64())))
            .unwrap_or_default();
        eprintln!(
            "shrinking {} failure(s) on {jobs} job(s): at most {planned} reruns ({} each at most, {} in all \
             at most), about {} at {run_s:.2} s a run{wall}; a line as each is done; Ctrl-C keeps what is shrunk so far",
            todo.len(),
            sweep.shrink_runs,
            sweep.shrink_total_runs,
            crate::progress::duration_text(planned as f64 * run_s / jobs as f64),
        );
    }
    let stop = Arc::new(AtomicBool::new(false));
    watch_ctrl_c(Arc::clone(&stop), "hilbench-shrink-ctrl-c");
    let deadline = sweep.shrink_wall.map(|w| started + w);
    let finished = AtomicUsize::new(0);
    let next = AtomicUsize::new(0);
    let (tx, rx) = mpsc::channel::<(usize, shrink::FailureTrace)>();
    std::thread::scope(|s| {
        for _ in 0..sweep.jobs.clamp(1, todo.len().max(1)) {
            let tx = tx.clone();
            let (next, stop, todo, budgets, done, finished) =
                (&next, &stop, &todo, &budgets, &result.done, &finished);
            s.spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    let k = next.fetch_add(1, Ordering::Relaxed);
                    let (Some(&i), Some(&budget)) = (todo.get(k), budgets.get(k)) else { break };
                    let d = &done[i];
                    let Some(mut failure) = d.failure.clone() else { continue };
                    if budget == 0 {
                        // The total budget ran out before this failure: said, not shrunk.
                        failure.shrink = Some((0, false));
                        if tx.send((i, failure)).is_err() {
                            break;
                        }
                        continue;
                    }
                    let Some(controller) = sweep.controllers.iter().find(|c| c.name() == d.row.controller)
                    else {
                        continue;
                    };
                    let rerun = Rerun {
                        scenario: &sweep.scenario,
                        trace_name: format!("sweep-run-{}", d.row.run),
                        controller,
                        driver: &sweep.driver,
                        timeout: sweep.run_timeout,
                        stop,
                        deadline,
                    };
                    let want = d.row.outcome;
                    let fails = |f: &crate::fly::Flight| Verdict::from(f.summary.outcome()) == want;
                    let passes = shrink::Passes::for_outcome(want);
                    let nonzero = |d: &[f64]| d.iter().filter(|x| **x != 0.0).count();
                    let (from, from_nonzero) = (failure.delays_s.len(), nonzero(&failure.delays_s));
                    let shrunk = shrink::shrink(&rerun, budget, failure, passes, &fails);
                    if show {
                        // A line a failure, on a terminal or in a log alike.
                        let n = finished.fetch_add(1, Ordering::Relaxed) + 1;
                        let (reruns, complete) = shrunk.shrink.unwrap_or((0, false));
                        eprintln!(
                            "  shrunk {n} of {}: run {} ({}) from {from} delays ({from_nonzero} not zero) to {} ({} not zero) in {reruns} reruns{}, {} in",
                            todo.len(),
                            d.row.run,
                            d.row.controller,
                            shrunk.delays_s.len(),
                            nonzero(&shrunk.delays_s),
                            if complete { "" } else { " (its budget of reruns or wall time used up, or interrupted)" },
                            crate::progress::duration_text(started.elapsed().as_secs_f64()),
                        );
                    }
                    if tx.send((i, shrunk)).is_err() {
                        break;
                    }
                }
            });
        }
        drop(tx);
    });
    let mut reruns = 0;
    for (i, shrunk) in rx {
        reruns += shrunk.shrink.map_or(0, |(r, _)| r);
        result.done[i].failure = Some(shrunk);
    }
    let interrupted = stop.load(Ordering::Relaxed);
    ShrinkSpent {
        failures: todo.len(),
        shrunk,
        reruns,
        per_failure_budget: sweep.shrink_runs,
        total_budget: sweep.shrink_total_runs,
        wall_time_s: started.elapsed().as_secs_f64(),
        interrupted,
    }
}
