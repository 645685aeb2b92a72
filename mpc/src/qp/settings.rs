//! The QP fallback's settings (validated data with documented defaults) and the budget of one
//! solve.

use std::time::Duration;

use crate::error::MpcError;

/// Settings of the QP fallback (validated in [`QpFallback::new`](super::QpFallback::new)).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct QpSettings {
    /// A cylinder gets a half-plane at a predicted point when the nominal point is within this
    /// horizontal distance of its inflated surface (or inside it), m.
    pub activation_distance_m: f64,
    /// Optional floor: every predicted point of every scenario keeps `z >= min_altitude_m`, m.
    /// Off (`None`) in paper mode, which has no floor.
    pub min_altitude_m: Option<f64>,
    /// Optional trust region: `|u_j[c] - u_bar_j[c]| <= trust_region[c]` per channel
    /// (`[m/s^2, rad, rad]`), intersected with the input bounds. `None`: bounds only.
    pub trust_region: Option<[f64; 3]>,
    /// Linearize-and-solve rounds per solve: round `k + 1` linearizes around the solution of
    /// round `k` (a few steps of sequential quadratic programming). 1 is the plain fallback.
    pub sqp_rounds: usize,
    /// Interior-point iterations per QP.
    pub max_iterations: u32,
    /// Clarabel's absolute and relative duality-gap tolerance.
    pub gap_tolerance: f64,
    /// Clarabel's primal/dual feasibility tolerance.
    pub feasibility_tolerance: f64,
    /// Move blocking: the first `unblocked_steps` steps of the correction `u - u_bar` are free,
    /// each later block of `block_steps` steps shares one correction (the nominal keeps its own
    /// value at every step). `block_steps = 1` is the unblocked QP in all `3N` inputs.
    pub unblocked_steps: usize,
    /// Steps per block after the unblocked ones (the last block may be shorter); see
    /// [`QpSettings::unblocked_steps`].
    pub block_steps: usize,
    /// Lazy rows: a half-plane or floor row whose nominal slack exceeds this starts outside
    /// clarabel's QP; when a solution violates such a row, it joins the QP (with every lazy
    /// row within 0.1 m of violation) and the QP is solved again; m. The returned solution is
    /// the QP's with every row either way (a solution of a relaxation that satisfies the
    /// dropped rows is optimal for the whole QP). `f64::INFINITY`: every row from the start.
    pub lazy_slack_m: f64,
    /// Screening of the lazy rows' first solve: when more rows are within
    /// [`QpSettings::lazy_slack_m`] than the QP has variables, the first solve takes of each run
    /// (consecutive points of one scenario near one cylinder, or near the floor) only the local
    /// minima of the nominal slack, the points of closest approach. Past the number of
    /// variables most such rows cannot be active at a solution (at most one per variable are,
    /// at a vertex), yet each adds to every interior-point iteration's factorization; between
    /// two cylinders 125 rows were within 0.2 m and 6 were active (BENCHMARKS.md). The rows a
    /// screened solution violates join in the next solve, so the result is the same QP's.
    pub screen_runs: bool,
    /// A lazy row within this of violation at a solution joins the QP with the violated ones,
    /// m: a little ahead of need, so the next solve does not stop just short of the next row.
    pub lazy_add_margin_m: f64,
    /// Re-solves that add only the violated (and nearly violated) lazy rows; if a solution
    /// still violates a lazy row after them, the next re-solve takes every row. Each re-solve
    /// is a full clarabel solve under the same [`QpBudget`].
    pub max_lazy_rounds: usize,
    /// Clarabel's iterative refinement of each KKT solve. Off by default: it was a quarter of
    /// the QP's instructions (a KKT product and a triangular solve per refinement step) and
    /// changed neither the iteration counts nor the solutions of the benchmark problems beyond
    /// the solver's tolerances (BENCHMARKS.md); clarabel's termination tests use the true
    /// residuals either way.
    pub iterative_refinement: bool,
    /// Elastic rows: a half-plane or floor row that the nominal point already violates gets a
    /// slack `0 <= s <= (its nominal violation)` priced at this cost per metre in the
    /// objective, so the QP pushes the point out as far as it can instead of being infeasible.
    /// Such points are common: PANOC's plans may cut into the inflated cylinders (or dip below
    /// the floor) by centimetres (its constraint tolerance), and the first points of a
    /// prediction hardly depend on the inputs, so without slacks a hard row there makes the
    /// whole QP infeasible although a useful, truly clear plan exists. The price is far above
    /// the rows' multipliers, so when the hard QP is feasible the elastic one has the same
    /// solution (tested); when it is not, the status is [`QpStatus::SolvedElastic`](super::QpStatus::SolvedElastic) and the
    /// report gives the remaining violation. `None` (the default): hard rows only
    /// (infeasibility is then reported as such). Measured (BENCHMARKS.md): `1e5` solves every
    /// QP along the paper closed loops and returns more truly clear plans, but the safety layer
    /// then accepts QP plans that use up the margin, and the paper's controller (no dead-time
    /// compensation) collided in 6 of 20 uniform delay traces instead of 2; so it is opt-in.
    pub elastic_penalty_per_m: Option<f64>,
}

/// An elastic slack above this (m) at the solution means the hard QP had no solution: the
/// interior point leaves zero slacks at about its feasibility tolerance, far below this.
pub(super) const ELASTIC_TOLERANCE_M: f64 = 1e-6;

impl Default for QpSettings {
    fn default() -> Self {
        Self {
            activation_distance_m: 2.0,
            min_altitude_m: None,
            trust_region: None,
            sqp_rounds: 1,
            max_iterations: 100,
            gap_tolerance: 1e-7,
            feasibility_tolerance: 1e-8,
            unblocked_steps: 6,
            block_steps: 6,
            lazy_slack_m: 0.2,
            screen_runs: true,
            lazy_add_margin_m: 0.01,
            max_lazy_rounds: 3,
            iterative_refinement: false,
            elastic_penalty_per_m: None,
        }
    }
}

impl QpSettings {
    /// Names the first invalid setting.
    pub fn validate(&self) -> Result<(), MpcError> {
        let bad = |field: &'static str, reason: &'static str| Err(MpcError::InvalidSetting { field, reason });
        if !(self.activation_distance_m.is_finite() && self.activation_distance_m >= 0.0) {
            return bad("activation_distance_m", "must be finite and >= 0");
        }
        if self.min_altitude_m.is_some_and(|z| !z.is_finite()) {
            return bad("min_altitude_m", "must be finite");
        }
        if self.trust_region.is_some_and(|tr| tr.iter().any(|v| !(v.is_finite() && *v > 0.0))) {
            return bad("trust_region", "every channel must be finite and > 0");
        }
        if self.sqp_rounds == 0 {
            return bad("sqp_rounds", "must be > 0");
        }
        if self.max_iterations == 0 {
            return bad("max_iterations", "must be > 0");
        }
        if !(self.gap_tolerance.is_finite() && self.gap_tolerance > 0.0) {
            return bad("gap_tolerance", "must be finite and > 0");
        }
        if !(self.feasibility_tolerance.is_finite() && self.feasibility_tolerance > 0.0) {
            return bad("feasibility_tolerance", "must be finite and > 0");
        }
        if self.elastic_penalty_per_m.is_some_and(|p| !(p.is_finite() && p > 0.0)) {
            return bad("elastic_penalty_per_m", "must be finite and > 0");
        }
        if self.block_steps == 0 {
            return bad("block_steps", "must be > 0");
        }
        if self.lazy_slack_m.is_nan() {
            return bad("lazy_slack_m", "must not be NaN");
        }
        if !(self.lazy_add_margin_m.is_finite() && self.lazy_add_margin_m >= 0.0) {
            return bad("lazy_add_margin_m", "must be finite and >= 0");
        }
        Ok(())
    }
}

/// What one QP solve may spend. Iterations bound a lockstep solve (deterministic); a
/// wall-clock limit (clarabel's own timer) is added in real time.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct QpBudget {
    /// Overrides [`QpSettings::max_iterations`] when set.
    pub max_iterations: Option<u32>,
    /// Wall-clock limit of each clarabel solve.
    pub deadline: Option<Duration>,
}
