//! The figure of `hilbench falsify`: each search's best robustness against the runs it has
//! flown (a step curve that never rises), with zero (the property fails below it) marked.
//!
//! It takes plain values (a label and `(runs, best score)` points per search), so it needs
//! nothing of the search.

use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use plotters::coord::Shift;
use plotters::prelude::*;

use super::style::{BOUND, PALETTE, draw_legend, draw_mesh, extent, pad, title_font};
use super::{DrawResult, register_font};

/// One search's convergence: after each batch, the runs flown so far and the best score so far
/// (m).
pub struct Curve {
    pub label: String,
    pub points: Vec<(f64, f64)>,
}

/// Size of the figure, px.
const SIZE: (u32, u32) = (1000, 650);

/// Writes `<stem>.png` and `<stem>.svg` into `dir`; returns the paths written.
pub fn write(dir: &Path, stem: &str, title: &str, curves: &[Curve]) -> anyhow::Result<Vec<PathBuf>> {
    register_font()?;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let png = dir.join(format!("{stem}.png"));
    let svg = dir.join(format!("{stem}.svg"));
    {
        let root = BitMapBackend::new(&png, SIZE).into_drawing_area();
        draw(&root, title, curves).map_err(|e| anyhow!("cannot draw {}: {e}", png.display()))?;
        root.present().map_err(|e| anyhow!("cannot write {}: {e}", png.display()))?;
    }
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, SIZE).into_drawing_area();
        draw(&root, title, curves).map_err(|e| anyhow!("cannot draw {}: {e}", svg.display()))?;
        root.present().map_err(|e| anyhow!("cannot draw {}: {e}", svg.display()))?;
    }
    std::fs::write(&svg, text).with_context(|| format!("cannot write {}", svg.display()))?;
    Ok(vec![png, svg])
}

fn draw<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, title: &str, curves: &[Curve]) -> DrawResult<DB> {
    root.fill(&WHITE)?;
    let root = root.titled(title, title_font())?;
    let finite = || curves.iter().flat_map(|c| c.points.iter()).filter(|p| p.1.is_finite());
    let runs = finite().map(|p| p.0).fold(1.0, f64::max);
    let (lo, hi) = extent(finite().map(|p| p.1), (-0.1, 1.0));
    let y = pad((lo.min(0.0), hi.max(0.0)), 0.05, 0.02);
    let mut chart = ChartBuilder::on(&root)
        .margin(15)
        .margin_right(25)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..runs * 1.02, y.clone())?;
    draw_mesh(&mut chart, "runs flown", "best robustness so far [m] (below 0: failed)")?;
    chart.draw_series([PathElement::new(vec![(0.0, 0.0), (runs * 1.02, 0.0)], BOUND.stroke_width(1))])?;
    for (i, curve) in curves.iter().enumerate() {
        let mut steps = Vec::with_capacity(2 * curve.points.len());
        let mut last: Option<f64> = None;
        for &(r, best) in curve.points.iter().filter(|p| p.1.is_finite()) {
            if let Some(prev) = last {
                steps.push((r, prev));
            }
            steps.push((r, best));
            last = Some(best);
        }
        let color = PALETTE[i % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(steps, color.stroke_width(3)))?
            .label(curve.label.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3)));
    }
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight)
}
