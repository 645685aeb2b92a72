//! Lazy rows (see [`QpSettings::lazy_slack_m`](super::QpSettings::lazy_slack_m)): rows far from
//! violation start outside clarabel's QP and join it when a solution violates them; the first
//! solve may take only each run's closest points
//! ([`QpSettings::screen_runs`](super::QpSettings::screen_runs)).

use super::QpFallback;

/// The runs of the dense rows: consecutive points of one scenario near one constraint.
#[derive(Debug, Clone)]
pub(super) struct RowRuns {
    /// Per dense row, the row of the same scenario and constraint at the previous point.
    pub(super) prev: Vec<Option<usize>>,
    /// Per dense row, the row of the same scenario and constraint at the next point.
    pub(super) next: Vec<Option<usize>>,
    /// Per constraint (cylinders, then the floor), its last row and point while building one
    /// scenario's rows.
    pub(super) last: Vec<Option<(usize, usize)>>,
    /// Per dense row, `[scenario, constraint, point]` (for the tests).
    #[cfg(test)]
    pub(super) owner: Vec<[usize; 3]>,
}

impl RowRuns {
    /// The rows that follow belong to the next scenario: no run continues into it.
    pub(super) fn start_scenario(&mut self) {
        self.last.iter_mut().for_each(|l| *l = None);
    }

    /// Records row `r`, of scenario `i`'s constraint `c` at point `k`, after the same
    /// constraint's row at point `k - 1` when there is one (`last` is cleared per scenario).
    pub(super) fn link(
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

impl QpFallback {
    /// The rows of the first clarabel solve: those within [`QpSettings::lazy_slack_m`](super::QpSettings::lazy_slack_m) of
    /// violation, screened to each run's closest points when they outnumber the QP's variables
    /// (see [`QpSettings::screen_runs`](super::QpSettings::screen_runs)).
    pub(super) fn select_initial_rows(&mut self) {
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
    }

    /// After a solve with a subset of the rows: selects the unselected rows that the solution
    /// violates or nearly violates (every unselected row when `all`). True when rows were added
    /// and the QP must be solved again.
    pub(super) fn add_violated_rows(&mut self, all: bool) -> bool {
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
}
