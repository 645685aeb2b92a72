//! What a sweep writes into its directory: `sweep.json` (stable keys, docs/output.md),
//! `runs.csv`, `failures/<run>.csv`, `report.md` and the plots; and `hilbench sweep-merge`,
//! which puts shards' directories together into the directory of the whole sweep.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde_json::{Value, json};

use super::stats::{self, RunRow};
use super::{Done, Sweep, SweepResult};

/// Largest shard `sweep.json` `sweep-merge` reads, bytes (a shard's failures are listed in it).
const MAX_SWEEP_JSON_BYTES: u64 = 256 << 20;
/// Largest shard `runs.csv` `sweep-merge` reads, bytes: a million rows of about 250 bytes.
const MAX_RUNS_CSV_BYTES: u64 = 512 << 20;

/// Folder of the failures' traces.
pub const FAILURES_DIR: &str = "failures";

/// What `sweep.json` says besides the numbers of the runs.
#[derive(Debug, Clone, PartialEq)]
pub struct Meta {
    pub scenario: String,
    /// The fingerprint of the scenario and `[sweep]` table as flown (traces inline), FNV-1a
    /// over their JSON: shards of different contents are not merged.
    pub scenario_fnv1a64: String,
    pub file: String,
    pub seed: u64,
    /// Runs of the whole sweep (every shard).
    pub runs_planned: u64,
    /// `i/K`, or none for a whole sweep.
    pub shard: Option<String>,
    /// Where the shard came from: `flag` (`--shard I/K`), `slurm` or `kubernetes`
    /// (`--shard auto`); none for a whole sweep.
    pub shard_from: Option<String>,
    pub controllers: Vec<String>,
    /// The external controller's command line, when the sweep flew one.
    pub controller_cmd: Option<String>,
    pub families: Vec<String>,
    pub transport: String,
    pub shrink: bool,
}

impl Meta {
    pub fn of(sweep: &Sweep) -> Self {
        Self {
            scenario: sweep.scenario.name.clone(),
            scenario_fnv1a64: sweep.scenario_fingerprint(),
            file: sweep.file.display().to_string(),
            seed: sweep.seed,
            runs_planned: sweep.runs,
            shard: sweep.shard.map(|s| format!("{}/{}", s.index, s.count)),
            shard_from: sweep.shard.map(|s| s.from.name().to_string()),
            controllers: sweep.controller_names(),
            controller_cmd: sweep.controller_cmd().map(str::to_string),
            families: sweep.table.families.iter().map(|f| f.name().to_string()).collect(),
            transport: sweep.driver.name().to_string(),
            shrink: sweep.shrink,
        }
    }
}

/// The file name of a failure's trace: `<run>.csv`, or `<run>-<controller>.csv` when the sweep
/// flies more than one controller.
pub fn failure_file(run: u64, controller: &str, controllers: usize) -> String {
    if controllers > 1 { format!("{run}-{controller}.csv") } else { format!("{run}.csv") }
}

/// `sweep.json`: the numbers of `rows`, `failures` as given, `timing`.
pub fn sweep_json(
    meta: &Meta,
    rows: &[&RunRow],
    failures: Vec<Value>,
    interrupted: bool,
    timing: Value,
) -> Value {
    let mut v = stats::aggregate_with_families(rows, &meta.families);
    if meta.controllers.len() > 1 {
        let mut by = serde_json::Map::new();
        for c in &meta.controllers {
            let of: Vec<&RunRow> = rows.iter().copied().filter(|r| &r.controller == c).collect();
            by.insert(c.clone(), stats::aggregate_with_families(&of, &meta.families));
        }
        v["by_controller"] = Value::Object(by);
    }
    v["failures"] = Value::Array(failures);
    v["scenario"] = json!(meta.scenario);
    v["scenario_fnv1a64"] = json!(meta.scenario_fnv1a64);
    v["file"] = json!(meta.file);
    v["seed"] = json!(meta.seed);
    v["runs_planned"] = json!(meta.runs_planned);
    v["shard"] = json!(meta.shard);
    v["shard_from"] = json!(meta.shard_from);
    v["controllers"] = json!(meta.controllers);
    v["controller_cmd"] = json!(meta.controller_cmd);
    v["family_order"] = json!(meta.families);
    v["transport"] = json!(meta.transport);
    v["time_mode"] = json!("lockstep");
    v["shrink"] = json!(meta.shrink);
    v["interrupted"] = json!(interrupted);
    // `--shrink`'s spending: set by the sweep that shrank.
    v["shrinking"] = Value::Null;
    v["timing"] = timing;
    v["hilbench_version"] = json!(env!("CARGO_PKG_VERSION"));
    v["hilbench_commit"] = json!(env!("HILBENCH_COMMIT"));
    v
}

/// One entry of `failures`.
fn failure_json(d: &Done, meta: &Meta) -> Value {
    let r = &d.row;
    let file = d
        .failure
        .as_ref()
        .map(|_| format!("{FAILURES_DIR}/{}", failure_file(r.run, &r.controller, meta.controllers.len())));
    let f = d.failure.as_ref();
    json!({
        "run": r.run,
        "controller": r.controller,
        "family": r.family,
        "parameters": r.params,
        "outcome": r.outcome,
        "what": r.what,
        "time_s": r.fail_time_s,
        "position_m": r.fail_position_m,
        "trace_file": file,
        "trace_delays": f.map(|f| f.delays_s.len()),
        "flown_delays": f.map(|f| f.original_len),
        "shrink": f.and_then(|f| f.shrink).map(|(reruns, complete)| json!({"reruns": reruns, "complete": complete})),
        "replay": f.and_then(|f| f.replay.as_ref()),
    })
}

/// Writes the directory of a finished (or interrupted) sweep; returns `sweep.json`'s value.
pub fn write(dir: &Path, sweep: &Sweep, result: &SweepResult, plots: bool) -> anyhow::Result<Value> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let meta = Meta::of(sweep);
    let rows: Vec<&RunRow> = result.done.iter().map(|d| &d.row).collect();
    write_file(&dir.join("runs.csv"), &stats::to_csv(&rows))?;
    let mut failures = Vec::new();
    for d in result.done.iter().filter(|d| d.row.failed()) {
        if let Some(f) = &d.failure {
            let folder = dir.join(FAILURES_DIR);
            std::fs::create_dir_all(&folder)
                .with_context(|| format!("cannot create {}", folder.display()))?;
            let r = &d.row;
            let controllers = meta.controllers.len();
            let mut header = vec![
                format!(
                    "hilbench sweep {} (seed {}): run {} with {}",
                    meta.file, meta.seed, r.run, r.controller
                ),
                format!("family {} ({}): {}", r.family, r.params, r.what),
            ];
            header.extend(f.provenance(&crate::shrink::replay_command(
                &meta.file,
                meta.controller_cmd.as_deref(),
                &r.controller,
                "<this file>",
            )));
            write_file(&folder.join(failure_file(r.run, &r.controller, controllers)), &f.to_text(&header))?;
        }
        failures.push(failure_json(d, &meta));
    }
    let run_wall_s = crate::run::total(rows.iter().map(|r| r.wall_s));
    let solver_s = crate::run::total(rows.iter().filter_map(|r| r.solver_s));
    // After --resume, the runs taken from the journal were flown by another process.
    let flown_here = rows.len().saturating_sub(sweep.finished.len());
    let timing = json!({
        "wall_time_s": result.wall_time_s,
        "runs_per_s": flown_here as f64 / result.wall_time_s.max(1e-9),
        "resumed_runs": sweep.finished.len(),
        "jobs": sweep.jobs,
        "run_wall_s": run_wall_s,
        "solver_s": solver_s,
    });
    let mut summary = sweep_json(&meta, &rows, failures, result.interrupted, timing);
    if let Some(until) = &result.until_bound {
        summary["until_bound"] = until.clone();
    }
    summary["shrinking"] = json!(result.shrinking);
    finish(dir, &meta, &rows, &summary, &sweep.scenario, plots)?;
    Ok(summary)
}

/// `sweep.json`, `report.md` and the plots of `rows`.
fn finish(
    dir: &Path,
    meta: &Meta,
    rows: &[&RunRow],
    summary: &Value,
    scenario: &mav::Scenario,
    plots: bool,
) -> anyhow::Result<()> {
    write_file(&dir.join("sweep.json"), &serde_json::to_string_pretty(summary)?)?;
    let figures = if plots {
        super::plots::write(dir, scenario, rows, &meta.families, &meta.controllers)?
    } else {
        Vec::new()
    };
    write_file(&dir.join("report.md"), &report(meta, summary, rows, &figures, dir))?;
    Ok(())
}

fn write_file(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// `report.md`: the numbers of each controller in a section of its own when the sweep flew
/// several (`terminal::sweep_sections`), never pooled.
fn report(meta: &Meta, v: &Value, rows: &[&RunRow], figures: &[PathBuf], dir: &Path) -> String {
    use crate::output::terminal::{failure_text, sweep_runs, sweep_sections};
    let mut out = String::new();
    let f = |x: &Value| x.as_f64().map_or_else(|| "-".to_string(), |x| format!("{x:.3}"));
    let _ = writeln!(out, "# hilbench sweep {}\n", meta.file);
    let shard = meta.shard.as_ref().map(|s| format!(", shard {s}")).unwrap_or_default();
    let sections = sweep_sections(v);
    let controllers = if sections.len() > 1 {
        format!("each flown by every controller ({}: {} flights)", meta.controllers.join(", "), rows.len())
    } else {
        format!("controller {}", meta.controllers.join(", "))
    };
    let _ = writeln!(
        out,
        "Scenario `{}`, {} of {} runs{shard}, seed {}, {controllers}, {} in lockstep{}.\n",
        meta.scenario,
        sweep_runs(v),
        meta.runs_planned,
        meta.seed,
        meta.transport,
        if v["interrupted"] == true { " (interrupted: what had finished)" } else { "" }
    );
    let line = |name: &str, a: &Value| {
        format!(
            "| {name} | {} | {} | {} | {} | {} | {} | {} | {} / {} / {} | {} / {} | {} / {} |",
            a["runs"],
            a["reached"],
            a["collided"],
            a["collided_ground"],
            a["missed"],
            a["errors"],
            a["best_effort_cycles"],
            f(&a["min_clearance_m"]["p1"]),
            f(&a["min_clearance_m"]["p5"]),
            f(&a["min_clearance_m"]["p50"]),
            f(&a["path_length_m"]["p50"]),
            f(&a["path_length_m"]["p95"]),
            f(&a["time_to_goal_s"]["p50"]),
            f(&a["time_to_goal_s"]["p95"]),
        )
    };
    for (controller, a) in &sections {
        if let Some(c) = controller {
            let _ = writeln!(
                out,
                "## {} (`{c}`): {} runs, {} reached, {} collided, {} missed, {}{} errors\n",
                crate::output::plots::style::controller_label(c),
                a["runs"],
                a["reached"],
                a["collided"],
                a["missed"],
                crate::output::terminal::aborted_text(a),
                a["errors"]
            );
        }
        let _ = writeln!(
            out,
            "| family | runs | reached | collided | of which ground | missed | errors | best-effort cycles | clearance p1 / p5 / p50 [m] | path p50 / p95 [m] | time to goal p50 / p95 [s] |"
        );
        let _ = writeln!(out, "|---|---|---|---|---|---|---|---|---|---|---|");
        for name in &meta.families {
            let _ = writeln!(out, "{}", line(name, &a["families"][name]));
        }
        let _ = writeln!(out, "{}\n", line("**all**", a));
        let _ = writeln!(
            out,
            "How sure (two-sided Clopper-Pearson intervals at {:.0} %, from the runs that flew):\n",
            100.0 * stats::CONFIDENCE
        );
        for (name, x) in meta.families.iter().map(|n| (n.as_str(), &a["families"][n])).chain([("all", *a)]) {
            let p = &x["failure_probability"];
            let _ = writeln!(
                out,
                "- {name}: {}; {}; {}",
                failure_text("collisions", &p["collision"]),
                failure_text("missed goals", &p["missed"]),
                failure_text("any failure", &p["any"])
            );
            if x["aborted"].as_u64().is_some_and(|n| n > 0) {
                let _ = writeln!(out, "  - {}", failure_text("runs the controller stopped", &p["aborted"]));
            }
        }
        let _ = writeln!(out);
        if v["controller_cmd"].is_string() {
            let _ = writeln!(
                out,
                "Solve time: the external controller's own, not seen (the bench sees its commands).\n"
            );
        } else {
            let _ = writeln!(
                out,
                "Solve time (ms, over runs): median of the runs' medians {}, 99th percentile of their 99th percentiles {}, max {}.\n",
                f(&a["solve_ms"]["p50"]),
                f(&a["solve_ms"]["p99"]),
                f(&a["solve_ms"]["max"])
            );
        }
    }
    let failures = v["failures"].as_array().cloned().unwrap_or_default();
    if !failures.is_empty() {
        let _ = writeln!(out, "## Failures\n");
        for x in failures.iter().take(200) {
            let trace = x["trace_file"].as_str().map(|t| format!(" ([trace]({t}))")).unwrap_or_default();
            let _ = writeln!(
                out,
                "- run {} ({}, {} {}): {}: {}{trace}",
                x["run"],
                x["controller"].as_str().unwrap_or(""),
                x["family"].as_str().unwrap_or(""),
                x["parameters"].as_str().unwrap_or(""),
                x["outcome"].as_str().unwrap_or(""),
                x["what"].as_str().unwrap_or("")
            );
        }
        if failures.len() > 200 {
            let _ = writeln!(out, "- ... and {} more (sweep.json)", failures.len() - 200);
        }
        let _ = writeln!(out);
    }
    let pngs: Vec<&PathBuf> = figures.iter().filter(|p| p.extension().is_some_and(|e| e == "png")).collect();
    if !pngs.is_empty() {
        let _ = writeln!(out, "## Plots\n");
        for p in pngs {
            let rel = p.strip_prefix(dir).unwrap_or(p);
            let _ = writeln!(out, "![{}]({})\n", rel.display(), rel.display());
        }
    }
    let _ = writeln!(
        out,
        "Every run is a line of [runs.csv](runs.csv); the numbers are in [sweep.json](sweep.json)."
    );
    out
}

/// The shards of a sweep, read and checked by [`read_shards`]: nothing written yet.
#[derive(Debug)]
pub struct Shards {
    meta: Meta,
    rows: Vec<RunRow>,
    /// Each failure of `sweep.json` with the trace it names, read from its shard.
    failures: Vec<(Value, Option<String>)>,
    interrupted: bool,
    shrinkings: Vec<Value>,
    run_wall_s: f64,
    solver_s: f64,
    count: usize,
}

/// `hilbench sweep-merge`'s first half: every shard's `sweep.json`, `runs.csv` and failure
/// traces read and checked, writing nothing, so that a refused merge leaves no trace. The
/// shards must come from the same scenario as flown (its contents' fingerprint), seed and
/// number of runs, no (run, controller) may be in two of them, and each shard's failures must
/// be the runs its `runs.csv` says did not reach the goal, with the same outcomes.
pub fn read_shards(dirs: &[PathBuf]) -> anyhow::Result<Shards> {
    anyhow::ensure!(!dirs.is_empty(), "sweep-merge: no shard directory given");
    let mut rows = Vec::new();
    let mut failures = Vec::new();
    let mut meta: Option<Meta> = None;
    let mut interrupted = false;
    let mut shrinkings = Vec::new();
    let (mut run_wall_s, mut solver_s) = (0.0, 0.0);
    for dir in dirs {
        anyhow::ensure!(
            !crate::output::out_dir::unfinished(dir),
            "{}: its sweep did not finish (killed, or still running): give its command again with --resume \
             to fly the runs it lacks, then merge",
            dir.display()
        );
        let path = dir.join("sweep.json");
        let text = hilbench_scenario_file::user_file::read_text(
            &path,
            MAX_SWEEP_JSON_BYTES,
            "a sweep's sweep.json",
        )?;
        let v: Value =
            serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
        let strings = |key: &str| -> Vec<String> {
            v[key].as_array().into_iter().flatten().filter_map(|s| s.as_str().map(String::from)).collect()
        };
        let this = Meta {
            scenario: v["scenario"].as_str().unwrap_or_default().to_string(),
            scenario_fnv1a64: v["scenario_fnv1a64"]
                .as_str()
                .with_context(|| {
                    format!(
                        "{}: no `scenario_fnv1a64` (the fingerprint of the scenario it flew): a shard of an \
                         older hilbench; fly it again with this one",
                        path.display()
                    )
                })?
                .to_string(),
            file: v["file"].as_str().unwrap_or_default().to_string(),
            seed: v["seed"].as_u64().with_context(|| format!("{}: no `seed`", path.display()))?,
            runs_planned: v["runs_planned"]
                .as_u64()
                .with_context(|| format!("{}: no `runs_planned`", path.display()))?,
            shard: None,
            shard_from: None,
            controllers: strings("controllers"),
            controller_cmd: v["controller_cmd"].as_str().map(String::from),
            families: strings("family_order"),
            transport: v["transport"].as_str().unwrap_or_default().to_string(),
            shrink: v["shrink"] == true,
        };
        match &meta {
            None => meta = Some(this),
            Some(m) if m.scenario_fnv1a64 != this.scenario_fnv1a64 => anyhow::bail!(
                "{}: flew another scenario than {} (scenario_fnv1a64 {} against {}: the file's contents, \
                 its [sweep] table or a trace it reads changed between the shards); fly every shard from \
                 the same file",
                path.display(),
                dirs[0].display(),
                this.scenario_fnv1a64,
                m.scenario_fnv1a64
            ),
            Some(m) => anyhow::ensure!(
                *m == this,
                "{}: another sweep than {} (file, seed, runs, controllers, families, transport and --shrink must agree)",
                path.display(),
                dirs[0].display()
            ),
        }
        interrupted |= v["interrupted"] == true;
        shrinkings.push(v["shrinking"].clone());
        run_wall_s += v["timing"]["run_wall_s"].as_f64().unwrap_or(0.0);
        solver_s += v["timing"]["solver_s"].as_f64().unwrap_or(0.0);
        let csv_path = dir.join("runs.csv");
        let csv = hilbench_scenario_file::user_file::read_text(
            &csv_path,
            MAX_RUNS_CSV_BYTES,
            "a sweep's runs.csv",
        )?;
        let shard_rows = stats::from_csv(&csv).map_err(|e| anyhow::anyhow!("{}: {e}", csv_path.display()))?;
        let listed = v["failures"].as_array().cloned().unwrap_or_default();
        check_failures_agree(&listed, &shard_rows).map_err(|e| {
            anyhow::anyhow!(
                "{}: {e} (runs.csv and sweep.json disagree: was one of them edited?)",
                dir.display()
            )
        })?;
        rows.extend(shard_rows);
        for failure in listed {
            let trace = match failure["trace_file"].as_str() {
                Some(trace) => {
                    anyhow::ensure!(
                        is_failure_trace(trace),
                        "{}: trace_file {trace:?} is not {FAILURES_DIR}/<file> (a shard's failures are copied \
                         from its {FAILURES_DIR}/ only)",
                        path.display()
                    );
                    // Read as every user file is: a FIFO or a device is refused, not waited on.
                    Some(hilbench_scenario_file::user_file::read_text(
                        &dir.join(trace),
                        hilbench_scenario_file::user_file::MAX_TRACE_FILE_BYTES,
                        "a shard's failure trace",
                    )?)
                }
                None => None,
            };
            failures.push((failure, trace));
        }
    }
    let meta = meta.context("sweep-merge: no shard")?;
    // An interrupted shard flew part of its runs: the merge is of what finished, interrupted.
    let rows = stats::merge_rows(rows, &meta.controllers, meta.runs_planned, interrupted)
        .map_err(|e| anyhow::anyhow!("sweep-merge: {e}"))?;
    Ok(Shards { meta, rows, failures, interrupted, shrinkings, run_wall_s, solver_s, count: dirs.len() })
}

/// Whether a shard's `failures` (from `sweep.json`) are exactly its rows that did not reach the
/// goal, with the same outcomes.
fn check_failures_agree(listed: &[Value], rows: &[RunRow]) -> Result<(), String> {
    let from_csv: std::collections::BTreeMap<(u64, &str), &str> = rows
        .iter()
        .filter(|r| r.failed())
        .map(|r| ((r.run, r.controller.as_str()), r.outcome.name()))
        .collect();
    let mut from_json = std::collections::BTreeMap::new();
    for f in listed {
        let run = f["run"].as_u64().ok_or("a failure without `run`")?;
        let controller = f["controller"].as_str().ok_or("a failure without `controller`")?;
        let outcome = f["outcome"].as_str().ok_or("a failure without `outcome`")?;
        from_json.insert((run, controller), outcome);
    }
    for (key, outcome) in &from_json {
        match from_csv.get(key) {
            None => {
                return Err(format!(
                    "run {} ({}) is a failure ({outcome}) in sweep.json but not in runs.csv",
                    key.0, key.1
                ));
            }
            Some(row) if row != outcome => {
                return Err(format!(
                    "run {} ({}) is {outcome} in sweep.json but {row} in runs.csv",
                    key.0, key.1
                ));
            }
            Some(_) => {}
        }
    }
    if let Some((key, outcome)) = from_csv.iter().find(|(k, _)| !from_json.contains_key(*k)) {
        return Err(format!(
            "run {} ({}) is a failure ({outcome}) in runs.csv but not listed in sweep.json",
            key.0, key.1
        ));
    }
    Ok(())
}

/// `hilbench sweep-merge`'s second half: the shards' `runs.csv`, failures and traces into
/// `out` (claimed by the caller), and the `sweep.json` of the whole.
pub fn write_merged(shards: Shards, out: &Path, plots: bool) -> anyhow::Result<Value> {
    let Shards { meta, rows, failures, interrupted, shrinkings, run_wall_s, solver_s, count } = shards;
    let mut listed = Vec::with_capacity(failures.len());
    for (failure, trace) in failures {
        if let (Some(name), Some(text)) = (failure["trace_file"].as_str(), trace) {
            let to = out.join(name);
            if let Some(parent) = to.parent() {
                std::fs::create_dir_all(parent)
                    .with_context(|| format!("cannot create {}", parent.display()))?;
            }
            write_file(&to, &text)?;
        }
        listed.push(failure);
    }
    let mut failures = listed;
    let order = |c: &str| meta.controllers.iter().position(|x| x == c).unwrap_or(usize::MAX);
    failures.sort_by_key(|f| {
        (f["run"].as_u64().unwrap_or(u64::MAX), order(f["controller"].as_str().unwrap_or("")))
    });
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let refs: Vec<&RunRow> = rows.iter().collect();
    write_file(&out.join("runs.csv"), &stats::to_csv(&refs))?;
    let timing = json!({ "shards": count, "run_wall_s": run_wall_s, "solver_s": solver_s });
    let mut summary = sweep_json(&meta, &refs, failures, interrupted, timing);
    summary["shrinking"] = merged_shrinking(&shrinkings);
    let scenario = crate::scenario_file::ScenarioFile::load(Path::new(&meta.file)).map(|f| f.scenario).ok();
    match scenario {
        Some(s) => finish(out, &meta, &refs, &summary, &s, plots)?,
        // The scenario file is elsewhere: no top view of the failures.
        None => finish_without_scenario(out, &meta, &refs, &summary)?,
    }
    Ok(summary)
}

/// A failure's `trace_file` as a sweep writes it: `failures/<file>`, one plain name below
/// [`FAILURES_DIR`]. A shard's sweep.json is input to `sweep-merge`: `../../x` there copied a
/// file from outside the shard to outside `--out`.
fn is_failure_trace(trace: &str) -> bool {
    use std::path::Component;
    let mut parts = Path::new(trace).components();
    matches!(parts.next(), Some(Component::Normal(d)) if d == FAILURES_DIR)
        && matches!(parts.next(), Some(Component::Normal(_)))
        && parts.next().is_none()
}

fn finish_without_scenario(dir: &Path, meta: &Meta, rows: &[&RunRow], summary: &Value) -> anyhow::Result<()> {
    write_file(&dir.join("sweep.json"), &serde_json::to_string_pretty(summary)?)?;
    write_file(&dir.join("report.md"), &report(meta, summary, rows, &[], dir))
}

/// The shards' `shrinking` added up (each shard spends its own budget): null when none shrank.
fn merged_shrinking(shards: &[Value]) -> Value {
    let shrank: Vec<&Value> = shards.iter().filter(|v| v.is_object()).collect();
    let Some(first) = shrank.first() else { return Value::Null };
    let sum = |key: &str| shrank.iter().filter_map(|v| v[key].as_u64()).sum::<u64>();
    json!({
        "failures": sum("failures"),
        "shrunk": sum("shrunk"),
        "reruns": sum("reruns"),
        "per_failure_budget": first["per_failure_budget"],
        "total_budget": first["total_budget"],
        "wall_time_s": shrank.iter().filter_map(|v| v["wall_time_s"].as_f64()).sum::<f64>(),
        "interrupted": shrank.iter().any(|v| v["interrupted"] == true),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sweep_merge_copies_a_failure_trace_only_from_below_failures() {
        assert!(is_failure_trace("failures/3.csv"));
        assert!(is_failure_trace("failures/12-multistage.csv"));
        for bad in [
            "../../escape.csv",
            "failures/../../x.csv",
            "/etc/passwd",
            "failures",
            "failures/a/b.csv",
            "x/3.csv",
            "",
        ] {
            assert!(!is_failure_trace(bad), "{bad:?}");
        }
    }
}
