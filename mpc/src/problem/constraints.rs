//! The constraints of each predicted point: the cylinders (in the paper's penalty form or in
//! metres for the augmented Lagrangian) and the floor, their values and gradients, and the set
//! of those the penalty sees.

use super::{Evaluator, ObstacleFormulation};

/// A cylinder as the constraint sees it: inflated radius squared, precomputed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ObstacleTerm {
    pub xo: f64,
    pub yo: f64,
    pub r2: f64,
    pub zo: f64,
    pub r: f64,
}

/// A constraint the penalty's gradient sees: `c g + y > 0` at a step of a scenario.
#[derive(Debug, Clone, Copy)]
pub(super) struct ActiveTerm {
    pub(super) step: usize,
    pub(super) constraint: usize,
    pub(super) value: f64,
}

impl Evaluator {
    /// Whether any constraint enters the penalty term of `psi(z; c, y)` at `z`: the same test
    /// as the adjoint pass's active set ([`Evaluator::collect_active`]).
    pub(crate) fn has_penalty_terms(&mut self, z: &[f64], c: f64, y: &[f64]) -> bool {
        self.ensure_forward(z);
        any_penalty_term(&self.con, y, c)
    }

    /// Lists the constraints with `c g + y > 0` (those the penalty's gradient sees) with that
    /// value, scenario by scenario in `con` order; scenario `i`'s are
    /// `active[active_start[i]..active_start[i + 1]]`. Most are inactive: one contiguous pass
    /// here spares the adjoint pass a test per point.
    pub(super) fn collect_active(&mut self, c: f64, multipliers: &[f64]) {
        let Self { m, n, n_con, con, active, active_start, .. } = self;
        let (m, n_con) = (*m, *n_con);
        let block = *n * n_con;
        active.clear();
        for i in 0..m {
            active_start[i] = active.len();
            if c <= 0.0 {
                continue;
            }
            // Without multipliers for the whole scenario, none (`c g + 0`).
            let y = multipliers.get(i * block..(i + 1) * block).unwrap_or(&[]);
            for_each_positive(
                &con[i * block..(i + 1) * block],
                y,
                |g, y| c * g + y,
                |k, v| active.push(ActiveTerm { step: k / n_con, constraint: k % n_con, value: v }),
            );
        }
        active_start[m] = active.len();
    }

    /// Gradient in `(px, py, pz)` of constraint `o` of a point (cylinders, then the floor) at
    /// state `x`.
    #[inline]
    pub(super) fn constraint_gradient(&self, o: usize, x: &[f64; 8]) -> [f64; 3] {
        constraint_gradient(&self.obstacles, self.formulation, self.min_altitude_m, o, x)
    }
}

/// Whether any `c g_k + y_k > 0` (`y_k` = 0 past the end of `y`; none for `c <= 0`): a constraint
/// in the augmented Lagrangian `(c / 2) sum_k [g_k + y_k / c]_+^2`, or in the penalty method's
/// `F2` with `y` empty.
pub(super) fn any_penalty_term(g: &[f64], y: &[f64], c: f64) -> bool {
    let mut any = false;
    if c > 0.0 {
        for_each_positive(g, y, |g, y| c * g + y, |_, _| any = true);
    }
    any
}

/// `visit(k, v)`, in increasing `k`, for every `k` with `v = value(g[k], y[k]) > 0`, where
/// `y[k]` is 0 past the end of `y`. The values are computed four at a time (vectorized) and
/// tested with one branch, as most are not positive; the values and the visits are the same,
/// in the same order, as one `k` at a time.
#[inline(always)]
pub(super) fn for_each_positive(
    g: &[f64],
    y: &[f64],
    value: impl Fn(f64, f64) -> f64,
    mut visit: impl FnMut(usize, f64),
) {
    let (g_y, g_alone) = g.split_at(y.len().min(g.len()));
    let y = &y[..g_y.len()];
    let mut visit_positive = |k: usize, v: f64| {
        if v > 0.0 {
            visit(k, v);
        }
    };
    let (g4, y4) = (g_y.chunks_exact(4), y.chunks_exact(4));
    let (g_rest, y_rest) = (g4.remainder(), y4.remainder());
    for (chunk, (g, y)) in g4.zip(y4).enumerate() {
        let v: [f64; 4] = std::array::from_fn(|t| value(g[t], y[t]));
        // `max` skips NaN, which is not positive either.
        if v[0].max(v[1]).max(v[2].max(v[3])) > 0.0 {
            for (t, v) in v.into_iter().enumerate() {
                visit_positive(4 * chunk + t, v);
            }
        }
    }
    let rest = g_y.len() - g_rest.len();
    for (t, (g, y)) in g_rest.iter().zip(y_rest).enumerate() {
        visit_positive(rest + t, value(*g, *y));
    }
    for (t, g) in g_alone.iter().enumerate() {
        visit_positive(g_y.len() + t, value(*g, 0.0));
    }
}

/// One constraint value alone at position `(px, py, pz)`: the same arithmetic as
/// [`constraint`] without the gradient's divisions.
#[inline(always)]
pub(super) fn constraint_value(
    formulation: ObstacleFormulation,
    ob: &ObstacleTerm,
    px: f64,
    py: f64,
    pz: f64,
) -> f64 {
    let (dx, dy) = (px - ob.xo, py - ob.yo);
    let hz = ob.zo - pz;
    match formulation {
        ObstacleFormulation::PaperPenalty => {
            let hc = ob.r2 - dx * dx - dy * dy;
            if hc > 0.0 && hz > 0.0 { hc * hz } else { 0.0 }
        }
        ObstacleFormulation::DistanceAlm => {
            let d = (dx * dx + dy * dy).sqrt().max(1e-9);
            let radial = ob.r - d;
            if radial <= hz { radial } else { hz }
        }
    }
}

/// [`Evaluator::constraint_gradient`] from the fields it reads.
#[inline]
pub(super) fn constraint_gradient(
    obstacles: &[ObstacleTerm],
    formulation: ObstacleFormulation,
    min_altitude_m: Option<f64>,
    o: usize,
    x: &[f64; 8],
) -> [f64; 3] {
    match obstacles.get(o) {
        Some(ob) => constraint(formulation, ob, x).1,
        None => floor_constraint(formulation, min_altitude_m.unwrap_or(0.0), x).1,
    }
}

/// One constraint value and its gradient with respect to `(px, py, pz)`.
#[inline]
pub(super) fn constraint(
    formulation: ObstacleFormulation,
    ob: &ObstacleTerm,
    x: &[f64; 8],
) -> (f64, [f64; 3]) {
    let (dx, dy) = (x[0] - ob.xo, x[1] - ob.yo);
    let hz = ob.zo - x[2];
    match formulation {
        ObstacleFormulation::PaperPenalty => {
            let hc = ob.r2 - dx * dx - dy * dy;
            if hc > 0.0 && hz > 0.0 {
                (hc * hz, [-2.0 * dx * hz, -2.0 * dy * hz, -hc])
            } else {
                (0.0, [0.0; 3])
            }
        }
        ObstacleFormulation::DistanceAlm => {
            // The axis itself is never a solution; keep the gradient finite there.
            let d = (dx * dx + dy * dy).sqrt().max(1e-9);
            let radial = ob.r - d;
            if radial <= hz { (radial, [-dx / d, -dy / d, 0.0]) } else { (hz, [0.0, 0.0, -1.0]) }
        }
    }
}

/// The floor constraint `min_altitude_m - z <= 0` and its gradient in `(px, py, pz)`: in metres
/// for ALM, as a hinge `[min_altitude_m - z]_+ = 0` for the penalty method.
#[inline]
pub(super) fn floor_constraint(
    formulation: ObstacleFormulation,
    min_altitude_m: f64,
    x: &[f64; 8],
) -> (f64, [f64; 3]) {
    let below = min_altitude_m - x[2];
    match formulation {
        ObstacleFormulation::PaperPenalty if below <= 0.0 => (0.0, [0.0; 3]),
        _ => (below, [0.0, 0.0, -1.0]),
    }
}

/// The floor constraint's value alone at altitude `pz`: the same as [`floor_constraint`].
#[inline(always)]
pub(super) fn floor_value(formulation: ObstacleFormulation, min_altitude_m: f64, pz: f64) -> f64 {
    let below = min_altitude_m - pz;
    match formulation {
        ObstacleFormulation::PaperPenalty if below <= 0.0 => 0.0,
        _ => below,
    }
}
