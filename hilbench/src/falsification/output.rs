//! What `hilbench falsify` writes into its directory: `falsify.json` (stable keys,
//! docs/falsify.md), `runs.csv` (every run of every search), `traces/<space>-<method>.csv` (the
//! worst run of each search, replayable with `hilbench run --delay-trace`), `report.md` and a
//! convergence plot per space.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde_json::{Value, json};

use super::{Evaluation, Falsification, FalsifyResult, SearchRecord};
use crate::output::plots::PLOTS_DIR;
use crate::output::plots::convergence::{self, Curve};

/// Folder of the worst runs' traces.
pub const TRACES_DIR: &str = "traces";

/// The version of falsify.json's keys.
pub const SCHEMA: &str = "hilbench-falsify/1";

/// The trace file of a search's worst run, relative to the output directory.
pub fn trace_file(record: &SearchRecord) -> String {
    format!("{TRACES_DIR}/{}-{}.csv", record.space, record.method.name())
}

/// The controller flown, as the outputs name it.
fn controller(f: &Falsification) -> String {
    f.controller.name().to_string()
}

/// The command that flies a trace of this falsification again.
/// The command that replays `trace` (a path below `dir`, the output directory, or
/// `<this file>`), with paths that work from wherever the falsification ran.
pub fn replay_command(f: &Falsification, dir: &Path, trace: &str) -> String {
    let trace =
        if trace == "<this file>" { trace.to_string() } else { crate::shrink::absolute(&dir.join(trace)) };
    crate::shrink::replay_command(
        &f.file.display().to_string(),
        f.controller.command(),
        f.controller.name(),
        &trace,
    )
}

/// The run with the lowest score (NaN the worst; the first on ties).
fn best(record: &SearchRecord) -> Option<&Evaluation> {
    let key = |e: &Evaluation| if e.score.is_nan() { f64::INFINITY } else { e.score };
    record.evaluations.iter().fold(None, |b: Option<&Evaluation>, e| match b {
        Some(b) if key(b) <= key(e) => Some(b),
        _ => Some(e),
    })
}

fn point_json(record: &SearchRecord, point: &[f64]) -> Value {
    Value::Object(record.dims.iter().zip(point).map(|(d, v)| (d.name.clone(), json!(v))).collect())
}

fn search_json(f: &Falsification, record: &SearchRecord, dir: &Path) -> Value {
    let r = &record.result;
    json!({
        "space": record.space,
        "method": record.method.name(),
        "dims": record.dims.iter().map(|d| json!({"name": d.name, "lo": d.lo, "hi": d.hi})).collect::<Vec<_>>(),
        "runs": record.evaluations.len(),
        "errors": record.errors(),
        "found": record.first_failure().is_some(),
        "first_failure_run": record.first_failure().map(|e| e.run),
        "best": best(record).map(|e| json!({
            "run": e.run,
            "score_m": e.score,
            "outcome": e.outcome,
            "point": point_json(record, &e.point),
        })),
        "restarts": r.restarts,
        "generations": r.generations.iter().map(|g| json!({
            "runs": g.runs,
            "batch_best_m": g.batch_best,
            "best_m": g.best,
            "step": g.step,
            "population": g.population,
            "restarts": g.restarts,
        })).collect::<Vec<_>>(),
        "worst_trace": record.worst.as_ref().map(|w| json!({
            "file": trace_file(record),
            "run": w.run,
            "score_m": w.score,
            "delays": w.trace.delays_s.len(),
            "original_delays": w.trace.original_len,
            "shrink_reruns": w.trace.shrink.map(|s| s.0),
            "shrink_complete": w.trace.shrink.map(|s| s.1),
            "replay": w.trace.replay,
            "replay_command": replay_command(f, dir, &trace_file(record)),
        })),
        "interrupted": record.interrupted,
        "wall_time_s": record.wall_time_s,
    })
}

/// `falsify.json`.
pub fn falsify_json(f: &Falsification, result: &FalsifyResult, dir: &Path) -> Value {
    let runs: usize = result.searches.iter().map(|s| s.evaluations.len()).sum();
    json!({
        "schema": SCHEMA,
        "file": f.file.display().to_string(),
        "scenario": f.scenario.name,
        "controller": controller(f),
        "controller_cmd": f.controller.command(),
        "driver": f.driver.name(),
        "property": f.property.name(),
        "budget": f.budget,
        "seed": f.seed,
        "methods": f.methods.iter().map(|m| m.name()).collect::<Vec<_>>(),
        "whole_budget": f.whole_budget,
        "warmup": f.warmup,
        "found": result.found(),
        "interrupted": result.interrupted,
        "searches": result.searches.iter().map(|s| search_json(f, s, dir)).collect::<Vec<_>>(),
        "timing": {
            "wall_time_s": result.wall_time_s,
            "runs": runs,
            "runs_per_s": runs as f64 / result.wall_time_s.max(1e-9),
            "resumed_runs": result.searches.iter().map(|s| s.resumed_runs).sum::<usize>(),
            "jobs": f.jobs,
        },
    })
}

/// `runs.csv`: every run of every search.
pub fn runs_csv(result: &FalsifyResult) -> String {
    let mut out = String::from(
        "space,method,run,score_m,outcome,cycles,min_clearance_m,end_time_s,wall_s,point,error\n",
    );
    let num = |v: Option<f64>| v.filter(|x| x.is_finite()).map_or(String::new(), |x| format!("{x}"));
    for s in &result.searches {
        for e in &s.evaluations {
            let point: Vec<String> =
                s.dims.iter().zip(&e.point).map(|(d, v)| format!("{}={v}", d.name)).collect();
            let _ = writeln!(
                out,
                "{},{},{},{},{},{},{},{},{:.3},{},\"{}\"",
                s.space,
                s.method.name(),
                e.run,
                if e.score == f64::INFINITY { "inf".to_string() } else { num(Some(e.score)) },
                e.outcome,
                e.cycles,
                num(e.min_clearance_m),
                num(e.end_time_s),
                e.wall_s,
                point.join(";"),
                e.error.replace('"', "\"\"").replace('\n', " "),
            );
        }
    }
    out
}

/// Writes the directory; returns `falsify.json`'s value.
pub fn write(dir: &Path, f: &Falsification, result: &FalsifyResult, plots: bool) -> anyhow::Result<Value> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    write_file(&dir.join("runs.csv"), &runs_csv(result))?;
    for record in &result.searches {
        let Some(worst) = &record.worst else { continue };
        let path = dir.join(trace_file(record));
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
        }
        let t = &worst.trace;
        let failed = if worst.score < 0.0 { "fails" } else { "holds" };
        let mut header = vec![
            format!(
                "hilbench falsify {} (seed {}): space {}, {}, run {} of {}",
                f.file.display(),
                f.seed,
                record.space,
                record.method.name(),
                worst.run,
                record.evaluations.len()
            ),
            format!("property {} {failed}: robustness {:.6} m", f.property.name(), worst.score),
        ];
        header.extend(t.provenance(&replay_command(f, dir, "<this file>")));
        write_file(&path, &t.to_text(&header))?;
    }
    let summary = falsify_json(f, result, dir);
    write_file(&dir.join("falsify.json"), &serde_json::to_string_pretty(&summary)?)?;
    let figures = if plots { convergence_plots(dir, f, result)? } else { Vec::new() };
    write_file(&dir.join("report.md"), &report(f, result, &figures, dir))?;
    Ok(summary)
}

/// One convergence plot per space: each method's best score against runs.
fn convergence_plots(dir: &Path, f: &Falsification, result: &FalsifyResult) -> anyhow::Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    let mut spaces: Vec<&str> = result.searches.iter().map(|s| s.space.as_str()).collect();
    spaces.dedup();
    for space in spaces {
        let curves: Vec<Curve> = result
            .searches
            .iter()
            .filter(|s| s.space == space)
            .map(|s| Curve {
                label: format!("{} ({} runs)", s.method.name(), s.evaluations.len()),
                points: s.result.generations.iter().map(|g| (g.runs as f64, g.best)).collect(),
            })
            .collect();
        let title = format!(
            "{}: {} in space {space}, property {}",
            f.scenario.name,
            controller(f),
            f.property.name()
        );
        let paths = convergence::write(
            &dir.join(PLOTS_DIR),
            &format!("falsify-convergence-{space}"),
            &title,
            &curves,
        )?;
        written.extend(paths);
    }
    Ok(written)
}

fn write_file(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// `report.md`.
fn report(f: &Falsification, result: &FalsifyResult, figures: &[PathBuf], dir: &Path) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "# hilbench falsify {}\n", f.file.display());
    let _ = writeln!(
        out,
        "Scenario `{}`, controller {}, property `{}`, budget {} runs per search, seed {}, {} in lockstep{}.\n",
        f.scenario.name,
        controller(f),
        f.property.name(),
        f.budget,
        f.seed,
        f.driver.name(),
        if result.interrupted { "; **interrupted** (Ctrl-C): what had flown is below" } else { "" }
    );
    let _ = writeln!(
        out,
        "A run's robustness is its clearance in metres, negative exactly when it fails the property \
         (docs/falsify.md). {}\n",
        if result.found() {
            "**A failing run was found**: its trace replays it (below)."
        } else {
            "No search found a failing run within its budget; the best score says how close one came."
        }
    );
    out.push_str("| space | method | runs | first failure at run | best robustness [m] | errors | worst run's trace |\n");
    out.push_str("|---|---|---|---|---|---|---|\n");
    for s in &result.searches {
        let best = best(s).map_or("-".into(), |e| format!("{:+.4} (run {}, {})", e.score, e.run, e.outcome));
        let trace = s.worst.as_ref().map_or("-".into(), |w| {
            let shrunk = match w.trace.shrink {
                Some((reruns, _)) => {
                    format!(
                        ", shrunk {} -> {} in {reruns} reruns",
                        w.trace.original_len,
                        w.trace.delays_s.len()
                    )
                }
                None => String::new(),
            };
            format!("[{}]({}) ({} delays{shrunk})", trace_file(s), trace_file(s), w.trace.delays_s.len())
        });
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {best} | {} | {trace} |",
            s.space,
            s.method.name(),
            s.evaluations.len(),
            s.first_failure().map_or("none".into(), |e| e.run.to_string()),
            s.errors(),
        );
    }
    for s in result.searches.iter().filter(|s| s.worst.is_some()) {
        if let Some(b) = best(s) {
            let point: Vec<String> =
                s.dims.iter().zip(&b.point).map(|(d, v)| format!("`{}` = {v:.4}", d.name)).collect();
            let _ = writeln!(
                out,
                "\n**{} / {}**: the worst run's point: {}.",
                s.space,
                s.method.name(),
                point.join(", ")
            );
            let _ = writeln!(out, "Replay: `{}`", replay_command(f, dir, &trace_file(s)));
        }
    }
    if !figures.is_empty() {
        out.push_str(
            "\n## Convergence\n\nThe best robustness so far against the runs flown, per method \
                      (docs/falsify.md, \"Reading a convergence plot\").\n\n",
        );
        for fig in figures.iter().filter(|p| p.extension().is_some_and(|e| e == "svg")) {
            let rel = fig.strip_prefix(dir).unwrap_or(fig);
            let _ = writeln!(out, "![convergence]({})\n", rel.display());
        }
    }
    out
}
