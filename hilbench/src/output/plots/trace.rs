//! The figure of `hilbench trace stats|fit`: a recorded link's delays against the probe
//! number (losses marked), their histogram on a log density axis with the fitted densities, and
//! their ECDF on a log delay axis beside the fitted CDFs (`trace stats` fits nothing, and its
//! captions say so).
//!
//! It takes plain values (the trace's entries, each fit as a label and two functions), so it
//! needs nothing of `linkfit` but what the caller hands it: `linkfit::Model::pdf` and `cdf`.

use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use plotters::coord::Shift;
use plotters::prelude::*;

use super::style::{BOUND, PALETTE, draw_legend, extent, panel_font, title_font};
use super::{DrawResult, register_font};

/// A fitted law, as the figure draws it: delays in s in, density in 1/s and CDF out.
pub struct FittedLaw<'a> {
    pub label: String,
    pub pdf: &'a dyn Fn(f64) -> f64,
    pub cdf: &'a dyn Fn(f64) -> f64,
}

/// Size of the figure, px.
const SIZE: (u32, u32) = (1500, 520);

/// Writes `<stem>.png` and `<stem>.svg` into `dir`: the entries `entries_s` (delays in s, and
/// `delay::LOST_S` for a loss) and the fits. Returns the paths written.
pub fn write(
    dir: &Path,
    stem: &str,
    title: &str,
    entries_s: &[f64],
    fits: &[FittedLaw<'_>],
) -> anyhow::Result<Vec<PathBuf>> {
    register_font()?;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let delivered: Vec<f64> =
        entries_s.iter().copied().filter(|d| !delay::is_lost(*d) && d.is_finite() && *d > 0.0).collect();
    anyhow::ensure!(!delivered.is_empty(), "{title}: no delay to plot");
    let png = dir.join(format!("{stem}.png"));
    let svg = dir.join(format!("{stem}.svg"));
    {
        let root = BitMapBackend::new(&png, SIZE).into_drawing_area();
        draw(&root, title, entries_s, &delivered, fits)
            .map_err(|e| anyhow!("cannot draw {}: {e}", png.display()))?;
        root.present().map_err(|e| anyhow!("cannot write {}: {e}", png.display()))?;
    }
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, SIZE).into_drawing_area();
        draw(&root, title, entries_s, &delivered, fits)
            .map_err(|e| anyhow!("cannot draw {}: {e}", svg.display()))?;
        root.present().map_err(|e| anyhow!("cannot draw {}: {e}", svg.display()))?;
    }
    std::fs::write(&svg, text).with_context(|| format!("cannot write {}", svg.display()))?;
    Ok(vec![png, svg])
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    entries_s: &[f64],
    delivered: &[f64],
    fits: &[FittedLaw<'_>],
) -> DrawResult<DB> {
    root.fill(&WHITE)?;
    let root = root.titled(title, title_font())?;
    let areas = root.split_evenly((1, 3));
    let color = PALETTE[0];
    let ms: Vec<f64> = delivered.iter().map(|d| d * 1e3).collect();
    let (lo, hi) = extent(ms.iter().copied(), (0.0, 1.0));
    let losses = entries_s.iter().filter(|d| delay::is_lost(**d)).count();

    // Time series: delay of each probe, a loss as a red tick at the top.
    let n = entries_s.len().max(2) as f64;
    let y_hi = (hi * 1.1).max(lo + 1e-6);
    let mut chart = ChartBuilder::on(&areas[0])
        .caption(format!("{} probes, {losses} lost", entries_s.len()), panel_font())
        .margin(10)
        .margin_right(20)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..n, 0.0..y_hi)?;
    chart
        .configure_mesh()
        .x_desc("probe")
        .x_labels(6)
        .x_label_formatter(&|k| format!("{k:.0}"))
        .y_desc("delay [ms]")
        .axis_desc_style((super::style::FONT, super::style::LABEL_PX))
        .label_style((super::style::FONT, super::style::TICK_PX))
        .light_line_style(BLACK.mix(0.05))
        .bold_line_style(BLACK.mix(0.15))
        .draw()?;
    chart.draw_series(LineSeries::new(
        entries_s.iter().enumerate().filter(|(_, d)| !delay::is_lost(**d)).map(|(k, d)| (k as f64, d * 1e3)),
        color.mix(0.7),
    ))?;
    if losses > 0 {
        chart
            .draw_series(
                entries_s
                    .iter()
                    .enumerate()
                    .filter(|(_, d)| delay::is_lost(**d))
                    .map(|(k, _)| Cross::new((k as f64, y_hi * 0.97), 4, BOUND.stroke_width(2))),
            )?
            .label("lost")
            .legend(|(x, y)| Cross::new((x + 10, y), 4, BOUND.stroke_width(2)));
        draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
    }

    // Histogram as a density (1/ms) with each fit's density, on a log density axis: a spike
    // mode holding 1 % of the delays is a hundredth of the main mode's height, invisible on a
    // linear axis. The axis starts a decade below the lowest bar (one delay in its bin).
    let bins = 40usize;
    let width = ((hi - lo) / bins as f64).max(1e-6);
    let mut counts = vec![0usize; bins];
    for v in &ms {
        counts[(((v - lo) / width) as usize).min(bins - 1)] += 1;
    }
    let total = ms.len() as f64;
    let density: Vec<f64> = counts.iter().map(|c| *c as f64 / (total * width)).collect();
    let y_max = extent(density.iter().copied(), (0.0, 1.0)).1.max(1e-9) * 2.0;
    let y_floor = (density.iter().copied().filter(|h| *h > 0.0).fold(f64::INFINITY, f64::min) / 10.0)
        .min(y_max / 100.0);
    let curve = |f: &dyn Fn(f64) -> f64| -> Vec<(f64, f64)> {
        (0..=300)
            .map(|i| lo + (hi - lo) * i as f64 / 300.0)
            .map(|x| (x, f(x * 1e-3) * 1e-3))
            .filter(|q| q.1.is_finite())
            .map(|(x, y)| (x, y.clamp(y_floor, y_max)))
            .collect()
    };
    let curves: Vec<Vec<(f64, f64)>> = fits.iter().map(|f| curve(f.pdf)).collect();
    let caption = if fits.is_empty() {
        "histogram (log density)"
    } else {
        "histogram (log density) and fitted densities"
    };
    let mut chart = ChartBuilder::on(&areas[1])
        .caption(caption, panel_font())
        .margin(10)
        .margin_right(20)
        .x_label_area_size(45)
        .y_label_area_size(80)
        .build_cartesian_2d(lo..hi.max(lo + 1e-6), (y_floor..y_max).log_scale())?;
    // Six labels on the delay axis, rounded: forty bins' worth of long labels overlapped.
    chart
        .configure_mesh()
        .x_desc("delay [ms]")
        .x_labels(6)
        .x_label_formatter(&|x| format!("{}", round_to(*x, 3)))
        .y_desc("density [1/ms]")
        .y_label_formatter(&|y| format!("{}", round_to(*y, 1)))
        .axis_desc_style((super::style::FONT, super::style::LABEL_PX))
        .label_style((super::style::FONT, super::style::TICK_PX))
        .light_line_style(BLACK.mix(0.05))
        .bold_line_style(BLACK.mix(0.15))
        .draw()?;
    chart.draw_series(density.iter().enumerate().filter(|(_, h)| **h > 0.0).map(|(i, h)| {
        let a = lo + width * i as f64;
        Rectangle::new([(a, y_floor), (a + width, *h)], color.mix(0.4).filled())
    }))?;
    for (i, (fit, c)) in fits.iter().zip(curves).enumerate() {
        let style = PALETTE[(i + 1) % PALETTE.len()].stroke_width(2);
        chart
            .draw_series(LineSeries::new(c, style))?
            .label(fit.label.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
    }
    if !fits.is_empty() {
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
    }

    // ECDF on a log delay axis, with each fit's CDF.
    let mut sorted = ms.clone();
    sorted.sort_unstable_by(f64::total_cmp);
    let x_lo = sorted[0].max(1e-6) * 0.9;
    let x_hi = (sorted[sorted.len() - 1] * 1.1).max(x_lo * 1.01);
    let mut chart = ChartBuilder::on(&areas[2])
        .caption(
            if fits.is_empty() { "ECDF (log axis)" } else { "ECDF (log axis) and fitted CDFs" },
            panel_font(),
        )
        .margin(10)
        .margin_right(20)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d((x_lo..x_hi).log_scale().with_key_points(log_ticks(x_lo, x_hi)), 0.0..1.0)?;
    chart
        .configure_mesh()
        .x_desc("delay [ms]")
        .x_label_formatter(&|x| format!("{}", round_to(*x, 2)))
        .y_desc("share of delays at or below")
        .axis_desc_style((super::style::FONT, super::style::LABEL_PX))
        .label_style((super::style::FONT, super::style::TICK_PX))
        .light_line_style(BLACK.mix(0.05))
        .bold_line_style(BLACK.mix(0.15))
        .draw()?;
    let m = sorted.len() as f64;
    chart.draw_series(LineSeries::new(
        sorted.iter().enumerate().flat_map(|(i, x)| [(*x, i as f64 / m), (*x, (i + 1) as f64 / m)]),
        color.stroke_width(2),
    ))?;
    for (i, fit) in fits.iter().enumerate() {
        let style = PALETTE[(i + 1) % PALETTE.len()].stroke_width(2);
        let ratio = x_hi / x_lo;
        let points = (0..=300)
            .map(|k| x_lo * ratio.powf(k as f64 / 300.0))
            .map(|x| (x, (fit.cdf)(x * 1e-3)))
            .filter(|q| q.1.is_finite());
        chart.draw_series(LineSeries::new(points, style))?;
    }
    Ok(())
}

/// Ticks for a log axis over `[lo, hi]`: 1, 2 and 5 times each power of ten inside, or,
/// when fewer than three of those fall inside (a range under a decade), seven points evenly
/// spaced in log, rounded to two significant digits.
fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let mut ticks = Vec::new();
    let mut decade = 10f64.powf(lo.log10().floor());
    while decade <= hi {
        for m in [1.0, 2.0, 5.0] {
            let t = m * decade;
            if (lo..=hi).contains(&t) {
                ticks.push(t);
            }
        }
        decade *= 10.0;
    }
    if ticks.len() >= 3 {
        return ticks;
    }
    let ratio = hi / lo;
    (1..=7).map(|k| round_to(lo * ratio.powf(k as f64 / 8.0), 2)).collect()
}

/// `x` to `digits` significant digits.
fn round_to(x: f64, digits: i32) -> f64 {
    if x == 0.0 || !x.is_finite() {
        return x;
    }
    let scale = 10f64.powi(digits - 1 - x.abs().log10().floor() as i32);
    (x * scale).round() / scale
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_trace_with_losses_and_two_fits_draws_a_png_and_an_svg_and_without_fits_claims_none() {
        let dir = std::env::temp_dir().join(format!("hilbench-trace-plot-{}", std::process::id()));
        let entries: Vec<f64> = (0..500)
            .map(|k| if k % 50 == 7 { delay::LOST_S } else { 0.02 + 0.01 * ((k * 37 % 100) as f64 / 100.0) })
            .collect();
        let uniform_pdf = |x: f64| if (0.02..=0.03).contains(&x) { 100.0 } else { 0.0 };
        let uniform_cdf = |x: f64| ((x - 0.02) / 0.01).clamp(0.0, 1.0);
        let flat_pdf = |_: f64| 50.0;
        let flat_cdf = |x: f64| (x / 0.02).clamp(0.0, 1.0);
        let fits = [
            FittedLaw { label: "uniform".into(), pdf: &uniform_pdf, cdf: &uniform_cdf },
            FittedLaw { label: "flat".into(), pdf: &flat_pdf, cdf: &flat_cdf },
        ];
        let written = write(&dir, "link", "a link", &entries, &fits).expect("drawn");
        assert_eq!(written.len(), 2);
        let svg = std::fs::read_to_string(&written[1]).expect("the svg");
        assert!(svg.contains("10 lost") && svg.contains("uniform"), "the svg names the losses and the fits");
        assert!(std::fs::metadata(&written[0]).expect("the png").len() > 10_000);
        assert!(write(&dir, "none", "none", &[delay::LOST_S], &fits).is_err(), "nothing to plot");
        // `trace stats` fits nothing: no caption claims a fit.
        let written = write(&dir, "stats", "a link", &entries, &[]).expect("drawn");
        let svg = std::fs::read_to_string(&written[1]).expect("the svg");
        assert!(
            svg.contains("histogram (log density)") && !svg.contains("fitted"),
            "{}",
            written[1].display()
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
