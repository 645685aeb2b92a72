//! The lane-parallel passes: the scenarios of a group in the lanes of `[f64; L]` arrays, so that
//! LLVM vectorizes each step's arithmetic across them, with every lane doing the scalar
//! recursion's operations in the same order (bit-identical results).

use super::constraints::{coasting_value, constraint_gradient, constraint_value, floor_value};
use super::euler::{cos_series, sin_series};
use super::{Evaluator, ObstacleFormulation};

/// Most scenarios the lane-parallel passes process together (see
/// [`Evaluator::forward_lanes`]); more form several groups.
pub(super) const MAX_LANES: usize = 8;

/// `$self.$method::<L>(args)` with the const `L` equal to `$width`, one of `1..=MAX_LANES`.
macro_rules! with_lanes {
    ($width:expr, $self:ident . $method:ident ( $($arg:expr),* )) => {
        match $width {
            1 => $self.$method::<1>($($arg),*),
            2 => $self.$method::<2>($($arg),*),
            3 => $self.$method::<3>($($arg),*),
            4 => $self.$method::<4>($($arg),*),
            5 => $self.$method::<5>($($arg),*),
            6 => $self.$method::<6>($($arg),*),
            7 => $self.$method::<7>($($arg),*),
            8 => $self.$method::<8>($($arg),*),
            w => unreachable!("scenario group of {w}"),
        }
    };
}
pub(super) use with_lanes;

impl Evaluator {
    /// Forward pass of scenarios `first..first + L` together, step-outer and scenario-inner.
    ///
    /// The scenarios are independent chains (own `dt` and `x0`) driven by the same inputs.
    /// With the scenarios of a group in the lanes of `[f64; L]` arrays, LLVM vectorizes each
    /// step's arithmetic across them (SSE2: two lanes per instruction), which matters because
    /// the pass is bound by instruction throughput, not by the chains' latency. Every lane
    /// does exactly the operations of the scalar recursion in the same order (Rust never
    /// contracts `a * b + c` into an FMA), so the results are bit-identical to one scenario
    /// at a time.
    pub(super) fn forward_lanes<const L: usize>(&mut self, first: usize) {
        // Fields as locals: the stores into the outputs would otherwise make LLVM reload every
        // field of `self` after each of them.
        let Self {
            n,
            params,
            dts,
            x0s,
            x_ref,
            q_x,
            obstacles,
            formulation,
            min_altitude_m,
            coast_s,
            n_con,
            u,
            states,
            trig,
            residual,
            con,
            state_costs,
            ..
        } = self;
        let (n, n_con, x_ref, q_x, formulation, coast_s) = (*n, *n_con, *x_ref, *q_x, *formulation, *coast_s);
        let p = *params;
        let (g, ax, ay, az) = (p.gravity_mps2, p.drag_x_per_s, p.drag_y_per_s, p.drag_z_per_s);
        let (kr, kp) = (p.gain_roll / p.tau_roll_s, p.gain_pitch / p.tau_pitch_s);
        let (ir, ip) = (1.0 / p.tau_roll_s, 1.0 / p.tau_pitch_s);
        let n_obs = obstacles.len();
        let dt: [f64; L] = lanes(|l| dts[first + l]);
        let mut x: [[f64; L]; 8] = std::array::from_fn(|k| lanes(|l| x0s[first + l][k]));
        // Scenario `first + l`'s predictions are `states[l * (n + 1)..]`.
        let states = &mut states[first * (n + 1)..(first + L) * (n + 1)];
        for l in 0..L {
            states[l * (n + 1)] = x0s[first + l];
        }
        // Scenario `first + l`'s constraint values are `con[l * n * n_con..]`.
        let con = &mut con[first * n * n_con..(first + L) * n * n_con];
        let mut state_cost = [0.0f64; L];
        let trig = trig[4 * n * first..4 * n * (first + L)].chunks_exact_mut(4 * L);
        let residual = residual[8 * n * first..8 * n * (first + L)].chunks_exact_mut(8 * L);
        for (j, (u, (trig, residual))) in u.chunks_exact(3).zip(trig.zip(residual)).enumerate() {
            let (sr, cr) = sin_cos_lanes(&x[6]);
            let (sp, cp) = sin_cos_lanes(&x[7]);
            for (q, v) in [sr, cr, sp, cp].iter().enumerate() {
                trig[q * L..(q + 1) * L].copy_from_slice(v);
            }
            let (t, rd, pd) = (u[0], u[1], u[2]);
            x = [
                lanes(|l| x[0][l] + dt[l] * x[3][l]),
                lanes(|l| x[1][l] + dt[l] * x[4][l]),
                lanes(|l| x[2][l] + dt[l] * x[5][l]),
                lanes(|l| x[3][l] + dt[l] * (t * cr[l] * sp[l] - ax * x[3][l])),
                lanes(|l| x[4][l] + dt[l] * (-t * sr[l] - ay * x[4][l])),
                lanes(|l| x[5][l] + dt[l] * (t * cr[l] * cp[l] - g - az * x[5][l])),
                lanes(|l| x[6][l] + dt[l] * (kr * rd - ir * x[6][l])),
                lanes(|l| x[7][l] + dt[l] * (kp * pd - ip * x[7][l])),
            ];
            for l in 0..L {
                states[l * (n + 1) + j + 1] = std::array::from_fn(|k| x[k][l]);
            }
            for k in 0..8 {
                for l in 0..L {
                    let e = x[k][l] - x_ref[k];
                    state_cost[l] += q_x[k] * e * e;
                    // For one scenario the adjoint pass reads the states instead: these stores
                    // would be all overhead. For several, they also make LLVM vectorize this
                    // loop over the lanes (it does not without them: callgrind).
                    if L > 1 {
                        residual[k * L + l] = e;
                    }
                }
            }
            // `con` keeps its layout (scenario, point, constraint): OpEn reads it as F1, and
            // the penalty sums it in that order.
            if L == 1 {
                // One scenario: a point's values are contiguous, and LLVM vectorizes over the
                // cylinders, as it did before the lanes.
                let row = &mut con[j * n_con..(j + 1) * n_con];
                let (px, py, pz) = (x[0][0], x[1][0], x[2][0]);
                let cylinders = obstacles.iter().zip(&mut row[..n_obs]);
                match formulation {
                    ObstacleFormulation::PaperPenalty => cylinders.for_each(|(ob, c)| {
                        *c = constraint_value(ObstacleFormulation::PaperPenalty, ob, px, py, pz);
                    }),
                    ObstacleFormulation::DistanceAlm if coast_s > 0.0 => {
                        let point = [px, py, pz, x[3][0], x[4][0]];
                        cylinders.for_each(|(ob, c)| *c = coasting_value(ob, coast_s, point));
                    }
                    ObstacleFormulation::DistanceAlm => cylinders.for_each(|(ob, c)| {
                        *c = constraint_value(ObstacleFormulation::DistanceAlm, ob, px, py, pz);
                    }),
                }
            } else {
                // Several: over the lanes, cylinder by cylinder (fewer instructions, callgrind).
                let point = |l: usize| (l * n + j) * n_con;
                for (o, ob) in obstacles.iter().enumerate() {
                    // One arm per formulation, so that the lane loops are branch-free.
                    let value: [f64; L] = match formulation {
                        ObstacleFormulation::PaperPenalty => lanes(|l| {
                            constraint_value(ObstacleFormulation::PaperPenalty, ob, x[0][l], x[1][l], x[2][l])
                        }),
                        ObstacleFormulation::DistanceAlm if coast_s > 0.0 => lanes(|l| {
                            coasting_value(ob, coast_s, [x[0][l], x[1][l], x[2][l], x[3][l], x[4][l]])
                        }),
                        ObstacleFormulation::DistanceAlm => lanes(|l| {
                            constraint_value(ObstacleFormulation::DistanceAlm, ob, x[0][l], x[1][l], x[2][l])
                        }),
                    };
                    for (l, v) in value.into_iter().enumerate() {
                        con[point(l) + o] = v;
                    }
                }
            }
            if let Some(floor) = *min_altitude_m {
                for l in 0..L {
                    con[(l * n + j) * n_con + n_obs] = floor_value(formulation, floor, x[2][l]);
                }
            }
        }
        state_costs[first..first + L].copy_from_slice(&state_cost);
    }

    /// Adjoint pass of scenarios `group + offset..group + offset + L` of the forward group
    /// `group..group + G` together, adding their input sensitivities to `grad_u`: backward
    /// over the steps, lane-parallel over the scenarios as in [`Evaluator::forward_lanes`],
    /// with the same operations per lane as one scenario at a time. The scenarios'
    /// contributions to each input are added in scenario order (the sub-groups of a group in
    /// order, the lanes of a sub-group in order), the order of the scalar pass, so `grad_u` is
    /// bit-identical too.
    pub(super) fn adjoint_lanes<const G: usize, const L: usize>(&mut self, group: usize, offset: usize) {
        let first = group + offset;
        // Fields as locals, as in `forward_lanes`; `grad_u` is the only output.
        let Self {
            n,
            params,
            dts,
            weights,
            q_x,
            x_ref,
            u,
            states,
            trig,
            residual,
            grad_u,
            active,
            active_start,
            obstacles,
            formulation,
            min_altitude_m,
            coast_s,
            ..
        } = self;
        let (n, q_x, x_ref) = (*n, *q_x, *x_ref);
        let p = *params;
        let (ax, ay, az) = (p.drag_x_per_s, p.drag_y_per_s, p.drag_z_per_s);
        let (kr, kp) = (p.gain_roll / p.tau_roll_s, p.gain_pitch / p.tau_pitch_s);
        let (ir, ip) = (1.0 / p.tau_roll_s, 1.0 / p.tau_pitch_s);
        let dt: [f64; L] = lanes(|l| dts[first + l]);
        let wq: [[f64; L]; 8] = std::array::from_fn(|k| lanes(|l| 2.0 * weights[first + l] * q_x[k]));
        // The forward pass's layout: lane `l` here is lane `offset + l` of its group.
        let trig = &trig[4 * n * group..4 * n * (group + G)];
        let residual = &residual[8 * n * group..8 * n * (group + G)];
        // Per lane, the active constraints of the steps not yet visited (they run backward) are
        // `active[start..end]`, and `next` is the step of the last of them (`n`: none).
        let start: [usize; L] = std::array::from_fn(|l| active_start[first + l]);
        let mut end: [usize; L] = std::array::from_fn(|l| active_start[first + l + 1]);
        let mut next: [usize; L] =
            std::array::from_fn(|l| if end[l] > start[l] { active[end[l] - 1].step } else { n });
        // The adjoint state `l` of each scenario, as `lam[k][lane]`.
        let mut lam = [[0.0f64; L]; 8];
        let steps = u.chunks_exact(3).zip(grad_u.chunks_exact_mut(3)).zip(trig.chunks_exact(4 * G));
        for (j, (((u, grad_u), trig), residual)) in steps.zip(residual.chunks_exact(8 * G)).enumerate().rev()
        {
            // Stage terms at x_{j+1}: `x - x_ref` as the forward pass computed it.
            if G == 1 {
                let x = &states[first * (n + 1) + j + 1];
                for k in 0..8 {
                    lam[k][0] += wq[k][0] * (x[k] - x_ref[k]);
                }
            } else {
                for k in 0..8 {
                    for l in 0..L {
                        lam[k][l] += wq[k][l] * residual[k * G + offset + l];
                    }
                }
            }
            // The active constraints at x_{j+1} (usually none), in constraint order.
            for l in 0..L {
                if next[l] != j {
                    continue;
                }
                let mut lo = end[l];
                while lo > start[l] && active[lo - 1].step == j {
                    lo -= 1;
                }
                let x = &states[(first + l) * (n + 1) + j + 1];
                for term in &active[lo..end[l]] {
                    let dg = constraint_gradient(
                        obstacles,
                        *formulation,
                        *min_altitude_m,
                        *coast_s,
                        term.constraint,
                        x,
                    );
                    lam[0][l] += term.value * dg[0];
                    lam[1][l] += term.value * dg[1];
                    lam[2][l] += term.value * dg[2];
                    lam[3][l] += term.value * dg[3];
                    lam[4][l] += term.value * dg[4];
                }
                end[l] = lo;
                next[l] = if lo > start[l] { active[lo - 1].step } else { n };
            }
            // Input sensitivity of x_{j+1} = x_j + dt f(x_j, u_j).
            let [sr, cr, sp, cp]: [[f64; L]; 4] =
                std::array::from_fn(|q| lanes(|l| trig[q * G + offset + l]));
            let t = u[0];
            let g0 = lanes::<L>(|l| {
                dt[l] * (cr[l] * sp[l] * lam[3][l] - sr[l] * lam[4][l] + cr[l] * cp[l] * lam[5][l])
            });
            let g1 = lanes::<L>(|l| dt[l] * kr * lam[6][l]);
            let g2 = lanes::<L>(|l| dt[l] * kp * lam[7][l]);
            // In scenario order, as the sum has always been taken.
            for l in 0..L {
                grad_u[0] += g0[l];
                grad_u[1] += g1[l];
                grad_u[2] += g2[l];
            }
            // Adjoint: l_j = (I + dt Fx(x_j, u_j))^T l_{j+1}.
            let l6 = lanes::<L>(|l| {
                lam[6][l]
                    + dt[l]
                        * (-t * sr[l] * sp[l] * lam[3][l]
                            - t * cr[l] * lam[4][l]
                            - t * sr[l] * cp[l] * lam[5][l]
                            - ir * lam[6][l])
            });
            let l7 = lanes::<L>(|l| {
                lam[7][l]
                    + dt[l] * (t * cr[l] * cp[l] * lam[3][l] - t * cr[l] * sp[l] * lam[5][l] - ip * lam[7][l])
            });
            for l in 0..L {
                lam[3][l] += dt[l] * (lam[0][l] - ax * lam[3][l]);
                lam[4][l] += dt[l] * (lam[1][l] - ay * lam[4][l]);
                lam[5][l] += dt[l] * (lam[2][l] - az * lam[5][l]);
            }
            lam[6] = l6;
            lam[7] = l7;
        }
    }
}

/// [`sin_cos_small`](super::euler::sin_cos_small) of every lane: the series everywhere, then libm in the rare lanes out of
/// the series' range. The same values lane by lane. The range test is one branch for all
/// lanes: with a branch per lane, LLVM moves the series into each lane's branch, and it no
/// longer vectorizes.
#[inline(always)]
pub(super) fn sin_cos_lanes<const L: usize>(x: &[f64; L]) -> ([f64; L], [f64; L]) {
    let mut s = lanes(|l| sin_series(x[l]));
    let mut c = lanes(|l| cos_series(x[l]));
    // `|` rather than `||`: no branch per lane.
    if x.iter().fold(false, |out, v| out | (v.abs() > 0.5)) {
        sin_cos_large_lanes(x, &mut s, &mut c);
    }
    (s, c)
}

/// libm's `(sin, cos)` in the lanes out of the series' range (see [`sin_cos_lanes`]).
#[cold]
#[inline(never)]
pub(super) fn sin_cos_large_lanes<const L: usize>(x: &[f64; L], s: &mut [f64; L], c: &mut [f64; L]) {
    for l in 0..L {
        if x[l].abs() > 0.5 {
            (s[l], c[l]) = x[l].sin_cos();
        }
    }
}

/// `[f(0), .., f(L - 1)]`: one value per lane (scenario of a group) of the lane-parallel passes.
#[inline(always)]
pub(super) fn lanes<const L: usize>(f: impl FnMut(usize) -> f64) -> [f64; L] {
    std::array::from_fn(f)
}
