//! The per-cycle log of a run as CSV, one row per control cycle, the same columns whether the
//! run went over gRPC (built from telemetry) or in process (built from the closed loop's
//! records), so that the two can be compared line by line (only `solve_ms`, a wall-clock time,
//! differs).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use hilbench_proto::convert::controller::decision_from_pb;
use hilbench_proto::pb;
use mpc::closed_loop::CycleRecord;

/// One control cycle.
#[derive(Debug, Clone, PartialEq)]
pub struct CycleRow {
    pub cycle: u64,
    /// Plant time of the sample the controller solved from, s.
    pub t_s: f64,
    pub state: [f64; 8],
    pub command: [f64; 3],
    /// The round-trip delay the controller knew at this cycle (that of the previous command,
    /// measured from plant stamps), s; 0 before the first measurement.
    pub known_delay_s: f64,
    pub weights: Vec<f64>,
    pub status: String,
    pub iterations: u64,
    pub solve_ms: f64,
    pub cost: f64,
    pub constraint_violation: f64,
    pub predicted_clearance_m: f64,
    /// What the safety layer sent: `panoc`, `qp`, `shifted_plan`, `brake` (empty when the
    /// layer is off).
    pub decision: String,
    /// QP cost minus PANOC cost on the nonlinear model, when the cross-check ran.
    pub cost_gap: Option<f64>,
}

/// Rows of an in-process run.
pub fn from_records(records: &[CycleRecord]) -> Vec<CycleRow> {
    records
        .iter()
        .enumerate()
        .map(|(k, r)| CycleRow {
            cycle: r.cycle,
            t_s: r.t_s,
            state: r.state,
            command: r.command,
            known_delay_s: if k == 0 { 0.0 } else { records[k - 1].delay_s },
            weights: r.weights_used.clone(),
            status: r.report.status.name().to_string(),
            iterations: r.report.iterations as u64,
            solve_ms: r.report.solve_time.as_secs_f64() * 1e3,
            cost: r.report.cost,
            constraint_violation: r.report.constraint_violation,
            predicted_clearance_m: r.report.min_clearance_m,
            decision: r.selection.map_or(String::new(), |s| s.decision.name().to_string()),
            cost_gap: r.selection.and_then(|s| s.cost_gap),
        })
        .collect()
}

fn status_name(code: i32) -> &'static str {
    match pb::SolveStatus::try_from(code) {
        Ok(pb::SolveStatus::Converged) => "converged",
        Ok(pb::SolveStatus::IterationLimit) => "iteration_limit",
        Ok(pb::SolveStatus::Deadline) => "deadline",
        Ok(pb::SolveStatus::NumericalFailure) => "numerical_failure",
        _ => "unspecified",
    }
}

/// Rows of a gRPC run.
pub fn from_telemetry(telemetry: &[pb::CycleTelemetry]) -> Vec<CycleRow> {
    telemetry
        .iter()
        .map(|t| {
            let sample = t.sample.as_ref();
            let mut state = [f64::NAN; 8];
            if let Some(x) = sample.and_then(|s| s.state.as_ref()) {
                for (dst, src) in state.iter_mut().zip(&x.x) {
                    *dst = *src;
                }
            }
            let command =
                t.command.as_ref().map_or([f64::NAN; 3], |c| [c.thrust_mps2, c.roll_rad, c.pitch_rad]);
            let solve = t.solve.unwrap_or_default();
            CycleRow {
                cycle: t.cycle,
                t_s: sample.map_or(f64::NAN, |s| mav::ns_to_s(s.time_ns)),
                state,
                command,
                known_delay_s: t.measured_delay_s,
                weights: t.scenario_weights.clone(),
                status: status_name(solve.status).to_string(),
                iterations: u64::from(solve.iterations),
                solve_ms: solve.solve_ms,
                cost: solve.cost,
                constraint_violation: solve.constraint_violation,
                predicted_clearance_m: if solve.min_clearance_m == f64::MAX {
                    f64::INFINITY
                } else {
                    solve.min_clearance_m
                },
                decision: if t.decision_reason.is_empty() {
                    String::new()
                } else {
                    decision_from_pb(t.solver).map_or("unspecified", |d| d.name()).to_string()
                },
                cost_gap: t.cost_gap,
            }
        })
        .collect()
}

/// The CSV text of `rows` (header first; numbers in Rust's shortest round-trip form).
pub fn to_csv(rows: &[CycleRow]) -> String {
    let m = rows.first().map_or(0, |r| r.weights.len());
    let mut out = String::from(
        "cycle,t_s,px_m,py_m,pz_m,vx_mps,vy_mps,vz_mps,roll_rad,pitch_rad,thrust_cmd_mps2,roll_cmd_rad,pitch_cmd_rad,known_delay_s",
    );
    for i in 0..m {
        let _ = write!(out, ",w{i}");
    }
    out.push_str(
        ",status,iterations,solve_ms,cost,constraint_violation,predicted_clearance_m,decision,cost_gap\n",
    );
    for r in rows {
        let _ = write!(out, "{},{}", r.cycle, r.t_s);
        for v in r.state.iter().chain(&r.command) {
            let _ = write!(out, ",{v}");
        }
        let _ = write!(out, ",{}", r.known_delay_s);
        for i in 0..m {
            let _ = write!(out, ",{}", r.weights.get(i).copied().unwrap_or(f64::NAN));
        }
        let _ = writeln!(
            out,
            ",{},{},{},{},{},{},{},{}",
            r.status,
            r.iterations,
            r.solve_ms,
            r.cost,
            r.constraint_violation,
            r.predicted_clearance_m,
            r.decision,
            r.cost_gap.map_or(String::new(), |g| g.to_string())
        );
    }
    out
}

/// Writes `dir/<scenario>-<controller>.csv`; returns its path.
pub fn write(dir: &Path, scenario: &str, controller: &str, rows: &[CycleRow]) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join(format!("{scenario}-{controller}.csv"));
    std::fs::write(&path, to_csv(rows)).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(path)
}
