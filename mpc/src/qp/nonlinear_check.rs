//! A plan checked on the nonlinear model: the QP is only as good as its linearization, so its
//! solution (and, in the safety layer, every candidate) is evaluated on every scenario's Euler
//! prediction.

use mav::Cylinder;

use crate::problem::Evaluator;

/// An input sequence checked on the nonlinear (Euler) predictions of every scenario.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct NonlinearCheck {
    /// The spec's objective `sum_i w_i J_i`.
    pub cost: f64,
    /// Smallest true clearance (no margin) of predicted points `1..=N` of every scenario, m.
    pub min_clearance_m: f64,
    /// Lowest predicted altitude of points `1..=N` of every scenario, m.
    pub min_altitude_m: f64,
    /// Every predicted value is finite.
    pub finite: bool,
}

/// Evaluates inputs `u` on the instance set in `ev`: objective, true clearance, altitude.
pub(crate) fn check_on_nonlinear_model(
    ev: &mut Evaluator,
    cylinders: &[Cylinder],
    u: &[f64],
) -> NonlinearCheck {
    let cost = ev.objective_at_inputs(u);
    let mut min_clearance_m = f64::INFINITY;
    let mut min_altitude_m = f64::INFINITY;
    let mut finite = cost.is_finite();
    for i in 0..ev.num_scenarios() {
        for x in &ev.predicted_states(i)[1..] {
            finite &= x.iter().all(|v| v.is_finite());
            let (c, _) = mav::geometry::min_clearance(cylinders, x[0], x[1], x[2]);
            min_clearance_m = min_clearance_m.min(c);
            min_altitude_m = min_altitude_m.min(x[2]);
        }
    }
    if !finite {
        min_clearance_m = f64::NAN;
        min_altitude_m = f64::NAN;
    }
    NonlinearCheck { cost, min_clearance_m, min_altitude_m, finite }
}
