//! Plots of the runs as PNG and SVG (plotters), drawn from the same rows as the per-cycle CSV
//! logs: per scenario, the paths of every controller seen from above and in 3D with the
//! cylinders to scale; per run, roll, pitch and thrust against time with their bounds, the
//! delays against time with their histogram and a fitted Gamma, and the scenario weights.
//!
//! Text is rendered with ab_glyph from the embedded DejaVu Sans (`assets/`, its license beside
//! it), so no system font library (fontconfig, freetype) is needed.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, anyhow};
use mav::Scenario;
use mav::scenario::DelayModel;
use mpc::closed_loop::RunSummary;
use plotters::coord::Shift;
use plotters::prelude::*;
use statrs::distribution::{Continuous, Gamma};

use crate::cycle_log::CycleRow;

/// Sub-directory of the output directory that holds the plots.
pub const PLOTS_DIR: &str = "plots";

const FONT: &str = "sans-serif";
const FONT_BYTES: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

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

fn register_font() -> anyhow::Result<()> {
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

/// The plots of `outcome`, whose runs are those of `jobs` in order (as [`crate::bench::run_all`]
/// returns them).
pub fn write_outcome(
    dir: &Path,
    jobs: &[crate::bench::Job],
    outcome: &crate::bench::Outcome,
) -> anyhow::Result<Vec<PathBuf>> {
    anyhow::ensure!(
        jobs.len() == outcome.runs.len() && jobs.len() == outcome.cycles.len(),
        "{} jobs for {} runs",
        jobs.len(),
        outcome.runs.len()
    );
    let runs: Vec<RunData<'_>> = jobs
        .iter()
        .zip(&outcome.runs)
        .zip(&outcome.cycles)
        .map(|(((scenario, _), summary), rows)| RunData { scenario, summary: summary.into(), rows })
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

type DrawResult<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

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
            Figure::Top(g) => draw_top(root, g),
            Figure::ThreeD(g) => draw_3d(root, g),
            Figure::Inputs(r) => draw_inputs(root, r),
            Figure::Delays(r) => draw_delays(root, r),
            Figure::Weights(r) => draw_weights(root, r),
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

// ---- styling ----

const TITLE_PX: u32 = 26;
const LABEL_PX: u32 = 18;
const TICK_PX: u32 = 15;
const BOUND: RGBColor = RGBColor(200, 30, 30);
const CYLINDER: RGBColor = RGBColor(120, 120, 120);
const PALETTE: [RGBColor; 6] = [
    RGBColor(27, 110, 180),
    RGBColor(217, 95, 2),
    RGBColor(27, 158, 119),
    RGBColor(117, 112, 179),
    RGBColor(231, 41, 138),
    RGBColor(102, 102, 102),
];

fn controller_color(controller: &str, i: usize) -> RGBColor {
    match controller {
        "multistage" => PALETTE[0],
        "nmpc" => PALETTE[1],
        _ => PALETTE[(i + 2) % PALETTE.len()],
    }
}

fn controller_label(controller: &str) -> &str {
    match controller {
        "multistage" => "multi-stage NMPC",
        "nmpc" => "standard NMPC",
        other => other,
    }
}

fn title_font() -> TextStyle<'static> {
    (FONT, TITLE_PX).into_font().color(&BLACK)
}

fn panel_font() -> TextStyle<'static> {
    (FONT, LABEL_PX + 2).into_font().color(&BLACK)
}

/// Finite `(min, max)` of `values`, or `fallback` when there is none.
/// The range of horizontal coordinate `axis` (0: x, 1: y) that shows the paths, every
/// cylinder whole, the start and the goal.
fn horizontal_extent(paths: &[Vec<[f64; 3]>], scenario: &Scenario, axis: usize) -> (f64, f64) {
    let centre = |c: &mav::Cylinder| if axis == 0 { c.x_m } else { c.y_m };
    let values = paths
        .iter()
        .flatten()
        .map(|p| p[axis])
        .chain(scenario.obstacles.iter().flat_map(|c| [centre(c) - c.radius_m, centre(c) + c.radius_m]))
        .chain([scenario.start[axis], scenario.goal_m[axis]]);
    extent(values, (-1.0, 1.0))
}

fn extent(values: impl Iterator<Item = f64>, fallback: (f64, f64)) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo.is_finite() && hi.is_finite() { (lo, hi) } else { fallback }
}

/// Widens `(lo, hi)` by `frac` of its span (at least `min_pad`).
fn pad((lo, hi): (f64, f64), frac: f64, min_pad: f64) -> std::ops::Range<f64> {
    let p = ((hi - lo) * frac).max(min_pad);
    (lo - p)..(hi + p)
}

/// The vehicle's positions at the start of every cycle, then where it ended.
fn path(r: &RunData<'_>) -> Vec<[f64; 3]> {
    r.rows
        .iter()
        .map(|row| [row.state[0], row.state[1], row.state[2]])
        .chain(std::iter::once(r.summary.final_position_m))
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .collect()
}

fn circle(x: f64, y: f64, r: f64) -> Vec<(f64, f64)> {
    const SEGMENTS: usize = 72;
    (0..=SEGMENTS)
        .map(|i| {
            let a = i as f64 / SEGMENTS as f64 * std::f64::consts::TAU;
            (x + r * a.cos(), y + r * a.sin())
        })
        .collect()
}

fn path_label(r: &RunData<'_>) -> String {
    let s = &r.summary;
    let outcome = match (s.reached, s.time_to_goal_s) {
        (true, Some(t)) => format!("reached in {t:.1} s"),
        _ => "not reached".to_string(),
    };
    let collided = if s.collided { ", COLLIDED" } else { "" };
    format!(
        "{}: {:.2} m, {outcome}, min clearance {:+.2} m{collided}",
        controller_label(&s.controller),
        s.path_length_m,
        s.min_clearance_m
    )
}

// ---- the figures ----

fn draw_top<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, group: &[&RunData<'_>]) -> DrawResult<DB> {
    let Some(first) = group.first() else { return Ok(()) };
    let scenario = first.scenario;
    let root = root.titled(&format!("{}: paths seen from above", scenario.name), title_font())?;
    // The legend goes under the chart, where it hides no path.
    let legend_h = 30 * (group.len() as u32 + 1) + 20;
    let (_, h) = root.dim_in_pixel();
    let (root, legend_area) = root.split_vertically(h.saturating_sub(legend_h));
    let paths: Vec<Vec<[f64; 3]>> = group.iter().map(|r| path(r)).collect();
    let x = pad(horizontal_extent(&paths, scenario, 0), 0.05, 0.5);
    let y = pad(horizontal_extent(&paths, scenario, 1), 0.05, 0.5);
    // Equal aspect: widen the shorter range to the plotting area's proportions.
    fn builder<'a, 'b, DB: DrawingBackend>(area: &'a DrawingArea<DB, Shift>) -> ChartBuilder<'a, 'b, DB> {
        let mut b = ChartBuilder::on(area);
        b.margin(15).margin_right(25).x_label_area_size(50).y_label_area_size(60);
        b
    }
    let (pw, ph) = builder(&root).build_cartesian_2d(0.0..1.0, 0.0..1.0)?.plotting_area().dim_in_pixel();
    let (pw, ph) = (f64::from(pw.max(1)), f64::from(ph.max(1)));
    let m_per_px = ((x.end - x.start) / pw).max((y.end - y.start) / ph);
    let (cx, cy) = ((x.start + x.end) / 2.0, (y.start + y.end) / 2.0);
    let (hw, hh) = (m_per_px * pw / 2.0, m_per_px * ph / 2.0);
    let mut chart = builder(&root).build_cartesian_2d((cx - hw)..(cx + hw), (cy - hh)..(cy + hh))?;
    chart
        .configure_mesh()
        .x_desc("x [m]")
        .y_desc("y [m]")
        .axis_desc_style((FONT, LABEL_PX))
        .label_style((FONT, TICK_PX))
        .light_line_style(BLACK.mix(0.05))
        .bold_line_style(BLACK.mix(0.15))
        .draw()?;
    for c in &scenario.obstacles {
        let outline = circle(c.x_m, c.y_m, c.radius_m);
        chart.draw_series([Polygon::new(outline.clone(), CYLINDER.mix(0.35).filled())])?;
        chart.draw_series([PathElement::new(outline, CYLINDER.stroke_width(1))])?;
    }
    let mut wide = Vec::new();
    for (i, (r, p)) in group.iter().zip(&paths).enumerate() {
        let color = controller_color(&r.summary.controller, i);
        chart.draw_series(LineSeries::new(p.iter().map(|q| (q[0], q[1])), color.stroke_width(3)))?;
        wide.push((Swatch::Line(color), path_label(r)));
    }
    let start = (scenario.start[0], scenario.start[1]);
    chart.draw_series([Circle::new(start, 7, GREEN.mix(0.9).filled())])?;
    let goal = (scenario.goal_m[0], scenario.goal_m[1]);
    chart.draw_series([Cross::new(goal, 8, BLACK.stroke_width(3))])?;
    let collisions: Vec<(f64, f64)> =
        group.iter().flat_map(|r| r.summary.collisions_m.iter().map(|c| (c[0], c[1]))).collect();
    let mut narrow = vec![
        (Swatch::Fill(CYLINDER.mix(0.35)), "cylinder (to scale)".to_string()),
        (Swatch::Dot(GREEN), "start".to_string()),
        (Swatch::Cross, "goal".to_string()),
    ];
    if !collisions.is_empty() {
        chart.draw_series(collisions.into_iter().map(|p| TriangleMarker::new(p, 9, BOUND.filled())))?;
        narrow.push((Swatch::Triangle(BOUND), "collision".to_string()));
    }
    draw_legend(&legend_area, &wide, &narrow)
}

/// The sample drawn before a legend entry.
enum Swatch {
    Line(RGBColor),
    Fill(RGBAColor),
    Dot(RGBColor),
    Cross,
    Triangle(RGBColor),
}

/// A legend in its own area: `wide` entries one per line, then `narrow` ones side by side.
fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    wide: &[(Swatch, String)],
    narrow: &[(Swatch, String)],
) -> DrawResult<DB> {
    let font = (FONT, LABEL_PX).into_font().color(&BLACK);
    let left = 80;
    let mut y = 18;
    let entry = |x: i32, y: i32, swatch: &Swatch, text: &str| -> DrawResult<DB> {
        match swatch {
            Swatch::Line(c) => area.draw(&PathElement::new(vec![(x, y), (x + 24, y)], c.stroke_width(3)))?,
            Swatch::Fill(c) => area.draw(&Rectangle::new([(x, y - 7), (x + 24, y + 7)], c.filled()))?,
            Swatch::Dot(c) => area.draw(&Circle::new((x + 12, y), 6, c.filled()))?,
            Swatch::Cross => area.draw(&Cross::new((x + 12, y), 6, BLACK.stroke_width(3)))?,
            Swatch::Triangle(c) => area.draw(&TriangleMarker::new((x + 12, y), 7, c.filled()))?,
        }
        area.draw(&Text::new(text.to_string(), (x + 34, y - (LABEL_PX as i32) / 2 - 1), font.clone()))
    };
    for (swatch, text) in wide {
        entry(left, y, swatch, text)?;
        y += 30;
    }
    let mut x = left;
    for (swatch, text) in narrow {
        entry(x, y, swatch, text)?;
        x += 60 + 10 * text.chars().count() as i32;
    }
    Ok(())
}

fn draw_3d<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, group: &[&RunData<'_>]) -> DrawResult<DB> {
    let Some(first) = group.first() else { return Ok(()) };
    let scenario = first.scenario;
    let root =
        root.titled(&format!("{}: paths in 3D (x, y, z in m; z stretched)", scenario.name), title_font())?;
    let paths: Vec<Vec<[f64; 3]>> = group.iter().map(|r| path(r)).collect();
    let zs = paths.iter().flatten().map(|p| p[2]).chain([0.0, scenario.start[2], scenario.goal_m[2]]);
    let x = pad(horizontal_extent(&paths, scenario, 0), 0.05, 0.3);
    let y = pad(horizontal_extent(&paths, scenario, 1), 0.05, 0.3);
    // The same span in x and y, so that the cylinders stay round.
    let half = (x.end - x.start).max(y.end - y.start) / 2.0;
    let (cx, cy) = ((x.start + x.end) / 2.0, (y.start + y.end) / 2.0);
    let (z_lo, z_hi) = extent(zs, (0.0, 1.0));
    let z = z_lo.min(0.0)..(z_hi + 0.5);
    // plotters' 3D charts are (x, vertical, depth): plot (x, z, y).
    let mut chart = ChartBuilder::on(&root).margin(20).build_cartesian_3d(
        (cx - half)..(cx + half),
        z.clone(),
        (cy - half)..(cy + half),
    )?;
    chart.with_projection(|mut p| {
        p.yaw = 0.75;
        p.pitch = 0.35;
        p.scale = 0.8;
        p.into_matrix()
    });
    chart
        .configure_axes()
        .label_style((FONT, TICK_PX))
        .light_grid_style(BLACK.mix(0.08))
        .bold_grid_style(BLACK.mix(0.15))
        .max_light_lines(2)
        .draw()?;
    let label = (FONT, LABEL_PX).into_font();
    // Beside the edges that carry the tick labels (x along y = max, y along x = max).
    chart.draw_series([
        Text::new("x [m]", (cx, z.start, cy + 1.3 * half), label.clone()),
        Text::new("y [m]", (cx + 1.3 * half, z.start, cy), label.clone()),
        Text::new("z [m]", (cx - half, z.end + 0.06 * (z.end - z.start), cy + half), label),
    ])?;
    for (i, c) in scenario.obstacles.iter().enumerate() {
        let top = c.height_m.min(z.end);
        let ring = circle(c.x_m, c.y_m, c.radius_m);
        let faces: Vec<Polygon<(f64, f64, f64)>> = ring
            .windows(2)
            .map(|w| {
                Polygon::new(
                    vec![
                        (w[0].0, 0.0, w[0].1),
                        (w[1].0, 0.0, w[1].1),
                        (w[1].0, top, w[1].1),
                        (w[0].0, top, w[0].1),
                    ],
                    CYLINDER.mix(0.12).filled(),
                )
            })
            .collect();
        let series = chart.draw_series(faces)?;
        if i == 0 {
            series
                .label("cylinder (to scale, cut at the top of the plot)")
                .legend(|(x, y)| Rectangle::new([(x, y - 6), (x + 20, y + 6)], CYLINDER.mix(0.35).filled()));
        }
        for h in [0.0, top] {
            chart.draw_series([PathElement::new(
                ring.iter().map(|&(px, py)| (px, h, py)).collect::<Vec<_>>(),
                CYLINDER.stroke_width(1),
            )])?;
        }
    }
    for (i, (r, p)) in group.iter().zip(&paths).enumerate() {
        let color = controller_color(&r.summary.controller, i);
        // The shadow on the ground helps reading the height.
        chart.draw_series(LineSeries::new(p.iter().map(|q| (q[0], 0.0, q[1])), color.mix(0.3)))?;
        chart
            .draw_series(LineSeries::new(p.iter().map(|q| (q[0], q[2], q[1])), color.stroke_width(3)))?
            .label(format!("{} (ground shadow lighter)", controller_label(&r.summary.controller)))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3)));
    }
    let s = scenario.start;
    let g = scenario.goal_m;
    chart
        .draw_series([Circle::new((s[0], s[2], s[1]), 7, GREEN.mix(0.9).filled())])?
        .label("start")
        .legend(|(x, y)| Circle::new((x + 10, y), 6, GREEN.mix(0.9).filled()));
    chart
        .draw_series([Cross::new((g[0], g[2], g[1]), 8, BLACK.stroke_width(3))])?
        .label("goal")
        .legend(|(x, y)| Cross::new((x + 10, y), 6, BLACK.stroke_width(3)));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .label_font((FONT, TICK_PX))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.4))
        .draw()?;
    Ok(())
}

/// A labelled line of `(t, value)` points.
type Series = (String, RGBColor, Vec<(f64, f64)>);

/// One panel of [`draw_inputs`]: series of `(t, value)` with labels, and the bounds.
struct Panel<'a> {
    title: &'a str,
    unit: &'a str,
    series: Vec<Series>,
    bounds: (f64, f64),
    /// An extra dashed reference line (hover thrust).
    reference: Option<(&'a str, f64)>,
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    t: (f64, f64),
    p: &Panel<'_>,
) -> DrawResult<DB> {
    let values = p.series.iter().flat_map(|(_, _, s)| s.iter().map(|q| q.1));
    let (lo, hi) = extent(values.chain([p.bounds.0, p.bounds.1]), p.bounds);
    let mut chart = ChartBuilder::on(area)
        .caption(p.title, panel_font())
        .margin(10)
        .margin_right(25)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(t.0..t.1.max(t.0 + 1e-3), pad((lo, hi), 0.08, 1e-3))?;
    chart
        .configure_mesh()
        .x_desc("plant time [s]")
        .y_desc(p.unit)
        .axis_desc_style((FONT, LABEL_PX))
        .label_style((FONT, TICK_PX))
        .light_line_style(BLACK.mix(0.05))
        .bold_line_style(BLACK.mix(0.15))
        .draw()?;
    for (i, b) in [p.bounds.0, p.bounds.1].into_iter().enumerate() {
        let s =
            chart.draw_series(DashedLineSeries::new([(t.0, b), (t.1, b)], 8, 5, BOUND.stroke_width(2)))?;
        if i == 0 {
            s.label("bounds")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BOUND.stroke_width(2)));
        }
    }
    if let Some((label, v)) = p.reference {
        let grey = BLACK.mix(0.45);
        chart
            .draw_series(DashedLineSeries::new([(t.0, v), (t.1, v)], 4, 4, grey.stroke_width(1)))?
            .label(label)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], grey.stroke_width(1)));
    }
    for (label, color, points) in &p.series {
        let color = *color;
        chart
            .draw_series(LineSeries::new(points.iter().copied(), color.stroke_width(2)))?
            .label(label.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font((FONT, TICK_PX))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.4))
        .draw()?;
    Ok(())
}

/// `(t, f(row))` for the rows where both are finite; commands hold until the next cycle, so
/// they are drawn as steps.
fn steps(rows: &[CycleRow], f: impl Fn(&CycleRow) -> f64) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(2 * rows.len());
    for (k, row) in rows.iter().enumerate() {
        let v = f(row);
        if !(row.t_s.is_finite() && v.is_finite()) {
            continue;
        }
        out.push((row.t_s, v));
        if let Some(next) = rows.get(k + 1).filter(|n| n.t_s.is_finite()) {
            out.push((next.t_s, v));
        }
    }
    out
}

fn samples(rows: &[CycleRow], f: impl Fn(&CycleRow) -> f64) -> Vec<(f64, f64)> {
    rows.iter().map(|r| (r.t_s, f(r))).filter(|(t, v)| t.is_finite() && v.is_finite()).collect()
}

fn draw_inputs<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, r: &RunData<'_>) -> DrawResult<DB> {
    let s = r.scenario;
    let root = root.titled(
        &format!("{} with the {}: inputs against time", s.name, controller_label(&r.summary.controller)),
        title_font(),
    )?;
    let t = extent(r.rows.iter().map(|row| row.t_s), (0.0, 1.0));
    let deg = 180.0 / std::f64::consts::PI;
    let b = &s.bounds;
    let color = controller_color(&r.summary.controller, 0);
    let panels = [
        Panel {
            title: "Thrust",
            unit: "thrust [m/s²]",
            series: vec![("commanded T".to_string(), color, steps(r.rows, |row| row.command[0]))],
            bounds: (b.min[0], b.max[0]),
            reference: Some(("hover (g)", s.model.gravity_mps2)),
        },
        Panel {
            title: "Roll",
            unit: "roll [deg]",
            series: vec![
                ("commanded φ_d".to_string(), color, steps(r.rows, |row| row.command[1] * deg)),
                ("plant φ".to_string(), PALETTE[2], samples(r.rows, |row| row.state[6] * deg)),
            ],
            bounds: (b.min[1] * deg, b.max[1] * deg),
            reference: None,
        },
        Panel {
            title: "Pitch",
            unit: "pitch [deg]",
            series: vec![
                ("commanded θ_d".to_string(), color, steps(r.rows, |row| row.command[2] * deg)),
                ("plant θ".to_string(), PALETTE[2], samples(r.rows, |row| row.state[7] * deg)),
            ],
            bounds: (b.min[2] * deg, b.max[2] * deg),
            reference: None,
        },
    ];
    for (area, panel) in root.split_evenly((3, 1)).iter().zip(&panels) {
        draw_panel(area, t, panel)?;
    }
    Ok(())
}

/// The round-trip delays of a run: `(plant time of the sample the command came from, delay)`,
/// s. Row k knows the delay of command k-1.
pub fn delays(rows: &[CycleRow]) -> Vec<(f64, f64)> {
    rows.windows(2)
        .map(|w| (w[0].t_s, w[1].known_delay_s))
        .filter(|(t, d)| t.is_finite() && d.is_finite() && *d >= 0.0)
        .collect()
}

/// Shape and scale (s) of the Gamma fitted to `delays_s` by moments.
pub fn gamma_fit(delays_s: &[f64]) -> Option<(f64, f64)> {
    let n = delays_s.len();
    if n < 2 {
        return None;
    }
    let mean = delays_s.iter().sum::<f64>() / n as f64;
    let var = delays_s.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    mpc::delays::GammaParams::from_moments(mean, var).map(|g| (g.shape, g.scale_s))
}

/// Density of Gamma(shape, scale) at `x` (same unit as the scale).
fn gamma_pdf(shape: f64, scale: f64, x: f64) -> Option<f64> {
    let g = Gamma::new(shape, 1.0 / scale).ok()?;
    Some(g.pdf(x))
}

fn draw_delays<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, r: &RunData<'_>) -> DrawResult<DB> {
    let root = root.titled(
        &format!(
            "{} with the {}: round-trip delays (from plant stamps)",
            r.scenario.name,
            controller_label(&r.summary.controller)
        ),
        title_font(),
    )?;
    let d = delays(r.rows);
    let ms: Vec<f64> = d.iter().map(|q| q.1 * 1e3).collect();
    let areas = root.split_evenly((1, 2));
    let (left, right) = (&areas[0], &areas[1]);
    let t = extent(d.iter().map(|q| q.0), (0.0, 1.0));
    let (lo, hi) = extent(ms.iter().copied(), (0.0, 1.0));
    let y_hi = (hi * 1.1).max(1.0);
    let color = controller_color(&r.summary.controller, 0);
    let mut chart = ChartBuilder::on(left)
        .caption("Delay of each command", panel_font())
        .margin(10)
        .margin_right(25)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(t.0..t.1.max(t.0 + 1e-3), 0.0..y_hi)?;
    chart
        .configure_mesh()
        .x_desc("plant time of the sample the command came from [s]")
        .y_desc("delay [ms]")
        .axis_desc_style((FONT, LABEL_PX))
        .label_style((FONT, TICK_PX))
        .light_line_style(BLACK.mix(0.05))
        .bold_line_style(BLACK.mix(0.15))
        .draw()?;
    chart.draw_series(LineSeries::new(d.iter().map(|q| (q.0, q.1 * 1e3)), color.mix(0.35)))?;
    chart.draw_series(d.iter().map(|q| Circle::new((q.0, q.1 * 1e3), 3, color.filled())))?;

    // Histogram as a density (1/ms), the fitted Gamma and the scenario's own delay model.
    let bins = 25usize;
    let width = ((hi - lo.min(hi)) / bins as f64).max(1.0);
    let x0 = (lo / width).floor() * width;
    let mut counts = vec![0usize; bins + 1];
    for v in &ms {
        let i = (((v - x0) / width).floor().max(0.0) as usize).min(bins);
        counts[i] += 1;
    }
    let n = ms.len().max(1) as f64;
    let density: Vec<f64> = counts.iter().map(|&c| c as f64 / (n * width)).collect();
    let fit = gamma_fit(&d.iter().map(|q| q.1).collect::<Vec<_>>());
    let model = match r.scenario.delays {
        DelayModel::Gamma { shape, scale_s } => Some((shape, scale_s)),
        DelayModel::None => None,
    };
    let x_hi = x0 + width * (bins + 1) as f64;
    let x_lo = (x0 - width).max(0.0);
    let curve = |(shape, scale_s): (f64, f64)| -> Vec<(f64, f64)> {
        (0..=200)
            .map(|i| x_lo + (x_hi - x_lo) * i as f64 / 200.0)
            .filter_map(|x| gamma_pdf(shape, scale_s * 1e3, x).map(|p| (x, p)))
            .filter(|q| q.1.is_finite())
            .collect()
    };
    let fit_curve = fit.map(curve).unwrap_or_default();
    let model_curve = model.map(curve).unwrap_or_default();
    let y_max =
        extent(density.iter().copied().chain(fit_curve.iter().chain(&model_curve).map(|q| q.1)), (0.0, 1.0))
            .1;
    let mut chart = ChartBuilder::on(right)
        .caption(format!("Histogram of {} delays", ms.len()), panel_font())
        .margin(10)
        .margin_right(25)
        .x_label_area_size(45)
        .y_label_area_size(80)
        .build_cartesian_2d(x_lo..x_hi, 0.0..(y_max * 1.4).max(1e-6))?;
    chart
        .configure_mesh()
        .x_desc("delay [ms]")
        .y_desc("density [1/ms]")
        .axis_desc_style((FONT, LABEL_PX))
        .label_style((FONT, TICK_PX))
        .light_line_style(BLACK.mix(0.05))
        .bold_line_style(BLACK.mix(0.15))
        .draw()?;
    chart
        .draw_series(density.iter().enumerate().filter(|(_, h)| **h > 0.0).map(|(i, h)| {
            let a = x0 + width * i as f64;
            Rectangle::new([(a, 0.0), (a + width, *h)], color.mix(0.45).filled())
        }))?
        .label("measured")
        .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 20, y + 6)], color.mix(0.45).filled()));
    if let Some((k, theta)) = fit {
        chart
            .draw_series(LineSeries::new(fit_curve, BLACK.stroke_width(2)))?
            .label(format!("Gamma fitted by moments: k = {k:.1}, θ = {:.1} ms", theta * 1e3))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(2)));
    }
    if let Some((k, theta)) = model {
        chart
            .draw_series(DashedLineSeries::new(model_curve, 8, 5, BOUND.stroke_width(2)))?
            .label(format!("scenario's delay model: k = {k}, θ = {:.1} ms", theta * 1e3))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BOUND.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font((FONT, TICK_PX))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.4))
        .draw()?;
    Ok(())
}

fn draw_weights<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, r: &RunData<'_>) -> DrawResult<DB> {
    let s = r.scenario;
    let m = r.rows.first().map_or(0, |row| row.weights.len());
    let t = extent(r.rows.iter().map(|row| row.t_s), (0.0, 1.0));
    let mut chart = ChartBuilder::on(root)
        .caption(
            format!("{} with the {}: scenario weights", s.name, controller_label(&r.summary.controller)),
            title_font(),
        )
        .margin(15)
        .margin_right(25)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(t.0..t.1.max(t.0 + 1e-3), 0.0..1.05)?;
    chart
        .configure_mesh()
        .x_desc("plant time [s]")
        .y_desc("weight [-]")
        .axis_desc_style((FONT, LABEL_PX))
        .label_style((FONT, TICK_PX))
        .light_line_style(BLACK.mix(0.05))
        .bold_line_style(BLACK.mix(0.15))
        .draw()?;
    for i in 0..m {
        let color = PALETTE[i % PALETTE.len()];
        let label = match s.sampling_times_s.get(i) {
            Some(ts) => format!("scenario {i}: sampling time {:.0} ms", ts * 1e3),
            None => format!("scenario {i}"),
        };
        chart
            .draw_series(LineSeries::new(
                steps(r.rows, |row| row.weights.get(i).copied().unwrap_or(f64::NAN)),
                color.stroke_width(2),
            ))?
            .label(label)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font((FONT, TICK_PX))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.4))
        .draw()?;
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests {
    use hilbench_proto::pb;

    use super::*;

    /// A fresh directory under the system's temporary directory.
    pub(crate) fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("hilbench-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("temporary directory");
        dir
    }

    pub(crate) fn facts(scenario: &str, controller: &str) -> RunFacts {
        RunFacts {
            scenario: scenario.to_string(),
            controller: controller.to_string(),
            reached: true,
            collided: false,
            time_to_goal_s: Some(11.8),
            path_length_m: 6.0,
            min_clearance_m: 0.2,
            cycles: 60,
            solve_ms_median: 1.0,
            final_position_m: [0.0, 9.0, 1.0],
            collisions_m: Vec::new(),
        }
    }

    /// A straight flight from the start to the goal with Gamma-like delays.
    fn rows(scenario: &Scenario, m: usize) -> Vec<CycleRow> {
        let n = 60;
        let telemetry: Vec<pb::CycleTelemetry> = (0..n)
            .map(|k| {
                let f = k as f64 / (n - 1) as f64;
                let p: Vec<f64> = (0..3)
                    .map(|i| scenario.start[i] + f * (scenario.goal_m[i] - scenario.start[i]))
                    .collect();
                // Through telemetry (prost messages have defaults), as a gRPC run builds them.
                pb::CycleTelemetry {
                    cycle: k as u64,
                    sample: Some(pb::StateSample {
                        time_ns: k as u64 * 200_000_000,
                        state: Some(pb::MavState { x: vec![p[0], p[1], p[2], 0.5, 0.5, 0.0, 0.01, -0.02] }),
                        ..Default::default()
                    }),
                    command: Some(pb::ControlInput {
                        thrust_mps2: 9.81 + (k as f64).sin(),
                        roll_rad: 0.05 * (k as f64 * 0.3).cos(),
                        pitch_rad: -0.05,
                    }),
                    measured_delay_s: if k == 0 { 0.0 } else { 0.15 + 0.05 * ((k * 7 % 11) as f64 / 11.0) },
                    scenario_weights: (0..m)
                        .map(|i| if i == k % m { 0.6 } else { 0.4 / (m as f64 - 1.0).max(1.0) })
                        .collect(),
                    ..Default::default()
                }
            })
            .collect();
        crate::cycle_log::from_telemetry(&telemetry)
    }

    fn is_png(bytes: &[u8]) -> bool {
        bytes.starts_with(&[0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1a, b'\n'])
    }

    #[test]
    fn plots_of_two_runs_are_written_as_png_and_svg_with_their_titles() {
        let scenario = Scenario::by_name("paper-2").expect("paper-2");
        let nmpc_rows = rows(&scenario, 1);
        let ms_rows = rows(&scenario, 5);
        let mut nmpc = facts("paper-2", "nmpc");
        nmpc.final_position_m = scenario.goal_m;
        let mut ms = facts("paper-2", "multistage");
        ms.final_position_m = scenario.goal_m;
        let runs = [
            RunData { scenario: &scenario, summary: nmpc, rows: &nmpc_rows },
            RunData { scenario: &scenario, summary: ms, rows: &ms_rows },
        ];
        let dir = temp_dir("plots");
        let written = write_all(&dir, &runs).expect("plots");
        // Two scenario figures, inputs and delays of both runs, weights of the multi-stage one.
        assert_eq!(written.len(), 2 * 7, "{written:?}");
        let expect = [
            (stem(Kind::Top, "paper-2", None), "paper-2: paths seen from above"),
            (stem(Kind::ThreeD, "paper-2", None), "paper-2: paths in 3D"),
            (stem(Kind::Inputs, "paper-2", Some("nmpc")), "inputs against time"),
            (stem(Kind::Delays, "paper-2", Some("multistage")), "Gamma fitted by moments"),
            (stem(Kind::Weights, "paper-2", Some("multistage")), "scenario weights"),
        ];
        for (stem, title) in expect {
            let png = std::fs::read(dir.join(PLOTS_DIR).join(format!("{stem}.png"))).expect("png");
            assert!(png.len() > 10_000 && is_png(&png), "{stem}.png: {} bytes", png.len());
            let svg = std::fs::read_to_string(dir.join(PLOTS_DIR).join(format!("{stem}.svg"))).expect("svg");
            assert!(svg.trim_start().starts_with("<svg") && svg.trim_end().ends_with("</svg>"), "{stem}.svg");
            assert!(svg.contains(title), "{stem}.svg lacks {title:?}");
        }
        // The top view holds both controllers' legends and the cylinders.
        let top = std::fs::read_to_string(
            dir.join(PLOTS_DIR).join(format!("{}.svg", stem(Kind::Top, "paper-2", None))),
        )
        .expect("svg");
        for label in ["standard NMPC", "multi-stage NMPC", "cylinder (to scale)", "x [m]", "y [m]"] {
            assert!(top.contains(label), "top view lacks {label:?}");
        }
        assert!(
            !dir.join(PLOTS_DIR)
                .join(format!("{}.png", stem(Kind::Weights, "paper-2", Some("nmpc"))))
                .exists()
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_moment_fit_recovers_a_gamma() {
        // Mean 0.18 s, variance 0.0027 s²: shape 12, scale 15 ms.
        let (mean, sd) = (0.18f64, 0.0027f64.sqrt());
        let delays: Vec<f64> = (0..1000).map(|i| mean + sd * if i % 2 == 0 { 1.0 } else { -1.0 }).collect();
        let (k, theta) = gamma_fit(&delays).expect("a fit");
        assert!((k - 12.0).abs() < 0.05 && (theta - 0.015).abs() < 1e-4, "{k} {theta}");
        assert!(gamma_fit(&[0.1]).is_none());
        let rows = rows(&Scenario::by_name("paper-1").expect("paper-1"), 1);
        let d = delays_of(&rows);
        assert_eq!(d.len(), rows.len() - 1);
        assert_eq!(d[0], (rows[0].t_s, rows[1].known_delay_s));
    }

    fn delays_of(rows: &[CycleRow]) -> Vec<(f64, f64)> {
        delays(rows)
    }
}
