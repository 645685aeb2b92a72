//! What a solve reports: how it ended ([`SolveStatus`]) and the plan's numbers
//! ([`SolveReport`]).

use std::time::Duration;

use crate::problem::PassCounts;

/// How deep a predicted point may sit inside a cylinder and still count as clear, m: rounding,
/// not a violation (the careful reference's solutions sit within it of the surface).
pub const INSIDE_TOLERANCE_M: f64 = 1e-6;

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SolveStatus {
    /// Tolerances met, constraint violation within tolerance, and no predicted point inside a
    /// cylinder's true surface (beyond [`INSIDE_TOLERANCE_M`]).
    Converged,
    /// The iteration budget ran out; the best iterate is returned: OpEn's, the feasible
    /// (projected) half step with the smallest fixed-point residual of the last inner problem,
    /// that is, the iterate closest to stationary for the multipliers and penalty reached.
    IterationLimit,
    /// The iteration budget (or the outer iterations) ran out with the returned plan predicted
    /// inside a cylinder: some predicted point of some scenario is more than
    /// [`INSIDE_TOLERANCE_M`] inside a cylinder's true surface (no margin), by
    /// [`SolveReport::depth_m`]. The plan is the best iterate, as for `IterationLimit`; what
    /// the solve could not do is clear the obstacles. Never a plain `IterationLimit` on such a
    /// plan (issue 39).
    InfeasibleAtLimit,
    /// The wall-clock budget ran out (real time only); the best iterate is returned, as for
    /// `IterationLimit` (the warm start when no PANOC iteration ran).
    Deadline,
    /// A non-finite value appeared; the warm start is returned unchanged.
    NumericalFailure,
}

impl SolveStatus {
    /// Every status, in declaration order.
    pub const ALL: [SolveStatus; 5] = [
        SolveStatus::Converged,
        SolveStatus::IterationLimit,
        SolveStatus::InfeasibleAtLimit,
        SolveStatus::Deadline,
        SolveStatus::NumericalFailure,
    ];

    /// The solve stopped at its iteration (or outer-iteration) budget, its plan clear or not.
    pub fn at_iteration_limit(self) -> bool {
        matches!(self, SolveStatus::IterationLimit | SolveStatus::InfeasibleAtLimit)
    }

    /// The status a solve that ended with `status` reports for a plan whose smallest predicted
    /// clearance is `min_clearance_m`: `InfeasibleAtLimit` for an `IterationLimit` plan inside a
    /// cylinder, `status` otherwise.
    pub fn with_clearance(self, min_clearance_m: f64) -> SolveStatus {
        if self == SolveStatus::IterationLimit && min_clearance_m < -INSIDE_TOLERANCE_M {
            SolveStatus::InfeasibleAtLimit
        } else {
            self
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            SolveStatus::Converged => "converged",
            SolveStatus::IterationLimit => "iteration_limit",
            SolveStatus::InfeasibleAtLimit => "infeasible_at_limit",
            SolveStatus::Deadline => "deadline",
            SolveStatus::NumericalFailure => "numerical_failure",
        }
    }
}

/// The outcome of one solve.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SolveReport {
    pub status: SolveStatus,
    /// PANOC iterations, summed over the outer iterations.
    pub iterations: usize,
    pub outer_iterations: usize,
    /// Wall-clock time measured by the solver.
    pub solve_time: Duration,
    /// The spec's objective `sum_i w_i J_i` at the returned inputs (no penalty, unscaled).
    pub cost: f64,
    /// `|F2|` at the returned inputs (0 when no predicted point, nor its coast with
    /// [`crate::OcpDefinition::coast_time_s`], enters an inflated cylinder).
    pub constraint_violation: f64,
    /// Penalty parameter of the last outer iteration.
    pub penalty_parameter: f64,
    /// Smallest true clearance (no margin) of any predicted point of any scenario, m.
    pub min_clearance_m: f64,
    /// Forward and adjoint passes this solve ran, the final evaluation included.
    pub passes: PassCounts,
}

impl SolveReport {
    /// How deep the plan's deepest predicted point sits inside a cylinder's true surface, m (0
    /// when every point is clear).
    pub fn depth_m(&self) -> f64 {
        (-self.min_clearance_m).max(0.0)
    }
}
