//! The one call into clarabel: the settings and budget mapped to clarabel's, the status mapped
//! back, and the solution unblocked into the inputs.

use std::time::Duration;

use clarabel::solver::{DefaultSettings, DefaultSolver, IPSolver, SupportedConeT};

use super::settings::ELASTIC_TOLERANCE_M;
use super::{QpBudget, QpFallback, QpStatus};

impl QpFallback {
    pub(super) fn solve_qp(&mut self, budget: &QpBudget) -> (QpStatus, u32, Duration) {
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
