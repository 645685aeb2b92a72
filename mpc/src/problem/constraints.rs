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

    /// Gradient in `(px, py, pz, vx, vy)` of constraint `o` of a point (cylinders, then the
    /// floor) at state `x`.
    #[inline]
    pub(super) fn constraint_gradient(&self, o: usize, x: &[f64; 8]) -> [f64; 5] {
        constraint_gradient(&self.obstacles, self.formulation, self.min_altitude_m, self.coast_s, o, x)
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

/// Where the straight coast `p + s v`, `s` in `[0, coast_s]`, from a point at horizontal
/// offset `(dx, dy)` from a cylinder's axis with horizontal velocity `(vx, vy)` comes closest
/// to the axis: that offset, and `s`. With `coast_s = 0` the point itself.
///
/// Why: the fail-safe check (`crate::fail_safe`) wants room to stop in front of a cylinder, and
/// that room grows with the speed toward it (the delays before a brake lands, the attitude's
/// lag): a plan that grazes the inflated cylinder at speed is refused, and the vehicle brakes
/// instead. Keeping the coasting segment clear asks the plan for that room where it heads for a
/// cylinder and not where it passes one (its segment runs along the surface).
#[inline(always)]
pub(super) fn closest_coast_point(dx: f64, dy: f64, vx: f64, vy: f64, coast_s: f64) -> (f64, f64, f64) {
    let speed2 = vx * vx + vy * vy;
    let toward = -(dx * vx + dy * vy);
    let s = (toward.max(0.0) / speed2.max(1e-12)).min(coast_s);
    (dx + s * vx, dy + s * vy, s)
}

/// The distance form's value along a coast (see [`closest_coast_point`]): `min(R - d_q,
/// zo - pz)` with `d_q` the coast's closest horizontal distance to the axis.
#[inline(always)]
pub(super) fn coasting_value(ob: &ObstacleTerm, coast_s: f64, x: [f64; 5]) -> f64 {
    let [px, py, pz, vx, vy] = x;
    let (qx, qy, _) = closest_coast_point(px - ob.xo, py - ob.yo, vx, vy, coast_s);
    let d = (qx * qx + qy * qy).sqrt().max(1e-9);
    let radial = ob.r - d;
    let hz = ob.zo - pz;
    if radial <= hz { radial } else { hz }
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
    coast_s: f64,
    o: usize,
    x: &[f64; 8],
) -> [f64; 5] {
    match obstacles.get(o) {
        Some(ob) => constraint(formulation, ob, coast_s, x).1,
        None => floor_constraint(formulation, min_altitude_m.unwrap_or(0.0), x).1,
    }
}

/// One constraint value and its gradient with respect to `(px, py, pz, vx, vy)` (the velocity
/// enters the distance form with a coast, [`closest_coast_point`]; PaperPenalty has none).
#[inline]
pub(super) fn constraint(
    formulation: ObstacleFormulation,
    ob: &ObstacleTerm,
    coast_s: f64,
    x: &[f64; 8],
) -> (f64, [f64; 5]) {
    let (dx, dy) = (x[0] - ob.xo, x[1] - ob.yo);
    let hz = ob.zo - x[2];
    match formulation {
        ObstacleFormulation::PaperPenalty => {
            let hc = ob.r2 - dx * dx - dy * dy;
            if hc > 0.0 && hz > 0.0 {
                (hc * hz, [-2.0 * dx * hz, -2.0 * dy * hz, -hc, 0.0, 0.0])
            } else {
                (0.0, [0.0; 5])
            }
        }
        ObstacleFormulation::DistanceAlm if coast_s > 0.0 => coasting_constraint(ob, coast_s, x),
        ObstacleFormulation::DistanceAlm => {
            // The axis itself is never a solution; keep the gradient finite there.
            let d = (dx * dx + dy * dy).sqrt().max(1e-9);
            let radial = ob.r - d;
            if radial <= hz {
                (radial, [-dx / d, -dy / d, 0.0, 0.0, 0.0])
            } else {
                (hz, [0.0, 0.0, -1.0, 0.0, 0.0])
            }
        }
    }
}

/// [`coasting_value`] and its gradient in `(px, py, pz, vx, vy)`. By the envelope theorem the
/// closest point's `s` does not move the gradient: in `p` it is the outward normal's, in `v`
/// that times `s`.
#[inline]
fn coasting_constraint(ob: &ObstacleTerm, coast_s: f64, x: &[f64; 8]) -> (f64, [f64; 5]) {
    let (vx, vy) = (x[3], x[4]);
    let (qx, qy, s) = closest_coast_point(x[0] - ob.xo, x[1] - ob.yo, vx, vy, coast_s);
    let dq = (qx * qx + qy * qy).sqrt();
    // The value as `coasting_value` computes it, to the bit.
    let d = dq.max(1e-9);
    let radial = ob.r - d;
    let hz = ob.zo - x[2];
    if radial <= hz {
        // The outward normal at the coast's closest point. A coast through the axis (a point
        // heading straight at it, as on paper-1's start-goal line) has none: either side is a
        // subgradient, and `q / d` would be about zero there, leaving the solver nothing to
        // turn by; take the left of the velocity.
        let speed = vx.hypot(vy);
        let (nx, ny) = if dq > 1e-12 {
            (qx / dq, qy / dq)
        } else if speed > 0.0 {
            (-vy / speed, vx / speed)
        } else {
            (1.0, 0.0)
        };
        (radial, [-nx, -ny, 0.0, -s * nx, -s * ny])
    } else {
        (hz, [0.0, 0.0, -1.0, 0.0, 0.0])
    }
}

/// The floor constraint `min_altitude_m - z <= 0` and its gradient in `(px, py, pz, vx, vy)`:
/// in metres for ALM, as a hinge `[min_altitude_m - z]_+ = 0` for the penalty method.
#[inline]
pub(super) fn floor_constraint(
    formulation: ObstacleFormulation,
    min_altitude_m: f64,
    x: &[f64; 8],
) -> (f64, [f64; 5]) {
    let below = min_altitude_m - x[2];
    match formulation {
        ObstacleFormulation::PaperPenalty if below <= 0.0 => (0.0, [0.0; 5]),
        _ => (below, [0.0, 0.0, -1.0, 0.0, 0.0]),
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
