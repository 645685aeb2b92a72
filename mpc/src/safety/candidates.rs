//! The selection, candidate by candidate in the order of preference (see the module
//! documentation of [`crate::safety`]): PANOC's plan, the QP's, the previous plan shifted,
//! braking, and when none passes the candidate that comes closest; then the selected plan
//! becomes the layer's memory.

use crate::command::{braking_command, sanitize_command};
use crate::solver::{SolveStatus, shift_plan_into};

use super::{CandidateCheck, Decision, QpReport, Rejection, SafetyLayer, Selection};

/// The fallbacks' outcome: what was decided, and the checks of the shifted plan and of braking
/// (`NotRun` when a better candidate passed).
struct Fallbacks {
    decision: Decision,
    shifted: CandidateCheck,
    brake: CandidateCheck,
    verified_safe: bool,
}

impl SafetyLayer {
    pub(super) fn select_inner(
        &mut self,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        weights: &[f64],
        panoc: Result<(&[f64], SolveStatus), ()>,
        no_iterations: bool,
    ) -> Selection {
        let valid = x0.iter().chain(u_prev).chain(weights).all(|v| v.is_finite())
            && weights.len() == self.m
            && weights.iter().all(|w| *w >= 0.0)
            && weights.iter().sum::<f64>() > 0.0;
        if !valid {
            return self.brake_on_invalid_instance(x0);
        }
        self.evaluator.set_instance(x0, u_prev, weights);
        self.x0 = *x0;
        self.u_prev = *u_prev;

        // 1. PANOC.
        let panoc_check = self.check_panoc(panoc, no_iterations);
        // 2. The QP, linearized around the previous plan shifted (hover without one).
        let (qp_check, qp_report) = self.check_qp(x0, u_prev, weights, panoc_check.accepted());
        let cost_gap = (panoc_check.cost.is_finite() && qp_check.cost.is_finite())
            .then_some(qp_check.cost - panoc_check.cost);
        // 3. The previous plan shifted; 4. braking; 5. the closest to passing.
        let brake_command = braking_command(&self.params, &self.bounds, x0, self.settings.brake_gain_per_s);
        let Fallbacks { decision, shifted: shifted_check, brake: brake_check, verified_safe } =
            self.decide(x0, weights, &panoc_check, &qp_check);
        let command = self.adopt(decision, panoc, &brake_check, brake_command);
        Selection {
            decision,
            command: sanitize_command(&self.params, &self.bounds, command),
            panoc: panoc_check,
            qp: qp_check,
            qp_report,
            shifted: shifted_check,
            brake: brake_check,
            cost_gap,
            verified_safe,
        }
    }

    /// A cycle whose state, last input or weights are not usable: brake (hover for a
    /// non-finite state), and say so.
    fn brake_on_invalid_instance(&mut self, x0: &[f64; 8]) -> Selection {
        let command = braking_command(&self.params, &self.bounds, x0, self.settings.brake_gain_per_s);
        self.store_brake_plan(command);
        let invalid = CandidateCheck::rejected(Rejection::InvalidInstance);
        Selection {
            decision: Decision::Brake,
            command,
            panoc: invalid,
            qp: invalid,
            qp_report: None,
            shifted: invalid,
            brake: invalid,
            cost_gap: None,
            verified_safe: false,
        }
    }

    /// PANOC's plan checked, and rejected when its status is not accepted or it ran no
    /// iteration.
    fn check_panoc(
        &mut self,
        panoc: Result<(&[f64], SolveStatus), ()>,
        no_iterations: bool,
    ) -> CandidateCheck {
        match panoc {
            Err(()) => CandidateCheck::rejected(Rejection::PanocError),
            Ok((u, status)) => {
                let status_ok = match status {
                    SolveStatus::Converged => true,
                    // A plan inside a cylinder is judged by the same check as any other (which
                    // rejects it under the plan check; the fail-safe check judges its command).
                    SolveStatus::IterationLimit | SolveStatus::InfeasibleAtLimit => {
                        self.settings.accept_iteration_limit
                    }
                    SolveStatus::Deadline => self.settings.accept_deadline,
                    SolveStatus::NumericalFailure => false,
                };
                let mut check = self.check_plan(u);
                if !status_ok {
                    check.rejection = Some(Rejection::PanocStatus { status });
                } else if no_iterations {
                    check.rejection = Some(Rejection::NoIterations);
                }
                check
            }
        }
    }

    /// The QP's plan checked, when the schedule asks for the cross-check or PANOC's plan was
    /// rejected (`NotRun` otherwise), with the QP's report when it ran. Counts the cycle.
    fn check_qp(
        &mut self,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        weights: &[f64],
        panoc_accepted: bool,
    ) -> (CandidateCheck, Option<QpReport>) {
        let run_qp = self.settings.qp_schedule.due(self.cycles) || !panoc_accepted;
        self.cycles += 1;
        let mut qp_report = None;
        let qp_check = if run_qp {
            let nominal = if self.has_plan {
                shift_plan_into(&self.plan, &mut self.shifted);
                Some(&self.shifted[..])
            } else {
                None
            };
            match self.qp.solve(x0, u_prev, weights, nominal, &self.qp_budget) {
                Err(_) => CandidateCheck::rejected(Rejection::NotRun),
                Ok(report) => {
                    qp_report = Some(report);
                    match self.qp.solution() {
                        Some(u) if report.status.has_solution() => {
                            // Re-checked here with the layer's own evaluator: the same rules
                            // for every candidate.
                            let u = u.to_vec();
                            self.check_plan(&u)
                        }
                        _ => CandidateCheck::rejected(Rejection::QpStatus { status: report.status }),
                    }
                }
            }
        } else {
            CandidateCheck::rejected(Rejection::NotRun)
        };
        (qp_check, qp_report)
    }

    /// The first candidate that passes, going down the fallbacks (the shifted plan, braking)
    /// only when PANOC's and the QP's plans did not; when none passes, braking or, with
    /// [`best_effort`](super::SafetySettings::best_effort), the candidate that comes closest.
    fn decide(
        &mut self,
        x0: &[f64; 8],
        weights: &[f64],
        panoc_check: &CandidateCheck,
        qp_check: &CandidateCheck,
    ) -> Fallbacks {
        let mut shifted_check = CandidateCheck::rejected(Rejection::NotRun);
        let mut brake_check = CandidateCheck::rejected(Rejection::NotRun);
        let mut verified_safe = true;
        let decision = if panoc_check.accepted() {
            Decision::Panoc
        } else if qp_check.accepted() {
            Decision::Qp
        } else {
            shifted_check = if self.has_plan && self.shifts < self.settings.max_plan_shifts {
                shift_plan_into(&self.plan, &mut self.shifted);
                let u = self.shifted.clone();
                self.check_plan(&u)
            } else {
                CandidateCheck::rejected(Rejection::NoPlan)
            };
            if shifted_check.accepted() {
                Decision::ShiftedPlan
            } else {
                self.fill_brake_plan(x0, weights);
                let brake_plan = self.brake_plan.clone();
                brake_check = self.check_plan(&brake_plan);
                if brake_check.accepted() {
                    Decision::Brake
                } else {
                    verified_safe = false;
                    let candidates = [
                        (Decision::Brake, &brake_check),
                        (Decision::Panoc, panoc_check),
                        (Decision::Qp, qp_check),
                        (Decision::ShiftedPlan, &shifted_check),
                    ];
                    let mut best = (Decision::Brake, self.safety_score(&brake_check));
                    if self.settings.best_effort {
                        for (d, c) in candidates.iter().skip(1) {
                            let score = self.safety_score(c);
                            if score > best.1 {
                                best = (*d, score);
                            }
                        }
                    }
                    best.0
                }
            }
        };
        Fallbacks { decision, shifted: shifted_check, brake: brake_check, verified_safe }
    }

    /// Makes the decided candidate's plan the layer's memory and returns its first input.
    fn adopt(
        &mut self,
        decision: Decision,
        panoc: Result<(&[f64], SolveStatus), ()>,
        brake_check: &CandidateCheck,
        brake_command: [f64; 3],
    ) -> [f64; 3] {
        match decision {
            Decision::Panoc => {
                if let Ok((u, _)) = panoc {
                    self.store_plan(u);
                }
                self.shifts = 0;
                self.first()
            }
            Decision::Qp => {
                if let Some(u) = self.qp.solution() {
                    let u = u.to_vec();
                    self.store_plan(&u);
                }
                self.shifts = 0;
                self.first()
            }
            Decision::ShiftedPlan => {
                std::mem::swap(&mut self.plan, &mut self.shifted);
                self.shifts += 1;
                self.first()
            }
            Decision::Brake if brake_check.rejection != Some(Rejection::NotRun) => {
                // The plan that was checked: brake, then hold.
                self.plan.copy_from_slice(&self.brake_plan);
                self.has_plan = true;
                self.shifts = 0;
                brake_command
            }
            Decision::Brake => {
                self.store_brake_plan(brake_command);
                brake_command
            }
        }
    }

    pub(super) fn first(&self) -> [f64; 3] {
        [self.plan[0], self.plan[1], self.plan[2]]
    }

    pub(super) fn store_plan(&mut self, u: &[f64]) {
        for (k, (p, v)) in self.plan.iter_mut().zip(u).enumerate() {
            *p = v.clamp(self.bounds.min[k % 3], self.bounds.max[k % 3]);
        }
        self.has_plan = true;
    }

    /// The braking candidate: the braking law applied along the Euler prediction of the
    /// most likely scenario (so it brakes, then holds position and altitude), as an input
    /// sequence. Holding the first braking command for the whole horizon instead reverses the
    /// motion and, with 0.33 s steps, predicts a descent of metres.
    pub(super) fn fill_brake_plan(&mut self, x0: &[f64; 8], weights: &[f64]) {
        let likely =
            weights.iter().enumerate().fold(0, |best, (i, w)| if *w > weights[best] { i } else { best });
        let dt = self.dts[likely];
        let mut x = *x0;
        for j in 0..self.n {
            let u = braking_command(&self.params, &self.bounds, &x, self.settings.brake_gain_per_s);
            self.brake_plan[3 * j..3 * j + 3].copy_from_slice(&u);
            x = crate::problem::euler_predict(&self.params, &x, &u, dt);
        }
    }

    /// After braking the plan is the braking command held (re-checked before any reuse).
    pub(super) fn store_brake_plan(&mut self, command: [f64; 3]) {
        for j in 0..self.n {
            self.plan[3 * j..3 * j + 3].copy_from_slice(&command);
        }
        self.has_plan = true;
        self.shifts = 0;
    }
}
