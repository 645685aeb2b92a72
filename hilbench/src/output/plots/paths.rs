//! What the two path figures (from above and in 3D) share: the paths, their labels, the
//! cylinders' outlines, the horizontal range and the legend.

use mav::Scenario;
use plotters::coord::Shift;
use plotters::prelude::*;

use super::style::{FONT, LABEL_PX, controller_label, extent};
use super::{DrawResult, RunData};

/// The range of horizontal coordinate `axis` (0: x, 1: y) that shows the paths, every
/// cylinder whole, the start and the goal.
pub(crate) fn horizontal_extent(paths: &[Vec<[f64; 3]>], scenario: &Scenario, axis: usize) -> (f64, f64) {
    let centre = |c: &mav::Cylinder| if axis == 0 { c.x_m } else { c.y_m };
    let values = paths
        .iter()
        .flatten()
        .map(|p| p[axis])
        .chain(scenario.obstacles.iter().flat_map(|c| [centre(c) - c.radius_m, centre(c) + c.radius_m]))
        .chain([scenario.start[axis], scenario.goal_m[axis]]);
    extent(values, (-1.0, 1.0))
}

/// The vehicle's positions at the start of every cycle, then where it ended.
pub(crate) fn path(r: &RunData<'_>) -> Vec<[f64; 3]> {
    r.rows
        .iter()
        .map(|row| [row.state[0], row.state[1], row.state[2]])
        .chain(std::iter::once(r.summary.final_position_m))
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .collect()
}

pub(crate) fn circle(x: f64, y: f64, r: f64) -> Vec<(f64, f64)> {
    const SEGMENTS: usize = 72;
    (0..=SEGMENTS)
        .map(|i| {
            let a = i as f64 / SEGMENTS as f64 * std::f64::consts::TAU;
            (x + r * a.cos(), y + r * a.sin())
        })
        .collect()
}

pub(crate) fn path_label(r: &RunData<'_>) -> String {
    let s = &r.summary;
    let outcome = match (s.reached, s.time_to_goal_s) {
        (true, Some(t)) => format!("reached in {t:.1} s"),
        _ => "not reached".to_string(),
    };
    let collided = if s.collided { ", COLLIDED" } else { "" };
    format!(
        "{}: {:.2} m, {outcome}, min clearance {:+.2} m{collided}",
        controller_label(&s.controller),
        s.path_length_m,
        s.min_clearance_m
    )
}

/// The sample drawn before a legend entry.
pub(crate) enum Swatch {
    Line(RGBColor),
    Fill(RGBAColor),
    Dot(RGBColor),
    Cross,
    Triangle(RGBColor),
}

/// A legend in its own area: `wide` entries one per line, then `narrow` ones side by side.
pub(crate) fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    wide: &[(Swatch, String)],
    narrow: &[(Swatch, String)],
) -> DrawResult<DB> {
    let font = (FONT, LABEL_PX).into_font().color(&BLACK);
    let left = 80;
    let mut y = 18;
    let entry = |x: i32, y: i32, swatch: &Swatch, text: &str| -> DrawResult<DB> {
        match swatch {
            Swatch::Line(c) => area.draw(&PathElement::new(vec![(x, y), (x + 24, y)], c.stroke_width(3)))?,
            Swatch::Fill(c) => area.draw(&Rectangle::new([(x, y - 7), (x + 24, y + 7)], c.filled()))?,
            Swatch::Dot(c) => area.draw(&Circle::new((x + 12, y), 6, c.filled()))?,
            Swatch::Cross => area.draw(&Cross::new((x + 12, y), 6, BLACK.stroke_width(3)))?,
            Swatch::Triangle(c) => area.draw(&TriangleMarker::new((x + 12, y), 7, c.filled()))?,
        }
        area.draw(&Text::new(text.to_string(), (x + 34, y - (LABEL_PX as i32) / 2 - 1), font.clone()))
    };
    for (swatch, text) in wide {
        entry(left, y, swatch, text)?;
        y += 30;
    }
    let mut x = left;
    for (swatch, text) in narrow {
        entry(x, y, swatch, text)?;
        x += 60 + 10 * text.chars().count() as i32;
    }
    Ok(())
}
