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
//! Speed (measured in `BENCHMARKS.md`, "The QP fallback"). The condensed QP is dense: `H` is a full
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
//!
//! Code map: the settings and the budget (`settings.rs`: [`QpSettings`], [`QpBudget`]); the
//! report (`report.rs`: [`QpStatus`], [`QpReport`]); the linearization (`linearize.rs`: nominal trajectories, sensitivities,
//! Gauss-Newton Hessian); the constraint rows (`rows.rs`: bounds, half-planes, floor, elastic
//! slacks); the condensing into the blocked corrections (`condense.rs`); the lazy rows
//! (`lazy_rows.rs`: runs, screening, re-solves); the one call into clarabel
//! (`interior_point.rs`); and the check of a plan on the nonlinear model
//! (`nonlinear_check.rs`). This file holds the workspace and the solve that runs the steps.

mod condense;
mod interior_point;
mod lazy_rows;
mod linearize;
mod nonlinear_check;
mod report;
mod rows;
mod settings;
#[cfg(test)]
mod tests;

use std::time::Duration;

use clarabel::algebra::CscMatrix;

use crate::error::{MpcError, invalid_input};
use crate::problem::{Evaluator, OcpDefinition, validate_instance};
use mav::{Cylinder, InputBounds};

use lazy_rows::RowRuns;
// The evaluator's scalar test reference steps with the same coefficients.
#[cfg(test)]
pub(crate) use linearize::EulerCoeffs;
pub use nonlinear_check::NonlinearCheck;
pub(crate) use nonlinear_check::check_on_nonlinear_model;
pub use report::{QpReport, QpStatus};
pub use settings::{QpBudget, QpSettings};

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
            self.build_rows();
            self.condense();
            self.select_initial_rows();
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
}
