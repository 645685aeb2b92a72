//! Everything a command writes from its runs: `summary.json` ([`summary`]), the per-cycle CSV
//! logs ([`cycle_log`]), MCAP files and the live Foxglove view ([`foxglove`]), the paper's
//! tables and verdicts ([`paper`]), `report.md` ([`report`]), plots ([`plots`]) and the
//! terminal's tables ([`terminal`]). [`write`] is the one pipeline of `reproduce` and `run`.
//! Outputs read the runs (`crate::run`, `crate::run::Batch`) and never fly one.

pub mod cycle_log;
pub mod foxglove;
pub mod journal;
pub mod out_dir;
pub mod paper;
pub mod plots;
pub mod report;
pub mod summary;
pub mod terminal;

use std::path::Path;
use std::time::Instant;

use anyhow::Context;

use crate::run::Batch;
use crate::run::Job;
use crate::scenario_file::ScenarioFile;

/// What to write besides the summary and the logs.
#[derive(Debug, Clone, Copy)]
pub struct Outputs {
    pub plots: bool,
    pub mcap: bool,
    /// Progress on the terminal (neither `--json` nor `--quiet`).
    pub show: bool,
}

/// What `report.md` says besides the runs.
#[derive(Debug, Clone)]
pub struct ReportParts {
    pub title: String,
    pub header: String,
    pub tables: Option<String>,
    pub verdicts: Vec<String>,
}

/// Writes the outputs of `batch` (the runs of `jobs`) into `dir`: the scenarios as flown, the
/// MCAP files, `summary.json` and the per-cycle logs always (what finished is kept after an
/// error or Ctrl-C); the plots and `report.md` when every run finished. Returns the summary.
pub fn write(
    dir: &Path,
    jobs: &[Job],
    batch: &Batch,
    outputs: Outputs,
    report: impl FnOnce(&Batch) -> ReportParts,
) -> anyhow::Result<serde_json::Value> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    write_scenarios(dir, jobs)?;
    let mut times = summary::OutputTimes::default();
    // Timed for the summary (BENCHMARKS.md: its share of the wall time).
    if outputs.mcap {
        let writing = Instant::now();
        foxglove::write_batch(dir, batch)?;
        times.mcap_s = Some(writing.elapsed().as_secs_f64());
    }
    let complete = !batch.interrupted && batch.error.is_none();
    if complete && outputs.plots {
        let plotting = Instant::now();
        let bar = crate::progress::bar(1, "plot sets", outputs.show);
        bar.set_message("drawing the plots");
        plots::write_batch(dir, batch)?;
        bar.finish_and_clear();
        times.plotting_s = Some(plotting.elapsed().as_secs_f64());
    }
    let typed = summary::summary_json(batch, times);
    summary::write(dir, &typed)?;
    let summary = serde_json::to_value(&typed)?;
    cycle_log::write_batch(dir, batch)?;
    if complete {
        let parts = report(batch);
        let text = report::ReportText {
            title: &parts.title,
            header: &parts.header,
            tables: parts.tables.as_deref(),
            verdicts: &parts.verdicts,
        };
        let facts: Vec<_> = batch.runs.iter().map(|r| plots::RunFacts::from(&r.summary)).collect();
        report::write(dir, &text, &facts, batch.driver, &summary)?;
    }
    Ok(summary)
}

/// Writes each scenario of `jobs` as flown (seed, delay trace and every override applied, trace
/// delays inline) to `dir/<name>.scenario.toml`: a scenario file `hilbench run` takes back.
pub fn write_scenarios(dir: &Path, jobs: &[Job]) -> anyhow::Result<()> {
    let mut written: Vec<&str> = Vec::new();
    for job in jobs {
        let scenario = &job.scenario;
        if written.contains(&scenario.name.as_str()) {
            continue;
        }
        written.push(&scenario.name);
        // `run.modes` needs a mode: an external controller's file names multistage there.
        let modes = jobs
            .iter()
            .filter(|j| j.scenario.name == scenario.name)
            .map(|j| j.controller.mode().unwrap_or(mpc::ControllerMode::Multistage))
            .collect();
        let path = dir.join(format!("{}.scenario.toml", scenario.name));
        let text = ScenarioFile::as_flown(scenario, modes).map_err(anyhow::Error::msg)?;
        std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}
