//! Styling shared by every figure: the embedded font, sizes, colours and labels, and the
//! axis ranges and series drawn from the per-cycle rows.

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use crate::run::CycleRow;

pub(crate) const FONT: &str = "sans-serif";
pub(crate) const FONT_BYTES: &[u8] = include_bytes!("../../../assets/DejaVuSans.ttf");

pub(crate) const TITLE_PX: u32 = 26;
pub(crate) const LABEL_PX: u32 = 18;
pub(crate) const TICK_PX: u32 = 15;
pub(crate) const BOUND: RGBColor = RGBColor(200, 30, 30);
pub(crate) const CYLINDER: RGBColor = RGBColor(120, 120, 120);
pub(crate) const PALETTE: [RGBColor; 6] = [
    RGBColor(27, 110, 180),
    RGBColor(217, 95, 2),
    RGBColor(27, 158, 119),
    RGBColor(117, 112, 179),
    RGBColor(231, 41, 138),
    RGBColor(102, 102, 102),
];

/// The legend of every figure: its series' labels at `position`, on a light box.
pub(crate) fn draw_legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> super::DrawResult<DB> {
    chart
        .configure_series_labels()
        .position(position)
        .label_font((FONT, TICK_PX))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.4))
        .draw()
}

/// A 2-D chart in metres on both axes.
pub(crate) type MetreChart<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// A chart on `area` whose x and y have the same scale (metres per pixel), so that a circle is
/// drawn round: the shorter of `x` and `y` widened about its centre to the plotting area's
/// proportions. Margins and label areas as every 2-D figure's.
pub(crate) fn equal_axes_chart<'a, 'b, DB: DrawingBackend + 'a>(
    area: &'a DrawingArea<DB, plotters::coord::Shift>,
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
) -> Result<MetreChart<'a, DB>, DrawingAreaErrorKind<DB::ErrorType>> {
    fn builder<'a, 'b, DB: DrawingBackend>(
        area: &'a DrawingArea<DB, plotters::coord::Shift>,
    ) -> ChartBuilder<'a, 'b, DB> {
        let mut b = ChartBuilder::on(area);
        b.margin(15).margin_right(25).x_label_area_size(50).y_label_area_size(60);
        b
    }
    // Building a chart without a caption draws nothing: this one only measures the area.
    let (pw, ph) = builder(area).build_cartesian_2d(0.0..1.0, 0.0..1.0)?.plotting_area().dim_in_pixel();
    let (pw, ph) = (f64::from(pw.max(1)), f64::from(ph.max(1)));
    let m_per_px = ((x.end - x.start) / pw).max((y.end - y.start) / ph);
    let (cx, cy) = ((x.start + x.end) / 2.0, (y.start + y.end) / 2.0);
    let (hw, hh) = (m_per_px * pw / 2.0, m_per_px * ph / 2.0);
    builder(area).build_cartesian_2d((cx - hw)..(cx + hw), (cy - hh)..(cy + hh))
}

/// The axes and grid of every 2-D figure: the axis descriptions, the fonts, a light grid.
pub(crate) fn draw_mesh<'a, DB: DrawingBackend + 'a>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    x_desc: &str,
    y_desc: &str,
) -> super::DrawResult<DB> {
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .axis_desc_style((FONT, LABEL_PX))
        .label_style((FONT, TICK_PX))
        .light_line_style(BLACK.mix(0.05))
        .bold_line_style(BLACK.mix(0.15))
        .draw()
}

pub(crate) fn controller_color(controller: &str, i: usize) -> RGBColor {
    match controller {
        "multistage" => PALETTE[0],
        "nmpc" => PALETTE[1],
        _ => PALETTE[(i + 2) % PALETTE.len()],
    }
}

pub(crate) fn controller_label(controller: &str) -> &str {
    match controller {
        "multistage" => "multi-stage NMPC",
        "nmpc" => "standard NMPC",
        other => other,
    }
}

pub(crate) fn title_font() -> TextStyle<'static> {
    (FONT, TITLE_PX).into_font().color(&BLACK)
}

pub(crate) fn panel_font() -> TextStyle<'static> {
    (FONT, LABEL_PX + 2).into_font().color(&BLACK)
}

/// Finite `(min, max)` of `values`, or `fallback` when there is none.
pub(crate) fn extent(values: impl Iterator<Item = f64>, fallback: (f64, f64)) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo.is_finite() && hi.is_finite() { (lo, hi) } else { fallback }
}

/// Widens `(lo, hi)` by `frac` of its span (at least `min_pad`).
pub(crate) fn pad((lo, hi): (f64, f64), frac: f64, min_pad: f64) -> std::ops::Range<f64> {
    let p = ((hi - lo) * frac).max(min_pad);
    (lo - p)..(hi + p)
}

/// `(t, f(row))` for the rows where both are finite; commands hold until the next cycle, so
/// they are drawn as steps.
pub(crate) fn steps(rows: &[CycleRow], f: impl Fn(&CycleRow) -> f64) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(2 * rows.len());
    for (k, row) in rows.iter().enumerate() {
        let v = f(row);
        if !(row.t_s.is_finite() && v.is_finite()) {
            continue;
        }
        out.push((row.t_s, v));
        if let Some(next) = rows.get(k + 1).filter(|n| n.t_s.is_finite()) {
            out.push((next.t_s, v));
        }
    }
    out
}

pub(crate) fn samples(rows: &[CycleRow], f: impl Fn(&CycleRow) -> f64) -> Vec<(f64, f64)> {
    rows.iter().map(|r| (r.t_s, f(r))).filter(|(t, v)| t.is_finite() && v.is_finite()).collect()
}
