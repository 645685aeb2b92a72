//! The paths of every controller of a scenario seen from above, with the cylinders to scale.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::paths::{Swatch, circle, draw_legend, horizontal_extent, path, path_label};
use super::style::{BOUND, CYLINDER, controller_color, draw_mesh, equal_axes_chart, pad, title_font};
use super::{DrawResult, RunData};

pub(super) fn draw_top<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    group: &[&RunData<'_>],
) -> DrawResult<DB> {
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
    let mut chart = equal_axes_chart(&root, x, y)?;
    draw_mesh(&mut chart, "x [m]", "y [m]")?;
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
