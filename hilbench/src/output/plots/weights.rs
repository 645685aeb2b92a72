//! The scenario weights of one multi-stage run against time.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::style::{PALETTE, controller_label, draw_legend, draw_mesh, extent, steps, title_font};
use super::{DrawResult, RunData};

pub(super) fn draw_weights<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    r: &RunData<'_>,
) -> DrawResult<DB> {
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
    draw_mesh(&mut chart, "plant time [s]", "weight [-]")?;
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
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
    Ok(())
}
