//! What a QP solve reports: how it ended ([`QpStatus`]) and the plan's numbers ([`QpReport`]).

use std::time::Duration;

use clarabel::solver::SolverStatus;

/// How a QP solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum QpStatus {
    /// Solved to the tolerances.
    Solved,
    /// Solved to clarabel's reduced tolerances (its `AlmostSolved`).
    SolvedReducedAccuracy,
    /// The hard QP has no solution, but its elastic form has (see
    /// [`QpSettings::elastic_penalty_per_m`](super::QpSettings::elastic_penalty_per_m)): the inputs keep their bounds, and violate the
    /// rows the nominal violated by at most [`QpReport::elastic_violation_m`], never more than
    /// the nominal did.
    SolvedElastic,
    /// The linear constraints have no common point (a certificate was found).
    Infeasible,
    /// The QP objective is unbounded below on the constraints (a certificate was found).
    Unbounded,
    /// The iteration budget ran out.
    IterationLimit,
    /// The wall-clock budget ran out.
    Deadline,
    /// Numerical trouble: non-finite data, lack of progress, a factorization failure.
    NumericalError,
}

impl QpStatus {
    pub fn name(self) -> &'static str {
        match self {
            QpStatus::Solved => "solved",
            QpStatus::SolvedReducedAccuracy => "solved_reduced_accuracy",
            QpStatus::SolvedElastic => "solved_elastic",
            QpStatus::Infeasible => "infeasible",
            QpStatus::Unbounded => "unbounded",
            QpStatus::IterationLimit => "iteration_limit",
            QpStatus::Deadline => "deadline",
            QpStatus::NumericalError => "numerical_error",
        }
    }

    /// True when the solve produced inputs (to be checked on the nonlinear model).
    pub fn has_solution(self) -> bool {
        matches!(self, QpStatus::Solved | QpStatus::SolvedReducedAccuracy | QpStatus::SolvedElastic)
    }

    pub(super) fn from_clarabel(s: SolverStatus) -> Self {
        match s {
            SolverStatus::Solved => QpStatus::Solved,
            SolverStatus::AlmostSolved => QpStatus::SolvedReducedAccuracy,
            SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible => QpStatus::Infeasible,
            SolverStatus::DualInfeasible | SolverStatus::AlmostDualInfeasible => QpStatus::Unbounded,
            SolverStatus::MaxIterations => QpStatus::IterationLimit,
            SolverStatus::MaxTime => QpStatus::Deadline,
            _ => QpStatus::NumericalError,
        }
    }
}

/// The outcome of one QP solve.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct QpReport {
    pub status: QpStatus,
    /// Interior-point iterations, summed over the SQP rounds.
    pub iterations: u32,
    /// SQP rounds run (the last one decides the status).
    pub rounds: usize,
    /// Clarabel's own measured time (setup + solve), summed over the rounds. The
    /// linearization and condensing are not included (see the `qp` bench for the total).
    pub solve_time: Duration,
    /// Rows of the last QP: bounds (2 per input), half-planes, floor rows.
    pub num_constraints: usize,
    /// Half-planes in the last QP.
    pub num_half_planes: usize,
    /// Rows clarabel saw in the last solve: bounds (2 per QP variable) and the selected
    /// half-plane and floor rows (see [`QpSettings::lazy_slack_m`](super::QpSettings::lazy_slack_m)).
    pub num_clarabel_rows: usize,
    /// Clarabel solves, summed over the SQP rounds (more than one per round when lazy rows
    /// were violated).
    pub clarabel_solves: usize,
    /// The spec's objective `sum_i w_i J_i` of the returned inputs on the nonlinear model
    /// (NaN without a solution).
    pub cost: f64,
    /// Smallest true clearance (no margin) of any nonlinear predicted point of any scenario
    /// to any cylinder surface, m (+inf without cylinders, NaN without a solution).
    pub min_clearance_m: f64,
    /// Lowest nonlinear predicted altitude of any scenario, m (NaN without a solution).
    pub min_altitude_m: f64,
    /// Largest violation of the QP's own linear constraints at the returned inputs (0 when
    /// satisfied; NaN without a solution).
    pub linear_violation: f64,
    /// Half-planes and floor rows the nominal violated, which got an elastic slack in the
    /// last QP.
    pub num_elastic_rows: usize,
    /// Largest slack of an elastic row at the solution, m: how far the QP had to leave a point
    /// inside an inflated cylinder or below the floor (0 when every row holds; NaN without a
    /// solution).
    pub elastic_violation_m: f64,
}
