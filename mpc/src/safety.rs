//! The per-cycle safety layer: cross-checks PANOC's plan against the QP-linearized fallback on
//! the nonlinear model and picks the command, as a pure function of the cycle's data and the
//! layer's memory (the last selected plan).
//!
//! Order of preference, first acceptable wins:
//! 1. PANOC's plan, when its status is acceptable (converged; iteration limit and deadline when
//!    the settings accept them), its inputs are finite and inside the bounds, and it passes the
//!    safety check (below).
//! 2. The QP's plan, when the QP has a solution and passes the same checks.
//! 3. The previously selected plan shifted by one step (last input repeated), while it passes
//!    the same checks and has not been shifted more than `max_plan_shifts` times in a row.
//! 4. A braking command: tilt against the horizontal velocity, thrust against the vertical one,
//!    clipped to the bounds (hover when the state is not finite), when it passes the checks.
//! 5. None passes: the candidate that comes closest (`best_effort`), flagged unverified.
//!
//! The safety check is one of two (`SafetySettings::braking_check`):
//! - the plan's predictions (paper mode): every scenario's Euler prediction of the plan keeps
//!   the required true clearance and the floor;
//! - the fail-safe check ([`crate::fail_safe`]): the plan's first input, the only one that is
//!   sent, followed by braking from the next cycle on, keeps them on the continuous model for
//!   every sampled round-trip delay in the range, including the previous command staying on
//!   until the new one lands. A passed command leaves braking as a candidate that passes the next
//!   cycle, which the plan check cannot promise under delays that change from cycle to cycle.
//!
//! Whatever is picked, the command is finite and inside the input bounds.

use std::fmt::Write as _;

use mav::{Cylinder, InputBounds, ModelParams, Scenario};

use crate::fail_safe::{BrakingCheck, Envelope, FailSafe, InFlight};
use crate::problem::{Evaluator, OcpDefinition};
use crate::qp::{
    NonlinearCheck, QpBudget, QpFallback, QpReport, QpSettings, QpStatus, check_on_nonlinear_model,
};
use crate::solver::{Mpc, MpcError, SolveReport, SolveStatus};

/// When the QP runs. Whatever the schedule, it also runs when PANOC's plan is rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum QpSchedule {
    /// Every cycle, so that the cost gap is always known (the cross-check).
    EveryCycle,
    /// Every `n`-th cycle (the first included): the cross-check at a fraction of its cost.
    EveryNth(u32),
    /// Only when PANOC's plan is rejected (saves the QP's time on good cycles).
    WhenNeeded,
}

impl QpSchedule {
    /// The default: the QP (median 0.65 ms, up to 5.6 ms along the paper loops, against
    /// PANOC's 0.25 ms median; see BENCHMARKS.md) every cycle would cost 3.1 ms per paper-2
    /// cycle against 1.9 ms with this schedule (1.6 ms without the layer), and its worst cases are a fifth of the
    /// 25 ms a real-time cycle gives the solvers; so the cross-check runs every 5th cycle, and
    /// the fallback whenever needed.
    pub const DEFAULT: QpSchedule = QpSchedule::EveryNth(5);

    /// Whether the cross-check is due on the `k`-th cycle of an episode (0-based).
    pub fn due(self, k: u64) -> bool {
        match self {
            QpSchedule::EveryCycle => true,
            QpSchedule::EveryNth(n) => k.is_multiple_of(u64::from(n.max(1))),
            QpSchedule::WhenNeeded => false,
        }
    }
}

/// Settings of the safety layer (validated in [`SafetyLayer::new`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SafetySettings {
    /// The QP fallback; its `min_altitude_m` is also the floor every candidate is checked
    /// against.
    pub qp: QpSettings,
    /// When the QP runs.
    pub qp_schedule: QpSchedule,
    /// Accept PANOC's best iterate after its iteration budget ran out (still checked).
    pub accept_iteration_limit: bool,
    /// Accept PANOC's best iterate after its wall-clock budget ran out (still checked).
    pub accept_deadline: bool,
    /// Smallest true clearance (no margin) any predicted point of an accepted plan may have, m.
    pub required_clearance_m: f64,
    /// How many cycles in a row the previous plan may be shifted and reused.
    pub max_plan_shifts: usize,
    /// Gain of the braking command: desired acceleration `-gain * v`, 1/s.
    pub brake_gain_per_s: f64,
    /// When no candidate passes the checks, not even braking (held over the horizon), send
    /// the candidate whose predictions come closest to passing (largest clearance, floor
    /// included) instead of braking blindly. The selection says so (`verified_safe: false`).
    pub best_effort: bool,
    /// How a candidate is judged safe. `None` (paper mode): its plan's predictions on the
    /// prediction model keep the required clearance. `Some`: its first input, followed by
    /// braking from the next cycle on, keeps it on the continuous model for every round-trip
    /// delay in the range (see [`crate::fail_safe`]); the plan's predictions then only give
    /// the cost.
    pub braking_check: Option<BrakingCheck>,
}

impl Default for SafetySettings {
    fn default() -> Self {
        Self {
            qp: QpSettings::default(),
            qp_schedule: QpSchedule::DEFAULT,
            accept_iteration_limit: true,
            accept_deadline: true,
            required_clearance_m: 0.0,
            max_plan_shifts: 10,
            brake_gain_per_s: 1.0,
            best_effort: true,
            braking_check: None,
        }
    }
}

impl SafetySettings {
    /// These settings for `scenario`: the fail-safe check over its delay range when the
    /// scenario asks for it and the settings do not set one already.
    pub fn for_scenario(self, scenario: &Scenario) -> Self {
        self.with_fail_safe(scenario, scenario.fail_safe)
    }

    /// These settings with the fail-safe check over `scenario`'s delay range when `on` and the
    /// settings do not set one already (whatever the scenario asks).
    pub fn with_fail_safe(mut self, scenario: &Scenario, on: bool) -> Self {
        if on && self.braking_check.is_none() {
            self.braking_check = Some(BrakingCheck::for_scenario(scenario));
        }
        self
    }

    /// Names the first invalid setting.
    pub fn validate(&self) -> Result<(), MpcError> {
        self.qp.validate()?;
        let bad = |field: &'static str, reason: &'static str| Err(MpcError::InvalidSetting { field, reason });
        if !self.required_clearance_m.is_finite() {
            return bad("required_clearance_m", "must be finite");
        }
        if self.qp_schedule == QpSchedule::EveryNth(0) {
            return bad("qp_schedule", "every n-th cycle needs n > 0");
        }
        if !(self.brake_gain_per_s.is_finite() && self.brake_gain_per_s >= 0.0) {
            return bad("brake_gain_per_s", "must be finite and >= 0");
        }
        if let Some(check) = &self.braking_check {
            check.validate()?;
        }
        Ok(())
    }
}

/// Which command was selected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Decision {
    Panoc,
    Qp,
    ShiftedPlan,
    Brake,
}

impl Decision {
    pub fn name(self) -> &'static str {
        match self {
            Decision::Panoc => "panoc",
            Decision::Qp => "qp",
            Decision::ShiftedPlan => "shifted_plan",
            Decision::Brake => "brake",
        }
    }

    /// True for the fallbacks (anything but PANOC).
    pub fn is_fallback(self) -> bool {
        self != Decision::Panoc
    }
}

/// Why a candidate was not selected.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Rejection {
    /// PANOC ended with a status the settings do not accept.
    PanocStatus { status: SolveStatus },
    /// PANOC's solve returned an error (no plan).
    PanocError,
    /// PANOC ran no iteration (zero budget): its plan is the warm start, not a solution.
    NoIterations,
    /// The QP had no solution.
    QpStatus { status: QpStatus },
    /// The QP did not run (schedule) or refused the instance.
    NotRun,
    /// Inputs or predictions are not finite.
    NotFinite,
    /// Inputs outside the input bounds.
    OutOfBounds,
    /// A predicted point is closer to a cylinder than required (true clearance, m).
    Collision { min_clearance_m: f64 },
    /// A predicted point is below the floor, or, for the fail-safe check without a floor,
    /// below the ground (lowest altitude, m).
    BelowFloor { min_altitude_m: f64 },
    /// No previous plan, or it was shifted `max_plan_shifts` times already.
    NoPlan,
    /// The cycle's state, last input or weights are not finite or malformed.
    InvalidInstance,
}

impl Rejection {
    fn describe(&self, out: &mut String) {
        let _ = match self {
            Rejection::PanocStatus { status } => write!(out, "status {}", status.name()),
            Rejection::PanocError => write!(out, "solve error"),
            Rejection::NoIterations => write!(out, "no iterations"),
            Rejection::QpStatus { status } => write!(out, "status {}", status.name()),
            Rejection::NotRun => write!(out, "not run"),
            Rejection::NotFinite => write!(out, "not finite"),
            Rejection::OutOfBounds => write!(out, "out of bounds"),
            Rejection::Collision { min_clearance_m } => write!(out, "clearance {min_clearance_m:.3} m"),
            Rejection::BelowFloor { min_altitude_m } => write!(out, "altitude {min_altitude_m:.3} m"),
            Rejection::NoPlan => write!(out, "no plan"),
            Rejection::InvalidInstance => write!(out, "invalid instance"),
        };
    }
}

/// One candidate plan checked on the nonlinear model.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CandidateCheck {
    /// The spec's objective on the nonlinear model (NaN when not evaluated).
    pub cost: f64,
    /// Smallest true clearance of its predictions, m (NaN when not evaluated).
    pub min_clearance_m: f64,
    /// Lowest predicted altitude, m (NaN when not evaluated).
    pub min_altitude_m: f64,
    /// `None` when acceptable.
    pub rejection: Option<Rejection>,
}

impl CandidateCheck {
    fn rejected(r: Rejection) -> Self {
        Self { cost: f64::NAN, min_clearance_m: f64::NAN, min_altitude_m: f64::NAN, rejection: Some(r) }
    }

    pub fn accepted(&self) -> bool {
        self.rejection.is_none()
    }
}

/// The outcome of one cycle's selection.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Selection {
    pub decision: Decision,
    /// The command to send: finite and inside the input bounds.
    pub command: [f64; 3],
    pub panoc: CandidateCheck,
    /// The QP's check; `rejection: NotRun` when the schedule skipped it.
    pub qp: CandidateCheck,
    /// The QP's own report when it ran.
    pub qp_report: Option<QpReport>,
    /// The shifted previous plan's check (`NotRun` when a better candidate was accepted).
    pub shifted: CandidateCheck,
    /// The braking command held over the horizon (`NotRun` when a better candidate was
    /// accepted).
    pub brake: CandidateCheck,
    /// QP cost minus PANOC cost, both on the nonlinear model (positive: PANOC is better);
    /// `None` unless both were evaluated.
    pub cost_gap: Option<f64>,
    /// True when the selected plan passed the checks.
    pub verified_safe: bool,
}

impl Selection {
    /// One line for logs and telemetry, e.g. `qp (panoc: clearance -0.120 m; gap 3.2)`.
    pub fn reason(&self) -> String {
        let mut out = String::from(self.decision.name());
        let mut parts = Vec::new();
        let candidates =
            [("panoc", &self.panoc), ("qp", &self.qp), ("shifted", &self.shifted), ("brake", &self.brake)];
        // The rejected candidates before the selected one; every one when none passed.
        let skip = match self.decision {
            _ if !self.verified_safe => 4,
            Decision::Panoc => 0,
            Decision::Qp => 1,
            Decision::ShiftedPlan => 2,
            Decision::Brake => 3,
        };
        if !self.verified_safe {
            out.push_str(" best effort");
        }
        for (name, c) in candidates.iter().take(skip) {
            let mut s = format!("{name}: ");
            match &c.rejection {
                Some(r) => r.describe(&mut s),
                None => s.push_str("ok"),
            }
            parts.push(s);
        }
        if let Some(gap) = self.cost_gap {
            parts.push(format!("gap {gap:.4}"));
        }
        if !parts.is_empty() {
            let _ = write!(out, " ({})", parts.join("; "));
        }
        out
    }
}

/// The safety layer's workspace: the QP fallback, an evaluator for the nonlinear checks, and
/// the last selected plan.
///
/// ## Memory allocation
/// The QP's workspace (see [`QpFallback`]), one [`Evaluator`], and two `3N` plans, allocated
/// in [`SafetyLayer::new`].
pub struct SafetyLayer {
    settings: SafetySettings,
    params: ModelParams,
    bounds: InputBounds,
    cylinders: Vec<Cylinder>,
    m: usize,
    n: usize,
    qp: QpFallback,
    evaluator: Evaluator,
    /// Sampling times of the scenarios, s.
    dts: Vec<f64>,
    /// The braking plan of the cycle (`N x 3`).
    brake_plan: Vec<f64>,
    plan: Vec<f64>,
    shifted: Vec<f64>,
    has_plan: bool,
    shifts: usize,
    qp_budget: QpBudget,
    /// The fail-safe check, when the settings ask for it.
    fail_safe: Option<FailSafe>,
    /// Real time: the commands in flight at this cycle's sample (`None`: lockstep timing).
    in_flight: Option<Vec<InFlight>>,
    /// The cycle's state and last applied input (for the fail-safe check).
    x0: [f64; 8],
    u_prev: [f64; 3],
    /// Selections made since the last reset (for the QP's schedule).
    cycles: u64,
}

impl SafetyLayer {
    /// The floor is the problem's (`def.min_altitude_m`) unless the QP settings set one.
    pub fn new(def: &OcpDefinition, settings: SafetySettings) -> Result<Self, MpcError> {
        let mut settings = settings;
        settings.qp.min_altitude_m = settings.qp.min_altitude_m.or(def.min_altitude_m);
        settings.validate()?;
        let qp = QpFallback::new(def, settings.qp)?;
        let nv = def.num_variables();
        let fail_safe = settings.braking_check.map(|check| {
            FailSafe::new(check, def.model, def.bounds, def.obstacles.clone(), settings.brake_gain_per_s)
        });
        Ok(Self {
            fail_safe,
            in_flight: None,
            x0: [0.0; 8],
            u_prev: [0.0; 3],
            settings,
            params: def.model,
            bounds: def.bounds,
            cylinders: def.obstacles.clone(),
            m: def.num_scenarios(),
            n: def.horizon,
            qp,
            evaluator: Evaluator::new(def),
            dts: def.sampling_times_s.clone(),
            brake_plan: vec![0.0; def.num_variables()],
            plan: vec![0.0; nv],
            shifted: vec![0.0; nv],
            has_plan: false,
            shifts: 0,
            qp_budget: QpBudget::default(),
            cycles: 0,
        })
    }

    pub fn settings(&self) -> &SafetySettings {
        &self.settings
    }

    /// The timing the fail-safe check assumes from the next selection on: `None`, lockstep (one
    /// command in flight); `Some`, real time with these commands sent before this cycle's and
    /// not landed at its sample, oldest first (see [`FailSafe::envelope_real_time`]).
    pub fn set_in_flight(&mut self, in_flight: Option<&[InFlight]>) {
        match (in_flight, &mut self.in_flight) {
            (Some(new), Some(kept)) => {
                kept.clear();
                kept.extend_from_slice(new);
            }
            (new, kept) => *kept = new.map(<[InFlight]>::to_vec),
        }
    }

    /// The QP's budget for the following cycles (iterations in lockstep, a deadline in real
    /// time).
    pub fn set_qp_budget(&mut self, budget: QpBudget) {
        self.qp_budget = budget;
    }

    /// The last selected plan (`N x 3`, within the bounds), if any. A caller may warm-start
    /// PANOC from it after a fallback ([`Mpc::set_warm_start`]).
    pub fn plan(&self) -> Option<&[f64]> {
        self.has_plan.then_some(&self.plan[..])
    }

    /// The QP workspace (its last solution and nominal).
    pub fn qp(&self) -> &QpFallback {
        &self.qp
    }

    /// Forgets the previous plan (new episode).
    pub fn reset(&mut self) {
        self.has_plan = false;
        self.shifts = 0;
        self.cycles = 0;
        self.qp.reset();
    }

    /// Selects this cycle's command from PANOC's solve (`panoc.solution()` and its report).
    pub fn select(
        &mut self,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        weights: &[f64],
        panoc: &Mpc,
        report: &SolveReport,
    ) -> Selection {
        // An iteration budget of zero returns the warm start untouched: not PANOC's answer.
        let no_iterations = report.iterations == 0 && report.status != SolveStatus::Converged;
        self.select_inner(x0, u_prev, weights, Ok((panoc.solution(), report.status)), no_iterations)
    }

    /// Selects this cycle's command when PANOC's solve returned an error (no plan).
    pub fn select_without_panoc(&mut self, x0: &[f64; 8], u_prev: &[f64; 3], weights: &[f64]) -> Selection {
        self.select_inner(x0, u_prev, weights, Err(()), false)
    }

    /// The selection on PANOC's plan `u` (`N x 3`) and status, or `Err` when PANOC failed
    /// without a plan.
    pub fn select_plan(
        &mut self,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        weights: &[f64],
        panoc: Result<(&[f64], SolveStatus), ()>,
    ) -> Selection {
        self.select_inner(x0, u_prev, weights, panoc, false)
    }

    fn select_inner(
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
            let command = braking_command(&self.params, &self.bounds, x0, self.settings.brake_gain_per_s);
            self.store_brake_plan(command);
            let invalid = CandidateCheck::rejected(Rejection::InvalidInstance);
            return Selection {
                decision: Decision::Brake,
                command,
                panoc: invalid,
                qp: invalid,
                qp_report: None,
                shifted: invalid,
                brake: invalid,
                cost_gap: None,
                verified_safe: false,
            };
        }
        self.evaluator.set_instance(x0, u_prev, weights);
        self.x0 = *x0;
        self.u_prev = *u_prev;

        // 1. PANOC.
        let panoc_check = match panoc {
            Err(()) => CandidateCheck::rejected(Rejection::PanocError),
            Ok((u, status)) => {
                let status_ok = match status {
                    SolveStatus::Converged => true,
                    SolveStatus::IterationLimit => self.settings.accept_iteration_limit,
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
        };

        // 2. The QP, linearized around the previous plan shifted (hover without one).
        let run_qp = self.settings.qp_schedule.due(self.cycles) || !panoc_check.accepted();
        self.cycles += 1;
        let mut qp_report = None;
        let qp_check = if run_qp {
            let nominal = if self.has_plan {
                crate::solver::shift_plan_into(&self.plan, &mut self.shifted);
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
        let cost_gap = (panoc_check.cost.is_finite() && qp_check.cost.is_finite())
            .then_some(qp_check.cost - panoc_check.cost);

        // 3. The previous plan shifted; 4. braking.
        let mut shifted_check = CandidateCheck::rejected(Rejection::NotRun);
        let mut brake_check = CandidateCheck::rejected(Rejection::NotRun);
        let brake_command = braking_command(&self.params, &self.bounds, x0, self.settings.brake_gain_per_s);
        let mut verified_safe = true;
        let decision = if panoc_check.accepted() {
            Decision::Panoc
        } else if qp_check.accepted() {
            Decision::Qp
        } else {
            shifted_check = if self.has_plan && self.shifts < self.settings.max_plan_shifts {
                crate::solver::shift_plan_into(&self.plan, &mut self.shifted);
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
                        (Decision::Panoc, &panoc_check),
                        (Decision::Qp, &qp_check),
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

        let command = match decision {
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
        };
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

    /// How close a checked candidate comes to passing: its smallest margin over the required
    /// clearance and the floor, m (`-inf` when it was not evaluated or is not finite).
    fn safety_score(&self, c: &CandidateCheck) -> f64 {
        // Only plans that are solutions and fail nothing but the safety checks compete (and
        // braking, always): not a failed solve's warm start, not a non-finite plan.
        let competes =
            matches!(c.rejection, None | Some(Rejection::Collision { .. } | Rejection::BelowFloor { .. }));
        if !competes || c.min_clearance_m.is_nan() {
            return f64::NEG_INFINITY;
        }
        let clearance = c.min_clearance_m - self.settings.required_clearance_m;
        let floor = match self.lowest_allowed_m() {
            Some(z) if c.min_altitude_m.is_finite() => c.min_altitude_m - z.min(self.x0[2]),
            _ => f64::INFINITY,
        };
        clearance.min(floor)
    }

    fn first(&self) -> [f64; 3] {
        [self.plan[0], self.plan[1], self.plan[2]]
    }

    fn store_plan(&mut self, u: &[f64]) {
        for (k, (p, v)) in self.plan.iter_mut().zip(u).enumerate() {
            *p = v.clamp(self.bounds.min[k % 3], self.bounds.max[k % 3]);
        }
        self.has_plan = true;
    }

    /// The braking candidate: the braking law applied along the Euler prediction of the
    /// most likely scenario (so it brakes, then holds position and altitude), as an input
    /// sequence. Holding the first braking command for the whole horizon instead reverses the
    /// motion and, with 0.33 s steps, predicts a descent of metres.
    fn fill_brake_plan(&mut self, x0: &[f64; 8], weights: &[f64]) {
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
    fn store_brake_plan(&mut self, command: [f64; 3]) {
        for j in 0..self.n {
            self.plan[3 * j..3 * j + 3].copy_from_slice(&command);
        }
        self.has_plan = true;
        self.shifts = 0;
    }

    /// The lowest altitude a candidate may reach: the floor when there is one, else, with the
    /// fail-safe check, the ground (see [`BrakingCheck::ground_z_m`]).
    fn lowest_allowed_m(&self) -> Option<f64> {
        self.settings.qp.min_altitude_m.or_else(|| self.fail_safe.as_ref().and_then(|fs| fs.check.ground_z_m))
    }

    /// Finite, inside the bounds, and safe on the nonlinear predictions of the instance set in
    /// the evaluator.
    fn check_plan(&mut self, u: &[f64]) -> CandidateCheck {
        if u.len() != 3 * self.n || u.iter().any(|v| !v.is_finite()) {
            return CandidateCheck::rejected(Rejection::NotFinite);
        }
        let tol = 1e-9;
        let inside = u
            .iter()
            .enumerate()
            .all(|(k, v)| *v >= self.bounds.min[k % 3] - tol && *v <= self.bounds.max[k % 3] + tol);
        if !inside {
            return CandidateCheck::rejected(Rejection::OutOfBounds);
        }
        let NonlinearCheck { cost, min_clearance_m, min_altitude_m, finite } = match &self.fail_safe {
            None => check_on_nonlinear_model(&mut self.evaluator, &self.cylinders, u),
            Some(fs) => {
                // The plan's predictions give only the cost. Only the first input is sent: it,
                // then braking, under every delay.
                let cost = self.evaluator.objective_at_inputs(u);
                let command = [u[0], u[1], u[2]];
                let Envelope { min_clearance_m, min_altitude_m, finite } = match &self.in_flight {
                    Some(in_flight) => fs.envelope_real_time(&self.x0, &self.u_prev, in_flight, &command),
                    None => fs.envelope(&self.x0, &self.u_prev, &command),
                };
                NonlinearCheck { cost, min_clearance_m, min_altitude_m, finite: finite && cost.is_finite() }
            }
        };
        let rejection = if !finite {
            Some(Rejection::NotFinite)
        } else if min_clearance_m < self.settings.required_clearance_m {
            Some(Rejection::Collision { min_clearance_m })
        } else if self.lowest_allowed_m().is_some_and(|floor| {
            // A vehicle already below the floor cannot be above it at once: it may not sink
            // further.
            min_altitude_m < floor.min(self.x0[2]) - 1e-9
        }) {
            Some(Rejection::BelowFloor { min_altitude_m })
        } else {
            None
        };
        CandidateCheck { cost, min_clearance_m, min_altitude_m, rejection }
    }
}

/// Finite and inside the bounds: non-finite components become hover's, then everything is
/// clipped to the box.
pub fn sanitize_command(params: &ModelParams, bounds: &InputBounds, u: [f64; 3]) -> [f64; 3] {
    let hover = [params.gravity_mps2, 0.0, 0.0];
    let mut out = [0.0; 3];
    for c in 0..3 {
        let v = if u[c].is_finite() { u[c] } else { hover[c] };
        out[c] = v.clamp(bounds.min[c], bounds.max[c]);
    }
    out
}

/// A braking command from state `x`: the thrust vector that gives the acceleration
/// `-gain * v` against gravity (`vx' = T cos(phi) sin(theta)`, `vy' = -T sin(phi)`,
/// `vz' = T cos(phi) cos(theta) - g`), clipped to the bounds. Hover for a non-finite state.
pub fn braking_command(params: &ModelParams, bounds: &InputBounds, x: &[f64; 8], gain: f64) -> [f64; 3] {
    let g = params.gravity_mps2;
    let (ax, ay, az) = (-gain * x[3], -gain * x[4], -gain * x[5]);
    let vertical = (g + az).max(0.1 * g);
    let t = (ax * ax + ay * ay + vertical * vertical).sqrt();
    let raw = if t.is_finite() && t > 0.0 {
        [t, (-ay / t).clamp(-1.0, 1.0).asin(), ax.atan2(vertical)]
    } else {
        [g, 0.0, 0.0]
    };
    sanitize_command(params, bounds, raw)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::{ControllerMode, ObstacleFormulation};
    use crate::solver::{MpcSettings, SolveBudget};
    use mav::Scenario;
    use proptest::prelude::*;

    const W5: [f64; 5] = [0.05, 0.15, 0.45, 0.30, 0.05];
    const HOVER: [f64; 3] = [9.81, 0.0, 0.0];

    fn def_of(s: &Scenario, mode: ControllerMode) -> OcpDefinition {
        OcpDefinition::from_scenario(s, mode, 0.1, ObstacleFormulation::DistanceAlm)
    }

    fn in_bounds(b: &InputBounds, u: [f64; 3]) -> bool {
        (0..3).all(|c| u[c].is_finite() && u[c] >= b.min[c] && u[c] <= b.max[c])
    }

    /// Smallest true clearance and altitude of `plan` re-simulated with `mav`'s Euler step,
    /// independently of the evaluator.
    fn resimulate(def: &OcpDefinition, x0: &[f64; 8], plan: &[f64]) -> (f64, f64) {
        let model = mav::MavModel::new(def.model);
        let (mut clearance, mut altitude) = (f64::INFINITY, f64::INFINITY);
        for &dt in &def.sampling_times_s {
            let mut x = mav::State::from(*x0);
            for j in 0..def.horizon {
                let u = mav::Input::new(plan[3 * j], plan[3 * j + 1], plan[3 * j + 2]);
                x = mav::euler_step(&model, &x, &u, dt);
                let (c, _) = mav::geometry::min_clearance(&def.obstacles, x[0], x[1], x[2]);
                clearance = clearance.min(c);
                altitude = altitude.min(x[2]);
            }
        }
        (clearance, altitude)
    }

    #[test]
    fn a_converged_safe_panoc_plan_is_selected_and_the_qp_cross_checks_it() {
        let s = Scenario::paper_2();
        let def = def_of(&s, ControllerMode::Multistage);
        let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
        let mut layer = SafetyLayer::new(&def, SafetySettings::default()).expect("valid");
        let r = mpc.solve(&s.start, &HOVER, &W5, &SolveBudget::default()).expect("valid");
        let sel = layer.select(&s.start, &HOVER, &W5, &mpc, &r);
        assert_eq!(sel.decision, Decision::Panoc, "{}", sel.reason());
        assert_eq!(sel.command, mpc.first_input());
        assert!(sel.verified_safe && sel.panoc.min_clearance_m >= 0.0);
        assert!(sel.qp_report.is_some(), "the first cycle is always cross-checked");
        assert!(sel.reason().starts_with("panoc"));
        assert_eq!(layer.plan(), Some(mpc.solution()));
    }

    #[test]
    fn panoc_forced_to_fail_hands_over_to_the_qp() {
        let s = Scenario::paper_2();
        let def = def_of(&s, ControllerMode::Multistage);
        let settings = MpcSettings { max_outer_iterations: 1, ..Default::default() };
        let mut mpc = Mpc::new(def.clone(), settings).expect("valid");
        let safety = SafetySettings { accept_iteration_limit: false, ..Default::default() };
        let mut layer = SafetyLayer::new(&def, safety).expect("valid");
        let budget = SolveBudget { max_inner_iterations: Some(1), deadline: None };
        let r = mpc.solve(&s.start, &HOVER, &W5, &budget).expect("valid");
        assert_eq!(r.status, SolveStatus::IterationLimit);
        let sel = layer.select(&s.start, &HOVER, &W5, &mpc, &r);
        assert_eq!(sel.decision, Decision::Qp, "{}", sel.reason());
        assert!(matches!(sel.panoc.rejection, Some(Rejection::PanocStatus { .. })));
        assert!(sel.verified_safe && sel.qp.min_clearance_m >= 0.0);
        assert!(in_bounds(&def.bounds, sel.command));
        let plan = layer.plan().expect("plan");
        let (clearance, _) = resimulate(&def, &s.start, plan);
        assert!(clearance >= 0.0, "{clearance}");
    }

    #[test]
    fn a_colliding_converged_plan_is_rejected() {
        // Drifting at the 0.4 m cylinder; "PANOC" claims convergence on the hover plan.
        let s = Scenario::paper_2();
        let def = def_of(&s, ControllerMode::Nmpc);
        let x0 = [2.8, 1.8, 0.8, 0.0, 1.0, 0.0, 0.0, 0.0];
        let hover_plan: Vec<f64> = (0..def.num_variables()).map(|k| HOVER[k % 3]).collect();
        let mut layer = SafetyLayer::new(&def, SafetySettings::default()).expect("valid");
        let sel = layer.select_plan(&x0, &HOVER, &[1.0], Ok((&hover_plan, SolveStatus::Converged)));
        assert!(
            matches!(sel.panoc.rejection, Some(Rejection::Collision { min_clearance_m }) if min_clearance_m < 0.0)
        );
        assert_ne!(sel.decision, Decision::Panoc);
        assert!(in_bounds(&def.bounds, sel.command));
        if sel.verified_safe {
            let (clearance, _) = resimulate(&def, &x0, layer.plan().expect("plan"));
            assert!(clearance >= 0.0);
        }
    }

    /// paper-2's standard NMPC definition, a layer with the default fail-safe check, the check
    /// alone, and a plan that hovers throughout.
    fn fail_safe_fixture() -> (OcpDefinition, SafetyLayer, FailSafe, Vec<f64>) {
        let def = def_of(&Scenario::paper_2(), ControllerMode::Nmpc);
        let check = BrakingCheck::default();
        let settings = SafetySettings { braking_check: Some(check), ..Default::default() };
        let layer = SafetyLayer::new(&def, settings).expect("valid");
        let gain = settings.brake_gain_per_s;
        let fail_safe = FailSafe::new(check, def.model, def.bounds, def.obstacles.clone(), gain);
        let hover_plan: Vec<f64> = (0..def.num_variables()).map(|k| HOVER[k % 3]).collect();
        (def, layer, fail_safe, hover_plan)
    }

    #[test]
    fn the_fail_safe_check_judges_the_first_input_followed_by_braking_under_every_delay() {
        let (def, mut layer, fail_safe, hover_plan) = fail_safe_fixture();
        let mut plan_layer = SafetyLayer::new(&def, SafetySettings::default()).expect("valid");
        let hover = Ok((&hover_plan[..], SolveStatus::Converged));
        // 0.8 m/s at the 0.4 m cylinder from 1.2 m. Drifting on at hover for the whole plan
        // (2 s) hits it, so the plan check rejects the plan; but only its first input is
        // sent, and braking from the next cycle on stops in time under every delay.
        let x0 = [2.8, 1.4, 1.0, 0.0, 0.8, 0.0, 0.0, 0.0];
        let sel = plan_layer.select_plan(&x0, &HOVER, &[1.0], hover);
        assert!(matches!(sel.panoc.rejection, Some(Rejection::Collision { .. })), "{}", sel.reason());
        let sel = layer.select_plan(&x0, &HOVER, &[1.0], hover);
        assert_eq!(sel.decision, Decision::Panoc, "{}", sel.reason());
        assert!(sel.verified_safe && sel.panoc.min_clearance_m >= 0.0);
        let e = fail_safe.envelope(&x0, &HOVER, &HOVER);
        assert_eq!(e.min_clearance_m, sel.panoc.min_clearance_m);
        // At 1 m/s it does not (the previous command may stay on for 0.33 s, the next one may
        // land 0.33 s after its sample): nothing passes, and the layer says so.
        let x0 = [2.8, 1.4, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        let sel = layer.select_plan(&x0, &HOVER, &[1.0], hover);
        assert!(matches!(sel.panoc.rejection, Some(Rejection::Collision { .. })), "{}", sel.reason());
        assert!(!sel.verified_safe, "{}", sel.reason());
        assert!(in_bounds(&def.bounds, sel.command));
    }

    #[test]
    fn without_a_floor_the_fail_safe_check_still_keeps_the_vehicle_above_the_ground() {
        // Paper mode has no floor. 0.3 m up, sinking at 0.5 m/s, a plan of zero thrust: its
        // first input, held up to 0.38 s before braking lands, takes the vehicle into the
        // ground, which the fail-safe check sees unless it is told there is no ground.
        let def = def_of(&Scenario::paper_2(), ControllerMode::Nmpc);
        assert_eq!(def.min_altitude_m, None);
        let falling = vec![0.0; def.num_variables()];
        let x0 = [3.2, 0.0, 0.3, 0.0, 0.0, -0.5, 0.0, 0.0];
        for ground_z_m in [Some(0.0), None] {
            let check = BrakingCheck { ground_z_m, ..BrakingCheck::default() };
            let settings = SafetySettings { braking_check: Some(check), ..Default::default() };
            let mut layer = SafetyLayer::new(&def, settings).expect("valid");
            let sel = layer.select_plan(&x0, &HOVER, &[1.0], Ok((&falling[..], SolveStatus::Converged)));
            match ground_z_m {
                Some(_) => {
                    assert!(
                        matches!(sel.panoc.rejection, Some(Rejection::BelowFloor { min_altitude_m }) if min_altitude_m < 0.0),
                        "{}",
                        sel.reason()
                    );
                    assert_ne!(sel.decision, Decision::Panoc);
                }
                None => assert_eq!(sel.decision, Decision::Panoc, "{}", sel.reason()),
            }
        }
        let bad = BrakingCheck { ground_z_m: Some(f64::NAN), ..BrakingCheck::default() };
        assert!(bad.validate().is_err());
    }

    #[test]
    fn in_real_time_the_fail_safe_check_flies_the_commands_in_flight_first() {
        let (_, mut layer, fail_safe, hover_plan) = fail_safe_fixture();
        let hover = Ok((&hover_plan[..], SolveStatus::Converged));
        // 0.8 m/s at the 0.4 m cylinder from 1.2 m: hover then braking passes (test above).
        let x0 = [2.8, 1.4, 1.0, 0.0, 0.8, 0.0, 0.0, 0.0];
        layer.set_in_flight(Some(&[]));
        let sel = layer.select_plan(&x0, &HOVER, &[1.0], hover);
        assert_eq!(sel.decision, Decision::Panoc, "{}", sel.reason());
        let e = fail_safe.envelope_real_time(&x0, &HOVER, &[], &HOVER);
        assert_eq!(e.min_clearance_m, sel.panoc.min_clearance_m);
        // Two earlier commands rolling towards it (+y) are still on their way: the same plan
        // no longer passes.
        let push = InFlight { sent_ago_s: 0.05, command: [11.0, -0.17, 0.0] };
        layer.set_in_flight(Some(&[InFlight { sent_ago_s: 0.1, ..push }, push]));
        let sel = layer.select_plan(&x0, &HOVER, &[1.0], hover);
        assert!(matches!(sel.panoc.rejection, Some(Rejection::Collision { .. })), "{}", sel.reason());
        // Back to lockstep timing: it passes again.
        layer.set_in_flight(None);
        let sel = layer.select_plan(&x0, &HOVER, &[1.0], hover);
        assert_eq!(sel.decision, Decision::Panoc, "{}", sel.reason());
    }

    #[test]
    fn a_missed_deadline_reuses_the_previous_plan_shifted() {
        let s = Scenario::paper_3();
        let def = def_of(&s, ControllerMode::Nmpc);
        let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
        let mut layer = SafetyLayer::new(&def, SafetySettings::default()).expect("valid");
        let r = mpc.solve(&s.start, &HOVER, &[1.0], &SolveBudget::default()).expect("valid");
        let first = layer.select(&s.start, &HOVER, &[1.0], &mpc, &r);
        assert_eq!(first.decision, Decision::Panoc);
        let plan = mpc.solution().to_vec();
        // Next cycle: PANOC errs and the QP runs out of its budget.
        layer.set_qp_budget(QpBudget { max_iterations: Some(1), deadline: None });
        let x1 = s.start;
        let sel = layer.select_without_panoc(&x1, &first.command, &[1.0]);
        assert_eq!(sel.decision, Decision::ShiftedPlan, "{}", sel.reason());
        assert_eq!(sel.panoc.rejection, Some(Rejection::PanocError));
        assert_eq!(sel.qp.rejection, Some(Rejection::QpStatus { status: QpStatus::IterationLimit }));
        assert_eq!(sel.command, [plan[3], plan[4], plan[5]]);
        // and only max_plan_shifts times in a row, then brake.
        let mut last = sel;
        for _ in 1..layer.settings().max_plan_shifts {
            last = layer.select_without_panoc(&x1, &last.command, &[1.0]);
            assert_eq!(last.decision, Decision::ShiftedPlan);
        }
        let sel = layer.select_without_panoc(&x1, &last.command, &[1.0]);
        assert_eq!(sel.decision, Decision::Brake);
        assert_eq!(sel.shifted.rejection, Some(Rejection::NoPlan));
    }

    #[test]
    fn non_finite_and_absurd_states_brake_with_a_finite_command() {
        let s = Scenario::paper_1();
        let def = def_of(&s, ControllerMode::Multistage);
        let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
        let mut layer = SafetyLayer::new(&def, SafetySettings::default()).expect("valid");
        // NaN state: PANOC refuses it; nothing can be checked.
        let mut x0 = s.start;
        x0[3] = f64::NAN;
        assert!(mpc.solve(&x0, &HOVER, &W5, &SolveBudget::default()).is_err());
        let sel = layer.select_without_panoc(&x0, &HOVER, &W5);
        assert_eq!(sel.decision, Decision::Brake);
        assert!(!sel.verified_safe);
        assert!(in_bounds(&def.bounds, sel.command));
        // Finite but absurd: PANOC fails numerically; every candidate is rejected as not finite.
        let x0 = [0.0, 0.0, 1.0, 1e200, -1e200, 1e200, 0.0, 0.0];
        let r = mpc.solve(&x0, &HOVER, &W5, &SolveBudget::default()).expect("valid input");
        assert_eq!(r.status, SolveStatus::NumericalFailure);
        let sel = layer.select(&x0, &HOVER, &W5, &mpc, &r);
        assert_eq!(sel.decision, Decision::Brake, "{}", sel.reason());
        assert!(in_bounds(&def.bounds, sel.command));
    }

    #[test]
    fn the_qp_runs_on_schedule_and_whenever_panoc_is_rejected() {
        assert!((0..10).all(|k| QpSchedule::EveryCycle.due(k)));
        assert_eq!((0..10).filter(|&k| QpSchedule::EveryNth(5).due(k)).collect::<Vec<_>>(), vec![0, 5]);
        assert!((0..10).all(|k| !QpSchedule::WhenNeeded.due(k)));
        let bad = SafetySettings { qp_schedule: QpSchedule::EveryNth(0), ..Default::default() };
        assert!(bad.validate().is_err());

        let s = Scenario::paper_3();
        let def = def_of(&s, ControllerMode::Nmpc);
        let settings = SafetySettings { qp_schedule: QpSchedule::WhenNeeded, ..Default::default() };
        let mut layer = SafetyLayer::new(&def, settings).expect("valid");
        let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
        let r = mpc.solve(&s.start, &HOVER, &[1.0], &SolveBudget::default()).expect("valid");
        let sel = layer.select(&s.start, &HOVER, &[1.0], &mpc, &r);
        assert_eq!(sel.decision, Decision::Panoc);
        assert!(sel.qp_report.is_none() && sel.cost_gap.is_none());
        let sel = layer.select_without_panoc(&s.start, &HOVER, &[1.0]);
        assert!(sel.qp_report.is_some(), "a rejected PANOC plan always brings the QP in");
    }

    #[test]
    fn braking_tilts_against_the_velocity() {
        let p = ModelParams::default();
        let b = InputBounds::paper(p.gravity_mps2);
        let u = braking_command(&p, &b, &[0.0, 0.0, 1.0, 2.0, -1.0, 0.5, 0.0, 0.0], 1.0);
        assert!(u[2] < 0.0, "pitch back against +vx: {u:?}");
        assert!(u[1] < 0.0, "roll against -vy (vy' = -T sin(phi)): {u:?}");
        assert!(u[0] < p.gravity_mps2 * 1.1 && in_bounds(&b, u));
        assert_eq!(braking_command(&p, &b, &[0.0; 8], 1.0), [p.gravity_mps2, 0.0, 0.0]);
        let nan = [f64::NAN; 8];
        assert_eq!(braking_command(&p, &b, &nan, 1.0), [p.gravity_mps2, 0.0, 0.0]);
    }

    fn arb_case() -> impl Strategy<Value = (OcpDefinition, [f64; 8], Vec<f64>)> {
        (
            2usize..=20,
            prop::collection::vec(0.03f64..0.35, 1..=5),
            prop::collection::vec((0.0f64..6.0, 0.0f64..6.0, 0.1f64..0.8), 0..=3),
            (0.0f64..6.0, 0.0f64..6.0, 0.3f64..3.0),
            (-2.0f64..2.0, -2.0f64..2.0, -1.0f64..1.0, -0.17f64..0.17, -0.17f64..0.17),
            prop::collection::vec(0.0f64..1.0, 5),
        )
            .prop_map(|(n, dts, obs, p, v, w)| {
                let mut def = def_of(&Scenario::paper_2(), ControllerMode::Multistage);
                def.horizon = n;
                def.sampling_times_s = dts;
                def.obstacles = obs.into_iter().map(|(x, y, r)| mav::Cylinder::new(x, y, r)).collect();
                let mut w: Vec<f64> = w[..def.num_scenarios()].to_vec();
                w[0] += 0.05;
                (def, [p.0, p.1, p.2, v.0, v.1, v.2, v.3, v.4], w)
            })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(40))]

        /// Whatever PANOC does: the command is finite and inside the bounds, and a plan
        /// reported safe keeps non-negative clearance (and the floor) on the nonlinear model,
        /// re-simulated independently.
        #[test]
        fn the_selected_command_is_bounded_and_a_safe_plan_is_clear(
            (def, x0, w) in arb_case(),
            inner in prop::sample::select(vec![1usize, 20, 200]),
            floor in prop::option::of(0.0f64..0.3),
        ) {
            let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
            let qp = QpSettings { min_altitude_m: floor, ..Default::default() };
            let mut layer = SafetyLayer::new(&def, SafetySettings { qp, ..Default::default() }).expect("valid");
            let mut u_prev = HOVER;
            let mut x = x0;
            let model = mav::MavModel::new(def.model);
            // Two cycles, so that the shifted plan and the QP's nominal come into play.
            for _ in 0..2 {
                let budget = SolveBudget { max_inner_iterations: Some(inner), deadline: None };
                let r = mpc.solve(&x, &u_prev, &w, &budget).expect("valid");
                let sel = layer.select(&x, &u_prev, &w, &mpc, &r);
                prop_assert!(in_bounds(&def.bounds, sel.command), "{:?}", sel.command);
                if sel.decision == Decision::Panoc {
                    prop_assert!(r.status != SolveStatus::NumericalFailure);
                }
                if sel.verified_safe {
                    let (clearance, altitude) = resimulate(&def, &x, layer.plan().expect("plan"));
                    prop_assert!(clearance >= -1e-9, "{}: clearance {clearance}", sel.reason());
                    if let Some(f) = floor {
                        prop_assert!(altitude >= f - 1e-6, "{}: altitude {altitude}", sel.reason());
                    }
                }
                if let Some(q) = sel.qp_report.filter(|q| q.status.has_solution()) {
                    let allowed = if q.status == QpStatus::SolvedElastic { q.elastic_violation_m } else { 0.0 };
                    prop_assert!(q.linear_violation <= allowed + 1e-6, "{q:?}");
                }
                let xs = mav::euler_step(&model, &mav::State::from(x), &mav::Input::from(sel.command), def.sampling_times_s[0]);
                x = std::array::from_fn(|k| xs[k]);
                u_prev = sel.command;
            }
        }
    }
}
