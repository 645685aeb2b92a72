//! The check of one candidate plan: finite, inside the bounds, and safe on the nonlinear
//! predictions (paper mode) or under the fail-safe check; and, for a candidate that fails, how
//! close it comes to passing.

use crate::fail_safe::Envelope;
use crate::qp::{NonlinearCheck, check_on_nonlinear_model};

use super::{CandidateCheck, Rejection, SafetyLayer};

impl SafetyLayer {
    /// Finite, inside the bounds, and safe on the nonlinear predictions of the instance set in
    /// the evaluator.
    pub(super) fn check_plan(&mut self, u: &[f64]) -> CandidateCheck {
        if u.len() != 3 * self.n || u.iter().any(|v| !v.is_finite()) {
            return CandidateCheck::rejected(Rejection::NotFinite);
        }
        let tol = 1e-9;
        let inside = u
            .iter()
            .enumerate()
            .all(|(k, v)| *v >= self.bounds.min[k % 3] - tol && *v <= self.bounds.max[k % 3] + tol);
        if !inside {
            return CandidateCheck::rejected(Rejection::OutOfBounds);
        }
        let NonlinearCheck { cost, min_clearance_m, min_altitude_m, finite } = match &self.fail_safe {
            None => check_on_nonlinear_model(&mut self.evaluator, &self.cylinders, u),
            Some(fs) => {
                // The plan's predictions give only the cost. Only the first input is sent: it,
                // then braking, under every delay.
                let cost = self.evaluator.objective_at_inputs(u);
                let command = [u[0], u[1], u[2]];
                let Envelope { min_clearance_m, min_altitude_m, finite } = match &self.in_flight {
                    Some(in_flight) => fs.envelope_real_time(&self.x0, &self.u_prev, in_flight, &command),
                    None => fs.envelope(&self.x0, &self.u_prev, &command),
                };
                NonlinearCheck { cost, min_clearance_m, min_altitude_m, finite: finite && cost.is_finite() }
            }
        };
        let rejection = if !finite {
            Some(Rejection::NotFinite)
        } else if min_clearance_m < self.settings.required_clearance_m {
            Some(Rejection::Collision { min_clearance_m })
        } else if self.lowest_allowed_m().is_some_and(|floor| {
            // A vehicle already below the floor cannot be above it at once: it may not sink
            // further.
            min_altitude_m < floor.min(self.x0[2]) - 1e-9
        }) {
            Some(Rejection::BelowFloor { min_altitude_m })
        } else {
            None
        };
        CandidateCheck { cost, min_clearance_m, min_altitude_m, rejection }
    }

    /// How close a checked candidate comes to passing: its smallest margin over the required
    /// clearance and the floor, m (`-inf` when it was not evaluated or is not finite).
    pub(super) fn safety_score(&self, c: &CandidateCheck) -> f64 {
        // Only plans that are solutions and fail nothing but the safety checks compete (and
        // braking, always): not a failed solve's warm start, not a non-finite plan.
        let competes =
            matches!(c.rejection, None | Some(Rejection::Collision { .. } | Rejection::BelowFloor { .. }));
        if !competes || c.min_clearance_m.is_nan() {
            return f64::NEG_INFINITY;
        }
        let clearance = c.min_clearance_m - self.settings.required_clearance_m;
        let floor = match self.lowest_allowed_m() {
            Some(z) if c.min_altitude_m.is_finite() => c.min_altitude_m - z.min(self.x0[2]),
            _ => f64::INFINITY,
        };
        clearance.min(floor)
    }

    /// The lowest altitude a candidate may reach: the floor when there is one, else, with the
    /// fail-safe check, the ground (see [`BrakingCheck::ground_z_m`](crate::fail_safe::BrakingCheck::ground_z_m)).
    pub(super) fn lowest_allowed_m(&self) -> Option<f64> {
        self.settings.qp.min_altitude_m.or_else(|| self.fail_safe.as_ref().and_then(|fs| fs.check.ground_z_m))
    }
}
