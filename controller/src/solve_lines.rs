//! `controller solve`: "what would the controller do from this logged state?" One JSON
//! problem per input line, one JSON answer per output line; a bad line gets an error line
//! naming the field, and the other lines are still solved.
//!
//! Input keys: the problem, as `scenario` (a built-in name such as `paper-1`, or a whole
//! scenario inline: the keys of a scenario file's `[scenario]` table as a JSON object) or
//! `scenario_file` (the path of a scenario file, its `[run]` options applied); `x0` (8
//! numbers), `u_prev` (3), `weights` (M numbers; M = 1 for `"mode": "nmpc"`, else the
//! scenario's sampling times). Optional: `mode` (`multistage` by default), `warm_start` (N x 3
//! inputs), `multipliers` (the ALM multipliers to start from, as an answer's `multipliers`
//! gives them), `obstacle_margin_m` (0 allowed: the paper's exact problem), `floor_m` (a
//! number, or `null` for none), `delay_compensation` (bool), `max_iterations` (PANOC's
//! budget); what is not given comes from the scenario, then from the command's flags. `x0` must lie in the plant's reset envelope and
//! `u_prev` within the scenario's input bounds. Every line is solved on its own: from its
//! `warm_start` (or hover) and `multipliers` (or zeros) with a fresh penalty, so that an answer
//! does not depend on the lines before it.
//! Output keys: `line`, `scenario`, `mode`, `solver` (whose PANOC solved it: the scenario's
//! own, as a scenario file's `[run] solver` or its default gives it, else `--solver`), `status` (`infeasible_at_limit` when the budget ran
//! out with the plan predicted inside a cylinder), `iterations`, `solve_ms`, `cost` (the
//! spec's objective, unscaled), `u` (N x 3), `multipliers`, `min_clearance_m`, `depth_m` (how
//! deep the plan's deepest point is inside a cylinder, 0 when clear), `constraint_violation`,
//! and the problem solved: `obstacle_margin_m`, `floor_m`, `delay_compensation`, `coast_time_s`; or `line`, `error` and `field`. Unknown and repeated
//! keys are errors naming the key, and a line longer than [`MAX_LINE_BYTES`] is refused
//! without being held in memory.

use std::io::{BufRead, Write};

use hilbench_proto::convert::plant::check_state_envelope;
use hilbench_scenario_file::ScenarioFile;
use mav::Scenario;
use mpc::{ControllerMode, Mpc, MpcSettings, OcpDefinition, SolveBudget};
use serde_json::{Value, json};

/// Longest input line, bytes (a warm start of a 1000-step horizon takes about 60 kB).
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// The keys a problem line may hold.
const KEYS: [&str; 12] = [
    "scenario",
    "scenario_file",
    "mode",
    "x0",
    "u_prev",
    "weights",
    "warm_start",
    "multipliers",
    "obstacle_margin_m",
    "floor_m",
    "delay_compensation",
    "max_iterations",
];

/// Solver workspaces kept for the problems seen last (a line with another problem builds one).
const MAX_WORKSPACES: usize = 8;

/// Most PANOC iterations a line may ask for.
const MAX_ITERATIONS: u64 = 1_000_000;

/// A JSON object's entries in order, repeated keys kept (a `serde_json::Map` keeps only the
/// last of them, which would hide a mistake).
struct Entries(Vec<(String, Value)>);

impl<'de> serde::Deserialize<'de> for Entries {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visit;
        impl<'de> serde::de::Visitor<'de> for Visit {
            type Value = Entries;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a JSON object")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<Entries, A::Error> {
                let mut entries = Vec::new();
                while let Some(entry) = map.next_entry::<String, Value>()? {
                    entries.push(entry);
                }
                Ok(Entries(entries))
            }
        }
        d.deserialize_map(Visit)
    }
}

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

/// Solves JSON-lines problems, reusing a solver workspace per problem definition.
pub struct LineSolver {
    settings: MpcSettings,
    /// The workspaces of the last problems, the most recent last.
    workspaces: Vec<Mpc>,
}

/// A line's scenario: a built-in name, a whole scenario inline, or a scenario file.
fn scenario_of(obj: &serde_json::Map<String, Value>) -> Result<Scenario, LineError> {
    match (obj.get("scenario"), obj.get("scenario_file")) {
        (Some(_), Some(_)) => Err(err("scenario_file", "give either scenario or scenario_file, not both")),
        (None, None) => {
            Err(err("scenario", "is required (a name such as paper-1, a scenario object, or scenario_file)"))
        }
        (Some(Value::String(name)), None) => {
            Scenario::by_name(name).map_err(|e| err("scenario", e.to_string()))
        }
        (Some(v @ Value::Object(_)), None) => {
            let scenario: Scenario = serde_path_to_error::deserialize(v).map_err(|e| {
                let path = e.path().to_string();
                let field = if path == "." { "scenario".to_string() } else { format!("scenario.{path}") };
                err(field, e.into_inner().to_string())
            })?;
            scenario.validate().map_err(|e| match e {
                mav::ScenarioError::Invalid { field, reason } => err(format!("scenario.{field}"), reason),
                other => err("scenario", other.to_string()),
            })?;
            Ok(scenario)
        }
        (Some(_), None) => Err(err("scenario", "must be a scenario name or a scenario object")),
        (None, Some(path)) => {
            let path = path.as_str().ok_or_else(|| err("scenario_file", "must be a path"))?;
            let path = std::path::Path::new(path);
            ScenarioFile::load(path)
                .and_then(|f| f.nmpc_tuning(path).map(|()| f.scenario))
                .map_err(|e| err("scenario_file", e.to_string()))
        }
    }
}

/// The line's options over the scenario's: margin, floor, dead-time compensation.
fn apply_options(obj: &serde_json::Map<String, Value>, scenario: &mut Scenario) -> Result<(), LineError> {
    if let Some(v) = obj.get("obstacle_margin_m") {
        let m = v
            .as_f64()
            .filter(|m| m.is_finite() && (0.0..=10.0).contains(m))
            .ok_or_else(|| err("obstacle_margin_m", "must be a number in [0, 10] m"))?;
        scenario.obstacle_margin_m = Some(m);
    }
    if let Some(v) = obj.get("floor_m") {
        scenario.min_altitude_m = match v {
            Value::Null => None,
            v => Some(
                v.as_f64()
                    .filter(|z| z.is_finite() && z.abs() <= 1e4)
                    .ok_or_else(|| err("floor_m", "must be a number of m (|z| <= 1e4) or null"))?,
            ),
        };
    }
    if let Some(v) = obj.get("delay_compensation") {
        scenario.delay_compensation =
            v.as_bool().ok_or_else(|| err("delay_compensation", "must be true or false"))?;
    }
    Ok(())
}

impl LineSolver {
    pub fn new(settings: MpcSettings) -> Self {
        Self { settings, workspaces: Vec::new() }
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

    /// The workspace of `def` solved with `settings`, built when none of the kept ones does.
    fn workspace(&mut self, def: OcpDefinition, settings: MpcSettings) -> Result<&mut Mpc, LineError> {
        match self.workspaces.iter().position(|m| *m.definition() == def && *m.settings() == settings) {
            Some(i) => {
                let mpc = self.workspaces.remove(i);
                self.workspaces.push(mpc);
            }
            None => {
                let mpc = Mpc::new(def, settings).map_err(|e| err("<settings>", e.to_string()))?;
                if self.workspaces.len() == MAX_WORKSPACES {
                    self.workspaces.remove(0);
                }
                self.workspaces.push(mpc);
            }
        }
        self.workspaces.last_mut().ok_or_else(|| err("<internal>", "workspace missing"))
    }

    fn solve_line(&mut self, line: &str) -> Result<Value, LineError> {
        let Entries(entries) = serde_json::from_str(line).map_err(|e| {
            if e.is_data() {
                err("<line>", "must be a JSON object")
            } else {
                err("<line>", format!("not JSON: {e}"))
            }
        })?;
        let mut obj = serde_json::Map::new();
        for (key, value) in entries {
            if !KEYS.contains(&key.as_str()) {
                return Err(err(key, format!("unknown key (known: {})", KEYS.join(", "))));
            }
            if obj.contains_key(&key) {
                return Err(err(key, "is given twice"));
            }
            obj.insert(key, value);
        }
        let mut scenario = scenario_of(&obj)?;
        apply_options(&obj, &mut scenario)?;
        let mode = match obj.get("mode") {
            None => ControllerMode::Multistage,
            Some(m) => m
                .as_str()
                .and_then(ControllerMode::parse)
                .ok_or_else(|| err("mode", "must be \"nmpc\" or \"multistage\""))?,
        };
        let x0 = numbers(obj.get("x0").ok_or_else(|| err("x0", "is required"))?, "x0", Some(8))?;
        let mut x = [0.0; 8];
        x.copy_from_slice(&x0);
        check_state_envelope(|i| format!("x0[{i}]"), &x).map_err(|e| err(e.field, e.reason))?;
        // A start in a collision is no problem to solve (a plan cannot leave it, and the solver
        // would answer `iteration_limit` after no iterations): refused, as a scenario's start is.
        if x[2] < scenario.ground_z_m {
            return Err(err(
                "x0[2]",
                format!("is below the ground (z {} m < ground_z_m {} m)", x[2], scenario.ground_z_m),
            ));
        }
        if let (depth, Some(k)) = mav::geometry::min_clearance(&scenario.obstacles, x[0], x[1], x[2])
            && depth < 0.0
        {
            return Err(err(
                "x0",
                format!(
                    "is inside cylinder {k} of {} ({:.3} m deep): a start in a collision",
                    scenario.name, -depth
                ),
            ));
        }
        let u_prev =
            numbers(obj.get("u_prev").ok_or_else(|| err("u_prev", "is required"))?, "u_prev", Some(3))?;
        let budget = match obj.get("max_iterations") {
            None => SolveBudget::default(),
            Some(v) => {
                let n = v.as_u64().filter(|n| (1..=MAX_ITERATIONS).contains(n)).ok_or_else(|| {
                    err("max_iterations", format!("must be an integer in [1, {MAX_ITERATIONS}]"))
                })?;
                SolveBudget { max_inner_iterations: Some(n as usize), ..SolveBudget::default() }
            }
        };
        let mut def = OcpDefinition::from_scenario(
            &scenario,
            mode,
            self.settings.obstacle_margin_m,
            self.settings.formulation,
        );
        // With the fail-safe check (a scenario file's default) the controller's plans keep
        // their coast clear: the same problem here (the check's range before any delay is
        // measured, the plant's default watchdog).
        if let Some(coast_s) = scenario
            .fail_safe
            .then(|| mpc::BrakingCheck::for_scenario(&scenario).coast_for(def.formulation))
            .flatten()
        {
            def.coast_time_s = coast_s;
        }
        // Whose PANOC solves it, decided as the controller's episode decides it
        // (`mpc::episode`): the scenario's own (a scenario file's `[run] solver`, ours by
        // default), else the command's `--solver`.
        let settings =
            MpcSettings { solver: scenario.solver.unwrap_or(self.settings.solver), ..self.settings };
        let mpc = self.workspace(def, settings)?;
        let bounds = mpc.definition().bounds;
        if let Some(i) = (0..3).find(|&i| !(bounds.min[i]..=bounds.max[i]).contains(&u_prev[i])) {
            return Err(err(
                format!("u_prev[{i}]"),
                format!(
                    "must be within the input bounds [{}, {}], got {}",
                    bounds.min[i], bounds.max[i], u_prev[i]
                ),
            ));
        }
        let m = mpc.definition().num_scenarios();
        let weights =
            numbers(obj.get("weights").ok_or_else(|| err("weights", "is required"))?, "weights", Some(m))?;
        let n = mpc.definition().horizon;
        // Fresh multipliers and penalty (and hover when no warm start is given): the previous
        // line's solve must not shape this one.
        mpc.reset_warm_start();
        if let Some(ws) = obj.get("warm_start") {
            let rows =
                ws.as_array().ok_or_else(|| err("warm_start", format!("must be {n} rows of 3 numbers")))?;
            if rows.len() != n {
                return Err(err("warm_start", format!("must hold {n} rows, got {}", rows.len())));
            }
            let mut flat = Vec::with_capacity(3 * n);
            for (j, r) in rows.iter().enumerate() {
                flat.extend(numbers(r, &format!("warm_start[{j}]"), Some(3))?);
            }
            mpc.set_warm_start(&flat).map_err(|e| err("warm_start", e.to_string()))?;
        }
        if let Some(y) = obj.get("multipliers") {
            let y = numbers(y, "multipliers", None)?;
            mpc.set_warm_multipliers(&y).map_err(mpc_error)?;
        }
        let mut up = [0.0; 3];
        up.copy_from_slice(&u_prev);
        let report = mpc.solve(&x, &up, &weights, &budget).map_err(mpc_error)?;
        let u: Vec<[f64; 3]> = mpc.solution().chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        let def = mpc.definition();
        Ok(json!({
            "scenario": scenario.name,
            "mode": mode.name(),
            "solver": settings.solver.name(),
            "status": report.status.name(),
            "iterations": report.iterations,
            "solve_ms": report.solve_time.as_secs_f64() * 1e3,
            "cost": report.cost,
            "u": u,
            "multipliers": mpc.multipliers(),
            "min_clearance_m": report.min_clearance_m,
            "depth_m": report.depth_m(),
            "constraint_violation": report.constraint_violation,
            "obstacle_margin_m": def.obstacle_margin_m,
            "floor_m": def.min_altitude_m,
            "delay_compensation": def.delay_compensation,
            "coast_time_s": def.coast_time_s,
        }))
    }

    /// Reads lines from `input` and writes one JSON line per non-empty input line. A line that
    /// is not UTF-8 gets an error line like any other bad line; only an I/O error stops the run.
    pub fn run(&mut self, mut input: impl BufRead, mut output: impl Write) -> std::io::Result<usize> {
        let mut count = 0;
        let mut buf = Vec::new();
        let mut line_no = 0;
        loop {
            buf.clear();
            if std::io::Read::take(&mut input, MAX_LINE_BYTES as u64 + 1).read_until(b'\n', &mut buf)? == 0 {
                break;
            }
            line_no += 1;
            if buf.len() > MAX_LINE_BYTES && buf.last() != Some(&b'\n') {
                skip_line(&mut input)?;
                let answer = json!({
                    "line": line_no,
                    "error": format!("invalid `<line>`: longer than {MAX_LINE_BYTES} bytes"),
                    "field": "<line>",
                });
                writeln!(output, "{answer}")?;
                count += 1;
                continue;
            }
            let answer = match std::str::from_utf8(&buf) {
                Ok(line) if line.trim().is_empty() => continue,
                Ok(line) => self.answer(line_no, line.trim_end_matches(['\n', '\r'])),
                Err(e) => json!({
                    "line": line_no,
                    "error": format!("invalid `<line>`: not UTF-8 ({e})"),
                    "field": "<line>",
                }),
            };
            writeln!(output, "{answer}")?;
            count += 1;
        }
        output.flush()?;
        Ok(count)
    }
}

/// A solver's refusal as a line error naming the field.
fn mpc_error(e: mpc::MpcError) -> LineError {
    match e {
        mpc::MpcError::InvalidInput { field, reason } => err(field, reason),
        other => err("<problem>", other.to_string()),
    }
}

/// Reads and drops the rest of a line (to its newline or the end), a buffer at a time.
fn skip_line(input: &mut impl BufRead) -> std::io::Result<()> {
    loop {
        let chunk = input.fill_buf()?;
        if chunk.is_empty() {
            return Ok(());
        }
        match chunk.iter().position(|b| *b == b'\n') {
            Some(i) => {
                input.consume(i + 1);
                return Ok(());
            }
            None => {
                let n = chunk.len();
                input.consume(n);
            }
        }
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

    #[test]
    fn unknown_and_repeated_keys_and_overlong_lines_are_refused_and_the_next_line_is_solved() {
        let good = r#"{"scenario":"paper-2","x0":[3.2,0,0,0,0,0,0,0],"u_prev":[9.81,0,0],"weights":[0.05,0.15,0.45,0.3,0.05]}"#;
        let typo = good.replace("\"u_prev\"", "\"u_prv\"");
        let twice = good.replace("\"x0\":", "\"x0\":[0,0,0,0,0,0,0,0],\"x0\":");
        let long = format!("{{\"scenario\":\"{}\"}}", "x".repeat(MAX_LINE_BYTES + 10));
        let array = "[1, 2, 3]";
        let out = solve(&[typo.as_str(), twice.as_str(), long.as_str(), array, good].join("\n"));
        assert_eq!(out.len(), 5, "{out:?}");
        assert_eq!(out[0]["field"], "u_prv");
        assert_eq!(out[1]["field"], "x0");
        assert!(out[1]["error"].as_str().is_some_and(|e| e.contains("twice")), "{}", out[1]);
        assert_eq!((out[2]["field"].as_str(), out[2]["line"].as_u64()), (Some("<line>"), Some(3)));
        assert!(out[2]["error"].as_str().is_some_and(|e| e.contains("longer than")), "{}", out[2]);
        assert_eq!(out[3]["field"], "<line>");
        assert_eq!(out[4]["line"], 5);
        assert!(out[4]["status"].is_string(), "{}", out[4]);
    }

    #[test]
    fn a_scenario_file_without_solver_is_solved_by_ours_as_hilbench_run_flies_it_and_the_answer_names_it() {
        let file = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenarios/slalom-4.toml");
        let from_file = format!(
            r#"{{"scenario_file":"{file}","x0":[0,0,0.5,0,0,0,0,0],"u_prev":[9.81,0,0],"weights":[0.2,0.2,0.2,0.2,0.2]}}"#
        );
        let by_name = r#"{"scenario":"paper-2","x0":[3.2,0,0,0,0,0,0,0],"u_prev":[9.81,0,0],"weights":[0.05,0.15,0.45,0.3,0.05]}"#;
        let out = solve(&[from_file.as_str(), by_name].join("\n"));
        assert_eq!(out.len(), 2, "{out:?}");
        // The file names no solver: the file's default (ours), whatever `--solver` says.
        assert_eq!(out[0]["solver"], hilbench_scenario_file::FILE_SOLVER.name(), "{}", out[0]);
        assert!(out[0]["status"].is_string(), "{}", out[0]);
        // A built-in scenario keeps the command's `--solver` (OpEn's by default).
        assert_eq!(out[1]["solver"], MpcSettings::default().solver.name(), "{}", out[1]);
        let mut own = Vec::new();
        let settings = MpcSettings { solver: mpc::PanocSolver::Own, ..MpcSettings::default() };
        LineSolver::new(settings).run(by_name.as_bytes(), &mut own).expect("in-memory io");
        let own: Value = serde_json::from_slice(&own).expect("json");
        assert_eq!(own["solver"], "own", "{own}");
    }

    fn without_timing(mut v: Value) -> Value {
        if let Some(o) = v.as_object_mut() {
            o.remove("line");
            o.remove("solve_ms");
        }
        v
    }

    #[test]
    fn an_answer_does_not_depend_on_the_lines_before_it() {
        // A warm-started line after an unrelated solve of the same scenario (which leaves
        // multipliers and a raised penalty in the workspace) and after nothing at all.
        let ws: Vec<String> = (0..40).map(|_| "[11.0,0.05,0.0]".to_string()).collect();
        let probe = format!(
            r#"{{"scenario":"paper-2","x0":[3.1,1.0,0.5,0.1,0.8,0.2,0.0,0.0],"u_prev":[9.81,0,0],"weights":[0.0,0.01,0.05,0.6,0.34],"warm_start":[{}]}}"#,
            ws.join(",")
        );
        let other = r#"{"scenario":"paper-2","x0":[3.2,0,0,0,0,0,0,0],"u_prev":[9.81,0,0],"weights":[0.05,0.15,0.45,0.3,0.05]}"#;
        let alone = solve(&probe);
        let after = solve(&[other, &probe].join("\n"));
        assert_eq!(alone.len(), 1);
        assert_eq!(after.len(), 2);
        assert!(alone[0]["status"].is_string(), "{}", alone[0]);
        assert_eq!(without_timing(alone[0].clone()), without_timing(after[1].clone()));
    }

    #[test]
    fn out_of_range_states_and_inputs_and_non_utf8_lines_get_error_lines() {
        let good = r#"{"scenario":"paper-2","x0":[3.2,0,0,0,0,0,0,0],"u_prev":[9.81,0,0],"weights":[0.05,0.15,0.45,0.3,0.05]}"#;
        let tilted = good.replace("[3.2,0,0,0,0,0,0,0]", "[3.2,0,0,0,0,0,2.0,0]");
        let far = good.replace("[3.2,0,0,0,0,0,0,0]", "[3.2,0,0,0,0,5000,0,0]");
        let negative_thrust = good.replace("[9.81,0,0]", "[-1.0,0,0]");
        let steep_roll = good.replace("[9.81,0,0]", "[9.81,0.5,0]");
        let mut input = Vec::new();
        for line in [tilted.as_str(), far.as_str(), negative_thrust.as_str(), steep_roll.as_str()] {
            input.extend_from_slice(line.as_bytes());
            input.push(b'\n');
        }
        input.extend_from_slice(b"{\"scenario\":\"paper-2\xff\"}\n");
        input.extend_from_slice(good.as_bytes());
        let mut out = Vec::new();
        let count =
            LineSolver::new(MpcSettings::default()).run(input.as_slice(), &mut out).expect("in-memory io");
        assert_eq!(count, 6);
        let out: Vec<Value> = String::from_utf8(out)
            .expect("utf8")
            .lines()
            .map(|l| serde_json::from_str(l).expect("json"))
            .collect();
        assert_eq!(out[0]["field"], "x0[6]");
        assert_eq!(out[1]["field"], "x0[5]");
        assert_eq!(out[2]["field"], "u_prev[0]");
        assert_eq!(out[3]["field"], "u_prev[1]");
        assert_eq!(out[4]["field"], "<line>");
        assert_eq!(out[4]["line"], 5);
        assert!(out[5]["status"].is_string(), "{}", out[5]);
        assert_eq!(out[5]["line"], 6);
    }

    #[test]
    fn a_start_inside_a_cylinder_or_below_the_ground_gets_an_error_line_naming_x0() {
        let good = r#"{"scenario":"paper-2","x0":[3.2,0,0,0,0,0,0,0],"u_prev":[9.81,0,0],"weights":[0.05,0.15,0.45,0.3,0.05]}"#;
        // paper-2's first cylinder: axis (3.5, 1.5), radius 0.25.
        let inside = good.replace("[3.2,0,0,0,0,0,0,0]", "[3.5,1.4,1.0,0,0,0,0,0]");
        let below = good.replace("[3.2,0,0,0,0,0,0,0]", "[3.2,0,-0.5,0,0,0,0,0]");
        let input = format!("{inside}\n{below}\n");
        let mut out = Vec::new();
        LineSolver::new(MpcSettings::default()).run(input.as_bytes(), &mut out).expect("in-memory io");
        let out: Vec<Value> = String::from_utf8(out)
            .expect("utf8")
            .lines()
            .map(|l| serde_json::from_str(l).expect("json"))
            .collect();
        assert_eq!(out[0]["field"], "x0", "{}", out[0]);
        let e = out[0]["error"].as_str().expect("an error");
        assert!(e.contains("inside cylinder 0 of paper-2 (0.150 m deep)"), "{e}");
        assert_eq!(out[1]["field"], "x0[2]", "{}", out[1]);
        assert!(out[1]["error"].as_str().is_some_and(|e| e.contains("below the ground")), "{}", out[1]);
    }
}

#[cfg(test)]
mod whole_problem_tests {
    use super::*;

    const PAPER_2: &str =
        r#""x0":[3.2,0.5,1.0,0,0.5,0,0,0],"u_prev":[9.81,0,0],"weights":[0.05,0.15,0.45,0.3,0.05]"#;

    fn solve(lines: &[String]) -> Vec<Value> {
        let mut out = Vec::new();
        LineSolver::new(MpcSettings::default())
            .run(lines.join("\n").as_bytes(), &mut out)
            .expect("in-memory io");
        String::from_utf8(out)
            .expect("utf8")
            .lines()
            .map(|l| serde_json::from_str(l).expect("json"))
            .collect()
    }

    /// The answer without what may differ between equal problems: the line, the wall time and
    /// the scenario's name.
    fn problem_answer(mut v: Value) -> Value {
        if let Some(o) = v.as_object_mut() {
            for key in ["line", "solve_ms", "scenario"] {
                o.remove(key);
            }
        }
        v
    }

    #[test]
    fn a_scenario_inline_or_from_its_file_is_solved_as_the_same_built_in() {
        let mut inline = serde_json::to_value(Scenario::paper_2()).expect("a scenario serialises");
        inline["name"] = json!("my-copy");
        let file = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenarios/paper-2.toml");
        let out = solve(&[
            format!(r#"{{"scenario":"paper-2",{PAPER_2}}}"#),
            format!(r#"{{"scenario":{inline},{PAPER_2}}}"#),
            format!(r#"{{"scenario_file":{file:?},{PAPER_2}}}"#),
        ]);
        assert!(out[0]["status"].is_string(), "{}", out[0]);
        assert_eq!(out[1]["scenario"], "my-copy");
        assert_eq!(problem_answer(out[1].clone()), problem_answer(out[0].clone()));
        assert_eq!(problem_answer(out[2].clone()), problem_answer(out[0].clone()));
    }

    #[test]
    fn a_scenario_file_with_the_fail_safe_check_is_solved_with_the_plans_coast() {
        let file = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenarios/fields/paper-2-field.toml");
        let out = solve(&[
            format!(r#"{{"scenario_file":{file:?},{PAPER_2}}}"#),
            format!(r#"{{"scenario":"paper-2",{PAPER_2}}}"#),
        ]);
        // Twice the tree's longest sampling time (0.33 s) plus the check's 0.3 s.
        let coast = out[0]["coast_time_s"].as_f64().expect("a number");
        assert!((coast - 0.96).abs() < 1e-9, "{}", out[0]);
        assert_eq!(out[1]["coast_time_s"], 0.0, "paper mode has no check: {}", out[1]);
    }

    #[test]
    fn margin_floor_compensation_and_budget_change_the_problem_solved() {
        let out = solve(&[
            format!(r#"{{"scenario":"paper-2",{PAPER_2}}}"#),
            format!(
                r#"{{"scenario":"paper-2","obstacle_margin_m":0,"floor_m":0.5,"delay_compensation":true,"max_iterations":3,{PAPER_2}}}"#
            ),
            format!(r#"{{"scenario":"paper-2","floor_m":null,{PAPER_2}}}"#),
        ]);
        assert_eq!(out[0]["obstacle_margin_m"], 0.1, "paper mode's margin: {}", out[0]);
        assert_eq!(out[0]["floor_m"], Value::Null);
        assert_eq!(out[0]["delay_compensation"], false);
        assert_eq!(out[1]["obstacle_margin_m"], 0.0);
        assert_eq!(out[1]["floor_m"], 0.5);
        assert_eq!(out[1]["delay_compensation"], true);
        assert!(out[1]["iterations"].as_u64().is_some_and(|i| i <= 3), "{}", out[1]);
        assert_eq!(problem_answer(out[2].clone()), problem_answer(out[0].clone()));
        // The floor adds a constraint per predicted point: more multipliers.
        let count = |v: &Value| v["multipliers"].as_array().map_or(0, Vec::len);
        assert!(count(&out[1]) > count(&out[0]), "{} vs {}", count(&out[1]), count(&out[0]));
    }

    #[test]
    fn an_answer_at_the_limit_with_its_plan_inside_a_cylinder_says_so_with_the_depth() {
        // paper-1's start, the paper's exact problem (no margin), two iterations: the long
        // scenarios' plans still cross the cylinder.
        let start = r#""x0":[0,0,0,0,0,0,0,0],"u_prev":[9.81,0,0],"weights":[0.05,0.15,0.45,0.3,0.05]"#;
        let out = solve(&[
            format!(r#"{{"scenario":"paper-1","obstacle_margin_m":0,"max_iterations":2,{start}}}"#),
            format!(r#"{{"scenario":"paper-2",{PAPER_2}}}"#),
        ]);
        assert_eq!(out[0]["status"], "infeasible_at_limit", "{}", out[0]);
        let depth = out[0]["depth_m"].as_f64().expect("a number");
        let clearance = out[0]["min_clearance_m"].as_f64().expect("a number");
        assert!(depth > 0.0 && depth == -clearance, "{}", out[0]);
        assert!(out[1]["status"].is_string(), "{}", out[1]);
        assert_ne!(out[1]["status"], "infeasible_at_limit", "{}", out[1]);
        assert_eq!(out[1]["depth_m"], 0.0, "{}", out[1]);
    }

    #[test]
    fn given_multipliers_start_the_solve_and_the_answer_depends_on_nothing_else() {
        let first = solve(&[format!(r#"{{"scenario":"paper-2",{PAPER_2}}}"#)]);
        let y = &first[0]["multipliers"];
        assert!(y.as_array().is_some_and(|y| !y.is_empty()), "{}", first[0]);
        let warm = format!(r#"{{"scenario":"paper-2","multipliers":{y},{PAPER_2}}}"#);
        let alone = solve(std::slice::from_ref(&warm));
        let after = solve(&[format!(r#"{{"scenario":"paper-2",{PAPER_2}}}"#), warm.clone()]);
        assert!(alone[0]["status"].is_string(), "{}", alone[0]);
        assert_eq!(problem_answer(alone[0].clone()), problem_answer(after[1].clone()));
    }

    #[test]
    fn bad_problem_keys_are_refused_naming_the_field() {
        let mut typo = serde_json::to_value(Scenario::paper_2()).expect("a scenario serialises");
        typo["name"] = json!("typo");
        typo["obstacles"][1]["radus_m"] = json!(0.3);
        let mut negative = serde_json::to_value(Scenario::paper_2()).expect("a scenario serialises");
        negative["name"] = json!("negative");
        negative["horizon"] = json!(0);
        let cases = [
            (format!(r#"{{"scenario":{typo},{PAPER_2}}}"#), "scenario.obstacles[1].radus_m"),
            (format!(r#"{{"scenario":{negative},{PAPER_2}}}"#), "scenario.horizon"),
            (format!(r#"{{"scenario":"paper-2","scenario_file":"x.toml",{PAPER_2}}}"#), "scenario_file"),
            (format!(r#"{{"scenario_file":"/no/such/file.toml",{PAPER_2}}}"#), "scenario_file"),
            (format!(r#"{{"scenario":"paper-2","obstacle_margin_m":-0.1,{PAPER_2}}}"#), "obstacle_margin_m"),
            (format!(r#"{{"scenario":"paper-2","floor_m":"low",{PAPER_2}}}"#), "floor_m"),
            (format!(r#"{{"scenario":"paper-2","delay_compensation":1,{PAPER_2}}}"#), "delay_compensation"),
            (format!(r#"{{"scenario":"paper-2","max_iterations":0,{PAPER_2}}}"#), "max_iterations"),
            (format!(r#"{{"scenario":"paper-2","multipliers":[1,2],{PAPER_2}}}"#), "multipliers"),
        ];
        let lines: Vec<String> = cases.iter().map(|(l, _)| l.clone()).collect();
        let out = solve(&lines);
        for ((_, field), answer) in cases.iter().zip(&out) {
            assert_eq!(answer["field"], *field, "{answer}");
        }
        let first = solve(&[format!(r#"{{"scenario":"paper-2",{PAPER_2}}}"#)]);
        let mut y: Vec<f64> = serde_json::from_value(first[0]["multipliers"].clone()).expect("numbers");
        y[3] = -1.0;
        let out = solve(&[format!(r#"{{"scenario":"paper-2","multipliers":{y:?},{PAPER_2}}}"#)]);
        assert_eq!(out[0]["field"], "multipliers[3]", "{}", out[0]);
    }
}
