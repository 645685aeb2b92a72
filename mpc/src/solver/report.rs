//! What a solve reports: how it ended ([`SolveStatus`]) and the plan's numbers
//! ([`SolveReport`]).

use std::time::Duration;

use crate::problem::PassCounts;

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SolveStatus {
    /// Tolerances met, constraint violation within tolerance.
    Converged,
    /// The iteration budget ran out; the best iterate is returned: OpEn's, the feasible
    /// (projected) half step with the smallest fixed-point residual of the last inner problem,
    /// that is, the iterate closest to stationary for the multipliers and penalty reached.
    IterationLimit,
    /// The wall-clock budget ran out (real time only); the best iterate is returned, as for
    /// `IterationLimit` (the warm start when no PANOC iteration ran).
    Deadline,
    /// A non-finite value appeared; the warm start is returned unchanged.
    NumericalFailure,
}

impl SolveStatus {
    pub fn name(self) -> &'static str {
        match self {
            SolveStatus::Converged => "converged",
            SolveStatus::IterationLimit => "iteration_limit",
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
    /// `|F2|` at the returned inputs (0 when no predicted point enters an inflated cylinder).
    pub constraint_violation: f64,
    /// Penalty parameter of the last outer iteration.
    pub penalty_parameter: f64,
    /// Smallest true clearance (no margin) of any predicted point of any scenario, m.
    pub min_clearance_m: f64,
    /// Forward and adjoint passes this solve ran, the final evaluation included.
    pub passes: PassCounts,
}
