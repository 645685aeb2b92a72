//! `summary.json` of `hilbench reproduce` and `run` (names are stable; the schema is in
//! docs/output.md): one entry per run, the verdicts, where the time went.

use std::path::{Path, PathBuf};

use anyhow::Context;
use mpc::RunSummary;

use crate::run::CycleRow;
use crate::run::{Batch, total};

/// Where the time went besides the runs, s (`None`: not done).
#[derive(Debug, Clone, Copy, Default)]
pub struct OutputTimes {
    pub plotting_s: Option<f64>,
    pub mcap_s: Option<f64>,
}

/// `summary.json` of `batch`.
pub fn summary_json(batch: &Batch, times: OutputTimes) -> serde_json::Value {
    let timed: Vec<serde_json::Value> = batch
        .runs
        .iter()
        .filter_map(|r| {
            let timing = r.timing?;
            let mut v = serde_json::json!({
                "scenario": r.job.scenario.name,
                "controller": r.controller(),
            });
            if let (Some(entry), serde_json::Value::Object(keys)) =
                (v.as_object_mut(), serde_json::json!(timing))
            {
                entry.extend(keys);
            }
            v["loop_overhead_s"] = serde_json::json!(timing.loop_overhead_s());
            Some(v)
        })
        .collect();
    let timing = serde_json::json!({
        "wall_time_s": batch.wall_time_s,
        "solver_s": batch.solver_s(),
        "setup_s": total(batch.runs.iter().filter_map(|r| r.timing).map(|t| t.setup_s)),
        "loop_overhead_s": total(batch.runs.iter().filter_map(|r| r.timing).map(|t| t.loop_overhead_s())),
        "teardown_s": total(batch.runs.iter().filter_map(|r| r.timing).map(|t| t.teardown_s)),
        "runs": timed,
        "plotting_s": times.plotting_s,
        "mcap_s": times.mcap_s,
    });
    let summaries: Vec<RunSummary> = batch.runs.iter().map(|r| r.summary.clone()).collect();
    serde_json::json!({
        "runs": batch
            .runs
            .iter()
            .map(|r| {
                let mut v = run_json(&r.summary);
                add_cycle_metrics(&mut v, &r.rows, &r.job.scenario.goal_m);
                r.faults.add_to(&mut v);
                v["delay_profile"] = serde_json::json!(r.delay_profile);
                v["plant"] = serde_json::json!(r.plant);
                if let Some(facts) = &r.external {
                    v["external_controller"] = serde_json::json!(facts);
                }
                // The run's own error: the batch's, or "interrupted (Ctrl-C)" for a run cut short.
                if r.error.is_some() {
                    v["error"] = serde_json::json!(r.error);
                }
                v
            })
            .collect::<Vec<_>>(),
        "verdicts": super::paper::verdicts(&summaries),
        "transport": batch.driver,
        "time_mode": batch.time_mode.name(),
        "wall_time_s": batch.wall_time_s,
        "timing": timing,
        "error": batch.error,
        "interrupted": batch.interrupted,
        "hilbench_version": env!("CARGO_PKG_VERSION"),
        "hilbench_commit": env!("HILBENCH_COMMIT"),
    })
}

/// Writes `summary` as `dir/summary.json` (creating `dir`); returns the file's path.
pub fn write(dir: &Path, summary: &serde_json::Value) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join("summary.json");
    std::fs::write(&path, serde_json::to_string_pretty(summary)?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(path)
}

/// One entry of `summary.json` (names are stable; see docs/output.md).
pub fn run_json(r: &RunSummary) -> serde_json::Value {
    serde_json::json!({
        "scenario": r.scenario,
        "controller": r.controller,
        "reached": r.reached,
        "collided": r.collided,
        "end_reason": r.end_reason,
        "time_to_goal_s": r.time_to_goal_s,
        "path_length_m": r.path_length_m,
        "min_clearance_m": r.min_clearance_m,
        "cycles": r.cycles,
        "solve_ms": { "mean": r.solve_ms_mean, "median": r.solve_ms_median, "p95": r.solve_ms_p95, "max": r.solve_ms_max },
        "iterations_median": r.iterations_median,
        "iteration_limits": r.iteration_limits,
        "infeasible_at_limit": r.infeasible_at_limit,
        "fallbacks": r.fallbacks,
        "decisions": r.decisions,
        "best_effort_cycles": r.best_effort_cycles,
        "commands_lost": r.commands_lost,
        "explanation": r.explanation,
        "cost_gap": r.cost_gap,
        "collisions": r.collisions,
        "final_position_m": r.final_position_m,
    })
}

/// Adds the keys computed from the per-cycle log to a run's `summary.json` entry:
/// `deadline_misses` (solves stopped by the wall-clock deadline; always 0 in lockstep),
/// `end_to_end_latency_ms` (median and p95 of the round-trip delays measured from plant stamps:
/// command applied minus the time of the sample it came from), and `tracking_rmse_m` (RMS over
/// cycles of the distance between the plant's position and the scenario's goal, the reference
/// of the tracking term of the cost).
pub fn add_cycle_metrics(entry: &mut serde_json::Value, rows: &[CycleRow], goal_m: &[f64; 3]) {
    use mpc::record::percentile;
    let deadline_misses = rows.iter().filter(|r| r.status == "deadline").count();
    // Row k knows the delay of command k-1; row 0 knows none.
    let mut latency_ms: Vec<f64> = rows.iter().skip(1).map(|r| r.known_delay_s * 1e3).collect();
    let latency = if latency_ms.is_empty() {
        serde_json::Value::Null
    } else {
        serde_json::json!({
            "median": percentile(&mut latency_ms, 50.0),
            "p95": percentile(&mut latency_ms, 95.0),
        })
    };
    let tracking = (!rows.is_empty()).then(|| {
        let sum: f64 =
            rows.iter().map(|r| (0..3).map(|k| (r.state[k] - goal_m[k]).powi(2)).sum::<f64>()).sum();
        (sum / rows.len() as f64).sqrt()
    });
    entry["deadline_misses"] = serde_json::json!(deadline_misses);
    entry["end_to_end_latency_ms"] = latency;
    entry["tracking_rmse_m"] = serde_json::json!(tracking);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cycle_metrics_are_computed_from_the_rows() {
        let row = |k: u64, delay_s: f64, px: f64, status: &str| CycleRow {
            cycle: k,
            t_s: k as f64 * 0.1,
            state: [px, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            command: [9.81, 0.0, 0.0],
            command_seq: k + 1,
            known_delay_s: delay_s,
            injected_delay_s: Some(delay_s),
            weights: vec![1.0],
            status: status.to_string(),
            iterations: 3,
            solve_ms: 0.1,
            cost: 1.0,
            constraint_violation: 0.0,
            predicted_clearance_m: 1.0,
            decision: "panoc".to_string(),
            reason: "panoc".to_string(),
            cost_gap: None,
        };
        // Positions 3 and 4 m from a goal at the origin (z on target): RMS = sqrt((9 + 16) / 2).
        let rows = vec![row(0, 0.0, 3.0, "converged"), row(1, 0.2, 4.0, "deadline")];
        let mut entry = serde_json::json!({});
        add_cycle_metrics(&mut entry, &rows, &[0.0, 0.0, 1.0]);
        assert_eq!(entry["deadline_misses"], 1);
        assert_eq!(entry["end_to_end_latency_ms"]["median"], 200.0);
        let rmse = entry["tracking_rmse_m"].as_f64().expect("a number");
        assert!((rmse - 12.5f64.sqrt()).abs() < 1e-12, "{rmse}");
    }
}
