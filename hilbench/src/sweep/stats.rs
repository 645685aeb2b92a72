//! A sweep's numbers: one [`RunRow`] per (run, controller), the line of `runs.csv`, built from
//! the run's `mpc::RunSummary` (the summary the rest of the bench uses) and its per-cycle rows;
//! and the distributions of `sweep.json` ([`aggregate`]), computed from rows alone so that the
//! shards of a sweep merge into the sweep's own numbers ([`merge_rows`]).
//!
//! Percentiles are `mpc::record::percentile`'s nearest rank. `solve_ms` is over runs: `p50` the
//! median of the runs' median solve times, `p99` the 99th percentile of the runs' 99th
//! percentiles, `max` the largest solve; wall-clock times, so they differ between two sweeps of
//! the same runs.

use std::fmt::Write as _;

use mpc::record::percentile;
use serde_json::{Value, json};

use super::draw::RunPlan;
use crate::fly::Flight;
use crate::run::{RunErrorKind, Verdict};

/// One (run, controller) of a sweep: a line of `runs.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct RunRow {
    pub run: u64,
    pub controller: String,
    pub family: String,
    /// The family's drawn parameters, `key=value;...`.
    pub params: String,
    /// The column `outcome`: the verdict's name.
    pub outcome: Verdict,
    /// Some collision was with the ground.
    pub collided_ground: bool,
    pub min_clearance_m: Option<f64>,
    pub path_length_m: Option<f64>,
    pub time_to_goal_s: Option<f64>,
    pub end_time_s: Option<f64>,
    pub cycles: u64,
    pub fallbacks: u64,
    pub best_effort_cycles: u64,
    pub solve_ms_p50: Option<f64>,
    pub solve_ms_p99: Option<f64>,
    pub solve_ms_max: Option<f64>,
    /// Mean and largest delay of the cycles flown, s.
    pub mean_delay_s: Option<f64>,
    pub max_delay_s: Option<f64>,
    /// Where and when a failure happened: the first collision, or where a missed run ended.
    pub fail_time_s: Option<f64>,
    pub fail_position_m: Option<[f64; 3]>,
    /// What happened, in words (empty for a run that reached its goal).
    pub what: String,
    /// Solver time of the run, s (wall clock).
    pub solver_s: Option<f64>,
    /// Wall time of the run, s.
    pub wall_s: f64,
}

/// The columns of `runs.csv`.
pub const CSV_HEADER: &str = "run,controller,family,params,outcome,collided_ground,min_clearance_m,path_length_m,time_to_goal_s,end_time_s,cycles,fallbacks,best_effort_cycles,solve_ms_p50,solve_ms_p99,solve_ms_max,mean_delay_s,max_delay_s,fail_time_s,fail_x_m,fail_y_m,fail_z_m,what,solver_s,wall_s";

impl RunRow {
    /// The row of a run that flew.
    pub fn of_flight(run: u64, controller: &str, plan: &RunPlan, flown: &Flight, wall_s: f64) -> Self {
        let s = &flown.summary;
        let mut solve_ms: Vec<f64> = flown.rows.iter().map(|r| r.solve_ms).collect();
        let stat = |v: &mut Vec<f64>, p: f64| (!v.is_empty()).then(|| percentile(v, p));
        // A lost message (a trace's `lost`) has no delay: it is left out of the delays' numbers.
        let flown_delays: Vec<f64> = plan.delays_s[..flown.delays_needed(plan.delays_s.len())]
            .iter()
            .copied()
            .filter(|d| !delay::is_lost(*d))
            .collect();
        let outcome = Verdict::from(s.outcome());
        let first = s.collisions.first();
        let (fail_time_s, fail_position_m, what) = match outcome {
            Verdict::Collided => (
                first.map(|c| c.time_s),
                first.map(|c| c.position_m),
                s.collisions.iter().map(|c| c.describe()).collect::<Vec<_>>().join("; "),
            ),
            Verdict::Missed => {
                let p = s.final_position_m;
                (
                    Some(s.end_time_s),
                    Some(p),
                    format!(
                        "missed the goal: {} at {:.2} s, at [{:.2}, {:.2}, {:.2}] m",
                        s.end_reason, s.end_time_s, p[0], p[1], p[2]
                    ),
                )
            }
            _ => (None, None, String::new()),
        };
        Self {
            run,
            controller: controller.to_string(),
            family: plan.family.clone(),
            params: plan.params_text(),
            outcome,
            collided_ground: s.collisions.iter().any(|c| c.kind == "ground"),
            min_clearance_m: Some(s.min_clearance_m),
            path_length_m: Some(s.path_length_m),
            time_to_goal_s: s.time_to_goal_s,
            end_time_s: Some(s.end_time_s),
            cycles: s.cycles,
            fallbacks: s.fallbacks,
            best_effort_cycles: s.best_effort_cycles,
            solve_ms_p50: stat(&mut solve_ms, 50.0),
            solve_ms_p99: stat(&mut solve_ms, 99.0),
            solve_ms_max: stat(&mut solve_ms, 100.0),
            mean_delay_s: (!flown_delays.is_empty())
                .then(|| flown_delays.iter().sum::<f64>() / flown_delays.len() as f64),
            max_delay_s: flown_delays.iter().copied().reduce(f64::max),
            fail_time_s,
            fail_position_m,
            what,
            solver_s: Some(s.solve_ms_mean * s.cycles as f64 * 1e-3).filter(|v| v.is_finite()),
            wall_s,
        }
    }

    /// The row of a run that did not fly to its end (a failed run or a time-out).
    pub fn of_error(
        run: u64,
        controller: &str,
        family: &str,
        params: &str,
        outcome: Verdict,
        what: &str,
        wall_s: f64,
    ) -> Self {
        Self {
            run,
            controller: controller.to_string(),
            family: family.to_string(),
            params: params.to_string(),
            outcome,
            collided_ground: false,
            min_clearance_m: None,
            path_length_m: None,
            time_to_goal_s: None,
            end_time_s: None,
            cycles: 0,
            fallbacks: 0,
            best_effort_cycles: 0,
            solve_ms_p50: None,
            solve_ms_p99: None,
            solve_ms_max: None,
            mean_delay_s: None,
            max_delay_s: None,
            fail_time_s: None,
            fail_position_m: None,
            what: what.to_string(),
            solver_s: None,
            wall_s,
        }
    }

    /// The line of `runs.csv` (numbers written so that they read back to the bit).
    pub fn to_csv(&self) -> String {
        let n = |v: Option<f64>| v.map(|v| format!("{v:?}")).unwrap_or_default();
        let p = self.fail_position_m;
        let cells = [
            self.run.to_string(),
            quote(&self.controller),
            quote(&self.family),
            quote(&self.params),
            self.outcome.to_string(),
            self.collided_ground.to_string(),
            n(self.min_clearance_m),
            n(self.path_length_m),
            n(self.time_to_goal_s),
            n(self.end_time_s),
            self.cycles.to_string(),
            self.fallbacks.to_string(),
            self.best_effort_cycles.to_string(),
            n(self.solve_ms_p50),
            n(self.solve_ms_p99),
            n(self.solve_ms_max),
            n(self.mean_delay_s),
            n(self.max_delay_s),
            n(self.fail_time_s),
            n(p.map(|p| p[0])),
            n(p.map(|p| p[1])),
            n(p.map(|p| p[2])),
            quote(&self.what),
            n(self.solver_s),
            format!("{:?}", self.wall_s),
        ];
        cells.join(",")
    }

    /// A line of `runs.csv` back (`line` is 1-based, for errors).
    pub fn from_csv(text: &str, line: usize) -> Result<Self, String> {
        let cells = split_csv(text).map_err(|e| format!("line {line}: {e}"))?;
        let columns = CSV_HEADER.split(',').count();
        if cells.len() != columns {
            return Err(format!("line {line}: {} cells, {columns} expected", cells.len()));
        }
        let col = |i: usize| CSV_HEADER.split(',').nth(i).unwrap_or("?");
        let num = |i: usize| -> Result<Option<f64>, String> {
            let c = &cells[i];
            if c.is_empty() {
                return Ok(None);
            }
            c.parse().map(Some).map_err(|_| format!("line {line}: `{}`: {c:?} is not a number", col(i)))
        };
        let int = |i: usize| -> Result<u64, String> {
            cells[i].parse().map_err(|_| format!("line {line}: `{}`: {:?} is not a count", col(i), cells[i]))
        };
        let position = match (num(19)?, num(20)?, num(21)?) {
            (Some(x), Some(y), Some(z)) => Some([x, y, z]),
            _ => None,
        };
        Ok(Self {
            run: int(0)?,
            controller: cells[1].clone(),
            family: cells[2].clone(),
            params: cells[3].clone(),
            outcome: cells[4].parse().map_err(|e| format!("line {line}: `outcome`: {e}"))?,
            collided_ground: cells[5] == "true",
            min_clearance_m: num(6)?,
            path_length_m: num(7)?,
            time_to_goal_s: num(8)?,
            end_time_s: num(9)?,
            cycles: int(10)?,
            fallbacks: int(11)?,
            best_effort_cycles: int(12)?,
            solve_ms_p50: num(13)?,
            solve_ms_p99: num(14)?,
            solve_ms_max: num(15)?,
            mean_delay_s: num(16)?,
            max_delay_s: num(17)?,
            fail_time_s: num(18)?,
            fail_position_m: position,
            what: cells[22].clone(),
            solver_s: num(23)?,
            wall_s: num(24)?.unwrap_or(0.0),
        })
    }

    pub fn failed(&self) -> bool {
        !self.outcome.is_reached()
    }
}

/// `runs.csv` of `rows`.
pub fn to_csv(rows: &[&RunRow]) -> String {
    let mut out = String::with_capacity(200 * (rows.len() + 1));
    let _ = writeln!(out, "{CSV_HEADER}");
    for r in rows {
        let _ = writeln!(out, "{}", r.to_csv());
    }
    out
}

/// The rows of a `runs.csv`.
pub fn from_csv(text: &str) -> Result<Vec<RunRow>, String> {
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, h)) if h == CSV_HEADER => {}
        _ => return Err("line 1: not the header of a sweep's runs.csv".into()),
    }
    lines.filter(|(_, l)| !l.is_empty()).map(|(i, l)| RunRow::from_csv(l, i + 1)).collect()
}

/// A CSV cell: quoted when it holds a comma, a quote or a line end.
fn quote(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) { format!("\"{}\"", s.replace('"', "\"\"")) } else { s.to_string() }
}

fn split_csv(line: &str) -> Result<Vec<String>, String> {
    let mut cells = Vec::new();
    let mut cell = String::new();
    let mut chars = line.chars().peekable();
    let mut quoted = false;
    while let Some(c) = chars.next() {
        match (quoted, c) {
            (true, '"') if chars.peek() == Some(&'"') => {
                cell.push('"');
                chars.next();
            }
            (true, '"') => quoted = false,
            (true, c) => cell.push(c),
            (false, '"') if cell.is_empty() => quoted = true,
            (false, ',') => cells.push(std::mem::take(&mut cell)),
            (false, c) => cell.push(c),
        }
    }
    if quoted {
        return Err("a quoted cell is not closed".into());
    }
    cells.push(cell);
    Ok(cells)
}

fn pct(values: &[f64], p: f64) -> Value {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() { Value::Null } else { json!(percentile(&mut v, p)) }
}

/// The keys of `sweep.json` over `rows` (and of each of its families).
pub fn aggregate(rows: &[&RunRow]) -> Value {
    let count = |outcome: Verdict| rows.iter().filter(|r| r.outcome == outcome).count();
    let clearance: Vec<f64> = rows.iter().filter_map(|r| r.min_clearance_m).collect();
    let reached: Vec<&&RunRow> = rows.iter().filter(|r| r.outcome.is_reached()).collect();
    let path: Vec<f64> = reached.iter().filter_map(|r| r.path_length_m).collect();
    let time: Vec<f64> = reached.iter().filter_map(|r| r.time_to_goal_s).collect();
    let p50s: Vec<f64> = rows.iter().filter_map(|r| r.solve_ms_p50).collect();
    let p99s: Vec<f64> = rows.iter().filter_map(|r| r.solve_ms_p99).collect();
    let max = rows.iter().filter_map(|r| r.solve_ms_max).reduce(f64::max);
    json!({
        "runs": rows.len(),
        "reached": count(Verdict::Reached),
        "collided": count(Verdict::Collided),
        "collided_ground": rows.iter().filter(|r| r.collided_ground).count(),
        "missed": count(Verdict::Missed),
        "aborted": count(Verdict::Failed(RunErrorKind::Controller)),
        "errors": rows.iter().filter(|r| r.outcome.is_the_benchs()).count(),
        "timeouts": count(Verdict::TimedOut),
        "best_effort_cycles": rows.iter().map(|r| r.best_effort_cycles).sum::<u64>(),
        "fallbacks": rows.iter().map(|r| r.fallbacks).sum::<u64>(),
        "min_clearance_m": { "p1": pct(&clearance, 1.0), "p5": pct(&clearance, 5.0), "p50": pct(&clearance, 50.0) },
        "path_length_m": { "p50": pct(&path, 50.0), "p95": pct(&path, 95.0) },
        "time_to_goal_s": { "p50": pct(&time, 50.0), "p95": pct(&time, 95.0) },
        "solve_ms": { "p50": pct(&p50s, 50.0), "p99": pct(&p99s, 99.0), "max": max },
        "failure_probability": failure_probability(rows),
    })
}

/// Confidence level of the failure probabilities' intervals.
pub const CONFIDENCE: f64 = 0.95;

/// The probability of each kind of failure (a collision, a missed goal, the controller
/// stopping the run, any of them) estimated from the runs that flew (the bench's errors and
/// time-outs are not outcomes), with its two-sided
/// Clopper-Pearson interval at [`CONFIDENCE`]: `{failures, runs, rate, lower, upper, level}`,
/// `null` without a run.
pub fn failure_probability(rows: &[&RunRow]) -> Value {
    let flown = rows.iter().filter(|r| r.outcome.judges_the_controller()).count();
    let of = |failed: &dyn Fn(Verdict) -> bool| -> Value {
        let failures = rows.iter().filter(|r| failed(r.outcome)).count() as u64;
        match linkfit::clopper_pearson(failures, flown as u64, CONFIDENCE) {
            Ok(i) => json!({
                "failures": failures,
                "runs": flown,
                "rate": i.rate,
                "lower": i.lower,
                "upper": i.upper,
                "level": i.level,
            }),
            Err(_) => Value::Null,
        }
    };
    json!({
        "collision": of(&|o| o == Verdict::Collided),
        "missed": of(&|o| o == Verdict::Missed),
        "aborted": of(&|o| o == Verdict::Failed(RunErrorKind::Controller)),
        "any": of(&Verdict::fails_the_controller),
    })
}

/// The aggregate keys, with `families` (the same per family, in `family_order`).
pub fn aggregate_with_families(rows: &[&RunRow], family_order: &[String]) -> Value {
    let mut v = aggregate(rows);
    let mut families = serde_json::Map::new();
    for name in family_order {
        let of: Vec<&RunRow> = rows.iter().copied().filter(|r| &r.family == name).collect();
        families.insert(name.clone(), aggregate(&of));
    }
    v["families"] = Value::Object(families);
    v
}

/// Rows of shards put together: sorted by run and controller (`modes` order), a (run,
/// controller) present twice refused. Unless `partial` (a shard was interrupted), every run
/// `0..runs` must be there with every controller: the runs missing are refused, named.
pub fn merge_rows(
    mut rows: Vec<RunRow>,
    modes: &[String],
    runs: u64,
    partial: bool,
) -> Result<Vec<RunRow>, String> {
    let order = |m: &str| modes.iter().position(|x| x == m).unwrap_or(usize::MAX);
    rows.sort_by_key(|a| (a.run, order(&a.controller)));
    for w in rows.windows(2) {
        if w[0].run == w[1].run && w[0].controller == w[1].controller {
            return Err(format!("run {} with {} is in two shards", w[0].run, w[0].controller));
        }
    }
    if let Some(r) = rows.iter().find(|r| r.run >= runs || order(&r.controller) == usize::MAX) {
        return Err(format!(
            "run {} with {} is not a run of this sweep (runs 0 to {} with {})",
            r.run,
            r.controller,
            runs.saturating_sub(1),
            modes.join(", ")
        ));
    }
    if !partial {
        for mode in modes {
            let have = rows.iter().filter(|r| &r.controller == mode).map(|r| r.run);
            let missing = gaps(have, runs);
            if !missing.is_empty() {
                let count: u64 = missing.iter().map(|g| g.end - g.start).sum();
                let shown: Vec<String> = missing
                    .iter()
                    .take(10)
                    .map(|g| {
                        if g.end - g.start == 1 {
                            format!("{}", g.start)
                        } else {
                            format!("{}-{}", g.start, g.end - 1)
                        }
                    })
                    .collect();
                let more = if missing.len() > 10 { ", ..." } else { "" };
                return Err(format!(
                    "{count} of the sweep's {runs} runs with {mode} are in no shard: runs {}{more} (a shard \
                     missing or not finished?)",
                    shown.join(", ")
                ));
            }
        }
    }
    Ok(rows)
}

/// The ranges of `0..runs` that `have` (sorted, no repeats) leaves out.
fn gaps(have: impl Iterator<Item = u64>, runs: u64) -> Vec<std::ops::Range<u64>> {
    let mut out = Vec::new();
    let mut next = 0;
    for run in have {
        if run > next {
            out.push(next..run);
        }
        next = run + 1;
    }
    if next < runs {
        out.push(next..runs);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(run: u64, outcome: Verdict, clearance: f64) -> RunRow {
        let mut r = RunRow::of_error(run, "multistage", "gamma", "shape=1.5;x=2", outcome, "", 0.25);
        r.min_clearance_m = Some(clearance);
        r.path_length_m = Some(5.0 + run as f64);
        r.time_to_goal_s = Some(10.0);
        r.what = "cylinder 1, 0.01 m deep, at \"3\" s".into();
        r.fail_position_m = Some([1.0, 2.0 / 3.0, 0.1]);
        r
    }

    #[test]
    fn merged_rows_with_runs_missing_or_repeated_or_foreign_are_refused_naming_them() {
        let modes = vec!["multistage".to_string()];
        let rows = |runs: &[u64]| runs.iter().map(|&r| row(r, Verdict::Reached, 0.5)).collect::<Vec<_>>();
        let merged = merge_rows(rows(&[3, 0, 2, 1]), &modes, 4, false).expect("every run once");
        assert_eq!(merged.iter().map(|r| r.run).collect::<Vec<_>>(), [0, 1, 2, 3]);
        let e = merge_rows(rows(&[0, 4, 5, 9]), &modes, 12, false).expect_err("runs missing");
        assert!(e.contains("8 of the sweep's 12 runs") && e.contains("runs 1-3, 6-8, 10-11"), "{e}");
        let e = merge_rows(rows(&[0, 1, 1]), &modes, 2, false).expect_err("a run twice");
        assert!(e.contains("run 1 with multistage is in two shards"), "{e}");
        let e = merge_rows(rows(&[0, 1, 2]), &modes, 2, false).expect_err("a run past the sweep");
        assert!(e.contains("run 2 with multistage is not a run of this sweep"), "{e}");
        // An interrupted shard: what finished is merged.
        assert_eq!(merge_rows(rows(&[0, 2]), &modes, 4, true).expect("partial").len(), 2);
    }

    #[test]
    fn a_runs_csv_line_reads_back_to_the_bit() {
        let rows = [
            row(0, Verdict::Reached, 0.1 / 3.0),
            row(1, Verdict::Collided, -0.02),
            row(2, Verdict::Failed(RunErrorKind::Bench), f64::MIN_POSITIVE),
        ];
        let text = to_csv(&rows.iter().collect::<Vec<_>>());
        assert_eq!(text.lines().count(), 4);
        assert_eq!(from_csv(&text), Ok(rows.to_vec()));
        assert!(from_csv("run,controller\n").is_err());
    }

    #[test]
    fn a_runs_csv_line_with_an_outcome_that_is_no_verdict_is_refused_naming_line_and_column() {
        let text = to_csv(&[&row(0, Verdict::Reached, 0.5)]).replace(",reached,", ",crashed,");
        let e = from_csv(&text).expect_err("not a verdict");
        assert!(e.starts_with("line 2: `outcome`: \"crashed\" is not an outcome"), "{e}");
    }

    #[test]
    fn aggregates_count_outcomes_and_take_nearest_rank_percentiles() {
        let rows: Vec<RunRow> = (0..100)
            .map(|i| row(i, if i < 3 { Verdict::Collided } else { Verdict::Reached }, i as f64))
            .collect();
        let refs: Vec<&RunRow> = rows.iter().collect();
        let v = aggregate_with_families(&refs, &["gamma".to_string()]);
        assert_eq!(
            (v["runs"].as_u64(), v["reached"].as_u64(), v["collided"].as_u64()),
            (Some(100), Some(97), Some(3))
        );
        assert_eq!(v["min_clearance_m"]["p1"], 0.0);
        assert_eq!(v["min_clearance_m"]["p5"], 4.0);
        assert_eq!(v["min_clearance_m"]["p50"], 49.0);
        // Path lengths over the 97 runs that reached the goal, 8..=104 m.
        assert_eq!(v["path_length_m"]["p50"], 56.0);
        assert_eq!(v["families"]["gamma"]["runs"], 100);
        let modes = ["multistage".to_string()];
        assert_eq!(
            merge_rows(vec![rows[1].clone(), rows[0].clone()], &modes, 2, false).map(|r| r[0].run),
            Ok(0)
        );
        assert!(merge_rows(vec![rows[1].clone(), rows[1].clone()], &modes, 2, false).is_err());
    }

    #[test]
    fn failure_probabilities_are_clopper_pearson_intervals_over_the_runs_that_flew() {
        // 0 collisions in 1,600 runs: the exact 95 % upper end is 1 - 0.025^(1/1600)
        // (scipy's binomtest(0, 1600).proportion_ci('exact'): 0.0023028939...); errors and
        // time-outs are not runs that flew.
        let mut rows: Vec<RunRow> = (0..1600).map(|i| row(i, Verdict::Reached, 1.0)).collect();
        rows.push(row(1600, Verdict::Failed(RunErrorKind::Bench), 1.0));
        rows.push(row(1601, Verdict::TimedOut, 1.0));
        let refs: Vec<&RunRow> = rows.iter().collect();
        let p = failure_probability(&refs);
        assert_eq!(
            (p["collision"]["failures"].as_u64(), p["collision"]["runs"].as_u64()),
            (Some(0), Some(1600))
        );
        let upper = p["collision"]["upper"].as_f64().expect("an upper end");
        assert!((upper - (1.0 - 0.025f64.powf(1.0 / 1600.0))).abs() < 1e-12, "{upper}");
        assert_eq!(p["collision"]["lower"], 0.0);
        assert_eq!(
            crate::output::terminal::failure_text("collisions", &p["collision"]),
            "collisions: 0 of 1600 runs, P < 0.23 % (95 %)"
        );
        // 3 collisions and 1 missed goal in 120 runs: "any" counts both.
        let rows: Vec<RunRow> = (0..120)
            .map(|i| {
                row(
                    i,
                    if i < 3 {
                        Verdict::Collided
                    } else if i == 3 {
                        Verdict::Missed
                    } else {
                        Verdict::Reached
                    },
                    1.0,
                )
            })
            .collect();
        let refs: Vec<&RunRow> = rows.iter().collect();
        let p = failure_probability(&refs);
        assert_eq!(p["any"]["failures"], 4);
        let (lower, upper) = (
            p["collision"]["lower"].as_f64().expect("a lower end"),
            p["collision"]["upper"].as_f64().expect("an upper end"),
        );
        assert!(lower > 0.0 && lower < 0.025 && upper > 0.025 && upper < 0.1, "[{lower}, {upper}]");
        // No run flew: no estimate.
        assert_eq!(failure_probability(&[])["any"], Value::Null);
    }
}
