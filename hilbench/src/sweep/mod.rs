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

use hilbench_svc::sweep_table::SweepSection;
use mav::Scenario;
use mpc::ControllerMode;

use crate::drive::Driver;
use crate::fly::{RunFate, fly_one, watch_ctrl_c};
use crate::run::Job;
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
    pub modes: Vec<ControllerMode>,
    /// The i-th of k slices of the runs, and where that came from.
    pub shard: Option<shard::Shard>,
    pub jobs: usize,
    pub driver: Driver,
    pub run_timeout: Duration,
    pub shrink: bool,
    pub shrink_runs: u64,
    /// Fly these runs instead of the shard's (a batch of `--until-bound`, [`until`]).
    pub batch: Option<Range<u64>>,
}

impl Sweep {
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
    /// Sorted by run, then controller (in `modes` order).
    pub done: Vec<Done>,
    pub interrupted: bool,
    pub wall_time_s: f64,
    /// `--until-bound`: the rule, how many runs it took and why it stopped (sweep.json's
    /// `until_bound`).
    pub until_bound: Option<serde_json::Value>,
}

/// Flies every run of the shard on `sweep.jobs` threads. `bar` counts finished runs.
pub fn execute(sweep: &Sweep, bar: &indicatif::ProgressBar, show: bool) -> SweepResult {
    let started = Instant::now();
    // The (run, controller) pairs, by their number: nothing is allocated per run up front.
    let (runs, per_run) = (sweep.indices(), sweep.modes.len().max(1));
    let total = usize::try_from(runs.end - runs.start).unwrap_or(usize::MAX).saturating_mul(per_run);
    let item = |k: usize| -> Option<(u64, ControllerMode)> {
        let mode = *sweep.modes.get(k % per_run)?;
        (k < total).then(|| (runs.start + (k / per_run) as u64, mode))
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
                    let Some((index, mode)) = item(next.fetch_add(1, Ordering::Relaxed)) else { break };
                    let result = one(sweep, index, mode, stop);
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
                    if d.row.outcome != "reached" {
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
    let order = |m: &str| sweep.modes.iter().position(|x| x.name() == m).unwrap_or(usize::MAX);
    done.sort_by_key(|a| (a.row.run, order(&a.row.controller)));
    SweepResult { done, interrupted, wall_time_s: started.elapsed().as_secs_f64(), until_bound: None }
}

/// Run `index` with `mode`: drawn, flown, its row, its failure's trace (shrunk when asked).
/// `None`: Ctrl-C.
fn one(sweep: &Sweep, index: u64, mode: ControllerMode, stop: &AtomicBool) -> Option<Done> {
    let started = Instant::now();
    let plan = match sweep.plan(index) {
        Ok(plan) => plan,
        Err(e) => {
            let row = RunRow::of_error(index, mode, "", "", "error", &e, 0.0);
            return Some(Done { row, failure: None });
        }
    };
    let job = Job { scenario: plan.scenario(&sweep.scenario), mode };
    let flight = fly_one(&job, &sweep.driver, sweep.run_timeout);
    let wall_s = started.elapsed().as_secs_f64();
    let row = match &flight {
        RunFate::Interrupted => return None,
        RunFate::Flown(f) => RunRow::of_flight(index, mode, &plan, f, wall_s),
        RunFate::Failed(e) => {
            RunRow::of_error(index, mode, &plan.family, &plan.params_text(), "error", e, wall_s)
        }
        RunFate::TimedOut(limit) => {
            let e = format!("the run took longer than the per-run time limit of {} s", limit.as_secs_f64());
            RunRow::of_error(index, mode, &plan.family, &plan.params_text(), "timeout", &e, wall_s)
        }
    };
    let failure = match &flight {
        _ if row.outcome == "reached" => None,
        RunFate::Flown(f) if sweep.shrink => {
            let rerun = Rerun {
                scenario: &sweep.scenario,
                trace_name: format!("sweep-run-{index}"),
                mode,
                driver: &sweep.driver,
                timeout: sweep.run_timeout,
                stop,
            };
            let want = f.summary.outcome();
            let fails = |f: &crate::fly::Flight| f.summary.outcome() == want;
            Some(shrink::shrink(&rerun, sweep.shrink_runs, &plan.delays_s, f, &fails))
        }
        RunFate::Flown(f) => Some(shrink::FailureTrace::unshrunk(&plan.delays_s, f)),
        _ => Some(shrink::FailureTrace::whole(&plan.delays_s)),
    };
    Some(Done { row, failure })
}
