//! The round-trip delays of one run against time, their histogram, the Gamma fitted to them
//! and the scenario's own delay model.

use plotters::coord::Shift;
use plotters::prelude::*;
use statrs::distribution::{Continuous, Gamma};

use super::style::{
    BOUND, controller_color, controller_label, draw_legend, draw_mesh, extent, panel_font, title_font,
};
use super::{DrawResult, RunData};
use crate::run::CycleRow;

/// The round-trip delays of a run: `(plant time of the sample the command came from, delay)`,
/// s. Row k knows the delay of command k-1.
pub fn delays(rows: &[CycleRow]) -> Vec<(f64, f64)> {
    rows.windows(2)
        .map(|w| (w[0].t_s, w[1].known_delay_s))
        .filter(|(t, d)| t.is_finite() && d.is_finite() && *d >= 0.0)
        .collect()
}

/// Shape and scale (s) of the Gamma fitted to `delays_s` as the controller fits its window
/// (`mpc::DelayWindow::fit`: moments with the population variance), so that the figure shows
/// the controller's fit over the run's delays, not another estimator's.
pub fn gamma_fit(delays_s: &[f64]) -> Option<(f64, f64)> {
    let mut window = mpc::DelayWindow::new(delays_s.len());
    for &d in delays_s {
        window.push(d);
    }
    window.fit(2).map(|g| (g.shape, g.scale_s))
}

/// Density of Gamma(shape, scale) at `x` (same unit as the scale).
fn gamma_pdf(shape: f64, scale: f64, x: f64) -> Option<f64> {
    let g = Gamma::new(shape, 1.0 / scale).ok()?;
    Some(g.pdf(x))
}

pub(super) fn draw_delays<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    r: &RunData<'_>,
) -> DrawResult<DB> {
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
    draw_mesh(&mut chart, "plant time of the sample the command came from [s]", "delay [ms]")?;
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
    let model = r.scenario.gamma_round_trip();
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
    draw_mesh(&mut chart, "delay [ms]", "density [1/ms]")?;
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
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
    Ok(())
}
