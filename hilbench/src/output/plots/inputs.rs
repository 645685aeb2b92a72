//! Roll, pitch and thrust of one run against time, commanded and flown, with their bounds.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::style::{
    BOUND, PALETTE, controller_color, controller_label, draw_legend, draw_mesh, extent, pad, panel_font,
    samples, steps, title_font,
};
use super::{DrawResult, RunData};

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
    draw_mesh(&mut chart, "plant time [s]", p.unit)?;
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
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
    Ok(())
}

pub(super) fn draw_inputs<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    r: &RunData<'_>,
) -> DrawResult<DB> {
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
