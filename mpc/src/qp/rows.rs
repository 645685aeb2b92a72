//! The QP's constraints in the inputs: the bounds (with the trust region), one half-plane per
//! predicted point near an inflated cylinder, the floor rows, and the elastic slacks of the rows
//! the nominal already violates.

use super::QpFallback;

impl QpFallback {
    /// The constraints in the inputs at the nominal: the bounds (`lo <= u <= hi`, with the
    /// trust region), the dense half-plane and floor rows `A u <= b` with their runs, each
    /// row's nominal slack, and the elastic slacks of the rows the nominal violates.
    pub(super) fn build_rows(&mut self) {
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
