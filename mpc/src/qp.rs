//! The QP-linearized fallback: the problem of [`OcpDefinition`] linearized around a nominal
//! input sequence, condensed to a convex QP in the inputs (move-blocked corrections by
//! default, see below) and solved with clarabel's interior-point method.
//!
//! Each scenario's Euler prediction is linearized around the nominal inputs `u_bar` and the
//! nominal trajectory they produce: `x_k(u) ~ x_k(u_bar) + S_k (u - u_bar)`. The cost is the
//! spec's objective with that linear model (its Gauss-Newton approximation, convex, with the
//! multi-stage weights), the inputs keep their box bounds (optionally intersected with a trust
//! region around `u_bar`), and every cylinder is replaced, at every predicted point of every
//! scenario, by the half-plane tangent to the inflated cylinder on the side of the nominal
//! point: `n^T (p_k - c) >= R` with `n` the horizontal unit vector from the axis to the nominal
//! point. The half-plane lies outside the disc, so a linear prediction that satisfies it is
//! clear of the inflated cylinder. Only cylinders whose inflated surface is within
//! `activation_distance_m` of the nominal point get a half-plane, to keep the QP small. An
//! optional floor adds `z_k >= min_altitude_m`.
//!
//! Optionally ([`QpSettings::elastic_penalty_per_m`]), half-planes and floor rows that the
//! nominal point already violates are elastic: a bounded, heavily priced slack lets such a
//! row stay violated by at most the nominal's violation. With hard rows, a point the inputs
//! cannot move out in time (the first points of a prediction barely depend on the inputs)
//! makes the QP infeasible: a tenth to a sixth of the QPs along the paper closed loops
//! (BENCHMARKS.md). When the hard QP is feasible the elastic one has its solution; when it is
//! not, the status says so ([`QpStatus::SolvedElastic`]).
//!
//! The QP is only as good as the linearization: its solution is evaluated on the nonlinear
//! model (the spec's objective and the true clearance of every scenario's prediction) and the
//! report says both, so that a caller (see [`crate::safety`]) never trusts the linear model.
//!
//! Condensing: `H = sum_i w_i S_i^T 2Qx S_i + input terms` is built column by column with one
//! forward sensitivity pass and one adjoint pass per input (`O(M N^2)` small vector
//! operations, no `8N x 3N` matrix products), the gradient with one adjoint pass per scenario.
//!
//! Speed (issue 5; measured in `BENCHMARKS.md`). The condensed QP is dense: `H` is a full
//! matrix and a half-plane at point `k` involves every input before `k`, so each of clarabel's
//! ~20 KKT factorizations costs about `sum over rows of width^2` with QDLDL's scalar scatter
//! loop (faer's supernodal LDL is no faster here: every row is its own size-1 supernode). Two
//! settings cut that work:
//! - Move blocking ([`QpSettings::unblocked_steps`], [`QpSettings::block_steps`]): the QP's
//!   variables are the corrections `d` in `u = u_bar + T d`, free for the first steps and held
//!   over blocks of steps after them; the nominal keeps its own value at every step. Default
//!   6 + 6: 12 blocks, 36 variables instead of 120 for `N = 40`. This restricts the QP (the
//!   late corrections are coarser), a fidelity loss measured in the bench; `block_steps = 1`
//!   is the full QP.
//! - Lazy rows ([`QpSettings::lazy_slack_m`]): rows whose nominal slack is large start outside
//!   clarabel's QP and join it only when a solution violates them. This is exact: the QP is
//!   re-solved until its solution satisfies every row, so the result is the full QP's.
//!   When the candidates outnumber the QP's variables, the first solve takes only each run's
//!   closest points ([`QpSettings::screen_runs`]): near a cylinder, consecutive points of a
//!   prediction give nearly parallel rows of which one or two are active.

use std::time::Duration;

use clarabel::algebra::CscMatrix;
use clarabel::solver::{DefaultSettings, DefaultSolver, IPSolver, SolverStatus, SupportedConeT};

use crate::problem::{Evaluator, OcpDefinition, validate_instance};
use crate::solver::{MpcError, invalid_input};
use mav::{Cylinder, InputBounds, ModelParams};

/// Settings of the QP fallback (validated in [`QpFallback::new`]).
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
    /// solution (tested); when it is not, the status is [`QpStatus::SolvedElastic`] and the
    /// report gives the remaining violation. `None` (the default): hard rows only
    /// (infeasibility is then reported as such). Measured (BENCHMARKS.md): `1e5` solves every
    /// QP along the paper closed loops and returns more truly clear plans, but the safety layer
    /// then accepts QP plans that use up the margin, and the paper's controller (no dead-time
    /// compensation) collided in 6 of 20 uniform delay traces instead of 2; so it is opt-in.
    pub elastic_penalty_per_m: Option<f64>,
}

/// An elastic slack above this (m) at the solution means the hard QP had no solution: the
/// interior point leaves zero slacks at about its feasibility tolerance, far below this.
const ELASTIC_TOLERANCE_M: f64 = 1e-6;

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

/// How a QP solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum QpStatus {
    /// Solved to the tolerances.
    Solved,
    /// Solved to clarabel's reduced tolerances (its `AlmostSolved`).
    SolvedReducedAccuracy,
    /// The hard QP has no solution, but its elastic form has (see
    /// [`QpSettings::elastic_penalty_per_m`]): the inputs keep their bounds, and violate the
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

    fn from_clarabel(s: SolverStatus) -> Self {
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
    /// half-plane and floor rows (see [`QpSettings::lazy_slack_m`]).
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

/// An inflated cylinder as the half-planes see it.
#[derive(Debug, Clone, Copy)]
struct Obstacle {
    x: f64,
    y: f64,
    /// Radius plus the definition's margin.
    r: f64,
    top: f64,
}

/// The QP fallback's workspace: linearization buffers, the QP in CSC form, the last solution.
///
/// ## Memory allocation
/// Allocated in [`QpFallback::new`]: `M (N + 1)` nominal states, `M N` attitude sin/cos
/// quadruples, position sensitivities (`M N 3N` triples), the dense `3N x 3N` Hessian and its
/// blocked forms (`3B x 3N`, `3B x 3B` for `B` blocks), a dense row buffer for up to
/// `M N (n_obs + 1)` half-plane and floor rows with their slacks, and the CSC arrays of `P`
/// and `A` at their largest size. Clarabel itself allocates its KKT system on every solve: the
/// set of half-planes changes from cycle to cycle, and clarabel's data updates keep the
/// sparsity pattern fixed.
pub struct QpFallback {
    settings: QpSettings,
    bounds: InputBounds,
    obstacles: Vec<Obstacle>,
    cylinders: Vec<Cylinder>,
    /// Checks the plans on the nonlinear model, and holds the definition's sizes, model,
    /// sampling times, costs and dead-time compensation, which the linearization reads too.
    evaluator: Evaluator,
    // Per-cycle data.
    x0: [f64; 8],
    u_prev: [f64; 3],
    weights: Vec<f64>,
    // Linearization.
    nominal: Vec<f64>,
    states: Vec<[f64; 8]>,
    trig: Vec<[f64; 4]>,
    /// d(p_k)/d(u_v) of scenario i at point k = 1..N: index `(i N + k - 1) 3N + v`.
    sens: Vec<[f64; 3]>,
    col: Vec<[f64; 8]>,
    hess: Vec<f64>,
    grad: Vec<f64>,
    /// Step `j`'s correction is the QP variables `3 block_of[j] .. 3 block_of[j] + 3`.
    block_of: Vec<usize>,
    num_blocks: usize,
    /// `T^T H T` (blocked Hessian, dense, `3B x 3B`) and its half-way `T^T H` (`3B x 3N`).
    hess_b: Vec<f64>,
    hess_tmp: Vec<f64>,
    // The constraints in the inputs: `lo <= u <= hi` and the dense rows `A u <= b`.
    lo: Vec<f64>,
    hi: Vec<f64>,
    rows: Vec<f64>,
    b: Vec<f64>,
    /// Per dense row, its nominal slack `b - A u_bar` and whether clarabel sees it.
    slack: Vec<f64>,
    selected: Vec<bool>,
    /// The dense rows' runs (for [`QpSettings::screen_runs`]).
    runs: RowRuns,
    /// Per dense row, the index of its elastic slack variable (after the corrections).
    elastic_of: Vec<Option<usize>>,
    /// Nominal violation (`-slack`) of each elastic row, in the slack variables' order.
    elastic_bound: Vec<f64>,
    /// Largest elastic slack of the last clarabel solution.
    elastic_violation_m: f64,
    /// The QP's right-hand side in the blocked corrections: bound rows, then the selected
    /// rows' slacks.
    b_qp: Vec<f64>,
    /// Per cylinder, the shared normal of a prediction that passes through it.
    side: Vec<Option<[f64; 2]>>,
    num_rows: usize,
    num_half_planes: usize,
    p_csc: CscMatrix<f64>,
    a_csc: CscMatrix<f64>,
    q: Vec<f64>,
    // Results.
    solution: Vec<f64>,
    has_solution: bool,
    previous: Vec<f64>,
    has_previous: bool,
}

impl QpFallback {
    pub fn new(def: &OcpDefinition, settings: QpSettings) -> Result<Self, MpcError> {
        settings.validate()?;
        if def.horizon == 0 || def.sampling_times_s.is_empty() {
            return Err(MpcError::InvalidProblem("needs a horizon and at least one sampling time".into()));
        }
        if def.sampling_times_s.iter().any(|t| !(t.is_finite() && *t > 0.0)) {
            return Err(MpcError::InvalidProblem("sampling times must be finite and > 0".into()));
        }
        def.bounds.validate().map_err(|f| MpcError::InvalidProblem(format!("input bounds: {f}")))?;
        let (m, n) = (def.num_scenarios(), def.horizon);
        let nv = 3 * n;
        let obstacles: Vec<Obstacle> = def
            .obstacles
            .iter()
            .map(|c| Obstacle { x: c.x_m, y: c.y_m, r: c.radius_m + def.obstacle_margin_m, top: c.height_m })
            .collect();
        let max_dense = m * n * (obstacles.len() + 1);
        let block_of: Vec<usize> = (0..n)
            .map(|j| match j.checked_sub(settings.unblocked_steps) {
                None => j,
                Some(late) => settings.unblocked_steps + late / settings.block_steps,
            })
            .collect();
        let num_blocks = block_of.last().map_or(0, |b| b + 1);
        let nb = 3 * num_blocks;
        let p_nnz = nb * (nb + 1) / 2;
        // Columns of P and A: the corrections, then up to one elastic slack per dense row.
        let colptr = || {
            let mut colptr = Vec::with_capacity(nb + max_dense + 1);
            colptr.resize(nb + 1, 0);
            colptr
        };
        let mut p_csc = CscMatrix::new(nb, nb, colptr(), Vec::new(), Vec::new());
        p_csc.rowval.reserve(p_nnz);
        p_csc.nzval.reserve(p_nnz);
        let mut a_csc = CscMatrix::new(0, nb, colptr(), Vec::new(), Vec::new());
        a_csc.rowval.reserve(max_dense * nb + 2 * nb + 3 * max_dense);
        a_csc.nzval.reserve(max_dense * nb + 2 * nb + 3 * max_dense);
        let mut hover = vec![0.0; nv];
        for j in 0..n {
            hover[3 * j..3 * j + 3].copy_from_slice(&def.u_ref);
        }
        Ok(Self {
            settings,
            bounds: def.bounds,
            obstacles,
            cylinders: def.obstacles.clone(),
            evaluator: Evaluator::new(def),
            x0: [0.0; 8],
            u_prev: def.u_ref,
            weights: vec![1.0; m],
            nominal: hover.clone(),
            states: vec![[0.0; 8]; m * (n + 1)],
            trig: vec![[0.0; 4]; m * n],
            sens: vec![[0.0; 3]; m * n * nv],
            col: vec![[0.0; 8]; n + 1],
            hess: vec![0.0; nv * nv],
            grad: vec![0.0; nv],
            block_of,
            num_blocks,
            hess_b: vec![0.0; nb * nb],
            hess_tmp: vec![0.0; nb * nv],
            lo: vec![0.0; nv],
            hi: vec![0.0; nv],
            rows: vec![0.0; max_dense * nv],
            b: Vec::with_capacity(max_dense),
            slack: Vec::with_capacity(max_dense),
            selected: Vec::with_capacity(max_dense),
            runs: RowRuns {
                prev: Vec::with_capacity(max_dense),
                next: Vec::with_capacity(max_dense),
                last: vec![None; def.obstacles.len() + 1],
                #[cfg(test)]
                owner: Vec::with_capacity(max_dense),
            },
            elastic_of: Vec::with_capacity(max_dense),
            elastic_bound: Vec::with_capacity(max_dense),
            elastic_violation_m: 0.0,
            b_qp: Vec::with_capacity(2 * nb + 3 * max_dense),
            side: vec![None; def.obstacles.len()],
            num_rows: 0,
            num_half_planes: 0,
            p_csc,
            a_csc,
            q: Vec::with_capacity(nb + max_dense),
            solution: hover.clone(),
            has_solution: false,
            previous: hover,
            has_previous: false,
        })
    }

    pub fn settings(&self) -> &QpSettings {
        &self.settings
    }

    /// Inputs of a plan (`3N`).
    pub fn num_variables(&self) -> usize {
        3 * self.evaluator.n
    }

    /// Variables of the QP clarabel solves: three corrections per input block (see
    /// [`QpSettings::block_steps`]).
    pub fn num_qp_variables(&self) -> usize {
        3 * self.num_blocks
    }

    /// The inputs of the last solve when it produced a solution (`N x 3`, flattened, within
    /// the bounds).
    pub fn solution(&self) -> Option<&[f64]> {
        self.has_solution.then_some(&self.solution[..])
    }

    /// The first input of the last solution, if any.
    pub fn first_input(&self) -> Option<[f64; 3]> {
        self.solution().map(|u| [u[0], u[1], u[2]])
    }

    /// The nominal inputs the last QP was linearized around.
    pub fn nominal(&self) -> &[f64] {
        &self.nominal
    }

    /// Forgets the previous solution: the next solve without a nominal linearizes at hover.
    pub fn reset(&mut self) {
        self.has_previous = false;
        self.has_solution = false;
    }

    /// Largest violation (0 when none) of the last QP's linear constraints in the inputs at
    /// inputs `u`: the bounds (with the trust region), the half-planes and the floor rows. (The
    /// move blocking is a restriction of the QP's variables, not a constraint checked here.)
    pub fn linear_violation(&self, u: &[f64]) -> f64 {
        let nv = 3 * self.evaluator.n;
        let mut worst = 0.0f64;
        for (v, &uv) in u.iter().enumerate().take(nv) {
            worst = worst.max(uv - self.hi[v]).max(self.lo[v] - uv);
        }
        for (row, b) in self.rows.chunks_exact(nv).zip(&self.b) {
            let au: f64 = row.iter().zip(u).map(|(a, x)| a * x).sum();
            worst = worst.max(au - b);
        }
        worst
    }

    fn validate_instance(
        &self,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        weights: &[f64],
        nominal: Option<&[f64]>,
    ) -> Result<(), MpcError> {
        validate_instance(self.evaluator.m, x0, u_prev, weights)?;
        if let Some(u) = nominal {
            if u.len() != 3 * self.evaluator.n {
                return Err(invalid_input("nominal", format!("must hold {} values", 3 * self.evaluator.n)));
            }
            if let Some(k) = u.iter().position(|v| !v.is_finite()) {
                return Err(invalid_input(format!("nominal[{}][{}]", k / 3, k % 3), "must be finite"));
            }
        }
        Ok(())
    }

    /// Linearizes around `nominal` (or, without one, the previous solution shifted by one
    /// step, or hover), builds the QP and solves it; repeats for `sqp_rounds`.
    ///
    /// `Err` only for invalid input (nothing changes); every solver outcome is in the report.
    /// The inputs are in [`QpFallback::solution`] only when the status has a solution.
    pub fn solve(
        &mut self,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        weights: &[f64],
        nominal: Option<&[f64]>,
        budget: &QpBudget,
    ) -> Result<QpReport, MpcError> {
        self.validate_instance(x0, u_prev, weights, nominal)?;
        self.x0 = *x0;
        self.u_prev = *u_prev;
        self.weights.copy_from_slice(weights);
        let nv = 3 * self.evaluator.n;
        match nominal {
            Some(u) => self.nominal.copy_from_slice(u),
            None if self.has_previous => {
                self.nominal[..nv - 3].copy_from_slice(&self.previous[3..]);
                let last = [self.previous[nv - 3], self.previous[nv - 2], self.previous[nv - 1]];
                self.nominal[nv - 3..].copy_from_slice(&last);
            }
            None => {
                for j in 0..self.evaluator.n {
                    self.nominal[3 * j..3 * j + 3].copy_from_slice(&self.evaluator.u_ref);
                }
            }
        }
        for (k, u) in self.nominal.iter_mut().enumerate() {
            *u = u.clamp(self.bounds.min[k % 3], self.bounds.max[k % 3]);
        }
        self.has_solution = false;
        let mut iterations = 0;
        let mut solve_time = Duration::ZERO;
        let mut status = QpStatus::NumericalError;
        let mut rounds = 0;
        let mut clarabel_solves = 0;
        for round in 0..self.settings.sqp_rounds {
            if round > 0 {
                if !status.has_solution() {
                    break;
                }
                let sol = std::mem::take(&mut self.solution);
                self.nominal.copy_from_slice(&sol);
                self.solution = sol;
            }
            rounds += 1;
            self.linearize();
            self.build_qp();
            let lazy = self.settings.lazy_slack_m;
            self.selected.clear();
            let candidates = self.slack.iter().filter(|s| **s <= lazy).count();
            // (`lazy_slack_m = INFINITY` asks for every row from the start: no screening.)
            if self.settings.screen_runs && lazy.is_finite() && candidates > 3 * self.num_blocks {
                let sl = &self.slack;
                let runs = &self.runs;
                let closest = |r: usize| {
                    runs.prev[r].is_none_or(|p| sl[r] <= sl[p]) && runs.next[r].is_none_or(|q| sl[r] <= sl[q])
                };
                self.selected.extend((0..sl.len()).map(|r| sl[r] <= lazy && closest(r)));
            } else {
                self.selected.extend(self.slack.iter().map(|s| *s <= lazy));
            }
            for lazy_round in 0.. {
                self.assemble_constraints();
                let (s, it, t) = self.solve_qp(budget);
                status = s;
                iterations += it;
                solve_time += t;
                clarabel_solves += 1;
                // A subset's infeasibility is the QP's; any other failure ends the solve too.
                if !status.has_solution()
                    || !self.add_violated_rows(lazy_round >= self.settings.max_lazy_rounds)
                {
                    break;
                }
            }
        }
        let nan = f64::NAN;
        let (mut cost, mut min_clearance_m, mut min_altitude_m, mut linear_violation) = (nan, nan, nan, nan);
        if status.has_solution() {
            linear_violation = self.linear_violation(&self.solution).max(0.0);
            for (k, u) in self.solution.iter_mut().enumerate() {
                *u = u.clamp(self.bounds.min[k % 3], self.bounds.max[k % 3]);
            }
            self.evaluator.set_instance(x0, u_prev, weights);
            let check = check_on_nonlinear_model(&mut self.evaluator, &self.cylinders, &self.solution);
            cost = check.cost;
            min_clearance_m = check.min_clearance_m;
            min_altitude_m = check.min_altitude_m;
            self.has_solution = true;
            self.previous.copy_from_slice(&self.solution);
            self.has_previous = true;
        }
        Ok(QpReport {
            status,
            iterations,
            rounds,
            solve_time,
            num_constraints: 2 * nv + self.b.len(),
            num_half_planes: self.num_half_planes,
            num_clarabel_rows: self.num_rows,
            clarabel_solves,
            cost,
            min_clearance_m,
            min_altitude_m,
            linear_violation,
            num_elastic_rows: self.elastic_bound.len(),
            elastic_violation_m: if status.has_solution() { self.elastic_violation_m } else { f64::NAN },
        })
    }

    /// Nominal trajectories, position sensitivities, Gauss-Newton Hessian and gradient.
    fn linearize(&mut self) {
        let (m, n) = (self.evaluator.m, self.evaluator.n);
        let nv = 3 * n;
        let e = EulerCoeffs::new(&self.evaluator.params);
        let EulerCoeffs { ax, ay, az, kr, kp, ir, ip, .. } = e;
        let u = &self.nominal;
        self.hess.iter_mut().for_each(|h| *h = 0.0);
        self.grad.iter_mut().for_each(|h| *h = 0.0);
        for i in 0..m {
            let dt = self.evaluator.dts[i];
            let w2 = 2.0 * self.weights[i];
            let base = i * (n + 1);
            // Nominal forward pass (from the state after the dead time, with compensation).
            let mut x = if self.evaluator.delay_compensation {
                crate::problem::euler_predict(&self.evaluator.params, &self.x0, &self.u_prev, dt)
            } else {
                self.x0
            };
            self.states[base] = x;
            for j in 0..n {
                let (sr, cr) = x[6].sin_cos();
                let (sp, cp) = x[7].sin_cos();
                self.trig[i * n + j] = [sr, cr, sp, cp];
                x = e.step(&x, &u[3 * j..3 * j + 3], dt, [sr, cr, sp, cp]);
                self.states[base + j + 1] = x;
            }
            // Gradient of the state cost at the nominal inputs: one adjoint pass.
            let mut l = [0.0f64; 8];
            for j in (0..n).rev() {
                let xs = &self.states[base + j + 1];
                for k in 0..8 {
                    l[k] += w2 * self.evaluator.q_x[k] * (xs[k] - self.evaluator.x_ref[k]);
                }
                let [sr, cr, sp, cp] = self.trig[i * n + j];
                let t = u[3 * j];
                self.grad[3 * j] += dt * (cr * sp * l[3] - sr * l[4] + cr * cp * l[5]);
                self.grad[3 * j + 1] += dt * kr * l[6];
                self.grad[3 * j + 2] += dt * kp * l[7];
                e.adjoint_step(&mut l, dt, t, [sr, cr, sp, cp]);
            }
            // Hessian and position sensitivities: per input, a forward sensitivity pass and an
            // adjoint pass.
            for v in 0..nv {
                let (jv, c) = (v / 3, v % 3);
                let [sr, cr, sp, cp] = self.trig[i * n + jv];
                // s = d x_{jv+1} / d u_v = dt B_jv e_c
                let mut s = [0.0f64; 8];
                match c {
                    0 => {
                        s[3] = dt * cr * sp;
                        s[4] = -dt * sr;
                        s[5] = dt * cr * cp;
                    }
                    1 => s[6] = dt * kr,
                    _ => s[7] = dt * kp,
                }
                // Points before jv + 1 do not depend on u_v (and are never read for it).
                self.col[jv + 1] = s;
                self.sens[(i * n + jv) * nv + v] = [s[0], s[1], s[2]];
                for j in jv + 1..n {
                    let [sr, cr, sp, cp] = self.trig[i * n + j];
                    let t = u[3 * j];
                    s = [
                        s[0] + dt * s[3],
                        s[1] + dt * s[4],
                        s[2] + dt * s[5],
                        s[3] + dt * (-ax * s[3] - t * sr * sp * s[6] + t * cr * cp * s[7]),
                        s[4] + dt * (-ay * s[4] - t * cr * s[6]),
                        s[5] + dt * (-az * s[5] - t * sr * cp * s[6] - t * cr * sp * s[7]),
                        s[6] - dt * ir * s[6],
                        s[7] - dt * ip * s[7],
                    ];
                    self.col[j + 1] = s;
                    self.sens[(i * n + j) * nv + v] = [s[0], s[1], s[2]];
                }
                // Adjoint: H[(j, c'), v] = B_j^T lambda_{j+1}, lambda_k = A_k^T lambda_{k+1} + 2 w Q s_k.
                let mut l = [0.0f64; 8];
                for j in (jv..n).rev() {
                    let s = &self.col[j + 1];
                    for k in 0..8 {
                        l[k] += w2 * self.evaluator.q_x[k] * s[k];
                    }
                    let [sr, cr, sp, cp] = self.trig[i * n + j];
                    let row = 3 * j;
                    self.hess[v * nv + row] += dt * (cr * sp * l[3] - sr * l[4] + cr * cp * l[5]);
                    self.hess[v * nv + row + 1] += dt * kr * l[6];
                    self.hess[v * nv + row + 2] += dt * kp * l[7];
                    if j > jv {
                        e.adjoint_step(&mut l, dt, u[3 * j], [sr, cr, sp, cp]);
                    }
                }
            }
        }
        // `hess[v nv + r]` holds H[r][v] for r >= 3 (v / 3): mirror into the upper triangle.
        for v in 0..nv {
            for r in (3 * (v / 3))..nv {
                if r > v {
                    self.hess[r * nv + v] = self.hess[v * nv + r];
                }
            }
        }
        // Input cost W sum_j |u_j - u_r|^2_Qu + |u_j - u_{j-1}|^2_Qdu: Hessian and gradient.
        let wsum: f64 = self.weights.iter().sum();
        let (q_u, q_du, u_ref) = (self.evaluator.q_u, self.evaluator.q_du, self.evaluator.u_ref);
        for j in 0..n {
            for c in 0..3 {
                let k = 3 * j + c;
                let uk = u[k];
                let prev = if j == 0 { self.u_prev[c] } else { u[k - 3] };
                let mut gk = q_u[c] * (uk - u_ref[c]) + q_du[c] * (uk - prev);
                let mut diag = q_u[c] + q_du[c];
                if j + 1 < n {
                    gk -= q_du[c] * (u[k + 3] - uk);
                    diag += q_du[c];
                    self.hess[k * nv + k + 3] -= 2.0 * wsum * q_du[c];
                    self.hess[(k + 3) * nv + k] -= 2.0 * wsum * q_du[c];
                }
                self.grad[k] += 2.0 * wsum * gk;
                self.hess[k * nv + k] += 2.0 * wsum * diag;
            }
        }
    }

    /// The constraints in the inputs (`lo <= u <= hi`, dense rows `A u <= b`), then the QP in
    /// the blocked corrections `d` (`u = u_bar + T d`): the CSC forms of `P = T^T H T` (upper
    /// triangle) and of `A T` below the bound rows, `q = T^T g` and the right-hand sides.
    fn build_qp(&mut self) {
        let (m, n) = (self.evaluator.m, self.evaluator.n);
        let nv = 3 * n;
        self.b.clear();
        let mut r = 0;
        // Bounds (and trust region).
        for v in 0..nv {
            let c = v % 3;
            let (mut lo, mut hi) = (self.bounds.min[c], self.bounds.max[c]);
            if let Some(tr) = self.settings.trust_region {
                lo = lo.max(self.nominal[v] - tr[c]);
                hi = hi.min(self.nominal[v] + tr[c]);
            }
            self.lo[v] = lo;
            self.hi[v] = hi;
        }
        let act = self.settings.activation_distance_m;
        let mut n_half = 0;
        self.runs.prev.clear();
        self.runs.next.clear();
        #[cfg(test)]
        self.runs.owner.clear();
        let n_obs = self.obstacles.len();
        // Dense rows of the half-planes and the floor.
        for i in 0..m {
            self.runs.start_scenario();
            // A nominal prediction that passes through a cylinder would get half-planes facing
            // backwards before the axis and forwards after it, which no trajectory satisfies.
            // Its points inside the cylinder share one normal instead: towards the side of
            // its closest approach (perpendicular to the velocity there when it hits the axis).
            for (o, ob) in self.obstacles.iter().enumerate() {
                let mut best = (f64::INFINITY, 0);
                for k in 1..=n {
                    let xb = &self.states[i * (n + 1) + k];
                    let d = (xb[0] - ob.x).hypot(xb[1] - ob.y);
                    if xb[2] < ob.top && d < best.0 {
                        best = (d, k);
                    }
                }
                self.side[o] = None;
                if best.0 < ob.r {
                    let xb = &self.states[i * (n + 1) + best.1];
                    let (dx, dy) = (xb[0] - ob.x, xb[1] - ob.y);
                    let speed = xb[3].hypot(xb[4]);
                    self.side[o] = Some(if best.0 > 1e-6 {
                        [dx / best.0, dy / best.0]
                    } else if speed > 1e-9 {
                        [-xb[4] / speed, xb[3] / speed]
                    } else {
                        [1.0, 0.0]
                    });
                }
            }
            for k in 1..=n {
                let xb = self.states[i * (n + 1) + k];
                let sens = &self.sens[(i * n + k - 1) * nv..(i * n + k) * nv];
                // Point k depends on inputs 0..k-1 only.
                let width = 3 * k;
                for (o, ob) in self.obstacles.iter().enumerate() {
                    if xb[2] >= ob.top {
                        continue;
                    }
                    let (dx, dy) = (xb[0] - ob.x, xb[1] - ob.y);
                    let d = dx.hypot(dy);
                    if d - ob.r > act {
                        continue;
                    }
                    let (nx, ny) = match self.side[o] {
                        Some([sx, sy]) if d < ob.r => (sx, sy),
                        _ if d > 1e-9 => (dx / d, dy / d),
                        _ => (1.0, 0.0),
                    };
                    // n^T (p_bar + S (u - u_bar) - c) >= R  <=>  -n^T S u <= n^T (p_bar - c) - R - n^T S u_bar
                    let row = &mut self.rows[r * nv..(r + 1) * nv];
                    let (su, norm) =
                        fill_row(row, width, &self.nominal, |v| -(nx * sens[v][0] + ny * sens[v][1]));
                    // A point the inputs cannot move constrains nothing the QP can change.
                    if norm < 1e-12 {
                        continue;
                    }
                    self.b.push(nx * dx + ny * dy - ob.r + su);
                    self.runs.link(i, o, r, k);
                    r += 1;
                    n_half += 1;
                }
                if let Some(floor) = self.settings.min_altitude_m {
                    // z_bar + S_z (u - u_bar) >= floor  <=>  -S_z u <= z_bar - floor - S_z u_bar
                    let row = &mut self.rows[r * nv..(r + 1) * nv];
                    let (su, norm) = fill_row(row, width, &self.nominal, |v| -sens[v][2]);
                    if norm < 1e-12 {
                        continue;
                    }
                    self.b.push(xb[2] - floor + su);
                    self.runs.link(i, n_obs, r, k);
                    r += 1;
                }
            }
        }
        self.num_half_planes = n_half;
        let nb = 3 * self.num_blocks;
        // The nominal slack of every dense row, `b - A u_bar` (metres: the nominal clearance to
        // the inflated cylinder, the nominal height above the floor).
        self.slack.clear();
        for (row, b) in self.rows.chunks_exact(nv).zip(&self.b) {
            let au: f64 = row.iter().zip(&self.nominal).map(|(a, u)| a * u).sum();
            self.slack.push(b - au);
        }
        // Elastic slacks for the rows the nominal violates.
        self.elastic_of.clear();
        self.elastic_bound.clear();
        let elastic = self.settings.elastic_penalty_per_m.is_some();
        for slack in &self.slack {
            if elastic && *slack < 0.0 {
                self.elastic_of.push(Some(self.elastic_bound.len()));
                self.elastic_bound.push(-slack);
            } else {
                self.elastic_of.push(None);
            }
        }
        let ne = self.elastic_bound.len();
        // T^T H (rows summed over blocks), then T^T H T (columns summed), and q = T^T g.
        self.hess_tmp.iter_mut().for_each(|h| *h = 0.0);
        self.hess_b.iter_mut().for_each(|h| *h = 0.0);
        self.q.clear();
        self.q.resize(nb, 0.0);
        self.q.resize(nb + ne, self.settings.elastic_penalty_per_m.unwrap_or(0.0));
        for v in 0..nv {
            let bv = 3 * self.block_of[v / 3] + v % 3;
            self.q[bv] += self.grad[v];
            let (src, dst) = (&self.hess[v * nv..(v + 1) * nv], &mut self.hess_tmp[bv * nv..(bv + 1) * nv]);
            dst.iter_mut().zip(src).for_each(|(d, h)| *d += h);
        }
        for rb in 0..nb {
            for v in 0..nv {
                let bv = 3 * self.block_of[v / 3] + v % 3;
                self.hess_b[rb * nb + bv] += self.hess_tmp[rb * nv + v];
            }
        }
        // P: upper triangle, column by column.
        let p = &mut self.p_csc;
        p.rowval.clear();
        p.nzval.clear();
        p.colptr[0] = 0;
        for c in 0..nb {
            for rr in 0..=c {
                // average the two halves so that P is exactly symmetric
                let val = 0.5 * (self.hess_b[rr * nb + c] + self.hess_b[c * nb + rr]);
                p.rowval.push(rr);
                p.nzval.push(val);
            }
            p.colptr[c + 1] = p.rowval.len();
        }
        // The slacks enter the objective linearly only: empty columns.
        p.n = nb + ne;
        p.m = nb + ne;
        p.colptr.truncate(nb + 1);
        p.colptr.resize(nb + ne + 1, p.rowval.len());
    }

    /// After a solve with a subset of the rows: selects the unselected rows that the solution
    /// violates or nearly violates (every unselected row when `all`). True when rows were added
    /// and the QP must be solved again.
    fn add_violated_rows(&mut self, all: bool) -> bool {
        let nv = 3 * self.evaluator.n;
        let u = &self.solution;
        let excess = |row: &[f64], b: f64| row.iter().zip(u).map(|(a, x)| a * x).sum::<f64>() - b;
        let mut unselected =
            self.rows.chunks_exact(nv).zip(&self.b).zip(&self.selected).filter(|(_, sel)| !**sel);
        if !unselected.any(|((row, b), _)| excess(row, *b) > 0.0) {
            return false;
        }
        let margin = self.settings.lazy_add_margin_m;
        for ((row, b), sel) in self.rows.chunks_exact(nv).zip(&self.b).zip(self.selected.iter_mut()) {
            *sel = *sel || all || excess(row, *b) > -margin;
        }
        true
    }

    /// The constraints clarabel sees: the bound rows of the corrections and of the elastic
    /// slacks, then the selected dense rows, in CSC (`[A T, -E]`, `E` picking each elastic
    /// row's slack) with their right-hand sides.
    fn assemble_constraints(&mut self) {
        let n = self.evaluator.n;
        let nv = 3 * n;
        let nb = 3 * self.num_blocks;
        let ne = self.elastic_bound.len();
        let n_bound_rows = 2 * nb + 2 * ne;
        self.num_rows = n_bound_rows + self.selected.iter().take(self.b.len()).filter(|s| **s).count();
        // Right-hand sides in the corrections: per block variable `d <= min(hi - u_bar)` and
        // `-d <= -max(lo - u_bar)` over its steps (a box containing 0: the nominal is inside the
        // bounds), then `A T d <= b - A u_bar`.
        self.b_qp.clear();
        self.b_qp.resize(2 * nb, f64::INFINITY);
        for v in 0..nv {
            let col = 3 * self.block_of[v / 3] + v % 3;
            let (lo, hi) = (self.lo[v] - self.nominal[v], self.hi[v] - self.nominal[v]);
            self.b_qp[2 * col] = self.b_qp[2 * col].min(hi);
            self.b_qp[2 * col + 1] = self.b_qp[2 * col + 1].min(-lo);
        }
        // `-s <= 0` and `s <= nominal violation` per elastic slack.
        for bound in &self.elastic_bound {
            self.b_qp.push(0.0);
            self.b_qp.push(*bound);
        }
        for (slack, _) in self.slack.iter().zip(&self.selected).filter(|(_, sel)| **sel) {
            self.b_qp.push(*slack);
        }
        // A T in CSC, column by column: the two bound rows, then the selected dense rows summed
        // over the block's steps.
        let a = &mut self.a_csc;
        a.m = self.num_rows;
        a.rowval.clear();
        a.nzval.clear();
        a.colptr[0] = 0;
        let mut first_step = 0;
        for blk in 0..self.num_blocks {
            let mut end_step = first_step;
            while end_step < n && self.block_of[end_step] == blk {
                end_step += 1;
            }
            for c in 0..3 {
                let col = 3 * blk + c;
                a.rowval.push(2 * col);
                a.nzval.push(1.0);
                a.rowval.push(2 * col + 1);
                a.nzval.push(-1.0);
                let chosen = self.rows.chunks_exact(nv).zip(&self.selected).filter(|(_, sel)| **sel);
                for (rr, (row, _)) in chosen.enumerate() {
                    let val: f64 = (first_step..end_step).map(|j| row[3 * j + c]).sum();
                    if val != 0.0 {
                        a.rowval.push(n_bound_rows + rr);
                        a.nzval.push(val);
                    }
                }
                a.colptr[col + 1] = a.rowval.len();
            }
            first_step = end_step;
        }
        // The slack columns: their two bound rows, then -1 in their own row when it is selected
        // (slacks are numbered in the order of their rows, so the columns come out in order).
        a.n = nb + ne;
        a.colptr.truncate(nb + 1);
        let mut position = n_bound_rows;
        for (elastic, sel) in self.elastic_of.iter().zip(&self.selected) {
            if let Some(e) = *elastic {
                a.rowval.push(2 * nb + 2 * e);
                a.nzval.push(-1.0);
                a.rowval.push(2 * nb + 2 * e + 1);
                a.nzval.push(1.0);
                if *sel {
                    a.rowval.push(position);
                    a.nzval.push(-1.0);
                }
                a.colptr.push(a.rowval.len());
            }
            if *sel {
                position += 1;
            }
        }
    }

    fn solve_qp(&mut self, budget: &QpBudget) -> (QpStatus, u32, Duration) {
        let finite = self
            .q
            .iter()
            .chain(&self.b_qp)
            .chain(&self.p_csc.nzval)
            .chain(&self.a_csc.nzval)
            .all(|v| v.is_finite());
        if !finite {
            return (QpStatus::NumericalError, 0, Duration::ZERO);
        }
        let s = &self.settings;
        let settings = DefaultSettings {
            verbose: false,
            max_iter: budget.max_iterations.unwrap_or(s.max_iterations).max(1),
            time_limit: budget.deadline.map_or(f64::INFINITY, |d| d.as_secs_f64()),
            tol_gap_abs: s.gap_tolerance,
            tol_gap_rel: s.gap_tolerance,
            tol_feas: s.feasibility_tolerance,
            max_threads: 1,
            iterative_refinement_enable: s.iterative_refinement,
            ..DefaultSettings::default()
        };
        let cones = [SupportedConeT::NonnegativeConeT(self.num_rows)];
        let mut solver =
            match DefaultSolver::new(&self.p_csc, &self.q, &self.a_csc, &self.b_qp, &cones, settings) {
                Ok(solver) => solver,
                Err(_) => return (QpStatus::NumericalError, 0, Duration::ZERO),
            };
        solver.solve();
        let mut status = QpStatus::from_clarabel(solver.solution.status);
        let time = Duration::from_secs_f64(solver.solution.solve_time.max(0.0));
        if status.has_solution() {
            if solver.solution.x.iter().all(|v| v.is_finite()) {
                // u = u_bar + T d
                for (v, u) in self.solution.iter_mut().enumerate() {
                    *u = self.nominal[v] + solver.solution.x[3 * self.block_of[v / 3] + v % 3];
                }
                let nb = 3 * self.num_blocks;
                self.elastic_violation_m = solver.solution.x[nb..].iter().fold(0.0f64, |a, s| a.max(*s));
                if self.elastic_violation_m > ELASTIC_TOLERANCE_M {
                    status = QpStatus::SolvedElastic;
                }
            } else {
                status = QpStatus::NumericalError;
            }
        }
        (status, solver.solution.iterations, time)
    }
}

/// The runs of the dense rows: consecutive points of one scenario near one constraint.
#[derive(Debug, Clone)]
struct RowRuns {
    /// Per dense row, the row of the same scenario and constraint at the previous point.
    prev: Vec<Option<usize>>,
    /// Per dense row, the row of the same scenario and constraint at the next point.
    next: Vec<Option<usize>>,
    /// Per constraint (cylinders, then the floor), its last row and point while building one
    /// scenario's rows.
    last: Vec<Option<(usize, usize)>>,
    /// Per dense row, `[scenario, constraint, point]` (for the tests).
    #[cfg(test)]
    owner: Vec<[usize; 3]>,
}

impl RowRuns {
    /// The rows that follow belong to the next scenario: no run continues into it.
    fn start_scenario(&mut self) {
        self.last.iter_mut().for_each(|l| *l = None);
    }

    /// Records row `r`, of scenario `i`'s constraint `c` at point `k`, after the same
    /// constraint's row at point `k - 1` when there is one (`last` is cleared per scenario).
    fn link(
        &mut self,
        #[cfg_attr(not(test), allow(unused_variables))] i: usize,
        c: usize,
        r: usize,
        k: usize,
    ) {
        let prev = self.last[c].filter(|(_, kp)| kp + 1 == k).map(|(rp, _)| rp);
        #[cfg(test)]
        self.owner.push([i, c, k]);
        self.prev.push(prev);
        self.next.push(None);
        if let Some(p) = prev {
            self.next[p] = Some(r);
        }
        self.last[c] = Some((r, k));
    }
}

/// Fills a dense row with `a_v = coeff(v)` for the inputs `0..width` that can move the
/// point, zeros beyond, and returns `(a^T u_bar, max |a_v|)` for the right-hand side and the
/// test for a row the inputs cannot change.
fn fill_row(row: &mut [f64], width: usize, nominal: &[f64], coeff: impl Fn(usize) -> f64) -> (f64, f64) {
    let mut su = 0.0;
    let mut norm = 0.0f64;
    for v in 0..width {
        let a = coeff(v);
        row[v] = a;
        su += a * nominal[v];
        norm = norm.max(a.abs());
    }
    row[width..].iter_mut().for_each(|a| *a = 0.0);
    (su, norm)
}

/// The coefficients of the MAV's Euler map that the linearization (and the evaluator's scalar
/// test reference) use, computed once per pass so that both round the same way.
#[derive(Debug, Clone, Copy)]
pub(crate) struct EulerCoeffs {
    pub g: f64,
    pub ax: f64,
    pub ay: f64,
    pub az: f64,
    /// Attitude gains over their time constants.
    pub kr: f64,
    pub kp: f64,
    /// Inverse attitude time constants.
    pub ir: f64,
    pub ip: f64,
}

impl EulerCoeffs {
    pub fn new(p: &ModelParams) -> Self {
        Self {
            g: p.gravity_mps2,
            ax: p.drag_x_per_s,
            ay: p.drag_y_per_s,
            az: p.drag_z_per_s,
            kr: p.gain_roll / p.tau_roll_s,
            kp: p.gain_pitch / p.tau_pitch_s,
            ir: 1.0 / p.tau_roll_s,
            ip: 1.0 / p.tau_pitch_s,
        }
    }

    /// `x + dt f(x, u)` with `trig` the `(sin, cos)` of `x`'s roll and pitch.
    #[inline]
    pub fn step(&self, x: &[f64; 8], u: &[f64], dt: f64, trig: [f64; 4]) -> [f64; 8] {
        let [sr, cr, sp, cp] = trig;
        let Self { g, ax, ay, az, kr, kp, ir, ip } = *self;
        let (t, rd, pd) = (u[0], u[1], u[2]);
        [
            x[0] + dt * x[3],
            x[1] + dt * x[4],
            x[2] + dt * x[5],
            x[3] + dt * (t * cr * sp - ax * x[3]),
            x[4] + dt * (-t * sr - ay * x[4]),
            x[5] + dt * (t * cr * cp - g - az * x[5]),
            x[6] + dt * (kr * rd - ir * x[6]),
            x[7] + dt * (kp * pd - ip * x[7]),
        ]
    }

    /// `l <- (I + dt Fx(x, u))^T l` (`trig` of `x`, thrust `t`).
    #[inline]
    pub fn adjoint_step(&self, l: &mut [f64; 8], dt: f64, t: f64, trig: [f64; 4]) {
        let [sr, cr, sp, cp] = trig;
        let Self { ax, ay, az, ir, ip, .. } = *self;
        let l6 = l[6] + dt * (-t * sr * sp * l[3] - t * cr * l[4] - t * sr * cp * l[5] - ir * l[6]);
        let l7 = l[7] + dt * (t * cr * cp * l[3] - t * cr * sp * l[5] - ip * l[7]);
        l[3] += dt * (l[0] - ax * l[3]);
        l[4] += dt * (l[1] - ay * l[4]);
        l[5] += dt * (l[2] - az * l[5]);
        l[6] = l6;
        l[7] = l7;
    }
}

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

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use crate::problem::{ControllerMode, ObstacleFormulation};
    use crate::solver::{Mpc, MpcSettings, SolveBudget};
    use mav::Scenario;
    use proptest::prelude::*;

    const W5: [f64; 5] = [0.05, 0.15, 0.45, 0.30, 0.05];
    const HOVER: [f64; 3] = [9.81, 0.0, 0.0];

    fn paper_def(scenario: &Scenario, mode: ControllerMode) -> OcpDefinition {
        OcpDefinition::from_scenario(scenario, mode, 0.1, ObstacleFormulation::DistanceAlm)
    }

    /// paper-3 without cylinders, goal 1 m up: a problem that stays near hover.
    fn free_space_def() -> OcpDefinition {
        let mut def = paper_def(&Scenario::paper_3(), ControllerMode::Multistage);
        def.obstacles.clear();
        def
    }

    /// A small problem for brute-force checks.
    fn small_def() -> OcpDefinition {
        let mut def = paper_def(&Scenario::paper_2(), ControllerMode::Multistage);
        def.horizon = 6;
        def.sampling_times_s = vec![0.05, 0.2];
        def
    }

    fn states_of(def: &OcpDefinition, x0: &[f64; 8], u: &[f64], dt: f64) -> Vec<[f64; 8]> {
        let model = mav::MavModel::new(def.model);
        let mut x = mav::State::from(*x0);
        let mut out = Vec::new();
        for j in 0..def.horizon {
            x = mav::euler_step(&model, &x, &mav::Input::new(u[3 * j], u[3 * j + 1], u[3 * j + 2]), dt);
            out.push(std::array::from_fn(|k| x[k]));
        }
        out
    }

    #[test]
    fn hessian_and_gradient_match_brute_force_gauss_newton() {
        let def = small_def();
        let x0 = [3.0, 1.0, 0.5, 0.3, 0.8, -0.2, 0.05, -0.04];
        let u_prev = [10.0, 0.01, -0.02];
        let w = [0.3, 0.7];
        let nv = def.num_variables();
        let nominal: Vec<f64> = (0..nv).map(|k| [10.5, 0.05, -0.08][k % 3] + 0.004 * (k as f64)).collect();
        assert!(nominal.iter().enumerate().all(|(k, v)| *v <= def.bounds.max[k % 3]), "inside the bounds");
        let mut qp = QpFallback::new(&def, QpSettings::default()).expect("valid");
        qp.solve(&x0, &u_prev, &w, Some(&nominal), &QpBudget::default()).expect("valid");
        // Brute force: Jacobians by central differences, H = sum_i 2 w_i J_i^T Q J_i + input terms.
        let mut h = vec![0.0; nv * nv];
        for (i, &dt) in def.sampling_times_s.iter().enumerate() {
            let mut jac = vec![vec![[0.0; 8]; def.horizon]; nv];
            for v in 0..nv {
                let (mut up, mut um) = (nominal.clone(), nominal.clone());
                up[v] += 1e-6;
                um[v] -= 1e-6;
                let (xp, xm) = (states_of(&def, &x0, &up, dt), states_of(&def, &x0, &um, dt));
                for k in 0..def.horizon {
                    for s in 0..8 {
                        jac[v][k][s] = (xp[k][s] - xm[k][s]) / 2e-6;
                    }
                    for s in 0..3 {
                        let got = qp.sens[(i * def.horizon + k) * nv + v][s];
                        assert!((got - jac[v][k][s]).abs() < 1e-6, "sensitivity {i} {k} {v} {s}: {got}");
                    }
                }
            }
            for a in 0..nv {
                for b in 0..nv {
                    let mut acc = 0.0;
                    for k in 0..def.horizon {
                        for s in 0..8 {
                            acc += 2.0 * w[i] * def.q_x[s] * jac[a][k][s] * jac[b][k][s];
                        }
                    }
                    h[a * nv + b] += acc;
                }
            }
        }
        let wsum: f64 = w.iter().sum();
        for k in 0..nv {
            let c = k % 3;
            h[k * nv + k] += 2.0 * wsum * (def.q_u[c] + def.q_du[c] * if k + 3 < nv { 2.0 } else { 1.0 });
            if k + 3 < nv {
                h[k * nv + k + 3] -= 2.0 * wsum * def.q_du[c];
                h[(k + 3) * nv + k] -= 2.0 * wsum * def.q_du[c];
            }
        }
        let scale = h.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for k in 0..nv * nv {
            assert!(
                (qp.hess[k] - h[k]).abs() < 1e-5 * scale,
                "H[{}][{}]: {} vs {}",
                k / nv,
                k % nv,
                qp.hess[k],
                h[k]
            );
        }
        // Gradient at the nominal against finite differences of the nonlinear objective.
        let mut ev = Evaluator::new(&def);
        ev.set_instance(&x0, &u_prev, &w);
        for v in 0..nv {
            let (mut up, mut um) = (nominal.clone(), nominal.clone());
            up[v] += 1e-6;
            um[v] -= 1e-6;
            let fd = (ev.objective_at_inputs(&up) - ev.objective_at_inputs(&um)) / 2e-6;
            assert!(
                (fd - qp.grad[v]).abs() < 1e-4 * (1.0 + fd.abs()),
                "gradient {v}: {} vs {fd}",
                qp.grad[v]
            );
        }
    }

    #[test]
    fn without_obstacles_near_hover_the_qp_agrees_with_panoc() {
        let def = free_space_def();
        let mut x0 = [0.0; 8];
        x0[..3].copy_from_slice(&[3.0, 4.6, 0.7]);
        let settings = MpcSettings { tolerance: 1e-7, max_inner_iterations: 3000, ..Default::default() };
        let mut mpc = Mpc::new(def.clone(), settings).expect("valid");
        let r = mpc.solve(&x0, &HOVER, &W5, &SolveBudget::default()).expect("valid");
        let range = [2.0 * 9.81, std::f64::consts::PI / 9.0, std::f64::consts::PI / 9.0];
        // The full QP (no move blocking) agrees closely; the default, move-blocked QP is a
        // restriction of it: its first inputs (the ones applied) and its cost stay close.
        let full = QpSettings { sqp_rounds: 2, block_steps: 1, ..Default::default() };
        let blocked = QpSettings { sqp_rounds: 2, ..Default::default() };
        for (settings, first_steps, input_tol, cost_tol) in [(full, 40, 0.01, 1e-3), (blocked, 6, 0.02, 5e-3)]
        {
            let mut qp = QpFallback::new(&def, settings).expect("valid");
            let q = qp.solve(&x0, &HOVER, &W5, None, &QpBudget::default()).expect("valid");
            assert_eq!(q.status, QpStatus::Solved);
            assert_eq!(q.num_half_planes, 0);
            let u = qp.solution().expect("solved");
            let mut worst = 0.0f64;
            for (k, (a, b)) in u.iter().zip(mpc.solution()).enumerate().take(3 * first_steps) {
                worst = worst.max((a - b).abs() / range[k % 3]);
            }
            assert!(
                worst < input_tol,
                "block_steps {}: input difference {worst} of the range",
                settings.block_steps
            );
            assert!(
                (q.cost - r.cost).abs() <= cost_tol * r.cost,
                "block_steps {}: QP cost {} vs PANOC cost {}",
                settings.block_steps,
                q.cost,
                r.cost
            );
        }
    }

    /// paper-2, standard NMPC, heading between the cylinders: many half-planes.
    fn between_cylinders() -> (OcpDefinition, [f64; 8]) {
        let def = paper_def(&Scenario::paper_2(), ControllerMode::Nmpc);
        (def, [3.3, 2.2, 0.9, 0.0, 0.6, 0.1, 0.0, 0.0])
    }

    #[test]
    fn lazy_rows_give_the_solution_of_the_qp_with_every_row() {
        let (def, x0) = between_cylinders();
        let eager = QpSettings { lazy_slack_m: f64::INFINITY, ..Default::default() };
        let mut qp = QpFallback::new(&def, eager).expect("valid");
        let r_all = qp.solve(&x0, &HOVER, &[1.0], None, &QpBudget::default()).expect("valid");
        assert_eq!(r_all.status, QpStatus::Solved);
        assert_eq!(r_all.clarabel_solves, 1);
        assert_eq!(
            r_all.num_clarabel_rows,
            2 * qp.num_qp_variables() + r_all.num_constraints - 2 * qp.num_variables()
        );
        let u_all = qp.solution().expect("solved").to_vec();
        // The default (rows with a large nominal slack start outside), no rows at first at all
        // (every row that matters must be found by the re-solves), and every row a candidate,
        // screened to each run's closest points (fewer rows in the end than every row).
        let none_first =
            QpSettings { lazy_slack_m: f64::NEG_INFINITY, max_lazy_rounds: 10, ..Default::default() };
        let screened = QpSettings { lazy_slack_m: 2.0, max_lazy_rounds: 10, ..Default::default() };
        for settings in [QpSettings::default(), none_first, screened] {
            let mut qp = QpFallback::new(&def, settings).expect("valid");
            let r = qp.solve(&x0, &HOVER, &[1.0], None, &QpBudget::default()).expect("valid");
            assert_eq!(r.status, QpStatus::Solved);
            assert_eq!(r.num_constraints, r_all.num_constraints);
            assert!(r.num_clarabel_rows < r_all.num_clarabel_rows, "rows {}", r.num_clarabel_rows);
            assert!(r.linear_violation <= 1e-6, "violation {}", r.linear_violation);
            if settings.lazy_slack_m == f64::NEG_INFINITY {
                assert!(r.clarabel_solves >= 2, "solves {}", r.clarabel_solves);
            }
            let u = qp.solution().expect("solved");
            let worst = u.iter().zip(&u_all).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
            assert!(worst < 1e-4, "{settings:?}: largest input difference {worst}");
            assert!((r.cost - r_all.cost).abs() <= 1e-6 * r_all.cost, "cost {} vs {}", r.cost, r_all.cost);
        }
    }

    #[test]
    fn a_run_ends_at_a_gap_and_at_the_end_of_a_scenario() {
        let mut runs = RowRuns { prev: Vec::new(), next: Vec::new(), last: vec![None; 2], owner: Vec::new() };
        // Scenario 0: constraint 0 at points 1, 2, then 4 (a gap); constraint 1 at 2, 3.
        // Scenario 1: constraint 0 at 5, 6 (right after scenario 0's point 4), constraint 1 at 4.
        let rows = [(0, 0, 1), (0, 0, 2), (0, 1, 2), (0, 1, 3), (0, 0, 4), (1, 0, 5), (1, 1, 4), (1, 0, 6)];
        for (r, &(i, c, k)) in rows.iter().enumerate() {
            if r > 0 && rows[r - 1].0 != i {
                runs.start_scenario();
            }
            runs.link(i, c, r, k);
        }
        assert_eq!(runs.prev, [None, Some(0), None, Some(2), None, None, None, Some(5)]);
        assert_eq!(runs.next, [Some(1), None, Some(3), None, None, Some(7), None, None]);
    }

    #[test]
    fn runs_link_consecutive_points_of_one_scenario_and_constraint_only() {
        // paper-2 multi-stage between the cylinders, with the floor: rows of five scenarios,
        // three cylinders and the floor; a short activation distance, so that runs also end
        // and start again.
        let (_, x0) = between_cylinders();
        let s = Scenario::paper_2();
        let def = paper_def(&s, ControllerMode::Multistage);
        let settings =
            QpSettings { min_altitude_m: Some(0.0), activation_distance_m: 0.3, ..Default::default() };
        let mut qp = QpFallback::new(&def, settings).expect("valid");
        let w = [0.05, 0.15, 0.45, 0.30, 0.05];
        qp.solve(&x0, &HOVER, &w, None, &QpBudget::default()).expect("valid");
        let runs = &qp.runs;
        assert_eq!(runs.owner.len(), qp.b.len());
        let scenarios: std::collections::BTreeSet<usize> = runs.owner.iter().map(|o| o[0]).collect();
        assert!(scenarios.len() > 1, "rows of several scenarios: {scenarios:?}");
        let (mut linked, mut starts) = (0, 0);
        for (r, &[i, c, k]) in runs.owner.iter().enumerate() {
            let before = runs.owner.iter().position(|o| *o == [i, c, k - 1]);
            assert_eq!(runs.prev[r], before, "row {r} {:?}", runs.owner[r]);
            let after = runs.owner.iter().position(|o| *o == [i, c, k + 1]);
            assert_eq!(runs.next[r], after, "row {r} {:?}", runs.owner[r]);
            if before.is_some() {
                linked += 1;
            } else {
                starts += 1;
            }
        }
        assert!(linked > 0 && starts > 0, "{linked} linked, {starts} run starts");
    }

    #[test]
    fn blocked_corrections_are_constant_over_each_block() {
        let (def, x0) = between_cylinders();
        let settings = QpSettings::default();
        let mut qp = QpFallback::new(&def, settings).expect("valid");
        // 6 free steps, then ceil(34 / 6) = 6 blocks.
        assert_eq!(qp.num_qp_variables(), 3 * 12);
        let nominal: Vec<f64> =
            (0..qp.num_variables()).map(|k| HOVER[k % 3] + 0.01 * ((k * 7) % 5) as f64).collect();
        let r = qp.solve(&x0, &HOVER, &[1.0], Some(&nominal), &QpBudget::default()).expect("valid");
        assert_eq!(r.status, QpStatus::Solved);
        let u = qp.solution().expect("solved");
        let d = |j: usize, c: usize| u[3 * j + c] - nominal[3 * j + c];
        let mut moved = 0.0f64;
        for j in 0..def.horizon {
            for c in 0..3 {
                moved = moved.max(d(j, c).abs());
                let first = if j < 6 { j } else { 6 + (j - 6) / 6 * 6 };
                assert!((d(j, c) - d(first, c)).abs() < 1e-12, "step {j} channel {c}");
            }
        }
        assert!(moved > 1e-3, "the QP moved the inputs by {moved}");
    }

    #[test]
    fn the_qp_solution_satisfies_its_own_linear_constraints() {
        let s = Scenario::paper_2();
        // Standard NMPC: from this state the multi-stage problem has points of the 0.2 s and
        // 0.33 s scenarios that no input keeps outside the inflated cylinder (infeasible).
        let def = paper_def(&s, ControllerMode::Nmpc);
        // Heading at the 0.4 m cylinder at (2.8, 3.0).
        let x0 = [2.9, 1.6, 0.8, 0.0, 0.6, 0.0, 0.0, 0.0];
        let settings = QpSettings { min_altitude_m: Some(0.2), ..Default::default() };
        let mut qp = QpFallback::new(&def, settings).expect("valid");
        let r = qp.solve(&x0, &HOVER, &[1.0], None, &QpBudget::default()).expect("valid");
        assert_eq!(r.status, QpStatus::Solved);
        assert!(r.num_half_planes > 50, "half-planes: {}", r.num_half_planes);
        assert!(r.linear_violation <= 1e-6, "violation {}", r.linear_violation);
        let u = qp.solution().expect("solved");
        for (k, v) in u.iter().enumerate() {
            assert!(*v >= def.bounds.min[k % 3] && *v <= def.bounds.max[k % 3]);
        }
        assert!(r.cost.is_finite() && r.min_clearance_m.is_finite() && r.min_altitude_m.is_finite());
    }

    #[test]
    fn a_floor_above_reach_is_infeasible_never_a_solution() {
        let def = paper_def(&Scenario::paper_2(), ControllerMode::Multistage);
        let settings =
            QpSettings { min_altitude_m: Some(500.0), elastic_penalty_per_m: None, ..Default::default() };
        let mut qp = QpFallback::new(&def, settings).expect("valid");
        let r = qp.solve(&Scenario::paper_2().start, &HOVER, &W5, None, &QpBudget::default()).expect("valid");
        assert_eq!(r.status, QpStatus::Infeasible);
        assert!(qp.solution().is_none() && qp.first_input().is_none());
        assert!(r.cost.is_nan());
        // Elastic (the default): the best climb there is, and the status says it is not enough.
        let mut qp = QpFallback::new(&def, QpSettings { elastic_penalty_per_m: Some(1e5), ..settings })
            .expect("valid");
        let r = qp.solve(&Scenario::paper_2().start, &HOVER, &W5, None, &QpBudget::default()).expect("valid");
        assert_eq!(r.status, QpStatus::SolvedElastic);
        assert!(r.elastic_violation_m > 400.0, "{r:?}");
    }

    #[test]
    fn contradictory_half_planes_are_infeasible_or_elastic_never_solved() {
        // The nominal (hover, drifting at 1.5 m/s) flies straight through the cylinder and a
        // tiny trust region forbids turning away: the half-planes contradict the box.
        let def = paper_def(&Scenario::paper_2(), ControllerMode::Nmpc);
        let x0 = [2.8, 2.0, 0.8, 0.0, 1.5, 0.0, 0.0, 0.0];
        let tr = [1e-3, 1e-4, 1e-4];
        let hard = QpSettings { trust_region: Some(tr), elastic_penalty_per_m: None, ..Default::default() };
        let mut qp = QpFallback::new(&def, hard).expect("valid");
        let r = qp.solve(&x0, &HOVER, &[1.0], None, &QpBudget::default()).expect("valid");
        assert_eq!(r.status, QpStatus::Infeasible);
        assert!(qp.solution().is_none() && r.elastic_violation_m.is_nan());
        // Elastic: a solution that says how far it stays inside, never "solved"; it keeps the
        // box and trust region, and leaves no point deeper than the nominal put it.
        let elastic =
            QpSettings { trust_region: Some(tr), elastic_penalty_per_m: Some(1e5), ..Default::default() };
        let mut qp = QpFallback::new(&def, elastic).expect("valid");
        let r = qp.solve(&x0, &HOVER, &[1.0], None, &QpBudget::default()).expect("valid");
        assert_eq!(r.status, QpStatus::SolvedElastic);
        assert!(r.num_elastic_rows > 0 && r.elastic_violation_m > 1e-3, "{r:?}");
        assert!(r.linear_violation <= r.elastic_violation_m + 1e-6, "{r:?}");
        let u = qp.solution().expect("elastic solution").to_vec();
        let nominal = qp.nominal().to_vec();
        for (k, (v, nom)) in u.iter().zip(&nominal).enumerate() {
            assert!((v - nom).abs() <= tr[k % 3] + 1e-7, "input {k}: {v} vs nominal {nom}");
        }
        let nv = u.len();
        for ((row, b), slack) in qp.rows.chunks_exact(nv).zip(&qp.b).zip(&qp.slack) {
            let excess = row.iter().zip(&u).map(|(a, x)| a * x).sum::<f64>() - b;
            assert!(excess <= (-slack).max(0.0) + 1e-6, "a row went deeper: {excess} > {}", -slack);
        }
    }

    #[test]
    fn elastic_rows_change_nothing_when_the_hard_qp_is_feasible() {
        // Paper-1 from a state on its way (in front of the cylinder), linearized around
        // PANOC's plan shifted as in the loop: PANOC's plans cut into the inflated cylinder by
        // up to its constraint tolerance, so some half-planes start violated, yet the inputs
        // can satisfy them all.
        let scenario = Scenario::paper_1();
        let def = paper_def(&scenario, ControllerMode::Multistage);
        let hard = QpSettings { elastic_penalty_per_m: None, ..Default::default() };
        let mut qp_hard = QpFallback::new(&def, hard).expect("valid");
        let elastic = QpSettings { elastic_penalty_per_m: Some(1e5), ..Default::default() };
        let mut qp_elastic = QpFallback::new(&def, elastic).expect("valid");
        let x0 = [0.2, 0.9, 0.45, 0.17, 1.6, 0.57, -0.16, -0.01];
        let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
        mpc.solve(&x0, &HOVER, &W5, &SolveBudget::default()).expect("valid");
        let plan = mpc.solution();
        let mut nominal = plan[3..].to_vec();
        nominal.extend_from_slice(&plan[plan.len() - 3..]);
        let nominal = Some(&nominal[..]);
        let rh = qp_hard.solve(&x0, &HOVER, &W5, nominal, &QpBudget::default()).expect("valid");
        let re = qp_elastic.solve(&x0, &HOVER, &W5, nominal, &QpBudget::default()).expect("valid");
        assert_eq!(rh.status, QpStatus::Solved, "{rh:?}");
        assert_eq!(re.status, QpStatus::Solved, "{re:?}");
        assert!(re.num_elastic_rows > 0, "the case must have violated rows: {re:?}");
        assert!(re.elastic_violation_m <= ELASTIC_TOLERANCE_M);
        let (uh, ue) = (qp_hard.solution().expect("solved"), qp_elastic.solution().expect("solved"));
        let worst = uh.iter().zip(ue).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst < 1e-4, "largest input difference {worst}");
        assert!((rh.cost - re.cost).abs() <= 1e-6 * rh.cost.abs(), "cost {} vs {}", rh.cost, re.cost);
    }

    #[test]
    fn bad_input_and_settings_are_refused_naming_the_field() {
        let def = small_def();
        assert!(matches!(
            QpFallback::new(&def, QpSettings { sqp_rounds: 0, ..Default::default() }),
            Err(MpcError::InvalidSetting { field: "sqp_rounds", .. })
        ));
        assert!(matches!(
            QpFallback::new(&def, QpSettings { block_steps: 0, ..Default::default() }),
            Err(MpcError::InvalidSetting { field: "block_steps", .. })
        ));
        assert!(matches!(
            QpFallback::new(&def, QpSettings { lazy_slack_m: f64::NAN, ..Default::default() }),
            Err(MpcError::InvalidSetting { field: "lazy_slack_m", .. })
        ));
        let mut qp = QpFallback::new(&def, QpSettings::default()).expect("valid");
        let mut x0 = [0.0; 8];
        x0[3] = f64::NAN;
        let e = qp.solve(&x0, &HOVER, &[0.5, 0.5], None, &QpBudget::default());
        assert!(matches!(e, Err(MpcError::InvalidInput { field, .. }) if field == "x0[3]"));
        let e = qp.solve(&[0.0; 8], &HOVER, &[1.0], None, &QpBudget::default());
        assert!(matches!(e, Err(MpcError::InvalidInput { field, .. }) if field == "weights"));
        let e = qp.solve(&[0.0; 8], &HOVER, &[0.5, 0.5], Some(&[1.0; 5]), &QpBudget::default());
        assert!(matches!(e, Err(MpcError::InvalidInput { field, .. }) if field == "nominal"));
    }

    fn arb_def() -> impl Strategy<Value = OcpDefinition> {
        (
            2usize..=25,
            prop::collection::vec(0.03f64..0.35, 1..=5),
            prop::collection::vec((0.5f64..6.0, 0.5f64..6.0, 0.1f64..0.8), 0..=3),
        )
            .prop_map(|(n, dts, obs)| {
                let mut def = paper_def(&Scenario::paper_2(), ControllerMode::Multistage);
                def.horizon = n;
                def.sampling_times_s = dts;
                def.obstacles = obs.into_iter().map(|(x, y, r)| mav::Cylinder::new(x, y, r)).collect();
                def
            })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]

        /// A solution is a solution of the QP, and an infeasible floor is never "solved".
        #[test]
        fn the_qp_never_reports_success_on_an_infeasible_problem(
            def in arb_def(),
            p in (0.0f64..6.0, 0.0f64..6.0, 0.0f64..3.0),
            v in (-2.0f64..2.0, -2.0f64..2.0, -1.0f64..1.0),
            att in (-0.17f64..0.17, -0.17f64..0.17),
            w in prop::collection::vec(0.01f64..1.0, 5),
            floor_above in 40.0f64..200.0,
        ) {
            let x0 = [p.0, p.1, p.2, v.0, v.1, v.2, att.0, att.1];
            let w = &w[..def.num_scenarios()];
            let mut qp = QpFallback::new(&def, QpSettings::default()).expect("valid");
            let r = qp.solve(&x0, &HOVER, w, None, &QpBudget::default()).expect("valid");
            if r.status.has_solution() {
                // Elastic rows may stay violated, by what the report says and only then.
                let allowed = if r.status == QpStatus::SolvedElastic { r.elastic_violation_m } else { 0.0 };
                prop_assert!(r.linear_violation <= allowed + 1e-6, "violation {} ({:?})", r.linear_violation, r.status);
                prop_assert!(r.status == QpStatus::SolvedElastic || r.elastic_violation_m <= ELASTIC_TOLERANCE_M);
                let u = qp.solution().expect("solution");
                prop_assert!(u.iter().all(|v| v.is_finite()));
                prop_assert!(r.cost.is_finite());
            } else {
                prop_assert!(qp.solution().is_none());
            }
            // A floor far above anything reachable within the horizon (at most 2g up).
            let horizon_s = def.horizon as f64 * def.sampling_times_s.iter().fold(0.0f64, |a, b| a.max(*b));
            let reach = p.2 + v.2.abs() * horizon_s + 0.5 * 9.81 * horizon_s * horizon_s;
            let settings = QpSettings {
                min_altitude_m: Some(reach + floor_above),
                elastic_penalty_per_m: None,
                ..Default::default()
            };
            let mut qp = QpFallback::new(&def, settings).expect("valid");
            let r = qp.solve(&x0, &HOVER, w, None, &QpBudget::default()).expect("valid");
            prop_assert!(!r.status.has_solution(), "status {:?} on an infeasible floor", r.status);
            prop_assert!(qp.solution().is_none());
            // Elastic: never "solved" either.
            let mut qp = QpFallback::new(&def, QpSettings { elastic_penalty_per_m: Some(1e5), ..settings }).expect("valid");
            let r = qp.solve(&x0, &HOVER, w, None, &QpBudget::default()).expect("valid");
            prop_assert!(r.status != QpStatus::Solved && r.status != QpStatus::SolvedReducedAccuracy, "{:?}", r.status);
        }
    }
}
