//! The paths of every controller of a scenario seen from above, with the cylinders to scale.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::paths::{Swatch, circle, draw_legend, horizontal_extent, path, path_label};
use super::style::{BOUND, CYLINDER, controller_color, draw_mesh, pad, title_font};
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
