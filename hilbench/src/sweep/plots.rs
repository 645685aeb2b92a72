//! The figures of `hilbench sweep`: the distribution of the minimum clearance per family (a
//! CDF), the histogram of path lengths of the runs that reached the goal, and where the
//! failures happened on the scenario's top view.

use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use mav::Scenario;
use plotters::coord::Shift;
use plotters::prelude::*;

use super::stats::RunRow;
use crate::output::plots::paths::circle;
use crate::output::plots::style::{
    BOUND, CYLINDER, FONT, LABEL_PX, PALETTE, TICK_PX, draw_legend, extent, pad, title_font,
};
use crate::output::plots::{DrawResult, PLOTS_DIR, register_font};

enum Figure<'a> {
    ClearanceCdf { rows: &'a [&'a RunRow], families: &'a [String] },
    PathLength { rows: &'a [&'a RunRow] },
    Failures { rows: &'a [&'a RunRow], scenario: &'a Scenario },
}

/// Writes the sweep's figures (PNG and SVG) into `dir/plots/`; returns the paths written.
pub fn write(
    dir: &Path,
    scenario: &Scenario,
    rows: &[&RunRow],
    families: &[String],
) -> anyhow::Result<Vec<PathBuf>> {
    register_font()?;
    let out = dir.join(PLOTS_DIR);
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let figures = [
        ("sweep-clearance-cdf", Figure::ClearanceCdf { rows, families }),
        ("sweep-path-length", Figure::PathLength { rows }),
        ("sweep-failures-top", Figure::Failures { rows, scenario }),
    ];
    let mut written = Vec::new();
    for (stem, figure) in &figures {
        let size = (1000, 700);
        let png = out.join(format!("{stem}.png"));
        {
            let root = BitMapBackend::new(&png, size).into_drawing_area();
            figure.draw(&root).map_err(|e| anyhow!("cannot draw {}: {e}", png.display()))?;
            root.present().map_err(|e| anyhow!("cannot write {}: {e}", png.display()))?;
        }
        let svg = out.join(format!("{stem}.svg"));
        let mut text = String::new();
        {
            let root = SVGBackend::with_string(&mut text, size).into_drawing_area();
            figure.draw(&root).map_err(|e| anyhow!("cannot draw {}: {e}", svg.display()))?;
            root.present().map_err(|e| anyhow!("cannot draw {}: {e}", svg.display()))?;
        }
        std::fs::write(&svg, text).with_context(|| format!("cannot write {}", svg.display()))?;
        written.extend([png, svg]);
    }
    Ok(written)
}

impl Figure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        match self {
            Figure::ClearanceCdf { rows, families } => clearance_cdf(root, rows, families),
            Figure::PathLength { rows } => path_length(root, rows),
            Figure::Failures { rows, scenario } => failures(root, rows, scenario),
        }
    }
}

fn clearance_cdf<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    rows: &[&RunRow],
    families: &[String],
) -> DrawResult<DB> {
    let root = root.titled("Minimum clearance per run, by family (CDF)", title_font())?;
    let (lo, hi) = extent(rows.iter().filter_map(|r| r.min_clearance_m), (-0.1, 1.0));
    let x = pad((lo.min(0.0), hi), 0.05, 0.02);
    let mut chart = ChartBuilder::on(&root)
        .margin(15)
        .margin_right(25)
        .x_label_area_size(50)
        .y_label_area_size(60)
        .build_cartesian_2d(x.clone(), 0.0..1.02)?;
    chart
        .configure_mesh()
        .x_desc("minimum clearance to a cylinder [m] (negative: collision)")
        .y_desc("fraction of runs")
        .axis_desc_style((FONT, LABEL_PX))
        .label_style((FONT, TICK_PX))
        .light_line_style(BLACK.mix(0.05))
        .bold_line_style(BLACK.mix(0.15))
        .draw()?;
    chart.draw_series([PathElement::new(vec![(0.0, 0.0), (0.0, 1.02)], BOUND.stroke_width(1))])?;
    for (i, name) in families.iter().enumerate() {
        let mut v: Vec<f64> = rows
            .iter()
            .filter(|r| &r.family == name)
            .filter_map(|r| r.min_clearance_m)
            .filter(|c| c.is_finite())
            .collect();
        if v.is_empty() {
            continue;
        }
        v.sort_by(f64::total_cmp);
        let n = v.len() as f64;
        let mut points = vec![(x.start, 0.0)];
        for (k, c) in v.iter().enumerate() {
            points.push((*c, k as f64 / n));
            points.push((*c, (k + 1) as f64 / n));
        }
        points.push((x.end, 1.0));
        let color = PALETTE[i % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(points, color.stroke_width(3)))?
            .label(format!("{name} ({} runs)", v.len()))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3)));
    }
    draw_legend(&mut chart, SeriesLabelPosition::LowerRight)
}

fn path_length<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, rows: &[&RunRow]) -> DrawResult<DB> {
    let root = root.titled("Path length of the runs that reached the goal", title_font())?;
    let lengths: Vec<f64> = rows
        .iter()
        .filter(|r| r.outcome == "reached")
        .filter_map(|r| r.path_length_m)
        .filter(|l| l.is_finite())
        .collect();
    let (lo, hi) = extent(lengths.iter().copied(), (0.0, 1.0));
    let bins = 30usize;
    let width = ((hi - lo) / bins as f64).max(1e-3);
    let mut counts = vec![0u32; bins];
    for l in &lengths {
        counts[(((l - lo) / width) as usize).min(bins - 1)] += 1;
    }
    let top = f64::from(counts.iter().copied().max().unwrap_or(1).max(1)) * 1.1;
    let mut chart = ChartBuilder::on(&root)
        .margin(15)
        .margin_right(25)
        .x_label_area_size(50)
        .y_label_area_size(60)
        .build_cartesian_2d(lo - width..lo + width * (bins as f64 + 1.0), 0.0..top)?;
    chart
        .configure_mesh()
        .x_desc("path length [m]")
        .y_desc("runs")
        .axis_desc_style((FONT, LABEL_PX))
        .label_style((FONT, TICK_PX))
        .light_line_style(BLACK.mix(0.05))
        .bold_line_style(BLACK.mix(0.15))
        .draw()?;
    chart.draw_series(counts.iter().enumerate().map(|(i, c)| {
        let x0 = lo + width * i as f64;
        Rectangle::new([(x0, 0.0), (x0 + width, f64::from(*c))], PALETTE[0].mix(0.7).filled())
    }))?;
    Ok(())
}

fn failures<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    rows: &[&RunRow],
    scenario: &Scenario,
) -> DrawResult<DB> {
    let failed: Vec<&&RunRow> = rows.iter().filter(|r| r.failed()).collect();
    let root = root.titled(
        &format!("{}: where the {} failures happened, seen from above", scenario.name, failed.len()),
        title_font(),
    )?;
    let xs = scenario.obstacles.iter().flat_map(|c| [c.x_m - c.radius_m, c.x_m + c.radius_m]);
    let ys = scenario.obstacles.iter().flat_map(|c| [c.y_m - c.radius_m, c.y_m + c.radius_m]);
    let points = failed.iter().filter_map(|r| r.fail_position_m);
    let x = extent(
        xs.chain([scenario.start[0], scenario.goal_m[0]]).chain(points.clone().map(|p| p[0])),
        (0.0, 1.0),
    );
    let y = extent(ys.chain([scenario.start[1], scenario.goal_m[1]]).chain(points.map(|p| p[1])), (0.0, 1.0));
    let mut chart = ChartBuilder::on(&root)
        .margin(15)
        .margin_right(25)
        .x_label_area_size(50)
        .y_label_area_size(60)
        .build_cartesian_2d(pad(x, 0.08, 0.5), pad(y, 0.08, 0.5))?;
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
    chart
        .draw_series([Circle::new((scenario.start[0], scenario.start[1]), 7, GREEN.mix(0.9).filled())])?
        .label("start")
        .legend(|(x, y)| Circle::new((x + 10, y), 6, GREEN.mix(0.9).filled()));
    chart
        .draw_series([Cross::new((scenario.goal_m[0], scenario.goal_m[1]), 8, BLACK.stroke_width(3))])?
        .label("goal")
        .legend(|(x, y)| Cross::new((x + 10, y), 6, BLACK.stroke_width(3)));
    let at = |outcome: &str| -> Vec<(f64, f64)> {
        failed
            .iter()
            .filter(|r| r.outcome == outcome)
            .filter_map(|r| r.fail_position_m)
            .map(|p| (p[0], p[1]))
            .collect()
    };
    let collided = at("collided");
    if !collided.is_empty() {
        chart
            .draw_series(collided.into_iter().map(|p| TriangleMarker::new(p, 8, BOUND.mix(0.8).filled())))?
            .label("first collision")
            .legend(|(x, y)| TriangleMarker::new((x + 10, y), 7, BOUND.filled()));
    }
    let missed = at("missed");
    if !missed.is_empty() {
        chart
            .draw_series(missed.into_iter().map(|p| Circle::new(p, 6, PALETTE[1].mix(0.8).filled())))?
            .label("missed: where the time ran out")
            .legend(|(x, y)| Circle::new((x + 10, y), 6, PALETTE[1].filled()));
    }
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight)
}
