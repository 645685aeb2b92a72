//! The figures of `hilbench sweep`: the distribution of the minimum clearance per family (a
//! CDF), the histogram of path lengths of the runs that reached the goal, and where the
//! failures happened on the scenario's top view (to scale, its legend under the chart). A
//! sweep of several controllers draws each controller apart, never pooled: a panel per
//! controller for the clearance and the failures, a bar per controller in each path-length
//! bin.

use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use mav::Scenario;
use plotters::coord::Shift;
use plotters::prelude::*;

use super::stats::RunRow;
use crate::output::plots::paths::{Swatch, circle, draw_legend as draw_legend_below};
use crate::output::plots::style::{
    BOUND, CYLINDER, PALETTE, controller_color, controller_label, draw_legend, draw_mesh, equal_axes_chart,
    extent, pad, panel_font, title_font,
};
use crate::output::plots::{DrawResult, PLOTS_DIR, register_font};
use crate::run::Verdict;

enum Figure<'a> {
    ClearanceCdf { rows: &'a [&'a RunRow], families: &'a [String], controllers: &'a [String] },
    PathLength { rows: &'a [&'a RunRow], controllers: &'a [String] },
    Failures { rows: &'a [&'a RunRow], scenario: &'a Scenario, controllers: &'a [String] },
}

/// Writes the sweep's figures (PNG and SVG) into `dir/plots/`; returns the paths written.
pub fn write(
    dir: &Path,
    scenario: &Scenario,
    rows: &[&RunRow],
    families: &[String],
    controllers: &[String],
) -> anyhow::Result<Vec<PathBuf>> {
    register_font()?;
    let out = dir.join(PLOTS_DIR);
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let n = controllers.len().max(1) as u32;
    let figures = [
        (
            "sweep-clearance-cdf",
            Figure::ClearanceCdf { rows, families, controllers },
            (1000, 700.max(450 * n)),
        ),
        ("sweep-path-length", Figure::PathLength { rows, controllers }, (1000, 700)),
        ("sweep-failures-top", Figure::Failures { rows, scenario, controllers }, (1000 * n, 800)),
    ];
    let mut written = Vec::new();
    for (stem, figure, size) in &figures {
        let size = *size;
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

/// The rows of each controller, with the caption of its panel: one group of every row when
/// the sweep flew one controller.
fn by_controller<'a>(
    rows: &'a [&'a RunRow],
    controllers: &'a [String],
) -> Vec<(Option<&'a str>, Vec<&'a RunRow>)> {
    if controllers.len() <= 1 {
        return vec![(None, rows.to_vec())];
    }
    controllers
        .iter()
        .map(|c| (Some(c.as_str()), rows.iter().copied().filter(|r| &r.controller == c).collect()))
        .collect()
}

/// A panel's caption: the controller's name and its runs.
fn caption(controller: &str, rows: &[&RunRow]) -> String {
    let n = rows.len();
    format!("{} ({n} {})", controller_label(controller), if n == 1 { "run" } else { "runs" })
}

impl Figure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        match self {
            Figure::ClearanceCdf { rows, families, controllers } => {
                let root = root.titled("Minimum clearance per run, by family (CDF)", title_font())?;
                let groups = by_controller(rows, controllers);
                // One x range for every panel, so that the controllers compare at a glance.
                let (lo, hi) = extent(rows.iter().filter_map(|r| r.min_clearance_m), (-0.1, 1.0));
                let x = pad((lo.min(0.0), hi), 0.05, 0.02);
                for ((controller, rows), area) in groups.iter().zip(root.split_evenly((groups.len(), 1))) {
                    let area = match controller {
                        Some(c) => area.titled(&caption(c, rows), panel_font())?,
                        None => area,
                    };
                    clearance_cdf(&area, rows, families, x.clone())?;
                }
                Ok(())
            }
            Figure::PathLength { rows, controllers } => path_length(root, rows, controllers),
            Figure::Failures { rows, scenario, controllers } => {
                let failed = rows.iter().filter(|r| r.failed()).count();
                let root = root.titled(
                    &format!("{}: where the {failed} failures happened, seen from above", scenario.name),
                    title_font(),
                )?;
                let groups = by_controller(rows, controllers);
                for ((controller, rows), area) in groups.iter().zip(root.split_evenly((1, groups.len()))) {
                    let area = match controller {
                        Some(c) => area.titled(&caption(c, rows), panel_font())?,
                        None => area,
                    };
                    failures(&area, rows, scenario)?;
                }
                Ok(())
            }
        }
    }
}

fn clearance_cdf<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    rows: &[&RunRow],
    families: &[String],
    x: std::ops::Range<f64>,
) -> DrawResult<DB> {
    let mut chart = ChartBuilder::on(root)
        .margin(15)
        .margin_right(25)
        .x_label_area_size(50)
        .y_label_area_size(60)
        .build_cartesian_2d(x.clone(), 0.0..1.02)?;
    draw_mesh(&mut chart, "minimum clearance to a cylinder [m] (negative: collision)", "fraction of runs")?;
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

/// The histogram of path lengths: in each bin a bar per controller, side by side, in the
/// controller's colour.
fn path_length<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    rows: &[&RunRow],
    controllers: &[String],
) -> DrawResult<DB> {
    let root = root.titled("Path length of the runs that reached the goal", title_font())?;
    let length = |r: &&RunRow| r.path_length_m.filter(|l| r.outcome.is_reached() && l.is_finite());
    let (lo, hi) = extent(rows.iter().filter_map(length), (0.0, 1.0));
    let bins = 30usize;
    let width = ((hi - lo) / bins as f64).max(1e-3);
    let groups = by_controller(rows, controllers);
    let counts: Vec<Vec<u32>> = groups
        .iter()
        .map(|(_, rows)| {
            let mut counts = vec![0u32; bins];
            for l in rows.iter().filter_map(length) {
                counts[(((l - lo) / width) as usize).min(bins - 1)] += 1;
            }
            counts
        })
        .collect();
    let top = f64::from(counts.iter().flatten().copied().max().unwrap_or(1).max(1)) * 1.1;
    let mut chart = ChartBuilder::on(&root)
        .margin(15)
        .margin_right(25)
        .x_label_area_size(50)
        .y_label_area_size(60)
        .build_cartesian_2d(lo - width..lo + width * (bins as f64 + 1.0), 0.0..top)?;
    draw_mesh(&mut chart, "path length [m]", "runs")?;
    let share = width / groups.len() as f64;
    for (j, ((controller, rows), counts)) in groups.iter().zip(&counts).enumerate() {
        let color = match controller {
            Some(c) => controller_color(c, j),
            None => PALETTE[0],
        };
        let series = chart.draw_series(counts.iter().enumerate().map(|(i, c)| {
            let x0 = lo + width * i as f64 + share * j as f64;
            Rectangle::new([(x0, 0.0), (x0 + share, f64::from(*c))], color.mix(0.7).filled())
        }))?;
        if let Some(c) = controller {
            let reached = rows.iter().filter_map(length).count();
            series
                .label(format!("{} ({reached} reached)", controller_label(c)))
                .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 20, y + 6)], color.mix(0.7).filled()));
        }
    }
    if groups.len() > 1 {
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
    }
    Ok(())
}

/// The failures of `rows` on the scenario seen from above, to scale; the legend under the
/// chart, where it hides no point.
fn failures<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    rows: &[&RunRow],
    scenario: &Scenario,
) -> DrawResult<DB> {
    let failed: Vec<&&RunRow> = rows.iter().filter(|r| r.failed()).collect();
    let at = |outcome: Verdict| -> Vec<(f64, f64)> {
        failed
            .iter()
            .filter(|r| r.outcome == outcome)
            .filter_map(|r| r.fail_position_m)
            .map(|p| (p[0], p[1]))
            .collect()
    };
    let (collided, missed) = (at(Verdict::Collided), at(Verdict::Missed));
    let mut wide = Vec::new();
    if !collided.is_empty() {
        wide.push((Swatch::Triangle(BOUND), format!("first collision ({} runs)", collided.len())));
    }
    if !missed.is_empty() {
        wide.push((
            Swatch::Dot(PALETTE[1]),
            format!("missed: where the time ran out ({} runs)", missed.len()),
        ));
    }
    let narrow = [
        (Swatch::Fill(CYLINDER.mix(0.35)), "cylinder (to scale)".to_string()),
        (Swatch::Dot(GREEN), "start".to_string()),
        (Swatch::Cross, "goal".to_string()),
    ];
    let legend_h = 30 * (wide.len() as u32 + 1) + 20;
    let (_, h) = root.dim_in_pixel();
    let (root, legend_area) = root.split_vertically(h.saturating_sub(legend_h));
    let xs = scenario.obstacles.iter().flat_map(|c| [c.x_m - c.radius_m, c.x_m + c.radius_m]);
    let ys = scenario.obstacles.iter().flat_map(|c| [c.y_m - c.radius_m, c.y_m + c.radius_m]);
    let points = collided.iter().chain(&missed);
    let x = extent(
        xs.chain([scenario.start[0], scenario.goal_m[0]]).chain(points.clone().map(|p| p.0)),
        (0.0, 1.0),
    );
    let y = extent(ys.chain([scenario.start[1], scenario.goal_m[1]]).chain(points.map(|p| p.1)), (0.0, 1.0));
    let mut chart = equal_axes_chart(&root, pad(x, 0.08, 0.5), pad(y, 0.08, 0.5))?;
    draw_mesh(&mut chart, "x [m]", "y [m]")?;
    for c in &scenario.obstacles {
        let outline = circle(c.x_m, c.y_m, c.radius_m);
        chart.draw_series([Polygon::new(outline.clone(), CYLINDER.mix(0.35).filled())])?;
        chart.draw_series([PathElement::new(outline, CYLINDER.stroke_width(1))])?;
    }
    chart.draw_series([Circle::new((scenario.start[0], scenario.start[1]), 7, GREEN.mix(0.9).filled())])?;
    chart.draw_series([Cross::new((scenario.goal_m[0], scenario.goal_m[1]), 8, BLACK.stroke_width(3))])?;
    chart.draw_series(collided.into_iter().map(|p| TriangleMarker::new(p, 8, BOUND.mix(0.8).filled())))?;
    chart.draw_series(missed.into_iter().map(|p| Circle::new(p, 6, PALETTE[1].mix(0.8).filled())))?;
    draw_legend_below(&legend_area, &wide, &narrow)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sweep::stats::RunRow;
    use mpc::ControllerMode;

    fn failed(run: u64, mode: ControllerMode, outcome: Verdict, at: [f64; 3]) -> RunRow {
        let mut r = RunRow::of_error(run, mode.name(), "long", "", outcome, "", 0.0);
        r.fail_position_m = Some(at);
        r.min_clearance_m = Some(-0.01);
        r
    }

    /// Width and height, px, of each filled polygon (the cylinders) of an SVG.
    fn polygons(svg: &str) -> Vec<(f64, f64)> {
        svg.split("<polygon")
            .skip(1)
            .filter_map(|p| {
                let points = p.split("points=\"").nth(1)?.split('"').next()?;
                let xy: Vec<(f64, f64)> = points
                    .split_whitespace()
                    .filter_map(|q| {
                        let (x, y) = q.split_once(',')?;
                        Some((x.parse().ok()?, y.parse().ok()?))
                    })
                    .collect();
                let span = |f: fn(&(f64, f64)) -> f64| {
                    let v = xy.iter().map(f);
                    v.clone().fold(f64::NEG_INFINITY, f64::max) - v.fold(f64::INFINITY, f64::min)
                };
                Some((span(|q| q.0), span(|q| q.1)))
            })
            .collect()
    }

    #[test]
    fn the_failures_top_view_draws_each_cylinder_round_for_one_controller_and_for_two() {
        register_font().expect("the font");
        let scenario = Scenario::paper_2();
        let rows = [
            failed(0, ControllerMode::Multistage, Verdict::Collided, [3.3, 1.4, 1.0]),
            failed(1, ControllerMode::Nmpc, Verdict::Missed, [3.1, 2.2, 1.0]),
            failed(2, ControllerMode::Nmpc, Verdict::Collided, [4.0, 4.0, 1.0]),
        ];
        let refs: Vec<&RunRow> = rows.iter().collect();
        for controllers in
            [vec!["multistage".to_string()], vec!["nmpc".to_string(), "multistage".to_string()]]
        {
            let figure = Figure::Failures { rows: &refs, scenario: &scenario, controllers: &controllers };
            let mut svg = String::new();
            {
                let root = SVGBackend::with_string(&mut svg, (1000 * controllers.len() as u32, 800))
                    .into_drawing_area();
                figure.draw(&root).expect("drawn");
                root.present().expect("presented");
            }
            // The markers of the collisions are polygons too, smaller than a cylinder.
            let cylinders: Vec<(f64, f64)> = polygons(&svg).into_iter().filter(|p| p.0 > 25.0).collect();
            assert_eq!(cylinders.len(), scenario.obstacles.len() * controllers.len(), "{controllers:?}");
            for (w, h) in cylinders {
                assert!((w - h).abs() <= 1.5, "a cylinder {w} px wide and {h} px high");
            }
            // The legend is under the chart: its labels are in the SVG, with the counts.
            assert!(svg.contains("cylinder (to scale)"), "{controllers:?}");
            if controllers.len() == 2 {
                assert!(svg.contains("standard NMPC (2 runs)") && svg.contains("multi-stage NMPC (1 run)"));
            }
        }
    }
}
