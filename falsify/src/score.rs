//! The robustness score of a finished run: continuous, negative exactly when the run fails the
//! property, and the further below zero the worse.
//!
//! - The clearance of a run is the smallest clearance to every cylinder over the run (the
//!   plant's, at every integration step: negative inside, by the depth), and, if the vehicle
//!   touched the ground after lift-off, minus the deepest ground contact. The ground counts only
//!   when touched: every run starts on it, so its clearance to the ground is 0 at the start of
//!   every run and would say nothing.
//! - `collision`: the clearance. `clearance_below_m = X`: the clearance minus `X`.
//! - `collision_or_miss`: the clearance, but a run that ended at its time limit without a
//!   collision scores minus its distance to the goal (a miss is a failure however close).

use crate::table::Property;

/// When a run came closest to a cylinder: the time of the smallest clearance among its
/// `samples` (`(time_s, position_m)`, the controller's samples, one per cycle), s; `None` for a
/// run without a sample or a scenario without a cylinder. The first such sample on ties.
///
/// What a run says beyond its score: a long delay matters when the vehicle is near an
/// obstacle, and this says when that was (`lab falsify --dump` writes it beside each run).
pub fn closest_approach_s(
    obstacles: &[mav::Cylinder],
    samples: impl IntoIterator<Item = (f64, [f64; 3])>,
) -> Option<f64> {
    let mut best: Option<(f64, f64)> = None;
    for (t_s, [x, y, z]) in samples {
        let (clearance, _) = mav::geometry::min_clearance(obstacles, x, y, z);
        if clearance.is_finite() && best.is_none_or(|(c, _)| clearance < c) {
            best = Some((clearance, t_s));
        }
    }
    best.map(|(_, t)| t)
}

/// What the score reads of a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunFacts {
    pub reached: bool,
    /// Some entry into a cylinder or the ground.
    pub collided: bool,
    /// Smallest clearance to any cylinder over the run, m (negative: inside; infinite: none).
    pub min_clearance_m: f64,
    /// The deepest contact with the ground, m (0: none).
    pub ground_depth_m: f64,
    /// Where the run ended, from the goal, m.
    pub distance_to_goal_m: f64,
}

impl RunFacts {
    /// The clearance part of the score, m.
    pub fn clearance_m(&self) -> f64 {
        let c = if self.ground_depth_m > 0.0 {
            self.min_clearance_m.min(-self.ground_depth_m)
        } else {
            self.min_clearance_m
        };
        // A collision is an entry, at negative clearance: keep the sign even for a contact
        // recorded as 0 deep.
        if self.collided { c.min(-f64::MIN_POSITIVE) } else { c }
    }

    /// The facts of `summary`, a run of `scenario`.
    #[cfg(feature = "mpc")]
    pub fn of(summary: &mpc::RunSummary, scenario: &mav::Scenario) -> Self {
        let [x, y, z] = summary.final_position_m;
        let [gx, gy, gz] = scenario.goal_m;
        let ground_depth_m =
            summary.collisions.iter().filter(|c| c.kind == "ground").map(|c| c.depth_m).fold(0.0, f64::max);
        Self {
            reached: summary.reached,
            collided: summary.collided,
            min_clearance_m: summary.min_clearance_m,
            ground_depth_m,
            distance_to_goal_m: ((x - gx).powi(2) + (y - gy).powi(2) + (z - gz).powi(2)).sqrt(),
        }
    }
}

impl Property {
    /// The robustness of a run: `< 0` exactly when the run fails the property, m.
    pub fn robustness(self, run: &RunFacts) -> f64 {
        let clearance = run.clearance_m();
        match self {
            Property::Collision => clearance,
            Property::ClearanceBelowM(x) => clearance - x,
            Property::CollisionOrMiss if run.collided || run.reached => clearance,
            // Missed: failed whatever the distance (a vehicle at the goal too fast for it).
            Property::CollisionOrMiss => -run.distance_to_goal_m.max(f64::MIN_POSITIVE),
        }
    }

    /// Whether a run fails the property.
    pub fn fails(self, run: &RunFacts) -> bool {
        self.robustness(run) < 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(
        reached: bool,
        collided: bool,
        min_clearance_m: f64,
        ground_depth_m: f64,
        distance: f64,
    ) -> RunFacts {
        RunFacts { reached, collided, min_clearance_m, ground_depth_m, distance_to_goal_m: distance }
    }

    #[test]
    fn a_clear_run_scores_its_clearance_a_collision_its_depth_below_zero() {
        let clear = run(true, false, 0.12, 0.0, 0.1);
        assert_eq!(Property::Collision.robustness(&clear), 0.12);
        assert_eq!(Property::CollisionOrMiss.robustness(&clear), 0.12);
        assert!((Property::ClearanceBelowM(0.05).robustness(&clear) - 0.07).abs() < 1e-15);
        assert!(Property::ClearanceBelowM(0.2).fails(&clear));
        let into_cylinder = run(false, true, -0.03, 0.0, 2.0);
        for p in [Property::Collision, Property::CollisionOrMiss, Property::ClearanceBelowM(0.0)] {
            assert_eq!(p.robustness(&into_cylinder), -0.03, "{p:?}");
        }
        let into_ground = run(false, true, 0.4, 0.02, 2.0);
        assert_eq!(Property::Collision.robustness(&into_ground), -0.02);
        // An entry recorded 0 deep is still a collision.
        assert!(Property::Collision.fails(&run(false, true, 0.3, 0.0, 1.0)));
    }

    #[test]
    fn the_closest_approach_is_the_sample_nearest_any_cylinder_first_on_ties() {
        let obstacles = [mav::Cylinder::new(0.0, 0.0, 1.0), mav::Cylinder::new(5.0, 0.0, 1.0)];
        let at = |x: f64| [x, 0.0, 0.5];
        // Clearances 1.5, 0.5 (to the second), 1.0, 0.5 again: the first 0.5 wins.
        let samples = [(0.0, at(2.5)), (0.1, at(3.5)), (0.2, at(3.0)), (0.3, at(1.5))];
        assert_eq!(closest_approach_s(&obstacles, samples), Some(0.1));
        assert_eq!(closest_approach_s(&[], samples), None, "no cylinder");
        assert_eq!(closest_approach_s(&obstacles, []), None, "no sample");
    }

    #[test]
    fn a_missed_goal_fails_collision_or_miss_only_scoring_its_distance() {
        let missed = run(false, false, 0.2, 0.0, 1.5);
        assert_eq!(Property::Collision.robustness(&missed), 0.2);
        assert_eq!(Property::CollisionOrMiss.robustness(&missed), -1.5);
        // At the goal but too fast for it by the time limit: still a miss.
        assert!(Property::CollisionOrMiss.fails(&run(false, false, 0.2, 0.0, 0.0)));
    }
}
