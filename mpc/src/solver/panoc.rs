//! Our own PANOC (Stella, Themelis, Sopasakis, Patrinos 2017): projected gradient steps on the
//! box, L-BFGS directions on the fixed-point residual, and a line search on the
//! forward-backward envelope (FBE). What it does that OpEn 0.12's cannot:
//!
//! - **The Lipschitz estimate is carried** from one call to the next (the next outer iteration,
//!   the next cycle), halved at each call so that it can also come down; OpEn estimates it
//!   afresh by finite differences at every call (one more gradient) and only ever raises it.
//! - **The stopping test is scale-free**: OpEn stops when `|z - zbar| = γ |R|` is small, with
//!   `γ = 0.95 / L`, so the same tolerance is loose where an active penalty makes `L` large and
//!   tight where it does not. Here the test is on the gradient mapping `R = (z - zbar) / γ`,
//!   which does not depend on `γ`, relative to the cost: `|R|² / 2 <= ε |ψ|`, the cost gap a
//!   unit-curvature model predicts (the variables are scaled to unit hover curvature, see
//!   `problem/scaling.rs`), as a fraction of the cost.
//! - The L-BFGS pairs are differences of `R`, not of `z - zbar`, so they stay valid when `γ`
//!   halves and the memory is kept (OpEn resets it at each change of `L`).
//!
//! Every buffer is allocated in [`Panoc::new`]; a call allocates nothing. There is no
//! randomness and no clock in the arithmetic (the clock only stops a call at its deadline), so
//! the same inputs give the same bits.

use std::time::Instant;

/// `γ L`: the step is this fraction of `1 / L` (as in OpEn).
const GAMMA_L: f64 = 0.95;
/// Relative slack of the Lipschitz test, for rounding in `ψ` (as in OpEn).
const LIPSCHITZ_SLACK: f64 = 1e-6;
/// Doublings of `L` per iteration before giving up on the test (the step is then used as is).
const MAX_LIPSCHITZ_DOUBLINGS: usize = 30;
/// Largest Lipschitz estimate.
const MAX_LIPSCHITZ: f64 = 1e12;
/// Smallest Lipschitz estimate (a call never starts below it).
const MIN_LIPSCHITZ: f64 = 1e-6;
/// Factor on the carried estimate at the start of a call: lets `L` fall where the penalty
/// relaxed, at the price of one more cost evaluation where it did not.
const LIPSCHITZ_CARRY_FACTOR: f64 = 0.5;
/// Added to every variable at the start of a call: a mirror-symmetric problem (paper-1's
/// cylinder on the start-goal line) has a symmetric stationary point in front of the cylinder,
/// and an iteration that keeps the symmetry exactly converges to it. OpEn's PANOC leaves its
/// iterate moved by its finite-difference step (`max(1e-6 u, 1e-12)`) at every call, which is
/// what takes its runs around the cylinder; this does the same on purpose.
const SYMMETRY_NUDGE: f64 = 1e-12;
/// Halvings of `τ` before the line search takes the projected gradient step (`τ = 0`, which
/// always decreases the FBE).
const MAX_LINE_SEARCH_HALVINGS: usize = 5;

/// The smooth part of the problem PANOC minimises over a box.
pub(crate) trait SmoothCost {
    /// `ψ(z)`.
    fn cost(&mut self, z: &[f64]) -> f64;
    /// `ψ(z)`, with `∇ψ(z)` written to `grad`.
    fn cost_and_gradient(&mut self, z: &[f64], grad: &mut [f64]) -> f64;
}

/// How a call ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PanocStatus {
    Converged,
    IterationLimit,
    Deadline,
    /// A cost or gradient that is not finite.
    NotFinite,
}

/// What a call reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PanocExit {
    pub status: PanocStatus,
    pub iterations: usize,
    /// `|R|` (2-norm) of the returned point's step.
    pub residual: f64,
    /// `ψ` at the returned point.
    pub cost: f64,
}

/// The PANOC workspace: `O(m n)` for L-BFGS memory `m` and `n` variables.
#[derive(Debug, Clone)]
pub(crate) struct Panoc {
    memory: usize,
    /// The Lipschitz estimate the last call ended with (0: none yet).
    lipschitz: f64,
    grad: Vec<f64>,
    zbar: Vec<f64>,
    /// `z - zbar` (the step's residual, `γ R`).
    rr: Vec<f64>,
    z_plus: Vec<f64>,
    grad_plus: Vec<f64>,
    zbar_plus: Vec<f64>,
    rr_plus: Vec<f64>,
    direction: Vec<f64>,
    z_prev: Vec<f64>,
    r_prev: Vec<f64>,
    best: Vec<f64>,
    /// L-BFGS pairs, ring buffers of `memory` rows.
    s: Vec<f64>,
    y: Vec<f64>,
    rho: Vec<f64>,
    alpha: Vec<f64>,
    pairs: usize,
    newest: usize,
}

impl Panoc {
    pub(crate) fn new(n: usize, memory: usize) -> Self {
        let v = || vec![0.0; n];
        Self {
            memory,
            lipschitz: 0.0,
            grad: v(),
            zbar: v(),
            rr: v(),
            z_plus: v(),
            grad_plus: v(),
            zbar_plus: v(),
            rr_plus: v(),
            direction: v(),
            z_prev: v(),
            r_prev: v(),
            best: v(),
            s: vec![0.0; memory * n],
            y: vec![0.0; memory * n],
            rho: vec![0.0; memory],
            alpha: vec![0.0; memory],
            pairs: 0,
            newest: 0,
        }
    }

    /// The Lipschitz estimate the next call starts from (before [`LIPSCHITZ_CARRY_FACTOR`]).
    #[cfg(test)]
    pub(crate) fn lipschitz(&self) -> f64 {
        self.lipschitz
    }

    /// Forgets the carried Lipschitz estimate: the next call estimates it by finite differences.
    pub(crate) fn forget_lipschitz(&mut self) {
        self.lipschitz = 0.0;
    }

    /// Minimises `problem` over the box `[lo, hi]` from `z` (projected first), with at most
    /// `max_iterations` iterations, until `|R|² / 2 <= tolerance |ψ|`. On return `z` holds the
    /// converged (or, at a limit, the best seen: smallest `|R|`) projected point `zbar`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn solve(
        &mut self,
        problem: &mut impl SmoothCost,
        z: &mut [f64],
        lo: &[f64],
        hi: &[f64],
        tolerance: f64,
        max_iterations: usize,
        deadline: Option<Instant>,
    ) -> PanocExit {
        let n = z.len();
        for k in 0..n {
            z[k] = (z[k] + SYMMETRY_NUDGE).clamp(lo[k], hi[k]);
        }
        self.pairs = 0;
        let mut f = problem.cost_and_gradient(z, &mut self.grad);
        if !f.is_finite() || self.grad.iter().any(|g| !g.is_finite()) {
            return PanocExit { status: PanocStatus::NotFinite, iterations: 0, residual: f64::NAN, cost: f };
        }
        let mut lipschitz = if self.lipschitz > 0.0 {
            (self.lipschitz * LIPSCHITZ_CARRY_FACTOR).max(MIN_LIPSCHITZ)
        } else {
            self.estimate_lipschitz(problem, z)
        };
        let mut gamma = GAMMA_L / lipschitz;
        half_step(z, &self.grad, gamma, lo, hi, &mut self.zbar, &mut self.rr);
        self.best.copy_from_slice(&self.zbar);
        let mut best_residual = f64::INFINITY;
        let mut best_cost = f;
        let mut iterations = 0;
        let status = loop {
            // The Lipschitz test at the half step: the descent lemma with the estimate `L`.
            let mut f_bar = problem.cost(&self.zbar);
            let mut doublings = 0;
            while f_bar.is_finite()
                && f_bar
                    > f + LIPSCHITZ_SLACK * f.abs() - dot(&self.grad, &self.rr)
                        + 0.5 * lipschitz * dot(&self.rr, &self.rr)
                && doublings < MAX_LIPSCHITZ_DOUBLINGS
                && lipschitz < MAX_LIPSCHITZ
            {
                lipschitz *= 2.0;
                gamma = GAMMA_L / lipschitz;
                half_step(z, &self.grad, gamma, lo, hi, &mut self.zbar, &mut self.rr);
                f_bar = problem.cost(&self.zbar);
                doublings += 1;
            }
            if !f_bar.is_finite() {
                break PanocStatus::NotFinite;
            }
            let rr2 = dot(&self.rr, &self.rr);
            let residual = rr2.sqrt() / gamma;
            if residual < best_residual {
                best_residual = residual;
                best_cost = f_bar;
                self.best.copy_from_slice(&self.zbar);
            }
            // The scale-free test: the gradient mapping's predicted cost gap against the cost.
            if 0.5 * residual * residual <= tolerance * f_bar.abs().max(f64::MIN_POSITIVE) {
                self.best.copy_from_slice(&self.zbar);
                best_residual = residual;
                best_cost = f_bar;
                break PanocStatus::Converged;
            }
            if iterations >= max_iterations {
                break PanocStatus::IterationLimit;
            }
            if deadline.is_some_and(|d| Instant::now() >= d) {
                break PanocStatus::Deadline;
            }
            iterations += 1;
            // L-BFGS on R = rr / γ: the pair of the last step, then the direction H R.
            if iterations > 1 {
                self.push_pair(z, gamma);
            }
            for k in 0..n {
                self.z_prev[k] = z[k];
                self.r_prev[k] = self.rr[k] / gamma;
            }
            self.lbfgs_direction(gamma);
            // Line search on the FBE: φ(z+) <= φ(z) - σ |rr|².
            let fbe = f - dot(&self.grad, &self.rr) + rr2 / (2.0 * gamma);
            let sigma = (1.0 - GAMMA_L) / (4.0 * gamma);
            let target = fbe - sigma * rr2;
            let mut tau = 1.0;
            let mut accepted = false;
            let mut f_plus = f;
            for _ in 0..=MAX_LINE_SEARCH_HALVINGS {
                for k in 0..n {
                    self.z_plus[k] = z[k] - (1.0 - tau) * self.rr[k] - tau * self.direction[k];
                }
                f_plus = problem.cost_and_gradient(&self.z_plus, &mut self.grad_plus);
                if f_plus.is_finite() {
                    half_step(
                        &self.z_plus,
                        &self.grad_plus,
                        gamma,
                        lo,
                        hi,
                        &mut self.zbar_plus,
                        &mut self.rr_plus,
                    );
                    let fbe_plus = f_plus - dot(&self.grad_plus, &self.rr_plus)
                        + dot(&self.rr_plus, &self.rr_plus) / (2.0 * gamma);
                    if fbe_plus <= target {
                        accepted = true;
                        break;
                    }
                }
                tau *= 0.5;
            }
            if !accepted {
                // τ = 0: the projected gradient step, which decreases the FBE whenever the
                // Lipschitz test held.
                self.z_plus.copy_from_slice(&self.zbar);
                f_plus = problem.cost_and_gradient(&self.z_plus, &mut self.grad_plus);
                half_step(
                    &self.z_plus,
                    &self.grad_plus,
                    gamma,
                    lo,
                    hi,
                    &mut self.zbar_plus,
                    &mut self.rr_plus,
                );
            }
            if !f_plus.is_finite() || self.grad_plus.iter().any(|g| !g.is_finite()) {
                break PanocStatus::NotFinite;
            }
            z.copy_from_slice(&self.z_plus);
            std::mem::swap(&mut self.grad, &mut self.grad_plus);
            std::mem::swap(&mut self.zbar, &mut self.zbar_plus);
            std::mem::swap(&mut self.rr, &mut self.rr_plus);
            f = f_plus;
        };
        self.lipschitz = lipschitz;
        if status != PanocStatus::NotFinite {
            z.copy_from_slice(&self.best);
        }
        PanocExit { status, iterations, residual: best_residual, cost: best_cost }
    }

    /// `|∇ψ(z + h) - ∇ψ(z)| / |h|` with `h_k = 1e-6 max(1, |z_k|)`, clamped: the first call's
    /// estimate (one more gradient). Leaves `grad` at `z` untouched.
    fn estimate_lipschitz(&mut self, problem: &mut impl SmoothCost, z: &[f64]) -> f64 {
        let mut h2 = 0.0;
        for k in 0..z.len() {
            let h = 1e-6 * z[k].abs().max(1.0);
            self.z_plus[k] = z[k] + h;
            h2 += h * h;
        }
        problem.cost_and_gradient(&self.z_plus, &mut self.grad_plus);
        let mut d2 = 0.0;
        for k in 0..z.len() {
            let d = self.grad_plus[k] - self.grad[k];
            d2 += d * d;
        }
        let l = (d2 / h2).sqrt();
        if l.is_finite() { l.clamp(MIN_LIPSCHITZ, MAX_LIPSCHITZ) } else { 1.0 }
    }

    /// Stores `s = z - z_prev`, `y = R - R_prev` if it has positive curvature.
    fn push_pair(&mut self, z: &[f64], gamma: f64) {
        let n = z.len();
        let slot = if self.pairs == 0 { 0 } else { (self.newest + 1) % self.memory };
        let (s, y) = (&mut self.s[slot * n..(slot + 1) * n], &mut self.y[slot * n..(slot + 1) * n]);
        let (mut sy, mut ss, mut yy) = (0.0, 0.0, 0.0);
        for k in 0..n {
            s[k] = z[k] - self.z_prev[k];
            y[k] = self.rr[k] / gamma - self.r_prev[k];
            sy += s[k] * y[k];
            ss += s[k] * s[k];
            yy += y[k] * y[k];
        }
        // Skip pairs of (near) zero or negative curvature: the inverse Hessian stays positive
        // definite.
        if !sy.is_finite() || sy <= 1e-12 * (ss * yy).sqrt() {
            // The slot held the oldest pair when the memory was full: it is gone.
            if self.pairs == self.memory {
                self.pairs -= 1;
            }
            return;
        }
        self.rho[slot] = 1.0 / sy;
        self.newest = slot;
        self.pairs = (self.pairs + 1).min(self.memory);
    }

    /// `direction = H R` by the two-loop recursion (`H0 = s'y / y'y` of the newest pair); with
    /// no pair, `H = γ` (the direction is `rr` and the step lands on `zbar`).
    fn lbfgs_direction(&mut self, gamma: f64) {
        let n = self.rr.len();
        if self.pairs == 0 {
            self.direction.copy_from_slice(&self.rr);
            return;
        }
        for k in 0..n {
            self.direction[k] = self.rr[k] / gamma;
        }
        let m = self.memory;
        for back in 0..self.pairs {
            let slot = (self.newest + m - back) % m;
            let s = &self.s[slot * n..(slot + 1) * n];
            let y = &self.y[slot * n..(slot + 1) * n];
            let a = self.rho[slot] * dot(s, &self.direction);
            self.alpha[slot] = a;
            for k in 0..n {
                self.direction[k] -= a * y[k];
            }
        }
        let newest = self.newest;
        let y = &self.y[newest * n..(newest + 1) * n];
        let h0 = 1.0 / (self.rho[newest] * dot(y, y));
        for d in self.direction.iter_mut() {
            *d *= h0;
        }
        for back in (0..self.pairs).rev() {
            let slot = (self.newest + m - back) % m;
            let s = &self.s[slot * n..(slot + 1) * n];
            let y = &self.y[slot * n..(slot + 1) * n];
            let b = self.rho[slot] * dot(y, &self.direction);
            let a = self.alpha[slot];
            for k in 0..n {
                self.direction[k] += (a - b) * s[k];
            }
        }
    }
}

/// `zbar = P(z - γ g)` on the box and `rr = z - zbar`.
fn half_step(z: &[f64], g: &[f64], gamma: f64, lo: &[f64], hi: &[f64], zbar: &mut [f64], rr: &mut [f64]) {
    for k in 0..z.len() {
        zbar[k] = (z[k] - gamma * g[k]).clamp(lo[k], hi[k]);
        rr[k] = z[k] - zbar[k];
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests;
