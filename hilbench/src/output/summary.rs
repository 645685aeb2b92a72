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

/// `summary.json`: the file's keys are these fields' names (written through a
/// `serde_json::Value`, so in sorted order as the file always has been).
#[derive(Debug, serde::Serialize)]
pub struct SummaryFile<'a> {
    pub runs: Vec<RunEntry<'a>>,
    pub verdicts: Vec<String>,
    pub transport: &'static str,
    pub time_mode: &'static str,
    pub wall_time_s: f64,
    pub timing: BatchTiming<'a>,
    pub error: Option<&'a crate::run::RunError>,
    pub interrupted: bool,
    pub hilbench_version: &'static str,
    pub hilbench_commit: &'static str,
}

/// One run of `summary.json`: its summary, the metrics of its cycles, its faults and what it
/// flew with.
#[derive(Debug, serde::Serialize)]
pub struct RunEntry<'a> {
    #[serde(flatten)]
    pub summary: RunSummaryEntry<'a>,
    #[serde(flatten)]
    pub cycles: CycleMetrics,
    #[serde(flatten)]
    pub faults: crate::run::RunFaults,
    pub delay_profile: &'a crate::run::DelayProfileInForce,
    pub plant: &'a str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub external_controller: Option<&'a crate::run::ExternalFacts>,
    /// The run's own error: the batch's, or "interrupted (Ctrl-C)" for a run cut short.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<&'a str>,
}

/// A run's [`RunSummary`] as `summary.json` names it (docs/output.md).
#[derive(Debug, serde::Serialize)]
pub struct RunSummaryEntry<'a> {
    pub scenario: &'a str,
    pub controller: &'a str,
    pub reached: bool,
    pub collided: bool,
    pub end_reason: mpc::RunEnd,
    pub time_to_goal_s: Option<f64>,
    pub path_length_m: f64,
    pub min_clearance_m: f64,
    pub cycles: u64,
    pub solve_ms: SolveMs,
    pub iterations_median: f64,
    pub iteration_limits: u64,
    pub infeasible_at_limit: u64,
    pub fallbacks: u64,
    pub decisions: &'a std::collections::BTreeMap<String, u64>,
    pub best_effort_cycles: u64,
    pub commands_lost: Option<u64>,
    pub explanation: &'a [String],
    pub cost_gap: &'a mpc::record::GapSummary,
    pub collisions: &'a [mpc::record::CollisionSummary],
    pub final_position_m: [f64; 3],
}

/// Solve times of a run, ms.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct SolveMs {
    pub mean: f64,
    pub median: f64,
    pub p95: f64,
    pub max: f64,
}

/// The keys computed from a run's per-cycle log.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CycleMetrics {
    /// Solves stopped by the wall-clock deadline (always 0 in lockstep).
    pub deadline_misses: usize,
    /// Median and p95 of the round-trip delays measured from plant stamps (command applied
    /// minus the time of the sample it came from); `None` without a second cycle.
    pub end_to_end_latency_ms: Option<Latency>,
    /// RMS over cycles of the distance between the plant's position and the scenario's goal,
    /// the reference of the cost's tracking term; `None` without a cycle.
    pub tracking_rmse_m: Option<f64>,
}

/// A latency's median and p95, ms.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Latency {
    pub median: f64,
    pub p95: f64,
}

/// Where the batch's wall time went.
#[derive(Debug, serde::Serialize)]
pub struct BatchTiming<'a> {
    pub wall_time_s: f64,
    pub solver_s: f64,
    pub setup_s: f64,
    pub loop_overhead_s: f64,
    pub teardown_s: f64,
    pub runs: Vec<TimedRun<'a>>,
    pub plotting_s: Option<f64>,
    pub mcap_s: Option<f64>,
}

/// Where one run's wall time went.
#[derive(Debug, serde::Serialize)]
pub struct TimedRun<'a> {
    pub scenario: &'a str,
    pub controller: &'a str,
    #[serde(flatten)]
    pub timing: crate::run::RunTiming,
    pub loop_overhead_s: f64,
}

/// `summary.json` of `batch`.
pub fn summary_json(batch: &Batch, times: OutputTimes) -> SummaryFile<'_> {
    let timings = || batch.runs.iter().filter_map(|r| r.timing);
    let timing = BatchTiming {
        wall_time_s: batch.wall_time_s,
        solver_s: batch.solver_s(),
        setup_s: total(timings().map(|t| t.setup_s)),
        loop_overhead_s: total(timings().map(|t| t.loop_overhead_s())),
        teardown_s: total(timings().map(|t| t.teardown_s)),
        runs: batch
            .runs
            .iter()
            .filter_map(|r| {
                let timing = r.timing?;
                Some(TimedRun {
                    scenario: &r.job.scenario.name,
                    controller: r.controller(),
                    timing,
                    loop_overhead_s: timing.loop_overhead_s(),
                })
            })
            .collect(),
        plotting_s: times.plotting_s,
        mcap_s: times.mcap_s,
    };
    let summaries: Vec<RunSummary> = batch.runs.iter().map(|r| r.summary.clone()).collect();
    SummaryFile {
        runs: batch
            .runs
            .iter()
            .map(|r| RunEntry {
                summary: run_entry(&r.summary),
                cycles: cycle_metrics(&r.rows, &r.job.scenario.goal_m),
                faults: r.faults,
                delay_profile: &r.delay_profile,
                plant: &r.plant,
                external_controller: r.external.as_ref(),
                error: r.error.as_deref(),
            })
            .collect(),
        verdicts: super::paper::verdicts(&summaries),
        transport: batch.driver,
        time_mode: batch.time_mode.name(),
        wall_time_s: batch.wall_time_s,
        timing,
        error: batch.error.as_ref(),
        interrupted: batch.interrupted,
        hilbench_version: env!("CARGO_PKG_VERSION"),
        hilbench_commit: env!("HILBENCH_COMMIT"),
    }
}

/// Writes `summary` as `dir/summary.json` (creating `dir`); returns the file's path. Through a
/// `serde_json::Value`: its keys sorted, a non-finite number `null`.
pub fn write(dir: &Path, summary: &SummaryFile<'_>) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join("summary.json");
    let value = serde_json::to_value(summary)?;
    std::fs::write(&path, serde_json::to_string_pretty(&value)?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(path)
}

/// One run's summary as `summary.json` names it (names are stable; see docs/output.md).
pub fn run_entry(r: &RunSummary) -> RunSummaryEntry<'_> {
    RunSummaryEntry {
        scenario: &r.scenario,
        controller: &r.controller,
        reached: r.reached,
        collided: r.collided,
        end_reason: r.end_reason,
        time_to_goal_s: r.time_to_goal_s,
        path_length_m: r.path_length_m,
        min_clearance_m: r.min_clearance_m,
        cycles: r.cycles,
        solve_ms: SolveMs {
            mean: r.solve_ms_mean,
            median: r.solve_ms_median,
            p95: r.solve_ms_p95,
            max: r.solve_ms_max,
        },
        iterations_median: r.iterations_median,
        iteration_limits: r.iteration_limits,
        infeasible_at_limit: r.infeasible_at_limit,
        fallbacks: r.fallbacks,
        decisions: &r.decisions,
        best_effort_cycles: r.best_effort_cycles,
        commands_lost: r.commands_lost,
        explanation: &r.explanation,
        cost_gap: &r.cost_gap,
        collisions: &r.collisions,
        final_position_m: r.final_position_m,
    }
}

/// The metrics of a run's per-cycle log ([`CycleMetrics`]).
pub fn cycle_metrics(rows: &[CycleRow], goal_m: &[f64; 3]) -> CycleMetrics {
    use mpc::record::percentile;
    let deadline_misses = rows.iter().filter(|r| r.status == "deadline").count();
    // Row k knows the delay of command k-1; row 0 knows none.
    let mut latency_ms: Vec<f64> = rows.iter().skip(1).map(|r| r.known_delay_s * 1e3).collect();
    let end_to_end_latency_ms = (!latency_ms.is_empty()).then(|| Latency {
        median: percentile(&mut latency_ms, 50.0),
        p95: percentile(&mut latency_ms, 95.0),
    });
    let tracking_rmse_m = (!rows.is_empty()).then(|| {
        let sum: f64 =
            rows.iter().map(|r| (0..3).map(|k| (r.state[k] - goal_m[k]).powi(2)).sum::<f64>()).sum();
        (sum / rows.len() as f64).sqrt()
    });
    CycleMetrics { deadline_misses, end_to_end_latency_ms, tracking_rmse_m }
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
        let metrics = cycle_metrics(&rows, &[0.0, 0.0, 1.0]);
        let entry = serde_json::to_value(metrics).expect("serialisable");
        assert_eq!(entry["deadline_misses"], 1);
        assert_eq!(entry["end_to_end_latency_ms"]["median"], 200.0);
        let rmse = entry["tracking_rmse_m"].as_f64().expect("a number");
        assert!((rmse - 12.5f64.sqrt()).abs() < 1e-12, "{rmse}");
    }
}
