//! The per-cycle log of a run as CSV, one row per control cycle, built from the run's
//! `mpc::CycleRecord`s whether it went over gRPC (telemetry decoded by `proto`) or in process,
//! so that the two can be compared line by line (only `solve_ms`, a wall-clock time, differs).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::run::CycleRow;
use anyhow::Context;

/// Writes the per-cycle CSV log of every run of `batch` into `dir`.
pub fn write_batch(dir: &Path, batch: &crate::run::Batch) -> anyhow::Result<Vec<PathBuf>> {
    batch.runs.iter().map(|r| write(dir, &r.summary.scenario, &r.summary.controller, &r.rows)).collect()
}

/// The CSV text of `rows` (header first; numbers in Rust's shortest round-trip form).
pub fn to_csv(rows: &[CycleRow]) -> String {
    let m = rows.first().map_or(0, |r| r.weights.len());
    let mut out = String::from(
        "cycle,t_s,px_m,py_m,pz_m,vx_mps,vy_mps,vz_mps,roll_rad,pitch_rad,thrust_cmd_mps2,roll_cmd_rad,pitch_cmd_rad,known_delay_s,injected_delay_s",
    );
    for i in 0..m {
        let _ = write!(out, ",w{i}");
    }
    out.push_str(
        ",status,iterations,solve_ms,cost,constraint_violation,predicted_clearance_m,decision,cost_gap,reason\n",
    );
    for r in rows {
        let _ = write!(out, "{},{}", r.cycle, r.t_s);
        for v in r.state.iter().chain(&r.command) {
            let _ = write!(out, ",{v}");
        }
        let _ = write!(out, ",{}", r.known_delay_s);
        let _ = write!(out, ",{}", r.injected_delay_s.map_or(String::new(), |d| d.to_string()));
        for i in 0..m {
            let _ = write!(out, ",{}", r.weights.get(i).copied().unwrap_or(f64::NAN));
        }
        let _ = writeln!(
            out,
            ",{},{},{},{},{},{},{},{},{}",
            r.status,
            r.iterations,
            r.solve_ms,
            r.cost,
            r.constraint_violation,
            r.predicted_clearance_m,
            r.decision,
            r.cost_gap.map_or(String::new(), |g| g.to_string()),
            csv_field(&r.reason)
        );
    }
    out
}

/// `text` as one CSV field: quoted (quotes doubled) when it holds a comma, a quote or a line
/// break (RFC 4180).
fn csv_field(text: &str) -> std::borrow::Cow<'_, str> {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\"")).into()
    } else {
        text.into()
    }
}

/// Writes `dir/<scenario>-<controller>.csv`; returns its path.
pub fn write(dir: &Path, scenario: &str, controller: &str, rows: &[CycleRow]) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join(format!("{scenario}-{controller}.csv"));
    std::fs::write(&path, to_csv(rows)).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reason_is_the_last_column_and_quoted_when_it_holds_a_comma_or_a_quote() {
        let row = |reason: &str| CycleRow {
            cycle: 7,
            t_s: 0.35,
            state: [0.0; 8],
            command: [9.81, 0.0, 0.0],
            command_seq: 8,
            known_delay_s: 0.0,
            injected_delay_s: None,
            weights: vec![1.0],
            status: "iteration_limit".to_string(),
            iterations: 200,
            solve_ms: 1.0,
            cost: 2.0,
            constraint_violation: 0.0,
            predicted_clearance_m: -0.1,
            decision: "best_effort".to_string(),
            reason: reason.to_string(),
            cost_gap: None,
        };
        let plain = "panoc best effort (panoc: clearance -0.100 m; qp: status infeasible)";
        let csv = to_csv(&[row(plain), row("odd, \"quoted\"")]);
        let lines: Vec<&str> = csv.lines().collect();
        assert!(lines[0].ends_with(",decision,cost_gap,reason"), "{}", lines[0]);
        assert!(lines[1].ends_with(&format!(",best_effort,,{plain}")), "{}", lines[1]);
        assert!(lines[2].ends_with(",best_effort,,\"odd, \"\"quoted\"\"\""), "{}", lines[2]);
    }
}
