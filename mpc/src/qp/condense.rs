//! Condensing into the blocked corrections `d` (`u = u_bar + T d`, see
//! [`QpSettings::block_steps`](super::QpSettings::block_steps)): the objective (`P = T^T H T`,
//! `q = T^T g`) and the constraints clarabel sees (`[A T, -E]`), in CSC form.

use super::QpFallback;

impl QpFallback {
    /// The QP in the blocked corrections `d` (`u = u_bar + T d`): `q = T^T g` (and the elastic
    /// slacks' prices) and the CSC form of `P = T^T H T` (upper triangle).
    pub(super) fn condense(&mut self) {
        let nv = 3 * self.evaluator.n;
        let nb = 3 * self.num_blocks;
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

    /// The constraints clarabel sees: the bound rows of the corrections and of the elastic
    /// slacks, then the selected dense rows, in CSC (`[A T, -E]`, `E` picking each elastic
    /// row's slack) with their right-hand sides.
    pub(super) fn assemble_constraints(&mut self) {
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
}
