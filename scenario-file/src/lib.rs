//! Scenario files: one TOML file holds everything of a run of `hilbench run`, and what
//! `plant --scenario FILE` and `controller --scenario FILE` load (the same loader, so a file
//! means the same to every program).
//!
//! ```toml
//! [run]                         # optional; what hilbench does with the scenario
//! modes = ["nmpc", "multistage"] # controllers to run, in this order (default: both)
//! time_mode = "lockstep"        # or "real-time" (the wall clock)
//!
//! [scenario]                    # exactly `mav::Scenario` (unknown keys are errors)
//! name = "slalom-4"
//! ...
//! ```
//!
//! netem's profiles are the scenario's network (`[scenario.delays]`, seeded with
//! `scenario.seed`; see `delay::spec`); trace files named there are read, relative to the
//! scenario file, into the scenario.
//!
//! Every error names the file, the line and the field: parse and type errors through toml's
//! spans, `Scenario::validate` errors by looking the field's path up in the parsed document.
//!
//! The crate is the format and its checks, and nothing of the programs that read it: no tokio,
//! tonic or clap (a flag maps onto these types at the command line's edge). Beside the loader:
//! [`sweep_table`] (`[sweep]`), [`falsify_table`] (`[falsify]`, the checks that need `[sweep]`)
//! and [`user_file`], the one reader of every file a user names (the services' TLS files
//! included).

pub mod falsify_table;
pub mod sweep_table;
pub mod user_file;

use std::fmt;
use std::ops::Range;
use std::path::{Path, PathBuf};

use mav::{ControllerMode, PanocSolver, Scenario, ScenarioError, TimeMode};
use toml::Spanned;
use toml::de::{DeTable, DeValue};

fn default_modes() -> Vec<ControllerMode> {
    vec![ControllerMode::Nmpc, ControllerMode::Multistage]
}

/// The `[run]` table: what the bench does with the scenario.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunSection {
    /// Controllers to run, in order.
    #[serde(default = "default_modes")]
    pub modes: Vec<ControllerMode>,
    /// `lockstep` (deterministic, the default) or `real-time`.
    #[serde(default)]
    pub time_mode: TimeMode,
    /// Keep the controller's predictions above a floor: `scenario.min_altitude_m` when given,
    /// else the ground. On by default, because under delays a controller can otherwise dive
    /// through the ground on its way round an obstacle; the paper files turn it off (the
    /// paper's problem has no floor).
    #[serde(default = "default_floor")]
    pub floor: bool,
    /// Dead-time compensation in the controller's predictions (each scenario holds the last
    /// applied input for its own sampling time before the plan starts). On by default: with
    /// delays up to 0.33 s the paper's prediction, which lets the new input act at once,
    /// collides under a constant 0.33 s delay; the paper files turn it off.
    #[serde(default = "default_floor")]
    pub delay_compensation: bool,
    /// Safety margin added to every cylinder radius by the controller, m. Default: 0.2 m with
    /// dead-time compensation (the bench's controller: with sampling times up to 0.33 s the
    /// Euler prediction alone is ~0.1 m off at 2 m/s^2; measured on random Gamma delay
    /// traces, 13 of 40 runs collide with 0.1 m and 1 of 40 with 0.2 m), else the
    /// controller's own (0.1 m, as in paper mode).
    #[serde(default)]
    pub obstacle_margin_m: Option<f64>,
    /// The safety layer's fail-safe check (each candidate command, then braking, on the
    /// continuous model under every delay, the plant's braking watchdog included; see
    /// `mpc::fail_safe`) instead of the plan check. On by default: with it the multi-stage
    /// controller reached every goal without a collision in the robustness campaigns (five
    /// fields, five delay processes with tails up to 2 s, 1,250 runs; 31 collided with the plan
    /// check), about 0.1 s later (median) (docs/robustness.md). The paper files turn it off.
    #[serde(default = "default_floor")]
    pub fail_safe: bool,
    /// Go on after the first collision (lockstep). Off by default: a run ends at its first
    /// collision, as a real flight does.
    #[serde(default)]
    pub continue_after_collision: bool,
    /// Whose PANOC the controller solves with: `"own"` (the bench's) or `"open"` (OpEn's, the
    /// paper's toolchain). Absent: [`FILE_SOLVER`], but for a file that holds a built-in (paper)
    /// scenario, which keeps the controller's own setting (`controller --solver`, OpEn's by
    /// default), as paper mode does.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub solver: Option<PanocSolver>,
}

/// The solver of a scenario file that names none (and holds no built-in scenario). Ours: along
/// the paper loops its multi-stage solves take half OpEn's iterations (BENCHMARKS.md "The
/// solver"), and the robustness campaigns with it reach every goal without a collision
/// (docs/robustness.md).
pub const FILE_SOLVER: PanocSolver = PanocSolver::Own;

/// The margin of the bench's controller (with dead-time compensation), m.
pub const BENCH_MARGIN_M: f64 = 0.2;

fn default_floor() -> bool {
    true
}

impl Default for RunSection {
    fn default() -> Self {
        Self {
            modes: default_modes(),
            time_mode: TimeMode::Lockstep,
            floor: default_floor(),
            delay_compensation: default_floor(),
            obstacle_margin_m: None,
            fail_safe: default_floor(),
            continue_after_collision: false,
            solver: None,
        }
    }
}

/// The keys of [`Scenario`] that a file gives in `[run]` (see [`ScenarioFile::validate`]).
const RUN_KEYS: [&str; 5] =
    ["delay_compensation", "obstacle_margin_m", "fail_safe", "continue_after_collision", "solver"];

/// serde's "unknown field `k`, expected one of ..." for `[scenario]`, without the keys that
/// belong in `[run]` (`Scenario` holds them, but a file that gives them in `[scenario]` is
/// refused): the list a user reads is the table's own.
fn without_run_keys(message: &str) -> String {
    let Some((head, list)) = message.split_once("expected one of ") else { return message.to_string() };
    let keys: Vec<&str> =
        list.split(", ").filter(|k| !RUN_KEYS.iter().any(|r| k.trim_matches('`') == *r)).collect();
    format!("{head}expected one of {} (the controller's options go in [run])", keys.join(", "))
}

/// A whole scenario file.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioFile {
    #[serde(default)]
    pub run: RunSection,
    pub scenario: Scenario,
    /// The delay families of `hilbench sweep` (optional; see `sweep_table`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sweep: Option<crate::sweep_table::SweepSection>,
    /// What `hilbench falsify` searches (optional; see `falsify_table`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub falsify: Option<falsify::FalsifyTable>,
    /// The keys of the bench's NMPC tuning ([`mav::NMPC_KEYS`]) the file leaves out: a file for
    /// an external controller needs none of them; [`ScenarioFile::nmpc_tuning`] refuses the
    /// file to the bench's own controllers.
    #[serde(skip)]
    pub nmpc_keys_absent: Vec<&'static str>,
}

/// A file that cannot be used, with where and why.
#[derive(Debug, Clone, PartialEq)]
pub struct FileError {
    pub path: PathBuf,
    /// 1-based line, when the error has a place in the file.
    pub line: Option<usize>,
    /// Dotted path of the field, e.g. `scenario.obstacles[0].radius_m`.
    pub field: Option<String>,
    pub message: String,
}

impl fmt::Display for FileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.path.display())?;
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
        }
        if let Some(field) = &self.field {
            write!(f, ": field `{field}`")?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for FileError {}

impl ScenarioFile {
    /// Reads, parses and validates `path`.
    pub fn load(path: &Path) -> Result<Self, FileError> {
        let text = crate::user_file::read_text(path, crate::user_file::MAX_SCENARIO_FILE_BYTES, "a scenario")
            .map_err(|e| FileError {
                path: path.to_path_buf(),
                line: None,
                field: None,
                message: e.reason,
            })?;
        Self::parse(path, &text)
    }

    /// The text of a file that holds `scenario` exactly as flown, its controller options in
    /// `[run]` (where files keep them) and its traces inline: what `hilbench` writes beside a
    /// run's results, and what [`ScenarioFile::parse`] reads back into the same scenario.
    pub fn as_flown(scenario: &Scenario, modes: Vec<ControllerMode>) -> Result<String, String> {
        let run = RunSection {
            modes,
            time_mode: TimeMode::Lockstep,
            floor: scenario.min_altitude_m.is_some(),
            delay_compensation: scenario.delay_compensation,
            obstacle_margin_m: scenario.obstacle_margin_m,
            fail_safe: scenario.fail_safe,
            continue_after_collision: scenario.continue_after_collision,
            solver: scenario.solver,
        };
        let mut scenario = scenario.clone();
        // Written in [run]; the loader puts them back.
        scenario.delay_compensation = false;
        scenario.obstacle_margin_m = None;
        scenario.fail_safe = false;
        scenario.continue_after_collision = false;
        scenario.solver = None;
        let file = ScenarioFile { run, scenario, sweep: None, falsify: None, nmpc_keys_absent: Vec::new() };
        let text = toml::to_string(&file).map_err(|e| format!("cannot write the scenario as TOML: {e}"))?;
        Ok(format!("# The scenario as flown (overrides applied, traces inline).\n{text}"))
    }

    /// Parses and validates `text`, read from `path` (named in errors).
    pub fn parse(path: &Path, text: &str) -> Result<Self, FileError> {
        let error = |span: Option<Range<usize>>, field: Option<String>, message: String| FileError {
            path: path.to_path_buf(),
            line: span.map(|s| line_of(text, s.start)),
            field,
            message,
        };
        let root = DeTable::parse(text).map_err(|e| {
            let message = match e.span() {
                Some(span) if e.message() == "duplicate key" => duplicate_key(text, span),
                _ => e.message().to_string(),
            };
            error(e.span(), None, message)
        })?;
        let mut file: ScenarioFile = serde::Deserialize::deserialize(toml::Deserializer::from(root.clone()))
            .map_err(|e| {
                let field = e.span().and_then(|s| field_at(&root, &s));
                let span = e.span();
                let message = match field.as_deref() {
                    Some(f) if f.strip_prefix("scenario.").is_some_and(|k| !k.contains(['.', '['])) => {
                        without_run_keys(e.message())
                    }
                    _ => e.message().to_string(),
                };
                error(span, field, message)
            })?;
        let written = |key: &str| match root.get_ref().get("scenario").map(|v| v.get_ref()) {
            Some(DeValue::Table(t)) => t.get(key).is_some(),
            _ => false,
        };
        file.nmpc_keys_absent = mav::NMPC_KEYS.into_iter().filter(|k| !written(k)).collect();
        // Trace files, relative to the scenario file, are read into the scenario (inline), so
        // that it travels whole to the services and replays without the file.
        if let Some(table) = file.scenario.delays.as_mut() {
            let dir = path.parent().unwrap_or(Path::new("."));
            table.load_traces(&mut |name| read_trace(&dir.join(name))).map_err(|e| {
                let field = format!("scenario.delays.{}", e.field);
                error(span_of(&root, &field), Some(field), e.reason)
            })?;
        }
        if let Some(sweep) = file.sweep.as_mut() {
            let dir = path.parent().unwrap_or(Path::new("."));
            sweep
                .load_traces(dir, &|p| read_trace(p))
                .map_err(|(field, message)| error(span_of(&root, &field), Some(field), message))?;
        }
        file.validate().map_err(|(field, message)| {
            let span = span_of(&root, &field);
            error(span, Some(field), message)
        })?;
        file.scenario.delay_compensation = file.run.delay_compensation;
        file.scenario.obstacle_margin_m =
            file.run.obstacle_margin_m.or(file.run.delay_compensation.then_some(BENCH_MARGIN_M));
        file.scenario.fail_safe = file.run.fail_safe;
        file.scenario.continue_after_collision = file.run.continue_after_collision;
        let built_in = Scenario::BUILT_IN.contains(&file.scenario.name.as_str());
        file.scenario.solver = file.run.solver.or((!built_in).then_some(FILE_SOLVER));
        if !file.run.floor {
            file.scenario.min_altitude_m = None;
        } else if file.scenario.min_altitude_m.is_none() {
            file.scenario.min_altitude_m = Some(file.scenario.ground_z_m);
        }
        Ok(file)
    }

    /// Whether the bench's NMPC (`nmpc`, `multistage`) may fly the file: refused, naming the
    /// keys, when the file leaves out part of its tuning ([`mav::NMPC_KEYS`]; an external
    /// controller's file may).
    pub fn nmpc_tuning(&self, path: &Path) -> Result<(), FileError> {
        if self.nmpc_keys_absent.is_empty() {
            return Ok(());
        }
        let keys: Vec<String> = self.nmpc_keys_absent.iter().map(|k| format!("`{k}`")).collect();
        Err(FileError {
            path: path.to_path_buf(),
            line: None,
            field: Some("scenario".into()),
            message: format!(
                "the bench's NMPC needs its tuning, and the file leaves out {} (only an external \
                 controller, --controller-cmd, flies a file without them; docs/scenario-file.md)",
                keys.join(", ")
            ),
        })
    }

    /// The checks serde cannot make: `(field path, reason)` of the first bad field.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if self.run.modes.is_empty() {
            return Err(("run.modes".into(), "must name at least one controller".into()));
        }
        if self.run.obstacle_margin_m.is_some_and(|m| !(m.is_finite() && (0.0..=10.0).contains(&m))) {
            return Err(("run.obstacle_margin_m".into(), "must be in [0, 10] m".into()));
        }
        for (i, m) in self.run.modes.iter().enumerate() {
            if self.run.modes[..i].contains(m) {
                return Err((format!("run.modes[{i}]"), "is listed twice".into()));
            }
        }
        if let Some(sweep) = &self.sweep {
            sweep.validate()?;
        }
        if let Some(falsify) = &self.falsify {
            crate::falsify_table::validate(falsify, self.sweep.as_ref())?;
        }
        let s = &self.scenario;
        // The controller's options beyond the paper come from `[run]`, which overwrites them.
        // Whether each of `RUN_KEYS` is set, in its order.
        let set = [
            s.delay_compensation,
            s.obstacle_margin_m.is_some(),
            s.fail_safe,
            s.continue_after_collision,
            s.solver.is_some(),
        ];
        if let Some((key, _)) = RUN_KEYS.iter().zip(set).find(|(_, set)| *set) {
            return Err((format!("scenario.{key}"), format!("belongs in [run] (run.{key})")));
        }
        if let Err(e) = s.validate() {
            return Err(match e {
                ScenarioError::Invalid { field, reason } => (format!("scenario.{field}"), reason),
                other => ("scenario".into(), other.to_string()),
            });
        }
        if self.sweep.is_some() || self.falsify.is_some() {
            crate::sweep_table::check_run_cycles(s)?;
        }
        // The services name scenarios: a file that takes a built-in name must hold it exactly,
        // but for what `hilbench reproduce` overrides in a built-in (its seed, which only the
        // network's draws use, and whether a run goes on after a collision), so that the
        // scenario it writes as flown loads back.
        if let Ok(mut built_in) = Scenario::by_name(&s.name)
            && {
                built_in.seed = s.seed;
                built_in.continue_after_collision = s.continue_after_collision;
                built_in != *s
            }
        {
            return Err((
                "scenario.name".into(),
                format!(
                    "{:?} is a built-in scenario and this file differs from it; give the scenario another name",
                    s.name
                ),
            ));
        }
        Ok(())
    }
}

/// A `--scenario` argument: a built-in name (`paper-1`, `paper-2`, `paper-3`), else the path
/// of a scenario file (loaded and validated as `hilbench run` loads it, `[run]`'s controller
/// options included).
pub fn scenario_arg(arg: &str) -> Result<Scenario, String> {
    scenario_or_file(arg).map(|(scenario, _)| scenario)
}

/// As [`scenario_arg`], for the bench's NMPC: a file must hold its whole tuning
/// ([`ScenarioFile::nmpc_tuning`]).
pub fn nmpc_scenario_arg(arg: &str) -> Result<Scenario, String> {
    let (scenario, file) = scenario_or_file(arg)?;
    if let Some(file) = file {
        file.nmpc_tuning(Path::new(arg)).map_err(|e| e.to_string())?;
    }
    Ok(scenario)
}

/// A built-in scenario, or a file's with the file.
fn scenario_or_file(arg: &str) -> Result<(Scenario, Option<ScenarioFile>), String> {
    if let Ok(built_in) = Scenario::by_name(arg) {
        return Ok((built_in, None));
    }
    let path = Path::new(arg);
    if !path.exists() {
        return Err(format!(
            "{arg:?} is neither a built-in scenario ({}) nor a scenario file",
            Scenario::BUILT_IN.join(", ")
        ));
    }
    let file = ScenarioFile::load(path).map_err(|e| e.to_string())?;
    Ok((file.scenario.clone(), Some(file)))
}

/// The delays of a trace file (`delay::parse_trace`'s format), or why not, naming the file.
pub fn read_trace(path: &Path) -> Result<Vec<f64>, String> {
    let text = crate::user_file::read_text(path, crate::user_file::MAX_TRACE_FILE_BYTES, "a trace")
        .map_err(|e| e.to_string())?;
    delay::parse_trace(&text).map_err(|e| format!("{}: {e}", path.display()))
}

/// toml's "duplicate key", said with the key and where it was first given: a table header
/// (`[scenario.delays]` pasted into a file that has one) by its first line.
fn duplicate_key(text: &str, span: Range<usize>) -> String {
    let before = text.get(..span.start).unwrap_or_default();
    let start = before.rfind('\n').map_or(0, |i| i + 1);
    let line = text.get(start..).unwrap_or_default().lines().next().unwrap_or_default().trim();
    if line.starts_with('[') {
        let header = line.split('#').next().unwrap_or(line).trim();
        let first = before[..start].lines().position(|l| l.split('#').next().unwrap_or(l).trim() == header);
        let first = first.map_or_else(String::new, |i| format!(" (first at line {})", i + 1));
        return format!(
            "duplicate key: the table `{header}` is given twice{first}; a file has each table once (replace the first)"
        );
    }
    let key = text.get(span).unwrap_or_default().trim();
    format!("duplicate key: `{key}` is given twice in its table")
}

/// 1-based line of byte `offset` in `text`.
fn line_of(text: &str, offset: usize) -> usize {
    let end = offset.min(text.len());
    text.as_bytes()[..end].iter().filter(|b| **b == b'\n').count() + 1
}

fn contains(outer: &Range<usize>, inner: &Range<usize>) -> bool {
    outer.start <= inner.start && inner.end <= outer.end && outer.start < outer.end
}

/// The dotted path of the deepest key or value whose span holds `span`. The whole tree is
/// searched: the span of a `[table]` does not enclose the keys under its header.
fn field_at(root: &Spanned<DeTable<'_>>, span: &Range<usize>) -> Option<String> {
    fn join(path: &str, key: &str) -> String {
        if path.is_empty() { key.to_string() } else { format!("{path}.{key}") }
    }
    fn in_table(t: &DeTable<'_>, span: &Range<usize>, path: &str) -> Option<String> {
        let mut fallback = None;
        for (k, v) in t.iter() {
            let here = join(path, k.get_ref());
            if contains(&k.span(), span) {
                return Some(here);
            }
            if let Some(found) = in_value(v.get_ref(), span, &here) {
                return Some(found);
            }
            if fallback.is_none() && contains(&v.span(), span) {
                fallback = Some(here);
            }
        }
        fallback
    }
    fn in_value(v: &DeValue<'_>, span: &Range<usize>, path: &str) -> Option<String> {
        match v {
            DeValue::Table(t) => in_table(t, span, path),
            DeValue::Array(a) => {
                let mut fallback = None;
                for (i, item) in a.iter().enumerate() {
                    let here = format!("{path}[{i}]");
                    if let Some(found) = in_value(item.get_ref(), span, &here) {
                        return Some(found);
                    }
                    if fallback.is_none() && contains(&item.span(), span) {
                        fallback = Some(here);
                    }
                }
                fallback
            }
            _ => None,
        }
    }
    in_table(root.get_ref(), span, "")
}

/// The span of the field at dotted `path` (`a.b[2].c`), or of its deepest part that is in the
/// file (a defaulted field points at its table).
fn span_of(root: &Spanned<DeTable<'_>>, path: &str) -> Option<Range<usize>> {
    let mut span: Option<Range<usize>> = None;
    let mut current: Option<&DeValue<'_>> = None;
    let mut table: &DeTable<'_> = root.get_ref();
    for part in path.split('.') {
        let (key, indices) = match part.find('[') {
            Some(i) => (&part[..i], &part[i..]),
            None => (part, ""),
        };
        if let Some(v) = current {
            match v {
                DeValue::Table(t) => table = t,
                _ => return span,
            }
        }
        let Some(value) = table.get(key) else { return span };
        span = Some(value.span());
        let mut value = value.get_ref();
        for index in indices.split(']').filter(|s| !s.is_empty()) {
            let Some(item) = index.trim_start_matches('[').parse::<usize>().ok().and_then(|i| value.get(i))
            else {
                return span;
            };
            span = Some(item.span());
            value = item.get_ref();
        }
        current = Some(value);
    }
    span
}

#[cfg(test)]
mod tests {
    use super::*;

    fn repo_root() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
    }

    #[test]
    fn paper_files_hold_exactly_the_built_in_scenarios() {
        for name in Scenario::BUILT_IN {
            let path = repo_root().join("scenarios").join(format!("{name}.toml"));
            let file = ScenarioFile::load(&path).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(file.scenario, Scenario::by_name(name).expect("built in"), "{name}");
            assert_eq!(
                file.run,
                RunSection {
                    floor: false,
                    delay_compensation: false,
                    fail_safe: false,
                    ..RunSection::default()
                }
            );
        }
    }

    #[test]
    fn a_file_is_solved_by_our_panoc_unless_it_names_opens_and_a_paper_file_keeps_the_controllers() {
        let path = repo_root().join("scenarios").join("slalom-4.toml");
        let text = std::fs::read_to_string(&path).expect("slalom-4.toml");
        let file = ScenarioFile::parse(&path, &text).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.run.solver, None, "slalom-4.toml names none");
        assert_eq!(file.scenario.solver, Some(PanocSolver::Own), "a file's default");
        let open =
            text.replacen("time_mode = \"lockstep\"", "time_mode = \"lockstep\"\nsolver = \"open\"", 1);
        let file = ScenarioFile::parse(&path, &open).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.scenario.solver, Some(PanocSolver::OpEn));
        let bad = text.replacen("time_mode = \"lockstep\"", "time_mode = \"lockstep\"\nsolver = \"OpEn\"", 1);
        let e = error_of(&bad);
        assert_eq!(e.field.as_deref(), Some("run.solver"), "{e}");
        let misplaced = text.replacen("ground_z_m = 0.0", "ground_z_m = 0.0\nsolver = \"own\"", 1);
        let e = error_of(&misplaced);
        assert_eq!(e.field.as_deref(), Some("scenario.solver"), "{e}");
        assert!(e.to_string().contains("run.solver"), "{e}");
        // The paper files hold built-in scenarios: the controller's own solver, as paper mode.
        for name in Scenario::BUILT_IN {
            let file = ScenarioFile::load(&repo_root().join("scenarios").join(format!("{name}.toml")))
                .unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(file.scenario.solver, None, "{name}");
        }
        // ...unless it names one, which is how paper-2 is flown with ours from a file.
        let (own, _) = edited("[run]", "[run]\nsolver = \"own\"");
        let file = ScenarioFile::parse(Path::new("x.toml"), &own).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.scenario.solver, Some(PanocSolver::Own));
        // A user scenario flown by ours is written as flown with it, and loads back.
        let mut flown = Scenario::paper_2();
        flown.name = "mine".into();
        flown.solver = Some(PanocSolver::Own);
        let text = ScenarioFile::as_flown(&flown, vec![ControllerMode::Multistage]).expect("TOML");
        assert!(text.contains("solver = \"own\""), "{text}");
        let back = ScenarioFile::parse(Path::new("as-flown.toml"), &text).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(back.scenario, flown);
    }

    #[test]
    fn floor_delay_compensation_and_the_fail_safe_check_default_on_and_can_be_set_or_turned_off() {
        let path = repo_root().join("scenarios").join("slalom-4.toml");
        let text = std::fs::read_to_string(&path).expect("slalom-4.toml");
        let file = ScenarioFile::parse(&path, &text).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.scenario.min_altitude_m, Some(file.scenario.ground_z_m));
        assert!(file.scenario.delay_compensation);
        assert_eq!(file.scenario.obstacle_margin_m, Some(BENCH_MARGIN_M));
        assert!(file.scenario.fail_safe, "on by default");
        let set = text.replacen("ground_z_m = 0.0", "ground_z_m = 0.0\nmin_altitude_m = 0.25", 1);
        let file = ScenarioFile::parse(&path, &set).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.scenario.min_altitude_m, Some(0.25));
        let off = text.replacen("time_mode = \"lockstep\"", "time_mode = \"lockstep\"\nfloor = false", 1);
        let file = ScenarioFile::parse(&path, &off).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.scenario.min_altitude_m, None);
        let paper = text.replacen(
            "time_mode = \"lockstep\"",
            "time_mode = \"lockstep\"\ndelay_compensation = false",
            1,
        );
        let file = ScenarioFile::parse(&path, &paper).unwrap_or_else(|e| panic!("{e}"));
        assert!(!file.scenario.delay_compensation);
        assert_eq!(file.scenario.obstacle_margin_m, None, "the controller's own");
        let plan_check =
            text.replacen("time_mode = \"lockstep\"", "time_mode = \"lockstep\"\nfail_safe = false", 1);
        let file = ScenarioFile::parse(&path, &plan_check).unwrap_or_else(|e| panic!("{e}"));
        assert!(!file.scenario.fail_safe);
        // In [scenario] it would be overwritten by [run]: refused, naming where it belongs.
        let misplaced = text.replacen("ground_z_m = 0.0", "ground_z_m = 0.0\nfail_safe = true", 1);
        let err = ScenarioFile::parse(&path, &misplaced).expect_err("misplaced key");
        assert_eq!(err.field.as_deref(), Some("scenario.fail_safe"), "{err}");
        assert!(err.to_string().contains("run.fail_safe"), "{err}");
        let margin =
            text.replacen("time_mode = \"lockstep\"", "time_mode = \"lockstep\"\nobstacle_margin_m = 0.3", 1);
        let file = ScenarioFile::parse(&path, &margin).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.scenario.obstacle_margin_m, Some(0.3));
        let bad = text.replacen(
            "time_mode = \"lockstep\"",
            "time_mode = \"lockstep\"\nobstacle_margin_m = -1.0",
            1,
        );
        let e = ScenarioFile::parse(&path, &bad).expect_err("negative margin");
        assert_eq!(e.field.as_deref(), Some("run.obstacle_margin_m"), "{e}");
        assert!(e.line.is_some(), "{e}");
    }

    #[test]
    fn every_file_in_scenarios_is_valid() {
        let mut n = 0;
        let mut sweeps = 0;
        let mut falsify = 0;
        let dirs = ["scenarios", "scenarios/sweeps", "scenarios/fields", "scenarios/falsify"];
        for dir in dirs.map(|d| repo_root().join(d)) {
            for entry in std::fs::read_dir(&dir).expect("scenarios/") {
                let path = entry.expect("entry").path();
                if path.extension().is_some_and(|e| e == "toml") {
                    let file = ScenarioFile::load(&path).unwrap_or_else(|e| panic!("{e}"));
                    n += 1;
                    sweeps += usize::from(file.sweep.is_some());
                    falsify += usize::from(file.falsify.is_some());
                }
            }
        }
        assert!(n >= 8, "{n} scenario files");
        assert!(sweeps >= 4, "{sweeps} sweep files");
        assert!(falsify >= 4, "{falsify} files with a [falsify] table");
    }

    #[test]
    fn a_file_without_the_nmpc_tuning_loads_for_an_external_controller_and_ours_are_refused_naming_the_keys()
    {
        let path = repo_root().join("examples/python-controller/open-field.toml");
        let file = ScenarioFile::load(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.nmpc_keys_absent, mav::NMPC_KEYS.to_vec(), "open-field has none of them");
        assert_eq!(file.scenario.horizon, Scenario::paper_2().horizon, "paper-2's tuning fills in");
        let e = file.nmpc_tuning(&path).expect_err("refused to the bench's NMPC");
        assert!(e.to_string().contains("`q_x`, `q_u`") && e.to_string().contains("--controller-cmd"), "{e}");
        let arg = path.to_str().expect("UTF-8");
        assert!(scenario_arg(arg).is_ok(), "the plant takes it");
        assert!(
            nmpc_scenario_arg(arg).is_err_and(|e| e.contains("`delay_window`")),
            "the controller does not"
        );
        // One key left out of a whole file is named alone.
        let (text, _) = edited("horizon = 40\n", "");
        let file = ScenarioFile::parse(Path::new("x.toml"), &text).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.nmpc_keys_absent, vec!["horizon"]);
        let e = file.nmpc_tuning(Path::new("x.toml")).expect_err("refused");
        assert!(e.to_string().contains("leaves out `horizon` ("), "{e}");
        // A whole file is flown by all.
        let paper_3 = repo_root().join("scenarios/paper-3.toml");
        let file = ScenarioFile::load(&paper_3).unwrap_or_else(|e| panic!("{e}"));
        assert!(file.nmpc_keys_absent.is_empty() && file.nmpc_tuning(&paper_3).is_ok());
        assert!(nmpc_scenario_arg("paper-1").is_ok());
    }

    /// paper-3 with one line replaced (1-based `line` of the file holding `old`).
    fn edited(old: &str, new: &str) -> (String, usize) {
        let text = std::fs::read_to_string(repo_root().join("scenarios/paper-3.toml")).expect("paper-3");
        let offset = text.find(old).unwrap_or_else(|| panic!("{old:?} not in paper-3.toml"));
        let line = line_of(&text, offset);
        (text.replacen(old, new, 1), line)
    }

    fn error_of(text: &str) -> FileError {
        match ScenarioFile::parse(Path::new("scenarios/x.toml"), text) {
            Ok(_) => panic!("accepted"),
            Err(e) => e,
        }
    }

    #[test]
    fn an_unknown_key_is_named_with_its_line() {
        let (text, line) = edited("horizon = 40", "horizon = 40\nhorizn = 40");
        let e = error_of(&text);
        assert_eq!(e.line, Some(line + 1), "{e}");
        assert_eq!(e.field.as_deref(), Some("scenario.horizn"), "{e}");
        assert!(e.message.contains("unknown field"), "{e}");
        assert!(
            e.to_string().starts_with(&format!("scenarios/x.toml:{}: field `scenario.horizn`", line + 1))
        );
    }

    #[test]
    fn an_unknown_scenario_key_lists_the_tables_own_keys() {
        let (text, _) = edited("horizon = 40", "horizon = 40\ncolour = \"red\"");
        let e = error_of(&text);
        assert_eq!(e.field.as_deref(), Some("scenario.colour"), "{e}");
        assert!(e.message.contains("`horizon`") && e.message.contains("go in [run]"), "{e}");
        for key in RUN_KEYS {
            assert!(!e.message.contains(&format!("`{key}`")), "{key} listed: {e}");
        }
    }

    #[test]
    fn a_wrong_type_is_named_with_its_line() {
        let (text, line) = edited("horizon = 40", "horizon = \"forty\"");
        let e = error_of(&text);
        assert_eq!((e.line, e.field.as_deref()), (Some(line), Some("scenario.horizon")), "{e}");
        let (text, line) = edited("radius_m = 0.4", "radius_m = [0.4]");
        let e = error_of(&text);
        assert_eq!((e.line, e.field.as_deref()), (Some(line), Some("scenario.obstacles[1].radius_m")), "{e}");
    }

    #[test]
    fn negative_and_nan_values_are_caught_by_validation_with_their_line() {
        let (text, line) = edited("radius_m = 0.4", "radius_m = -1.0");
        let e = error_of(&text);
        assert_eq!((e.line, e.field.as_deref()), (Some(line), Some("scenario.obstacles[1].radius_m")), "{e}");
        let (text, line) = edited("min_cycle_s = 0.05", "min_cycle_s = nan");
        let e = error_of(&text);
        assert_eq!((e.line, e.field.as_deref()), (Some(line), Some("scenario.min_cycle_s")), "{e}");
        let (text, line) = edited("q_u = [20.0, 20.0, 20.0]", "q_u = [20.0, -1.0, 20.0]");
        let e = error_of(&text);
        assert_eq!((e.line, e.field.as_deref()), (Some(line), Some("scenario.q_u[1]")), "{e}");
    }

    #[test]
    fn arrays_too_long_or_too_short_are_refused_naming_the_field_the_line_and_the_length() {
        // (the line replaced, its replacement, the field, the length found).
        let cases = [
            (
                "start = [3.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]",
                "start = [3.2, 0, 0, 0, 0, 0, 0, 0, 9]",
                "scenario.start",
                9,
            ),
            (
                "start = [3.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]",
                "start = [3.2, 0, 0, 0, 0, 0, 0]",
                "scenario.start",
                7,
            ),
            ("goal_m = [3.2, 5.0, 1.0]", "goal_m = [3.2, 5.0, 1.0, 0.0, 0.0]", "scenario.goal_m", 5),
            ("q_u = [20.0, 20.0, 20.0]", "q_u = [20.0, 20.0, 20.0, 20.0]", "scenario.q_u", 4),
            ("q_x = [12.5, 12.5, 20.0, 30.0, 30.0, 10.0, 20.0, 20.0]", "q_x = [12.5]", "scenario.q_x", 1),
            ("q_du = [40.0, 165.0, 165.0]", "q_du = [40.0, 165.0]", "scenario.q_du", 2),
            ("prior_gamma = [12.0, 0.015]", "prior_gamma = [12.0, 0.015, 3.0]", "scenario.prior_gamma", 3),
            (
                "min = [0.0, -0.17453292519943295, -0.17453292519943295]",
                "min = [0.0, -0.17, -0.17, 5.0]",
                "scenario.bounds.min",
                4,
            ),
            (
                "max = [19.62, 0.17453292519943295, 0.17453292519943295]",
                "max = [19.62, 0.17, 0.17, 1.0]",
                "scenario.bounds.max",
                4,
            ),
        ];
        for (old, new, field, len) in cases {
            let (text, line) = edited(old, new);
            let e = error_of(&text);
            assert_eq!((e.line, e.field.as_deref()), (Some(line), Some(field)), "{new}: {e}");
            assert!(e.message.contains(&format!("invalid length {len}")), "{new}: {e}");
        }
    }

    #[test]
    fn a_name_with_a_path_in_it_is_refused_with_its_line() {
        for bad in ["../../escape", "a/b", "with space"] {
            let (text, line) = edited("name = \"paper-3\"", &format!("name = {bad:?}"));
            let e = error_of(&text);
            assert_eq!((e.line, e.field.as_deref()), (Some(line), Some("scenario.name")), "{bad}: {e}");
            assert!(e.message.contains("identifier"), "{e}");
        }
    }

    #[test]
    fn a_sweep_whose_runs_would_draw_more_than_the_cycle_cap_is_refused_naming_max_duration_s() {
        let sweep = "\n[sweep]\nruns = 10\n\n[[sweep.families]]\nkind = \"none\"\n";
        // A day at the shortest cycle: 86,400,002 delays per run (691 MB), refused.
        let (day, _) = edited("max_duration_s = 60.0", "max_duration_s = 86400.0");
        let text = day.replacen("min_cycle_s = 0.05", "min_cycle_s = 0.001", 1);
        let line = text.lines().position(|l| l.starts_with("max_duration_s")).expect("the line") + 1;
        let e = error_of(&format!("{text}{sweep}"));
        assert_eq!((e.line, e.field.as_deref()), (Some(line), Some("scenario.max_duration_s")), "{e}");
        assert!(e.message.contains(&crate::sweep_table::MAX_RUN_CYCLES.to_string()), "{e}");
        // `hilbench falsify` draws its runs' traces up front as a sweep does: the same cap.
        let path = repo_root().join("scenarios/sweeps/paper-2-delays-plan-check.toml");
        let falsify = std::fs::read_to_string(&path).expect("a file with [falsify]");
        let sweep_at = falsify.find("\n[sweep]").expect("[sweep]");
        let falsify_at = falsify.find("\n[falsify]").expect("[falsify]");
        let falsify = format!("{}{}", &falsify[..sweep_at], &falsify[falsify_at..])
            .replacen("max_duration_s = 60.0", "max_duration_s = 86400.0", 1)
            .replacen("min_cycle_s = 0.05", "min_cycle_s = 0.001", 1);
        let e = error_of(&falsify);
        assert_eq!(e.field.as_deref(), Some("scenario.max_duration_s"), "{e}");
        // The same scenario without a sweep is a valid (long) run.
        let renamed = text.replacen("name = \"paper-3\"", "name = \"paper-3-day\"", 1);
        ScenarioFile::parse(Path::new("x.toml"), &renamed).unwrap_or_else(|e| panic!("{e}"));
    }

    #[test]
    fn a_trace_that_is_a_device_a_fifo_or_a_folder_of_devices_is_refused_naming_it() {
        let (text, line) = edited("kind = \"none\"", "kind = \"trace\"\nfile = \"/dev/zero\"");
        let e = error_of(&text);
        assert_eq!((e.line, e.field.as_deref()), (Some(line + 1), Some("scenario.delays.file")), "{e}");
        assert!(e.message.contains("/dev/zero") && e.message.contains("not a regular file"), "{e}");
        let (base, _) = edited("kind = \"none\"", "kind = \"none\"");
        let sweep = "\n[sweep]\nruns = 10\n\n[[sweep.families]]\nkind = \"traces\"\ndir = \"/dev\"\n";
        let e = error_of(&format!("{base}{sweep}"));
        assert_eq!(e.field.as_deref(), Some("sweep.families[0].dir"), "{e}");
        assert!(e.message.contains("/dev/") && e.message.contains("regular file"), "{e}");
        let e = ScenarioFile::load(Path::new("/dev/zero")).expect_err("a device");
        assert!(e.to_string().starts_with("/dev/zero: not a regular file"), "{e}");
    }

    #[test]
    fn bad_delays_are_refused_with_their_line_and_key() {
        // (table replacing paper-3's `kind = "none"`, the key named, its line below `kind`).
        let cases = [
            ("kind = \"constant\"\ndelay_s = 4000.0", "scenario.delays.delay_s", 1),
            ("kind = \"normal\"\nmean_s = 0.1\nstd_s = -1.0", "scenario.delays.std_s", 2),
            ("kind = \"gamma\"\nshape = nan\nscale_s = 0.01", "scenario.delays.shape", 1),
            ("kind = \"trace\"\nfile = \"no-such-trace.csv\"", "scenario.delays.file", 1),
            ("kind = \"regime\"\nstates = []", "scenario.delays.states", 1),
            ("kind = \"none\"\nloss_probability = 1.5", "scenario.delays.loss_probability", 1),
            ("kind = \"lognormal\"\nmean_s = 0.1", "scenario.delays.std_s", 0),
            (
                "kind = \"regime\"\n[[scenario.delays.states]]\nkind = \"constant\"\ndelay_s = 0.1\nmean_dwell_s = 0.0",
                "scenario.delays.states[0].mean_dwell_s",
                4,
            ),
        ];
        for (table, field, below) in cases {
            let (text, line) = edited("kind = \"none\"", table);
            let e = error_of(&text);
            assert_eq!(e.field.as_deref(), Some(field), "{table}: {e}");
            if below > 0 {
                assert_eq!(e.line, Some(line + below), "{table}: {e}");
            }
        }
        let (text, _) = edited("kind = \"none\"", "kind = \"trace\"\nfile = \"no-such-trace.csv\"");
        assert!(error_of(&text).message.contains("no-such-trace.csv"), "the missing file is named");
    }

    #[test]
    fn a_table_or_key_given_twice_is_named_with_where_it_was_first() {
        // A fit's [scenario.delays] pasted below the file's own.
        let text = std::fs::read_to_string(repo_root().join("scenarios/paper-3.toml")).expect("paper-3");
        let first = text.lines().position(|l| l.trim() == "[scenario.delays]").expect("a delays table") + 1;
        let e = error_of(&format!("{text}\n[scenario.delays]\nkind = \"constant\"\ndelay_s = 0.1\n"));
        assert_eq!(e.line, Some(text.lines().count() + 2), "{e}");
        assert!(
            e.message
                .contains(&format!("the table `[scenario.delays]` is given twice (first at line {first})")),
            "{e}"
        );
        let (twice, _) = edited("kind = \"none\"", "kind = \"none\"\nkind = \"constant\"");
        assert!(
            error_of(&twice).message.contains("`kind` is given twice in its table"),
            "{}",
            error_of(&twice)
        );
    }

    #[test]
    fn a_bad_sweep_table_is_refused_with_its_line_and_field() {
        let text = std::fs::read_to_string(repo_root().join("scenarios/paper-3.toml")).expect("paper-3");
        let sweep = "\n[sweep]\nruns = 10\n\n[[sweep.families]]\nkind = \"gamma\"\nshape = [30.0, 1.0]\nscale_s = 0.01\n";
        let e = error_of(&format!("{text}{sweep}"));
        assert_eq!(e.field.as_deref(), Some("sweep.families[0].shape"), "{e}");
        assert_eq!(e.line, Some(text.lines().count() + 7), "{e}");
        assert!(e.message.contains("min > max"), "{e}");
        let ok = ScenarioFile::parse(
            Path::new("x.toml"),
            &format!("{text}{}", sweep.replace("[30.0, 1.0]", "[1.0, 30.0]")),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(ok.sweep.map(|s| s.families.len()), Some(1));
        let e = error_of(&format!("{text}\n[sweep]\nrunz = 3\nfamilies = []\n"));
        assert_eq!(e.field.as_deref(), Some("sweep.runz"), "{e}");
    }

    #[test]
    fn run_section_and_names_are_checked() {
        let (text, line) = edited("time_mode = \"lockstep\"", "time_mode = \"realtime\"");
        let e = error_of(&text);
        assert_eq!((e.line, e.field.as_deref()), (Some(line), Some("run.time_mode")), "{e}");
        let (text, _) = edited("time_mode = \"lockstep\"", "time_mode = \"real-time\"");
        let file = ScenarioFile::parse(Path::new("x.toml"), &text).expect("real time");
        assert_eq!(file.run.time_mode, TimeMode::RealTime);
        let (text, line) = edited("modes = [\"nmpc\", \"multistage\"]", "modes = [\"nmpc\", \"mpc\"]");
        let e = error_of(&text);
        assert_eq!((e.line, e.field.as_deref()), (Some(line), Some("run.modes[1]")), "{e}");
        // A built-in name with other contents would be ambiguous for the services...
        let (text, _) = edited("horizon = 40", "horizon = 41");
        let e = error_of(&text);
        assert_eq!(e.field.as_deref(), Some("scenario.name"), "{e}");
        let ok = ScenarioFile::parse(Path::new("x.toml"), &text.replace("\"paper-3\"", "\"paper-3-long\""))
            .expect("renamed");
        assert_eq!(ok.scenario.horizon, 41);
        // ...but for the seed, which only the network's draws use (`reproduce --seed`).
        let (text, _) = edited("seed = 42", "seed = 43");
        let ok = ScenarioFile::parse(Path::new("x.toml"), &text).expect("another seed");
        assert_eq!(ok.scenario.seed, 43);
    }

    #[test]
    fn a_built_in_scenario_as_reproduce_flies_it_is_written_as_a_file_that_loads_back() {
        for name in Scenario::BUILT_IN {
            let mut flown = Scenario::by_name(name).expect("built in");
            flown.seed = 7;
            flown.continue_after_collision = true;
            let text = ScenarioFile::as_flown(&flown, vec![ControllerMode::Nmpc, ControllerMode::Multistage])
                .expect("TOML");
            let back =
                ScenarioFile::parse(Path::new("as-flown.toml"), &text).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(back.scenario, flown, "{name}");
        }
    }

    #[test]
    fn a_missing_file_or_bad_toml_is_reported_with_the_file() {
        let e = ScenarioFile::load(Path::new("scenarios/does-not-exist.toml")).expect_err("missing");
        assert!(e.to_string().starts_with("scenarios/does-not-exist.toml: cannot read"), "{e}");
        let e = error_of("[scenario\nname = 1\n");
        assert_eq!(e.line, Some(1), "{e}");
        let e = error_of("[run]\n");
        assert!(e.message.contains("missing field `scenario`"), "{e}");
    }
}
