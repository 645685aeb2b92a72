//! Plots of the runs as PNG and SVG (plotters), drawn from the same rows as the per-cycle CSV
//! logs: per scenario, the paths of every controller seen from above and in 3D with the
//! cylinders to scale; per run, roll, pitch and thrust against time with their bounds, the
//! delays against time with their histogram and a fitted Gamma, and the scenario weights.
//!
//! Text is rendered with ab_glyph from the embedded DejaVu Sans (`assets/`, its license beside
//! it), so no system font library (fontconfig, freetype) is needed.
//!
//! One file per figure (`top.rs`, `three_d.rs`, `inputs.rs`, `delays.rs`, `weights.rs`), the
//! helpers the two path figures share (`paths.rs`), and the styling and axis helpers every
//! figure uses (`style.rs`). This file lists the figures of a set of runs and writes them.

pub mod convergence;
mod delays;
mod inputs;
pub(crate) mod paths;
pub(crate) mod style;
#[cfg(test)]
pub(crate) mod tests;
mod three_d;
mod top;
pub mod trace;
mod weights;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, anyhow};
use mav::Scenario;
use mpc::RunSummary;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::run::CycleRow;
use style::{FONT, FONT_BYTES};

pub use delays::{delays, gamma_fit};

/// Sub-directory of the output directory that holds the plots.
pub const PLOTS_DIR: &str = "plots";

/// What the plots and `report.md` show of a run's summary (a view of `RunSummary`, so that
/// they need none of its other fields).
#[derive(Debug, Clone, PartialEq)]
pub struct RunFacts {
    pub scenario: String,
    pub controller: String,
    pub reached: bool,
    pub collided: bool,
    pub time_to_goal_s: Option<f64>,
    pub path_length_m: f64,
    pub min_clearance_m: f64,
    pub cycles: u64,
    pub solve_ms_median: f64,
    pub final_position_m: [f64; 3],
    /// Where each collision happened, m.
    pub collisions_m: Vec<[f64; 3]>,
    /// Each collision in words: kind, depth, time, place.
    pub collisions_described: Vec<String>,
    pub end_reason: mpc::RunEnd,
    /// Why the run went as it did (`RunSummary::explanation`).
    pub explanation: Vec<String>,
    /// Commands the network dropped (`RunSummary::commands_lost`).
    pub commands_lost: Option<u64>,
}

impl From<&RunSummary> for RunFacts {
    fn from(r: &RunSummary) -> Self {
        Self {
            scenario: r.scenario.clone(),
            controller: r.controller.clone(),
            reached: r.reached,
            collided: r.collided,
            time_to_goal_s: r.time_to_goal_s,
            path_length_m: r.path_length_m,
            min_clearance_m: r.min_clearance_m,
            cycles: r.cycles,
            solve_ms_median: r.solve_ms_median,
            final_position_m: r.final_position_m,
            collisions_m: r.collisions.iter().map(|c| c.position_m).collect(),
            collisions_described: r.collisions.iter().map(|c| c.describe()).collect(),
            end_reason: r.end_reason,
            explanation: r.explanation.clone(),
            commands_lost: r.commands_lost,
        }
    }
}

/// One run to plot: its scenario, summary and per-cycle rows.
#[derive(Debug, Clone)]
pub struct RunData<'a> {
    pub scenario: &'a Scenario,
    pub summary: RunFacts,
    pub rows: &'a [CycleRow],
}

/// What a plot shows; `stem` names its files.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Paths of every controller of a scenario, seen from above.
    Top,
    /// The same paths in 3D.
    ThreeD,
    /// Roll, pitch and thrust of one run against time.
    Inputs,
    /// Delays of one run against time, histogram, fitted Gamma.
    Delays,
    /// Scenario weights of one run against time (multi-stage only).
    Weights,
}

impl Kind {
    pub const SCENARIO: [Kind; 2] = [Kind::Top, Kind::ThreeD];
    pub const RUN: [Kind; 3] = [Kind::Inputs, Kind::Delays, Kind::Weights];

    fn suffix(self) -> &'static str {
        match self {
            Kind::Top => "paths-top",
            Kind::ThreeD => "paths-3d",
            Kind::Inputs => "inputs",
            Kind::Delays => "delays",
            Kind::Weights => "weights",
        }
    }

    /// One phrase for report.md.
    pub fn describe(self) -> &'static str {
        match self {
            Kind::Top => "paths seen from above",
            Kind::ThreeD => "paths in 3D",
            Kind::Inputs => "roll, pitch and thrust",
            Kind::Delays => "delays",
            Kind::Weights => "scenario weights",
        }
    }
}

/// File stem (without `.png`/`.svg`) of a scenario plot (`controller` = None) or a run plot.
pub fn stem(kind: Kind, scenario: &str, controller: Option<&str>) -> String {
    match controller {
        Some(c) => format!("{scenario}-{c}-{}", kind.suffix()),
        None => format!("{scenario}-{}", kind.suffix()),
    }
}

pub(crate) fn register_font() -> anyhow::Result<()> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED
        .get_or_init(|| plotters::style::register_font(FONT, FontStyle::Normal, FONT_BYTES).is_ok());
    anyhow::ensure!(ok, "the embedded font (assets/DejaVuSans.ttf) cannot be read");
    Ok(())
}

/// Writes every plot of `runs` into `dir/plots/` (PNG and SVG of each), the figures spread over
/// the available cores; returns the paths written.
pub fn write_all(dir: &Path, runs: &[RunData<'_>]) -> anyhow::Result<Vec<PathBuf>> {
    register_font()?;
    let out = dir.join(PLOTS_DIR);
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let figures = figures(runs);
    let next = AtomicUsize::new(0);
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).clamp(1, 4);
    let results: Vec<anyhow::Result<Vec<PathBuf>>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut written = Vec::new();
                    loop {
                        let i = next.fetch_add(1, Ordering::Relaxed);
                        let Some(f) = figures.get(i) else { return Ok(written) };
                        written.extend(f.save(&out)?);
                    }
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|_| Err(anyhow!("a plotting thread panicked"))))
            .collect()
    });
    let mut written = Vec::new();
    for r in results {
        written.extend(r?);
    }
    written.sort();
    Ok(written)
}

/// The plots of the runs of `batch`.
pub fn write_batch(dir: &Path, batch: &crate::run::Batch) -> anyhow::Result<Vec<PathBuf>> {
    let runs: Vec<RunData<'_>> = batch
        .runs
        .iter()
        .map(|r| RunData { scenario: &r.job.scenario, summary: (&r.summary).into(), rows: &r.rows })
        .collect();
    write_all(dir, &runs)
}

/// The figures of `runs`: the scenario plots once per scenario (in order of first appearance),
/// then the run plots.
fn figures<'a>(runs: &'a [RunData<'a>]) -> Vec<Figure<'a>> {
    let mut scenarios: Vec<&str> = Vec::new();
    for r in runs {
        if !scenarios.contains(&r.scenario.name.as_str()) {
            scenarios.push(&r.scenario.name);
        }
    }
    let mut figures = Vec::new();
    for name in scenarios {
        let group: Vec<&'a RunData<'a>> = runs.iter().filter(|r| r.scenario.name == name).collect();
        figures.push(Figure::Top(group.clone()));
        figures.push(Figure::ThreeD(group));
    }
    for r in runs {
        figures.push(Figure::Inputs(r));
        figures.push(Figure::Delays(r));
        if r.rows.first().is_some_and(|row| row.weights.len() > 1) {
            figures.push(Figure::Weights(r));
        }
    }
    figures
}

pub(crate) type DrawResult<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

enum Figure<'a> {
    Top(Vec<&'a RunData<'a>>),
    ThreeD(Vec<&'a RunData<'a>>),
    Inputs(&'a RunData<'a>),
    Delays(&'a RunData<'a>),
    Weights(&'a RunData<'a>),
}

impl Figure<'_> {
    fn stem(&self) -> String {
        match self {
            Figure::Top(g) => stem(Kind::Top, group_name(g), None),
            Figure::ThreeD(g) => stem(Kind::ThreeD, group_name(g), None),
            Figure::Inputs(r) => stem(Kind::Inputs, &r.scenario.name, Some(&r.summary.controller)),
            Figure::Delays(r) => stem(Kind::Delays, &r.scenario.name, Some(&r.summary.controller)),
            Figure::Weights(r) => stem(Kind::Weights, &r.scenario.name, Some(&r.summary.controller)),
        }
    }

    fn size(&self) -> (u32, u32) {
        match self {
            Figure::Top(_) => (900, 900),
            Figure::ThreeD(_) => (1000, 850),
            Figure::Inputs(_) => (1100, 950),
            Figure::Delays(_) => (1300, 520),
            Figure::Weights(_) => (1100, 500),
        }
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        match self {
            Figure::Top(g) => top::draw_top(root, g),
            Figure::ThreeD(g) => three_d::draw_3d(root, g),
            Figure::Inputs(r) => inputs::draw_inputs(root, r),
            Figure::Delays(r) => delays::draw_delays(root, r),
            Figure::Weights(r) => weights::draw_weights(root, r),
        }
    }

    /// Writes `<stem>.png` and `<stem>.svg` into `dir`.
    fn save(&self, dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
        let stem = self.stem();
        let png = dir.join(format!("{stem}.png"));
        let svg = dir.join(format!("{stem}.svg"));
        {
            let root = BitMapBackend::new(&png, self.size()).into_drawing_area();
            self.draw(&root).map_err(|e| anyhow!("cannot draw {}: {e}", png.display()))?;
            root.present().map_err(|e| anyhow!("cannot write {}: {e}", png.display()))?;
        }
        let mut text = String::new();
        {
            let root = SVGBackend::with_string(&mut text, self.size()).into_drawing_area();
            self.draw(&root).map_err(|e| anyhow!("cannot draw {}: {e}", svg.display()))?;
            root.present().map_err(|e| anyhow!("cannot draw {}: {e}", svg.display()))?;
        }
        std::fs::write(&svg, text).with_context(|| format!("cannot write {}", svg.display()))?;
        Ok(vec![png, svg])
    }
}

fn group_name<'a>(group: &[&'a RunData<'a>]) -> &'a str {
    group.first().map_or("none", |r| r.scenario.name.as_str())
}
