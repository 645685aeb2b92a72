//! The paths of every controller of a scenario in 3D, with the cylinders.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::paths::{circle, horizontal_extent, path};
use super::style::{
    CYLINDER, FONT, LABEL_PX, TICK_PX, controller_color, controller_label, draw_legend, extent, pad,
    title_font,
};
use super::{DrawResult, RunData};

pub(super) fn draw_3d<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    group: &[&RunData<'_>],
) -> DrawResult<DB> {
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
    draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
    Ok(())
}
