//! `controller solve`: "what would the controller do from this logged state?" One JSON
//! problem per input line, one JSON answer per output line; a bad line gets an error line
//! naming the field, and the other lines are still solved.
//!
//! Input keys: `scenario` (e.g. `paper-1`), `x0` (8 numbers), `u_prev` (3), `weights` (M
//! numbers; M = 1 for `"mode": "nmpc"`, else the scenario's sampling times), optional
//! `warm_start` (N x 3), optional `mode` (`multistage` by default).
//! Output keys: `line`, `status`, `iterations`, `solve_ms`, `cost` (the spec's objective,
//! unscaled), `u` (N x 3), `min_clearance_m`, `constraint_violation`; or `line` and `error`
//! (with `field`).

use std::collections::HashMap;
use std::io::{BufRead, Write};

use mpc::{ControllerMode, Mpc, MpcSettings, OcpDefinition, SolveBudget};
use serde_json::{Value, json};

/// A request line that failed validation.
#[derive(Debug, Clone, PartialEq)]
pub struct LineError {
    pub field: String,
    pub reason: String,
}

fn err(field: impl Into<String>, reason: impl Into<String>) -> LineError {
    LineError { field: field.into(), reason: reason.into() }
}

fn numbers(v: &Value, field: &str, len: Option<usize>) -> Result<Vec<f64>, LineError> {
    let arr = v.as_array().ok_or_else(|| err(field, "must be an array of numbers"))?;
    if let Some(n) = len
        && arr.len() != n
    {
        return Err(err(field, format!("must hold exactly {n} numbers, got {}", arr.len())));
    }
    arr.iter()
        .enumerate()
        .map(|(i, x)| {
            x.as_f64()
                .filter(|f| f.is_finite())
                .ok_or_else(|| err(format!("{field}[{i}]"), "must be a finite number"))
        })
        .collect()
}

/// Solves JSON-lines problems, reusing one solver workspace per (scenario, mode).
pub struct LineSolver {
    settings: MpcSettings,
    workspaces: HashMap<(String, ControllerMode), Mpc>,
}

impl LineSolver {
    pub fn new(settings: MpcSettings) -> Self {
        Self { settings, workspaces: HashMap::new() }
    }

    /// Answers one line (never fails: errors become error objects).
    pub fn answer(&mut self, line_no: usize, line: &str) -> Value {
        match self.solve_line(line) {
            Ok(mut v) => {
                v["line"] = json!(line_no);
                v
            }
            Err(e) => {
                json!({ "line": line_no, "error": format!("invalid `{}`: {}", e.field, e.reason), "field": e.field })
            }
        }
    }

    fn solve_line(&mut self, line: &str) -> Result<Value, LineError> {
        let v: Value = serde_json::from_str(line).map_err(|e| err("<line>", format!("not JSON: {e}")))?;
        let obj = v.as_object().ok_or_else(|| err("<line>", "must be a JSON object"))?;
        let name = obj
            .get("scenario")
            .and_then(Value::as_str)
            .ok_or_else(|| err("scenario", "is required (a name such as paper-1)"))?;
        let scenario = mav::Scenario::by_name(name).map_err(|e| err("scenario", e.to_string()))?;
        let mode = match obj.get("mode") {
            None => ControllerMode::Multistage,
            Some(m) => m
                .as_str()
                .and_then(ControllerMode::parse)
                .ok_or_else(|| err("mode", "must be \"nmpc\" or \"multistage\""))?,
        };
        let x0 = numbers(obj.get("x0").ok_or_else(|| err("x0", "is required"))?, "x0", Some(8))?;
        let u_prev =
            numbers(obj.get("u_prev").ok_or_else(|| err("u_prev", "is required"))?, "u_prev", Some(3))?;
        let key = (name.to_string(), mode);
        if !self.workspaces.contains_key(&key) {
            let def = OcpDefinition::from_scenario(
                &scenario,
                mode,
                self.settings.obstacle_margin_m,
                self.settings.formulation,
            );
            let mpc = Mpc::new(def, self.settings).map_err(|e| err("<settings>", e.to_string()))?;
            self.workspaces.insert(key.clone(), mpc);
        }
        let Some(mpc) = self.workspaces.get_mut(&key) else {
            return Err(err("<internal>", "workspace missing"));
        };
        let m = mpc.definition().num_scenarios();
        let weights =
            numbers(obj.get("weights").ok_or_else(|| err("weights", "is required"))?, "weights", Some(m))?;
        let n = mpc.definition().horizon;
        match obj.get("warm_start") {
            Some(ws) => {
                let rows = ws
                    .as_array()
                    .ok_or_else(|| err("warm_start", format!("must be {n} rows of 3 numbers")))?;
                if rows.len() != n {
                    return Err(err("warm_start", format!("must hold {n} rows, got {}", rows.len())));
                }
                let mut flat = Vec::with_capacity(3 * n);
                for (j, r) in rows.iter().enumerate() {
                    flat.extend(numbers(r, &format!("warm_start[{j}]"), Some(3))?);
                }
                mpc.set_warm_start(&flat).map_err(|e| err("warm_start", e.to_string()))?;
            }
            None => mpc.reset_warm_start(),
        }
        let mut x = [0.0; 8];
        x.copy_from_slice(&x0);
        let mut up = [0.0; 3];
        up.copy_from_slice(&u_prev);
        let report = mpc.solve(&x, &up, &weights, &SolveBudget::default()).map_err(|e| match e {
            mpc::MpcError::InvalidInput { field, reason } => err(field, reason),
            other => err("<problem>", other.to_string()),
        })?;
        let u: Vec<[f64; 3]> = mpc.solution().chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        Ok(json!({
            "scenario": name,
            "mode": mode.name(),
            "status": report.status.name(),
            "iterations": report.iterations,
            "solve_ms": report.solve_time.as_secs_f64() * 1e3,
            "cost": report.cost,
            "u": u,
            "min_clearance_m": report.min_clearance_m,
            "constraint_violation": report.constraint_violation,
        }))
    }

    /// Reads lines from `input` and writes one JSON line per non-empty input line.
    pub fn run(&mut self, input: impl BufRead, mut output: impl Write) -> std::io::Result<usize> {
        let mut count = 0;
        for (i, line) in input.lines().enumerate() {
            let line = line?;
            if line.trim().is_empty() {
                continue;
            }
            let answer = self.answer(i + 1, &line);
            writeln!(output, "{answer}")?;
            count += 1;
        }
        output.flush()?;
        Ok(count)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn solve(lines: &str) -> Vec<Value> {
        let mut out = Vec::new();
        LineSolver::new(MpcSettings::default()).run(lines.as_bytes(), &mut out).expect("in-memory io");
        String::from_utf8(out)
            .expect("utf8")
            .lines()
            .map(|l| serde_json::from_str(l).expect("json"))
            .collect()
    }

    #[test]
    fn good_lines_are_solved_and_bad_ones_name_the_field() {
        let good = r#"{"scenario":"paper-2","x0":[3.2,0,0,0,0,0,0,0],"u_prev":[9.81,0,0],"weights":[0.05,0.15,0.45,0.3,0.05]}"#;
        let nan_x0 = r#"{"scenario":"paper-2","x0":[3.2,0,"x",0,0,0,0,0],"u_prev":[9.81,0,0],"weights":[0.05,0.15,0.45,0.3,0.05]}"#;
        let short_w =
            r#"{"scenario":"paper-2","x0":[3.2,0,0,0,0,0,0,0],"u_prev":[9.81,0,0],"weights":[1.0]}"#;
        let unknown =
            r#"{"scenario":"paper-9","x0":[3.2,0,0,0,0,0,0,0],"u_prev":[9.81,0,0],"weights":[1.0]}"#;
        let nmpc = r#"{"scenario":"paper-1","mode":"nmpc","x0":[0,0,0,0,0,0,0,0],"u_prev":[9.81,0,0],"weights":[1.0]}"#;
        let out = solve(&[good, nan_x0, "not json", short_w, unknown, nmpc].join("\n"));
        assert_eq!(out.len(), 6);
        assert_eq!(out[0]["u"].as_array().map(Vec::len), Some(40));
        assert!(out[0]["cost"].as_f64().is_some_and(|c| c > 0.0));
        assert!(out[0]["min_clearance_m"].as_f64().is_some_and(|c| c >= 0.0));
        assert_eq!(out[1]["field"], "x0[2]");
        assert_eq!(out[2]["field"], "<line>");
        assert_eq!(out[3]["field"], "weights");
        assert_eq!(out[4]["field"], "scenario");
        assert!(out[5]["status"].is_string());
        // Thrust of the first input climbs towards the goal above.
        assert!(out[5]["u"][0][0].as_f64().is_some_and(|t| t > 9.81));
    }
}
