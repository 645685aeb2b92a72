//! Search spaces: a box of named ranges, and what a point of it flies.
//!
//! A point becomes a scenario's round trip as a trace of one delay per cycle (the kind every
//! transport replays to the bit, and what a failure is written as): the delay of cycle `k` is
//! the space's delay at the time the cycle's command is sent, `t_{k+1} = t_k + max(min_cycle_s,
//! d_k)` (the closed loop's own clock), for as many cycles as the run can have.
//!
//! - [`Space::signal`]: a segment-wise signal (`[falsify.signal]`): levels, and the times
//!   between which they hold or along which they are interpolated.
//! - [`Space::family`]: the ranged parameters of a delay family (a `[sweep]` family: the
//!   scenario loader builds it, since it owns the family), its process drawn with a fixed seed
//!   through `delay::DelayLine` at the same send times, clipped at `max_delay_s`.

use std::fmt;
use std::sync::Arc;

use delay::{DelayLine, DelaysTable, Direction};
use mav::Scenario;

use crate::table::{Interpolation, SignalTable};

/// One coordinate of a space: its name in the outputs and its range.
#[derive(Debug, Clone, PartialEq)]
pub struct Dim {
    /// E.g. `level[1]`, `switch_s[0]`, `shape`, `states[1].delay_s`.
    pub name: String,
    pub lo: f64,
    pub hi: f64,
}

impl Dim {
    pub fn new(name: impl Into<String>, lo: f64, hi: f64) -> Self {
        Self { name: name.into(), lo, hi }
    }
}

/// A family's delays table for a point (its ranged parameters in the order of the dims).
pub type FamilyTable = dyn Fn(&[f64]) -> DelaysTable + Send + Sync;

#[derive(Clone)]
enum Kind {
    Signal(SignalTable),
    Family { table: Arc<FamilyTable>, process_seed: u64, max_delay_s: f64 },
}

/// A search space: a box of ranges and the delays of each of its points.
#[derive(Clone)]
pub struct Space {
    /// The space's name in the outputs (`signal`, or the family's).
    pub name: String,
    pub dims: Vec<Dim>,
    kind: Kind,
}

impl fmt::Debug for Space {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut d = f.debug_struct("Space");
        d.field("name", &self.name).field("dims", &self.dims);
        match &self.kind {
            Kind::Signal(s) => d.field("signal", s),
            Kind::Family { process_seed, max_delay_s, .. } => {
                d.field("process_seed", process_seed).field("max_delay_s", max_delay_s)
            }
        }
        .finish()
    }
}

impl Space {
    /// The signal of `[falsify.signal]` (validated): `points` levels in `[min_delay_s,
    /// max_delay_s]` (dims `level[i]`), then, with `free_times`, the times in `[0, duration_s]`
    /// (dims `switch_s[i]`, the `points - 1` switches of a constant signal, or `time_s[i]`, the
    /// `points` knots of a linear one; sorted before use, so any order of them is a signal).
    pub fn signal(spec: &SignalTable) -> Self {
        let k = spec.points as usize;
        let mut dims: Vec<Dim> =
            (0..k).map(|i| Dim::new(format!("level[{i}]"), spec.min_delay_s, spec.max_delay_s)).collect();
        if spec.free_times {
            let (name, n) = match spec.interpolation {
                Interpolation::Constant => ("switch_s", k - 1),
                Interpolation::Linear => ("time_s", k),
            };
            dims.extend((0..n).map(|i| Dim::new(format!("{name}[{i}]"), 0.0, spec.duration_s)));
        }
        Self { name: "signal".into(), dims, kind: Kind::Signal(spec.clone()) }
    }

    /// A family's ranged parameters (`dims`, in the order `table` takes them): each point's
    /// table drawn with `process_seed`, clipped at `max_delay_s`.
    pub fn family(
        name: impl Into<String>,
        dims: Vec<Dim>,
        table: Arc<FamilyTable>,
        process_seed: u64,
        max_delay_s: f64,
    ) -> Self {
        Self { name: name.into(), dims, kind: Kind::Family { table, process_seed, max_delay_s } }
    }

    /// The delay of each cycle of a run of `scenario` at `point`, s.
    pub fn delays(&self, point: &[f64], scenario: &Scenario) -> Result<Vec<f64>, String> {
        if point.len() != self.dims.len() {
            return Err(format!(
                "a point of {} has {} coordinates, not {}",
                self.name,
                self.dims.len(),
                point.len()
            ));
        }
        match &self.kind {
            Kind::Signal(spec) => {
                let knots = knots(spec, point);
                Ok(trace_at_send_times(scenario, spec.max_delay_s, |t_ns| {
                    level_at(spec.interpolation, &knots, mav::ns_to_s(t_ns))
                }))
            }
            Kind::Family { table, process_seed, max_delay_s } => {
                let table = table(point);
                let network = table
                    .to_network(*process_seed, &mut |f| Err(format!("{f}: a family names no file")))
                    .map_err(|e| format!("family {}: {e}", self.name))?;
                let mut line = DelayLine::new(Direction::ControllerToPlant, network.to_plant)
                    .map_err(|e| format!("family {}: {e}", self.name))?;
                // A message the line loses (the family's `loss`) is a `lost` entry.
                Ok(trace_at_send_times(scenario, *max_delay_s, |t_ns| {
                    let draw = line.draw(t_ns);
                    if draw.lost && !draw.trace_ended { delay::LOST_S } else { draw.sampled_delay_s }
                }))
            }
        }
    }

    /// `scenario` with the delays of `point` as its round trip (a trace named `name`, not
    /// looping: it holds a delay for every cycle the run can have).
    pub fn scenario(&self, scenario: &Scenario, point: &[f64], name: &str) -> Result<Scenario, String> {
        let mut s = scenario.clone();
        s.delays = Some(DelaysTable::trace(name, self.delays(point, scenario)?, false));
        Ok(s)
    }
}

/// The signal's `(time_s, level_s)` knots, sorted by time. Constant: each level starts at its
/// switch (the first at 0). Linear: the levels at their times.
fn knots(spec: &SignalTable, point: &[f64]) -> Vec<(f64, f64)> {
    let k = spec.points as usize;
    let levels = &point[..k];
    let mut times: Vec<f64> = if spec.free_times {
        point[k..].to_vec()
    } else {
        match spec.interpolation {
            Interpolation::Constant => (1..k).map(|i| spec.duration_s * i as f64 / k as f64).collect(),
            Interpolation::Linear if k == 1 => vec![0.0],
            Interpolation::Linear => (0..k).map(|i| spec.duration_s * i as f64 / (k - 1) as f64).collect(),
        }
    };
    times.sort_by(f64::total_cmp);
    if spec.interpolation == Interpolation::Constant {
        times.insert(0, 0.0);
    }
    times.into_iter().zip(levels.iter().copied()).collect()
}

/// The signal at `t_s`.
fn level_at(interpolation: Interpolation, knots: &[(f64, f64)], t_s: f64) -> f64 {
    let after = knots.partition_point(|&(t, _)| t <= t_s);
    match (interpolation, after) {
        (_, 0) => knots.first().map_or(0.0, |k| k.1),
        (Interpolation::Constant, i) => knots[i - 1].1,
        (Interpolation::Linear, i) if i == knots.len() => knots[i - 1].1,
        (Interpolation::Linear, i) => {
            let ((t0, l0), (t1, l1)) = (knots[i - 1], knots[i]);
            if t1 > t0 { l0 + (l1 - l0) * (t_s - t0) / (t1 - t0) } else { l1 }
        }
    }
}

/// The most cycles a run of `scenario` can have, plus one (as `hilbench sweep`'s traces).
pub fn max_cycles(scenario: &Scenario) -> usize {
    let cycle_ns = delay::s_to_ns(scenario.min_cycle_s).unwrap_or(1).max(1);
    let limit_ns = delay::s_to_ns(scenario.max_duration_s).unwrap_or(u64::MAX);
    usize::try_from(limit_ns / cycle_ns).unwrap_or(usize::MAX).saturating_add(2)
}

/// One delay per cycle of a run of `scenario`: `delay_at(t_k)` at each send time, clipped to
/// `[0, clip_s]` (NaN: 0; a loss, [`delay::LOST_S`], kept), `t_{k+1} = t_k + max(min_cycle_s, d_k)`.
pub fn trace_at_send_times(
    scenario: &Scenario,
    clip_s: f64,
    mut delay_at: impl FnMut(u64) -> f64,
) -> Vec<f64> {
    let cycle_ns = delay::s_to_ns(scenario.min_cycle_s).unwrap_or(0);
    let mut t_ns = 0u64;
    (0..max_cycles(scenario))
        .map(|_| {
            let d = delay_at(t_ns);
            let d = if d.is_nan() {
                0.0
            } else if delay::is_lost(d) {
                d
            } else {
                d.clamp(0.0, clip_s)
            };
            t_ns = t_ns.saturating_add(cycle_ns.max(delay::delay_ns(d)));
            d
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(points: u32, interpolation: Interpolation, free_times: bool) -> SignalTable {
        SignalTable {
            points,
            interpolation,
            duration_s: 10.0,
            min_delay_s: 0.0,
            max_delay_s: 0.4,
            free_times,
        }
    }

    #[test]
    fn a_constant_signal_holds_each_level_from_its_switch_in_any_order_of_the_switches() {
        let s = Space::signal(&spec(3, Interpolation::Constant, true));
        let names: Vec<&str> = s.dims.iter().map(|d| d.name.as_str()).collect();
        assert_eq!(names, ["level[0]", "level[1]", "level[2]", "switch_s[0]", "switch_s[1]"]);
        let scenario = Scenario::paper_2();
        // 0.05 s until 2 s, 0.3 s until 3 s, then 0.1 s; the switches given out of order.
        let d = s.delays(&[0.05, 0.3, 0.1, 3.0, 2.0], &scenario).expect("delays");
        assert_eq!(d.len(), max_cycles(&scenario));
        let mut t = 0.0;
        for (k, dk) in d.iter().take(100).enumerate() {
            let want = if t < 2.0 - 1e-9 {
                0.05
            } else if t < 3.0 - 1e-9 {
                0.3
            } else {
                0.1
            };
            assert_eq!(*dk, want, "cycle {k} at {t} s");
            t += dk.max(scenario.min_cycle_s);
        }
    }

    #[test]
    fn a_linear_signal_interpolates_between_its_knots_and_holds_outside() {
        let knots = [(1.0, 0.1), (3.0, 0.3)];
        let at = |t| level_at(Interpolation::Linear, &knots, t);
        assert_eq!((at(0.0), at(1.0), at(3.0), at(9.0)), (0.1, 0.1, 0.3, 0.3));
        assert!((at(2.0) - 0.2).abs() < 1e-15);
        // Evenly spaced times: 0, 5, 10 s.
        let s = spec(3, Interpolation::Linear, false);
        assert_eq!(knots_of(&s, &[0.0, 0.4, 0.0]), vec![(0.0, 0.0), (5.0, 0.4), (10.0, 0.0)]);
        let s = spec(2, Interpolation::Constant, false);
        assert_eq!(knots_of(&s, &[0.2, 0.1]), vec![(0.0, 0.2), (5.0, 0.1)]);
    }

    fn knots_of(s: &SignalTable, point: &[f64]) -> Vec<(f64, f64)> {
        knots(s, point)
    }

    #[test]
    fn a_family_point_is_drawn_with_the_space_seed_and_clipped() {
        let table: Arc<FamilyTable> = Arc::new(|p: &[f64]| DelaysTable {
            kind: Some("uniform".into()),
            min_s: Some(p[0]),
            max_s: Some(p[0] + 1.0),
            ..DelaysTable::default()
        });
        let s = Space::family("u", vec![Dim::new("min_s", 0.0, 0.2)], table, 7, 0.5);
        let scenario = Scenario::paper_2();
        let a = s.delays(&[0.1], &scenario).expect("delays");
        assert_eq!(a, s.delays(&[0.1], &scenario).expect("again"));
        assert!(a.iter().all(|d| (0.1..=0.5).contains(d)));
        assert!(a.contains(&0.5), "clipped at 0.5");
        assert!(s.delays(&[0.1, 0.2], &scenario).is_err());
    }
}
