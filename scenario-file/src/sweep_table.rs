//! The `[sweep]` table of a scenario file: the delay families `hilbench sweep` draws each run's
//! delay process from.
//!
//! ```toml
//! [sweep]
//! runs = 200              # default of --runs
//! seed = 1                # default of --seed (else scenario.seed)
//! max_delay_s = 0.33      # every drawn delay clipped here (optional)
//!
//! [[sweep.families]]
//! name = "gamma"          # default: the kind
//! weight = 1.0            # default 1; a run's family is drawn by weight
//! kind = "gamma"          # a kind of [scenario.delays] ...
//! shape = [1.0, 30.0]     # ... whose parameters are numbers or ranges [min, max]
//! scale_s = [0.002, 0.04]
//! loss = [0.0, 0.05]     # the run's loss probability (optional, any kind; a regime's state
//!                         # may have its own: the loss of a message sent in that state)
//! ```
//!
//! A family is a delay kind of `delay::spec` (`constant`, `uniform`, `normal`, `gamma`,
//! `lognormal`, `pareto`, `regime` with ranged states) or `traces`, a folder of recorded trace
//! files. A run's parameters are drawn uniformly in each range; [`Family::table`] turns the
//! drawn values into a `delay::DelaysTable`, the one thing the rest of the bench flies. A
//! family's `loss` is that table's `loss_probability`: each command of the run is lost with
//! it (a `traces` family's recorded `lost` entries stay lost).
//!
//! Validation ([`SweepSection::validate`]) refuses ranges with min > max, non-finite or
//! negative values (but `mu`, the log of a delay), weights that do not sum to a positive
//! number, and any family some draw of which is not a valid delays table: every corner of the
//! ranges goes through `DelaysTable::to_network` (the one conversion), so a key that does not
//! belong to the kind, or a `uniform` whose `min_s` range overlaps its `max_s` range, is
//! refused with the key named.

use std::path::Path;

use crate::user_file::{MAX_TRACE_DIR_BYTES, MAX_TRACE_DIR_FILES};
use delay::DelaysTable;

/// A parameter of a family: one value for every run, or a range drawn uniformly per run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Param {
    Fixed(f64),
    Range(f64, f64),
}

impl Param {
    fn bounds(self) -> (f64, f64) {
        match self {
            Param::Fixed(v) => (v, v),
            Param::Range(lo, hi) => (lo, hi),
        }
    }
}

impl serde::Serialize for Param {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match *self {
            Param::Fixed(v) => s.serialize_f64(v),
            Param::Range(lo, hi) => [lo, hi].serialize(s),
        }
    }
}

impl<'de> serde::Deserialize<'de> for Param {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = Param;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a number or a range [min, max]")
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<Param, E> {
                Ok(Param::Fixed(v))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Param, E> {
                Ok(Param::Fixed(v as f64))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Param, E> {
                Ok(Param::Fixed(v as f64))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Param, A::Error> {
                let wrong = || serde::de::Error::custom("a range is [min, max]: two numbers");
                let lo: f64 = seq.next_element()?.ok_or_else(wrong)?;
                let hi: f64 = seq.next_element()?.ok_or_else(wrong)?;
                if seq.next_element::<f64>()?.is_some() {
                    return Err(wrong());
                }
                Ok(Param::Range(lo, hi))
            }
        }
        d.deserialize_any(Visitor)
    }
}

fn one() -> f64 {
    1.0
}

/// One family of delay processes.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Family {
    /// Name in the outputs (default: the kind); unique in the sweep.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Relative weight of the family (a regime's state has none).
    #[serde(default = "one")]
    pub weight: f64,
    /// A kind of `[scenario.delays]` but `trace`, or `traces` (a folder of trace files).
    pub kind: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub delay_s: Option<Param>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_s: Option<Param>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_s: Option<Param>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mean_s: Option<Param>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub std_s: Option<Param>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shape: Option<Param>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale_s: Option<Param>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mu: Option<Param>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma: Option<Param>,
    /// A regime state's mean dwell, in messages or seconds.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mean_dwell_messages: Option<Param>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mean_dwell_s: Option<Param>,
    /// A regime's states, each a family without name or weight.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub states: Option<Vec<Family>>,
    /// `traces`: the folder, relative to the scenario file; every file in it is a trace.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dir: Option<String>,
    /// `traces`: replay a trace from its start once used up (default: a run that outlasts
    /// its trace ends with an error, counted as a failure).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub looping: Option<bool>,
    /// The run's loss probability, in [0, 1): each command is lost with it, whatever its
    /// delay (the table's `loss_probability`), drawn after the other ranges; in a regime's
    /// state, the loss of a command sent in that state (the state table's own), drawn after
    /// the state's other ranges.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loss: Option<Param>,
    /// `traces`: the files read from `dir` (name, delays), sorted by name; filled by the loader.
    #[serde(skip)]
    pub traces: Vec<(String, Vec<f64>)>,
}

/// The numeric keys of a family, in the order they are drawn.
const NUMERIC: [&str; 11] = [
    "delay_s",
    "min_s",
    "max_s",
    "mean_s",
    "std_s",
    "shape",
    "scale_s",
    "mu",
    "sigma",
    "mean_dwell_messages",
    "mean_dwell_s",
];

impl Family {
    fn param(&self, key: &str) -> Option<Param> {
        match key {
            "delay_s" => self.delay_s,
            "min_s" => self.min_s,
            "max_s" => self.max_s,
            "mean_s" => self.mean_s,
            "std_s" => self.std_s,
            "shape" => self.shape,
            "scale_s" => self.scale_s,
            "mu" => self.mu,
            "sigma" => self.sigma,
            "mean_dwell_messages" => self.mean_dwell_messages,
            "mean_dwell_s" => self.mean_dwell_s,
            _ => None,
        }
    }

    /// The family's name in the outputs.
    pub fn name(&self) -> &str {
        self.name.as_deref().unwrap_or(&self.kind)
    }

    /// The delays table of one draw: `pick(key, lo, hi)` gives each ranged parameter's value
    /// (`key` is its path in the family, e.g. `states[1].delay_s`), `pick_trace(n)` the index
    /// of a `traces` family's file. Returns the table and the drawn values by path.
    pub fn table(
        &self,
        pick: &mut dyn FnMut(&str, f64, f64) -> f64,
        pick_trace: &mut dyn FnMut(usize) -> usize,
    ) -> (DelaysTable, Vec<(String, f64)>) {
        let mut params = Vec::new();
        let mut table = self.table_at("", pick, pick_trace, &mut params);
        if let Some(p) = self.loss {
            table.loss_probability = Some(value(p, "loss".into(), pick, &mut params));
        }
        (table, params)
    }

    fn table_at(
        &self,
        path: &str,
        pick: &mut dyn FnMut(&str, f64, f64) -> f64,
        pick_trace: &mut dyn FnMut(usize) -> usize,
        params: &mut Vec<(String, f64)>,
    ) -> DelaysTable {
        if self.kind == "traces" {
            let i = pick_trace(self.traces.len().max(1)).min(self.traces.len().saturating_sub(1));
            let (name, delays) = self.traces.get(i).cloned().unwrap_or_default();
            params.push((join(path, "trace"), i as f64));
            return DelaysTable::trace(&name, delays, self.looping.unwrap_or(false));
        }
        let mut table = DelaysTable { kind: Some(self.kind.clone()), ..DelaysTable::default() };
        for key in NUMERIC {
            let Some(p) = self.param(key) else { continue };
            let drawn = value(p, join(path, key), pick, params);
            let slot = match key {
                "delay_s" => &mut table.delay_s,
                "min_s" => &mut table.min_s,
                "max_s" => &mut table.max_s,
                "mean_s" => &mut table.mean_s,
                "std_s" => &mut table.std_s,
                "shape" => &mut table.shape,
                "scale_s" => &mut table.scale_s,
                "mu" => &mut table.mu,
                "sigma" => &mut table.sigma,
                "mean_dwell_messages" => &mut table.mean_dwell_messages,
                _ => &mut table.mean_dwell_s,
            };
            *slot = Some(drawn);
        }
        // A regime state's own loss (the family's is drawn last, by `table`).
        if let Some(p) = self.loss.filter(|_| !path.is_empty()) {
            table.loss_probability = Some(value(p, join(path, "loss"), pick, params));
        }
        if let Some(states) = &self.states {
            table.states = Some(
                states
                    .iter()
                    .enumerate()
                    .map(|(i, s)| s.table_at(&join(path, &format!("states[{i}]")), pick, pick_trace, params))
                    .collect(),
            );
        }
        table
    }

    /// `(path, reason)` of the first bad key of this family (at `path`).
    fn validate(&self, path: &str, state: bool) -> Result<(), (String, String)> {
        if state && (self.name.is_some() || self.weight != 1.0) {
            let key = if self.name.is_some() { "name" } else { "weight" };
            return Err((join(path, key), "a regime's state has no name or weight".into()));
        }
        let weight_ok = self.weight.is_finite() && self.weight >= 0.0;
        if !state && !weight_ok {
            return Err((join(path, "weight"), "must be a finite number >= 0".into()));
        }
        if self.kind == "trace" {
            return Err((
                join(path, "kind"),
                "a family of recorded traces is kind \"traces\" with `dir`, a folder of trace files".into(),
            ));
        }
        for key in NUMERIC {
            let Some(p) = self.param(key) else { continue };
            let (lo, hi) = p.bounds();
            if !(lo.is_finite() && hi.is_finite()) {
                return Err((join(path, key), "must be finite".into()));
            }
            if key != "mu" && (lo < 0.0 || hi < 0.0) {
                return Err((join(path, key), "must not be negative".into()));
            }
            if lo > hi {
                return Err((join(path, key), format!("range [{lo}, {hi}]: min > max")));
            }
        }
        if let Some(p) = self.loss {
            let key = join(path, "loss");
            let (lo, hi) = p.bounds();
            if !(0.0..1.0).contains(&lo) || !(0.0..1.0).contains(&hi) {
                return Err((key, "a loss probability must be in [0, 1)".into()));
            }
            if lo > hi {
                return Err((key, format!("range [{lo}, {hi}]: min > max")));
            }
        }
        if self.kind == "traces" {
            let extra = NUMERIC.iter().find(|k| self.param(k).is_some()).copied();
            if let Some(key) = extra.or(self.states.as_ref().map(|_| "states")) {
                return Err((
                    join(path, key),
                    "does not apply to kind \"traces\" (it takes dir, looping)".into(),
                ));
            }
            if self.dir.is_none() {
                return Err((
                    join(path, "dir"),
                    "missing: kind \"traces\" takes dir, a folder of trace files".into(),
                ));
            }
            return Ok(());
        }
        for (key, set) in [("dir", self.dir.is_some()), ("looping", self.looping.is_some())] {
            if set {
                return Err((join(path, key), "belongs to kind \"traces\" only".into()));
            }
        }
        if let Some(states) = &self.states {
            for (i, s) in states.iter().enumerate() {
                s.validate(&join(path, &format!("states[{i}]")), true)?;
            }
        }
        if state {
            return Ok(());
        }
        // Every corner of the ranges must be a valid delays table: the kind's keys, and the
        // constraints between them (a uniform's min_s <= max_s) are linear, so the corners
        // hold them all when they hold. Beyond 2^12 corners, the all-low and all-high ones.
        let ranged = self.ranged_count();
        let corners: Vec<u64> = if ranged <= 12 { (0..1u64 << ranged).collect() } else { vec![0, u64::MAX] };
        for corner in corners {
            let mut bit = 0;
            let (table, _) = self.table(
                &mut |_, lo, hi| {
                    let v = if corner >> bit.min(63) & 1 == 1 { hi } else { lo };
                    bit += 1;
                    v
                },
                &mut |_| 0,
            );
            table.to_network(0, &mut |_| Ok(vec![0.0])).map_err(|e| {
                let at_corner = if ranged > 0 { " (at a corner of the ranges)" } else { "" };
                (join(path, &e.field), format!("{}{at_corner}", e.reason))
            })?;
        }
        Ok(())
    }

    fn ranged_count(&self) -> u32 {
        let own = NUMERIC
            .iter()
            .map(|k| self.param(k))
            .chain([self.loss])
            .filter(|p| matches!(p, Some(Param::Range(..))))
            .count() as u32;
        own + self.states.iter().flatten().map(Family::ranged_count).sum::<u32>()
    }
}

/// A parameter's value in one draw: a fixed one as it is, a range's from `pick` (and listed in
/// `params` under `key`).
fn value(
    p: Param,
    key: String,
    pick: &mut dyn FnMut(&str, f64, f64) -> f64,
    params: &mut Vec<(String, f64)>,
) -> f64 {
    match p {
        Param::Fixed(v) => v,
        Param::Range(lo, hi) => {
            let v = pick(&key, lo, hi);
            params.push((key, v));
            v
        }
    }
}

fn join(path: &str, key: &str) -> String {
    if path.is_empty() { key.to_string() } else { format!("{path}.{key}") }
}

/// The default per-run time limit, s.
pub const DEFAULT_RUN_TIMEOUT_S: f64 = 300.0;
/// The default number of reruns `--shrink` may spend on one failure.
pub const DEFAULT_SHRINK_RUNS: u64 = 150;
/// The default number of reruns `--shrink` may spend on all the failures of a sweep process.
pub const DEFAULT_SHRINK_TOTAL_RUNS: u64 = 1500;

/// The `[sweep]` table.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SweepSection {
    /// Runs of the sweep (`--runs` overrides).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub runs: Option<u64>,
    /// Seed of the draws (`--seed` overrides; default `scenario.seed`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// Every drawn delay is clipped to this, s (a trace's too).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_delay_s: Option<f64>,
    /// A run that takes longer than this wall time is a failure (`--run-timeout-s` overrides).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub run_timeout_s: Option<f64>,
    /// Reruns `--shrink` may spend on one failure.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shrink_runs: Option<u64>,
    /// Reruns `--shrink` may spend on all the failures of a sweep process (its shard's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shrink_total_runs: Option<u64>,
    /// How run `i` picks its family.
    #[serde(default, skip_serializing_if = "FamilyChoice::is_default")]
    pub family_choice: FamilyChoice,
    pub families: Vec<Family>,
}

/// How a sweep's run picks its family.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FamilyChoice {
    /// Drawn by weight (run `i`'s generator).
    #[default]
    Weighted,
    /// Run `i` takes the `i mod F`-th of the `F` families of positive weight: every family gets
    /// the same number of runs (within one), as a campaign over families needs.
    InTurn,
}

impl FamilyChoice {
    fn is_default(&self) -> bool {
        *self == Self::Weighted
    }
}

/// Most runs one sweep process flies (its shard's, with `--shard`): every run's row is kept
/// until the sweep ends (a few hundred bytes each), so `--runs 100000000` asked for 50 GB up
/// front and aborted. A larger campaign is split into shards (`--shard I/K`) and merged.
pub const MAX_RUNS: u64 = 1_000_000;
/// Most cycles a run of a sweep may have (`max_duration_s / min_cycle_s`, plus 2): each run's
/// delays are drawn into a trace of that many values before it flies (8 bytes each, 8 MB at
/// the cap, per run in flight). A scenario of a day at 1 ms cycles asked for 691 GB.
pub const MAX_RUN_CYCLES: u64 = 1_000_000;

/// The most cycles a run of `scenario` can have, plus 2: the length of a sweep run's drawn
/// trace (`t_{k+1} >= t_k + min_cycle_s`, so at most `max_duration_s / min_cycle_s` cycles
/// start before the time limit).
pub fn run_cycles(scenario: &mav::Scenario) -> u64 {
    let cycle_ns = delay::s_to_ns(scenario.min_cycle_s).unwrap_or(1).max(1);
    let limit_ns = delay::s_to_ns(scenario.max_duration_s).unwrap_or(u64::MAX);
    (limit_ns / cycle_ns).saturating_add(2)
}

/// Refuses a scenario whose sweep or falsification runs (`hilbench falsify` draws each run's
/// trace up front too) would have more than [`MAX_RUN_CYCLES`] cycles:
/// `(field path, reason)`.
pub fn check_run_cycles(scenario: &mav::Scenario) -> Result<(), (String, String)> {
    let cycles = run_cycles(scenario);
    if cycles > MAX_RUN_CYCLES {
        return Err((
            "scenario.max_duration_s".into(),
            format!(
                "a run of a sweep or a falsification may have at most {MAX_RUN_CYCLES} cycles \
                 (max_duration_s / min_cycle_s), this one {cycles} ({} s / {} s): shorten \
                 max_duration_s or lengthen min_cycle_s",
                scenario.max_duration_s, scenario.min_cycle_s
            ),
        ));
    }
    Ok(())
}

/// The trace files of a `traces` family's folder, sorted: every entry must be a regular file
/// (or a link to one) of at most [`crate::user_file::MAX_TRACE_FILE_BYTES`], at most [`MAX_TRACE_DIR_FILES`] of
/// them, [`MAX_TRACE_DIR_BYTES`] in all. A folder such as `/dev` is refused at its first device
/// rather than read.
fn trace_folder(folder: &Path) -> Result<Vec<std::path::PathBuf>, String> {
    let shown = folder.display();
    let meta = std::fs::metadata(folder).map_err(|e| format!("{shown}: {e}"))?;
    if !meta.is_dir() {
        return Err(format!("{shown}: not a directory"));
    }
    let mut files = Vec::new();
    let mut bytes = 0u64;
    for entry in std::fs::read_dir(folder).map_err(|e| format!("{shown}: {e}"))? {
        let path = entry.map_err(|e| format!("{shown}: {e}"))?.path();
        if files.len() == MAX_TRACE_DIR_FILES {
            return Err(format!("{shown}: more than {MAX_TRACE_DIR_FILES} files"));
        }
        let meta = std::fs::metadata(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        crate::user_file::check_regular(&meta).map_err(|e| format!("{}: {e}", path.display()))?;
        bytes = bytes.saturating_add(meta.len());
        if bytes > MAX_TRACE_DIR_BYTES {
            return Err(format!("{shown}: more than {} MiB of trace files", MAX_TRACE_DIR_BYTES >> 20));
        }
        files.push(path);
    }
    files.sort();
    if files.is_empty() {
        return Err(format!("{shown}: holds no trace file"));
    }
    Ok(files)
}

impl SweepSection {
    /// `(field path, reason)` of the first bad key, paths under `sweep`.
    pub fn validate(&self) -> Result<(), (String, String)> {
        if self.families.is_empty() {
            return Err(("sweep.families".into(), "must hold at least one family".into()));
        }
        if self.runs == Some(0) {
            return Err(("sweep.runs".into(), "must be at least 1".into()));
        }
        if let Some(m) = self.max_delay_s
            && !(m.is_finite() && m > 0.0 && m <= delay::MAX_DELAY_S)
        {
            return Err(("sweep.max_delay_s".into(), format!("must be in (0, {}] s", delay::MAX_DELAY_S)));
        }
        if let Some(t) = self.run_timeout_s
            && !(t.is_finite() && t > 0.0 && t <= 86_400.0)
        {
            return Err(("sweep.run_timeout_s".into(), "must be in (0, 86400] s".into()));
        }
        let mut names: Vec<&str> = Vec::new();
        for (i, f) in self.families.iter().enumerate() {
            let path = format!("sweep.families[{i}]");
            f.validate(&path, false)?;
            let name = f.name();
            if name.is_empty() || name.len() > 64 || name.chars().any(|c| c.is_control() || c == ',') {
                return Err((join(&path, "name"), "must be 1 to 64 printable characters, no comma".into()));
            }
            if names.contains(&name) {
                return Err((
                    join(&path, "name"),
                    format!("{name:?} names two families; give each a `name`"),
                ));
            }
            names.push(name);
        }
        let total: f64 = self.families.iter().map(|f| f.weight).sum();
        if !(total.is_finite() && total > 0.0) {
            return Err(("sweep.families".into(), "the weights must sum to a positive number".into()));
        }
        Ok(())
    }

    /// Reads every `traces` family's folder (relative to `dir`, the scenario file's; see
    /// [`trace_folder`]) with `read_trace`; errors as `(field path, reason)`.
    pub fn load_traces(
        &mut self,
        dir: &Path,
        read_trace: &dyn Fn(&Path) -> Result<Vec<f64>, String>,
    ) -> Result<(), (String, String)> {
        for (i, f) in self.families.iter_mut().enumerate() {
            let Some(folder) = f.dir.as_deref().filter(|_| f.kind == "traces") else { continue };
            let field = format!("sweep.families[{i}].dir");
            let folder = dir.join(folder);
            let files = trace_folder(&folder).map_err(|e| (field.clone(), e))?;
            f.traces = files
                .iter()
                .map(|p| read_trace(p).map(|d| (p.display().to_string(), d)))
                .collect::<Result<_, _>>()
                .map_err(|e| (field.clone(), e))?;
        }
        Ok(())
    }

    /// The families' total weight.
    pub fn total_weight(&self) -> f64 {
        self.families.iter().map(|f| f.weight).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn section(text: &str) -> SweepSection {
        toml::from_str(text).unwrap_or_else(|e| panic!("{e}"))
    }

    fn field_of(text: &str) -> String {
        match section(text).validate() {
            Ok(()) => panic!("accepted: {text}"),
            Err((field, _)) => field,
        }
    }

    #[test]
    fn a_family_draws_its_ranges_into_a_delays_table() {
        let s = section(
            "[[families]]\nkind = \"gamma\"\nshape = [1.0, 30.0]\nscale_s = 0.01\n\
             [[families]]\nname = \"bursts\"\nweight = 2\nkind = \"regime\"\n\
             [[families.states]]\nkind = \"constant\"\ndelay_s = [0.0, 0.06]\nmean_dwell_messages = [10, 60]\n\
             [[families.states]]\nkind = \"constant\"\ndelay_s = 0.3\nmean_dwell_messages = 5\n",
        );
        assert_eq!(s.validate(), Ok(()));
        assert_eq!(s.total_weight(), 3.0);
        let (t, params) = s.families[0].table(&mut |_, lo, hi| (lo + hi) / 2.0, &mut |_| 0);
        assert_eq!((t.kind.as_deref(), t.shape, t.scale_s), (Some("gamma"), Some(15.5), Some(0.01)));
        assert_eq!(params, vec![("shape".to_string(), 15.5)]);
        let (t, params) = s.families[1].table(&mut |_, _, hi| hi, &mut |_| 0);
        let states = t.states.expect("states");
        assert_eq!((states[0].delay_s, states[0].mean_dwell_messages), (Some(0.06), Some(60.0)));
        assert_eq!(states[1].delay_s, Some(0.3));
        let names: Vec<&str> = params.iter().map(|(k, _)| k.as_str()).collect();
        assert_eq!(names, ["states[0].delay_s", "states[0].mean_dwell_messages"]);
        assert_eq!(s.families[1].name(), "bursts");
    }

    #[test]
    fn a_familys_loss_is_drawn_last_into_the_tables_loss_probability() {
        let s = section(
            "[[families]]\nkind = \"gamma\"\nshape = [1.0, 30.0]\nscale_s = 0.01\nloss = [0.0, 0.1]\n\
             [[families]]\nkind = \"constant\"\ndelay_s = 0.05\nloss = 0.02\n\
             [[families]]\nname = \"bursts\"\nkind = \"regime\"\nloss = [0.01, 0.03]\n\
             [[families.states]]\nkind = \"constant\"\ndelay_s = [0.0, 0.06]\nmean_dwell_messages = 10\n\
             [[families.states]]\nkind = \"constant\"\ndelay_s = 0.3\nmean_dwell_messages = 5\n",
        );
        assert_eq!(s.validate(), Ok(()));
        let (t, params) = s.families[0].table(&mut |_, lo, hi| (lo + hi) / 2.0, &mut |_| 0);
        assert_eq!((t.shape, t.loss_probability), (Some(15.5), Some(0.05)));
        assert_eq!(params, vec![("shape".to_string(), 15.5), ("loss".to_string(), 0.05)]);
        // A fixed loss is the table's for every run, and no drawn parameter.
        let (t, params) = s.families[1].table(&mut |_, lo, _| lo, &mut |_| 0);
        assert_eq!((t.loss_probability, params), (Some(0.02), vec![]));
        // A regime's loss is the family's (the whole table's), drawn after its states'.
        let (t, params) = s.families[2].table(&mut |_, _, hi| hi, &mut |_| 0);
        assert_eq!(t.loss_probability, Some(0.03));
        let names: Vec<&str> = params.iter().map(|(k, _)| k.as_str()).collect();
        assert_eq!(names, ["states[0].delay_s", "loss"]);
        let network = t.to_network(1, &mut |_| Ok(vec![])).expect("a network");
        assert_eq!(network.to_plant.loss_probability, 0.03);
        // A traces family's table carries it too.
        let mut traces = section("[[families]]\nkind = \"traces\"\ndir = \"t\"\nloss = 0.1\n");
        assert_eq!(traces.validate(), Ok(()));
        traces.families[0].traces = vec![("a.csv".into(), vec![0.1, delay::LOST_S])];
        let (t, _) = traces.families[0].table(&mut |_, lo, _| lo, &mut |_| 0);
        assert_eq!((t.delays_s.as_deref(), t.loss_probability), (Some(&[0.1, delay::LOST_S][..]), Some(0.1)));
    }

    #[test]
    fn a_loss_outside_0_to_1_is_refused_naming_the_field_in_a_family_or_a_state() {
        let gamma = |loss: &str| {
            format!("[[families]]\nkind = \"gamma\"\nshape = 2.0\nscale_s = 0.01\nloss = {loss}")
        };
        for bad in ["1.0", "-0.1", "[0.0, 1.0]", "[-0.01, 0.5]", "nan", "[0.2, 0.1]"] {
            assert_eq!(field_of(&gamma(bad)), "sweep.families[0].loss", "loss = {bad}");
        }
        for good in ["0.0", "0.999", "[0.0, 0.5]", "[0.1, 0.1]"] {
            assert_eq!(section(&gamma(good)).validate(), Ok(()), "loss = {good}");
        }
        let (_, why) = section(&gamma("1.5")).validate().expect_err("refused");
        assert!(why.contains("[0, 1)"), "{why}");
        let state = |loss: &str| {
            format!(
                "[[families]]\nkind = \"regime\"\n[[families.states]]\nkind = \"constant\"\ndelay_s = 0.1\nmean_dwell_messages = 2\nloss = {loss}"
            )
        };
        assert_eq!(field_of(&state("[0.1, 1.0]")), "sweep.families[0].states[0].loss");
        assert_eq!(section(&state("[0.0, 0.1]")).validate(), Ok(()));
    }

    #[test]
    fn a_regime_states_loss_is_drawn_after_its_other_ranges_into_the_states_table() {
        let s = section(
            "[[families]]\nkind = \"regime\"\n\
             [[families.states]]\nkind = \"constant\"\ndelay_s = [0.0, 0.06]\nmean_dwell_messages = 10\nloss = 0.002\n\
             [[families.states]]\nkind = \"constant\"\ndelay_s = 0.3\nmean_dwell_messages = [2.0, 8.0]\nloss = [0.04, 0.12]\n",
        );
        assert_eq!(s.validate(), Ok(()));
        let (t, params) = s.families[0].table(&mut |_, _, hi| hi, &mut |_| 0);
        let names: Vec<&str> = params.iter().map(|(k, _)| k.as_str()).collect();
        assert_eq!(names, ["states[0].delay_s", "states[1].mean_dwell_messages", "states[1].loss"]);
        assert_eq!(t.loss_probability, None);
        let network = t.to_network(1, &mut |_| Ok(vec![])).expect("a network");
        let delay::Distribution::Regime { states } = &network.to_plant.delay else { panic!("{network:?}") };
        assert_eq!((states[0].loss_probability, states[1].loss_probability), (Some(0.002), Some(0.12)));
    }

    #[test]
    fn bad_ranges_weights_and_keys_are_refused_naming_the_field() {
        let gamma = |extra: &str| format!("[[families]]\nkind = \"gamma\"\nscale_s = 0.01\n{extra}");
        assert_eq!(field_of(&gamma("shape = [30.0, 1.0]")), "sweep.families[0].shape");
        assert_eq!(field_of(&gamma("shape = [-1.0, 1.0]")), "sweep.families[0].shape");
        assert_eq!(field_of(&gamma("shape = nan")), "sweep.families[0].shape");
        assert_eq!(field_of(&gamma("shape = [1.0, inf]")), "sweep.families[0].shape");
        assert_eq!(field_of(&gamma("shape = 2.0\nweight = -1.0")), "sweep.families[0].weight");
        assert_eq!(field_of(&gamma("shape = 2.0\nweight = 0.0")), "sweep.families");
        assert_eq!(field_of(&gamma("shape = 2.0\nmin_s = 0.1")), "sweep.families[0].min_s");
        assert_eq!(field_of("[[families]]\nkind = \"gamma\"\nshape = 2.0"), "sweep.families[0].scale_s");
        // Some draws would have min_s > max_s.
        assert_eq!(
            field_of("[[families]]\nkind = \"uniform\"\nmin_s = [0.0, 0.2]\nmax_s = [0.1, 0.3]"),
            "sweep.families[0].max_s"
        );
        assert_eq!(field_of("families = []"), "sweep.families");
        assert_eq!(field_of("runs = 0\n[[families]]\nkind = \"none\""), "sweep.runs");
        assert_eq!(field_of("max_delay_s = -1.0\n[[families]]\nkind = \"none\""), "sweep.max_delay_s");
        assert_eq!(
            field_of("[[families]]\nkind = \"none\"\n[[families]]\nkind = \"none\""),
            "sweep.families[1].name"
        );
        assert_eq!(field_of("[[families]]\nkind = \"trace\""), "sweep.families[0].kind");
        assert_eq!(field_of("[[families]]\nkind = \"traces\""), "sweep.families[0].dir");
        assert_eq!(
            field_of("[[families]]\nkind = \"traces\"\ndir = \"x\"\nshape = 1.0"),
            "sweep.families[0].shape"
        );
        assert_eq!(field_of("[[families]]\nkind = \"gammma\""), "sweep.families[0].kind");
        assert_eq!(
            field_of(
                "[[families]]\nkind = \"regime\"\n[[families.states]]\nkind = \"constant\"\ndelay_s = 0.1\nmean_dwell_s = [2.0, 1.0]"
            ),
            "sweep.families[0].states[0].mean_dwell_s"
        );
        // Unknown keys and malformed ranges are serde's, with the key named.
        let e = toml::from_str::<SweepSection>("[[families]]\nkind = \"none\"\nshap = 1.0")
            .map_err(|e| e.to_string());
        assert!(e.as_ref().is_err_and(|m| m.contains("unknown field `shap`")), "{e:?}");
        let e = toml::from_str::<SweepSection>("[[families]]\nkind = \"gamma\"\nshape = [1.0, 2.0, 3.0]")
            .map_err(|e| e.to_string());
        assert!(e.as_ref().is_err_and(|m| m.contains("[min, max]")), "{e:?}");
    }
}
