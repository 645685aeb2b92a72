//! `hilbench sweep --until-bound P`: runs drawn in batches (run `i` is still run `i`: the same
//! draws as a sweep of a fixed size) until the 95 % Clopper-Pearson upper bound on the
//! failure probability (a collision or a missed goal: `sweep.json`'s `failure_probability.any`)
//! is below `P` for every controller, or a run fails, or the cap is reached. With
//! `--per-family` the bound must fall below `P` for each family the sweep draws (a positive
//! weight) on its own runs, every controller too: "my link", not the pool of links.
//!
//! The decision is taken on the runs in order, the first `n` of them: the sweep stops at the
//! first `n` that decides, and the runs a batch flew past it are left out. So the same file,
//! seed and `P` give the same `n` and the same `sweep.json` whatever `--jobs` is, at the cost of
//! at most one batch's runs flown for nothing. Errors and time-outs are not outcomes (as in
//! `failure_probability`): they count in neither the runs nor the failures.

use serde_json::{Value, json};

use super::{Done, Sweep, SweepResult, execute, stats::CONFIDENCE};
use crate::run::Verdict;

/// The most runs `--until-bound` flies when `--runs` does not say (`P = 3e-5` needs 100,000
/// runs without a failure).
pub const MAX_RUNS: u64 = 100_000;
/// A batch is `--jobs` runs at least, and at most this many times `--jobs` or an eighth of the
/// runs flown so far, whichever is more (few batches for a long sweep, each with its Ctrl-C
/// watcher; at most an eighth more runs flown past a failure).
const BATCH_PER_JOB: u64 = 8;

/// Why the runs stopped.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Stopped {
    /// Every controller's upper bound is below `P`.
    Below,
    /// This run failed: the bound is not shown below `P`.
    Failure(u64),
    /// The cap came first.
    Cap,
    Interrupted,
}

impl Stopped {
    fn name(self) -> &'static str {
        match self {
            Stopped::Below => "below",
            Stopped::Failure(_) => "failure",
            Stopped::Cap => "cap",
            Stopped::Interrupted => "interrupted",
        }
    }
}

/// Checks `P` and the cap before anything flies: `Err` says why the bound cannot be reached.
pub fn check(bound: f64, cap: u64) -> anyhow::Result<u64> {
    let need =
        linkfit::runs_needed(0, bound, CONFIDENCE).map_err(|e| anyhow::anyhow!("--until-bound: {e}"))?;
    anyhow::ensure!(
        need <= cap,
        "--until-bound {bound}: even without a failure the {:.0} % upper bound falls below {bound} only after {need} runs, more than the cap of {cap} (--runs)",
        100.0 * CONFIDENCE
    );
    Ok(need)
}

/// The first `n` runs of `done` (sorted by run) that decide, and why; `None`: none does.
/// `families`: each of these on its own (`--per-family`), else the runs pooled.
fn decide(
    done: &[Done],
    modes: &[String],
    families: Option<&[String]>,
    bound: f64,
) -> Option<(u64, Stopped)> {
    let groups = families.map_or(1, <[String]>::len);
    let mut counts = vec![0u64; modes.len() * groups];
    let mut i = 0;
    while i < done.len() {
        let run = done[i].row.run;
        let mut failed = false;
        while i < done.len() && done[i].row.run == run {
            let row = &done[i].row;
            match row.outcome {
                v if v.fails_the_controller() => failed = true,
                Verdict::Reached => {
                    let family = match families {
                        Some(f) => f.iter().position(|name| *name == row.family),
                        None => Some(0),
                    };
                    if let (Some(k), Some(f)) = (modes.iter().position(|m| *m == row.controller), family) {
                        counts[f * modes.len() + k] += 1;
                    }
                }
                _ => {}
            }
            i += 1;
        }
        if failed {
            return Some((run + 1, Stopped::Failure(run)));
        }
        let below = counts.iter().all(|&n| {
            matches!(linkfit::until_bound(0, n, bound, CONFIDENCE), Ok(linkfit::UntilBound::Below(_)))
        });
        if below {
            return Some((run + 1, Stopped::Below));
        }
    }
    None
}

/// Flies batches of `sweep`'s runs from run 0 until the rule stops them (`sweep.runs` is the
/// cap). Returns the result, its `until_bound` filled, and the number of runs it took.
pub fn execute_until(
    sweep: &Sweep,
    bound: f64,
    per_family: bool,
    bar: &indicatif::ProgressBar,
    show: bool,
) -> anyhow::Result<(SweepResult, u64)> {
    let drawn: Vec<String> =
        sweep.table.families.iter().filter(|f| f.weight > 0.0).map(|f| f.name().to_string()).collect();
    let families = per_family.then_some(drawn.as_slice());
    // Each family needs `need` runs of its own: about that many times the families, drawn.
    let need = check(bound, sweep.runs)? * families.map_or(1, |f| f.len().max(1) as u64);
    let modes = sweep.controller_names();
    let jobs = sweep.jobs.max(1) as u64;
    let mut done: Vec<Done> = Vec::new();
    let (mut next, mut wall_time_s) = (0u64, 0.0);
    let (n, stopped) = loop {
        // Runs the rule needs at least, if none fails: flown in one go when few.
        let at_least = need.saturating_sub(next).max(1);
        let size = at_least.clamp(jobs, (jobs * BATCH_PER_JOB).max(next / 8)).min(sweep.runs - next);
        bar.set_length(bar.length().unwrap_or(0).max((next + size) * modes.len() as u64));
        let batch = Sweep { batch: Some(next..next + size), ..sweep.clone() };
        let r = execute(&batch, bar, show);
        wall_time_s += r.wall_time_s;
        done.extend(r.done);
        next += size;
        if r.interrupted {
            break (done.iter().map(|d| d.row.run + 1).max().unwrap_or(0), Stopped::Interrupted);
        }
        if let Some(decided) = decide(&done, &modes, families, bound) {
            break decided;
        }
        if next >= sweep.runs {
            break (next, Stopped::Cap);
        }
    };
    let flown = done.len();
    if stopped != Stopped::Interrupted {
        done.retain(|d| d.row.run < n);
    }
    let mut by_controller = serde_json::Map::new();
    for m in &modes {
        let rows: Vec<_> = done.iter().map(|d| &d.row).filter(|r| &r.controller == m).collect();
        by_controller.insert(m.clone(), super::stats::failure_probability(&rows)["any"].clone());
    }
    let mut by_family = serde_json::Map::new();
    for name in families.unwrap_or_default() {
        let mut by = serde_json::Map::new();
        for m in &modes {
            let rows: Vec<_> =
                done.iter().map(|d| &d.row).filter(|r| &r.controller == m && &r.family == name).collect();
            by.insert(m.clone(), super::stats::failure_probability(&rows)["any"].clone());
        }
        by_family.insert(name.clone(), Value::Object(by));
    }
    let until = json!({
        "bound": bound,
        "per_family": per_family,
        "by_family": if per_family { Value::Object(by_family) } else { Value::Null },
        "level": CONFIDENCE,
        "cap": sweep.runs,
        "runs": n,
        "stopped": stopped.name(),
        "failed_run": match stopped { Stopped::Failure(r) => json!(r), _ => Value::Null },
        "runs_left_out": flown - done.len(),
        "any": by_controller,
    });
    let interrupted = stopped == Stopped::Interrupted;
    Ok((SweepResult { done, interrupted, wall_time_s, until_bound: Some(until), shrinking: None }, n))
}

/// The terminal's line about `sweep.json`'s `until_bound`.
pub fn say(until: &Value) -> String {
    let bound = until["bound"].as_f64().unwrap_or(f64::NAN);
    let runs = until["runs"].as_u64().unwrap_or(0);
    let pct = |v: &Value| v.as_f64().map_or_else(|| "-".to_string(), |x| format!("{:.3} %", 100.0 * x));
    let uppers: Vec<String> = until["any"]
        .as_object()
        .map(|o| o.iter().map(|(c, p)| format!("{c} {}", pct(&p["upper"]))).collect())
        .unwrap_or_default();
    let mut uppers = uppers.join(", ");
    // Per family: each family's bound, the one the rule waited for.
    if let Some(families) = until["by_family"].as_object() {
        let each: Vec<String> = families
            .iter()
            .flat_map(|(f, by)| {
                by.as_object()
                    .into_iter()
                    .flatten()
                    .map(move |(c, p)| format!("{f} {c} {}", pct(&p["upper"])))
            })
            .collect();
        uppers = format!("{uppers}; by family: {}", each.join(", "));
    }
    let each = if until["per_family"] == true { " for each family" } else { "" };
    match until["stopped"].as_str() {
        Some("below") => format!(
            "until-bound: after {runs} runs without a failure the failure probability is below {}{each} (95 % upper bound: {uppers})",
            pct(&until["bound"])
        ),
        Some("failure") => format!(
            "until-bound: run {} failed, so the failure probability is not shown below {}: stopped after {runs} runs (95 % upper bound: {uppers})",
            until["failed_run"],
            pct(&until["bound"])
        ),
        Some("cap") => format!(
            "until-bound: the cap of {runs} runs came first: upper bound {uppers}, not below {} ({bound})",
            pct(&until["bound"])
        ),
        _ => format!("until-bound: interrupted after {runs} runs (95 % upper bound: {uppers})"),
    }
}
