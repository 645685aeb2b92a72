//! The round-trip delays of one run against time, their histogram, the Gamma fitted to them
//! and the scenario's own delay model. Delays far beyond the bulk (spikes) are one tail bar
//! that says how many they are ([`Histogram`]), and the Gamma says when it fits badly
//! ([`FitQuality`]): a mixture of a link's ordinary delays and its spikes is no Gamma.

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

/// How well the Gamma fits: the Kolmogorov–Smirnov distance of the delays from it, and the
/// distance beyond which it is a poor fit (`linkfit::ks_limit_95`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitQuality {
    pub ks: f64,
    pub limit: f64,
}

impl FitQuality {
    pub fn of(delays_s: &[f64], (shape, scale_s): (f64, f64)) -> Self {
        let mut sorted = delays_s.to_vec();
        sorted.sort_by(f64::total_cmp);
        let law = linkfit::Model::Gamma { shape, scale_s };
        Self { ks: linkfit::ks_distance(&sorted, |x| law.cdf(x)), limit: linkfit::ks_limit_95(sorted.len()) }
    }

    pub fn poor(&self) -> bool {
        self.ks.is_nan() || self.ks > self.limit
    }
}

/// The histogram of the delays, ms: `bins` bins of `width` from `x0` over the bulk, and the
/// delays beyond `median + 10 MAD` (at least 10 ms beyond the median) counted in a tail, so
/// that a few spikes of 800 ms neither squeeze the bulk into a bin or two nor vanish as bars
/// a pixel high.
#[derive(Debug, Clone, PartialEq)]
pub struct Histogram {
    pub x0: f64,
    pub width: f64,
    pub counts: Vec<usize>,
    pub tail: Option<Tail>,
}

/// The delays of a [`Histogram`] beyond its bins.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tail {
    /// Every delay in the tail is longer than this, ms.
    pub beyond_ms: f64,
    pub count: usize,
    pub max_ms: f64,
}

impl Histogram {
    pub const BINS: usize = 25;

    pub fn of(ms: &[f64]) -> Self {
        let mut sorted: Vec<f64> = ms.iter().copied().filter(|v| v.is_finite()).collect();
        sorted.sort_by(f64::total_cmp);
        let tail = (sorted.len() >= 10)
            .then(|| {
                let median = sorted[sorted.len() / 2];
                let mut dev: Vec<f64> = sorted.iter().map(|v| (v - median).abs()).collect();
                dev.sort_by(f64::total_cmp);
                let beyond_ms = median + (10.0 * dev[dev.len() / 2]).max(10.0);
                let count = sorted.iter().filter(|v| **v > beyond_ms).count();
                (count > 0).then(|| Tail { beyond_ms, count, max_ms: sorted[sorted.len() - 1] })
            })
            .flatten();
        let body = || sorted.iter().copied().filter(|v| tail.is_none_or(|t| *v <= t.beyond_ms));
        let (lo, hi) = extent(body(), (0.0, 1.0));
        let width = ((hi - lo.min(hi)) / Self::BINS as f64).max(1.0);
        let x0 = (lo / width).floor() * width;
        let mut counts = vec![0usize; Self::BINS + 1];
        for v in body() {
            counts[(((v - x0) / width).floor().max(0.0) as usize).min(Self::BINS)] += 1;
        }
        Self { x0, width, counts, tail }
    }
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
    let hi = extent(ms.iter().copied(), (0.0, 1.0)).1;
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

    // Histogram as a density (1/ms), the fitted Gamma and the scenario's own delay model; the
    // tail's bar, if any, one bin right of the bins, in red.
    let Histogram { x0, width, counts, tail } = Histogram::of(&ms);
    let bins = counts.len();
    let n = ms.len().max(1) as f64;
    let density: Vec<f64> = counts.iter().map(|&c| c as f64 / (n * width)).collect();
    let tail_x = x0 + width * (bins + 1) as f64;
    let tail_density = tail.map(|t| t.count as f64 / (n * width));
    let delays_s: Vec<f64> = d.iter().map(|q| q.1).collect();
    let fit = gamma_fit(&delays_s);
    let model = r.scenario.gamma_round_trip();
    let bins_hi = x0 + width * bins as f64;
    let x_hi = if tail.is_some() { tail_x + width * 2.0 } else { bins_hi };
    let x_lo = (x0 - width).max(0.0);
    let curve = |(shape, scale_s): (f64, f64)| -> Vec<(f64, f64)> {
        (0..=200)
            .map(|i| x_lo + (bins_hi - x_lo) * i as f64 / 200.0)
            .filter_map(|x| gamma_pdf(shape, scale_s * 1e3, x).map(|p| (x, p)))
            .filter(|q| q.1.is_finite())
            .collect()
    };
    let fit_curve = fit.map(curve).unwrap_or_default();
    let model_curve = model.map(curve).unwrap_or_default();
    let y_max = extent(
        density.iter().copied().chain(tail_density).chain(fit_curve.iter().chain(&model_curve).map(|q| q.1)),
        (0.0, 1.0),
    )
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
    if let (Some(t), Some(h)) = (tail, tail_density) {
        chart
            .draw_series([Rectangle::new(
                [(tail_x, 0.0), (tail_x + width, h)],
                super::style::PALETTE[3].mix(0.7).filled(),
            )])?
            .label(format!(
                "right bar: {} delays beyond {:.0} ms (up to {:.0} ms), not to scale",
                t.count, t.beyond_ms, t.max_ms
            ))
            .legend(|(x, y)| {
                Rectangle::new([(x, y - 6), (x + 20, y + 6)], super::style::PALETTE[3].mix(0.7).filled())
            });
        chart.draw_series([Text::new(
            format!("{} > {:.0} ms", t.count, t.beyond_ms),
            (tail_x, h + y_max * 0.05),
            (super::style::FONT, super::style::TICK_PX).into_font(),
        )])?;
    }
    if let Some((k, theta)) = fit {
        let quality = FitQuality::of(&delays_s, (k, theta));
        let verdict = if quality.poor() {
            format!("poor fit: KS distance {:.2} > {:.2}", quality.ks, quality.limit)
        } else {
            format!("KS distance {:.2}", quality.ks)
        };
        chart
            .draw_series(LineSeries::new(fit_curve, BLACK.stroke_width(2)))?
            .label(format!("Gamma fitted by moments: k = {k:.1}, θ = {:.1} ms ({verdict})", theta * 1e3))
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
