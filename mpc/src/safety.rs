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
//!
//! Code map: the settings (`settings.rs`: [`SafetySettings`], [`QpSchedule`]); what a selection
//! reports (`selection.rs`: [`Selection`], [`Decision`], [`Rejection`], [`CandidateCheck`]); the
//! selection into candidates in the order of preference and the layer's plan memory
//! (`candidates.rs`); the check of one candidate on the nonlinear model, or with the fail-safe
//! check, and the score of a candidate that fails (`scoring.rs`). This file holds the
//! workspace [`SafetyLayer`] and its entry points.

mod candidates;
mod scoring;
mod selection;
mod settings;
#[cfg(test)]
mod tests;

use mav::{Cylinder, InputBounds, ModelParams};

use crate::error::MpcError;
use crate::fail_safe::{FailSafe, InFlight};
use crate::problem::{Evaluator, OcpDefinition};
use crate::qp::{QpBudget, QpFallback, QpReport};
use crate::solver::{Mpc, SolveReport, SolveStatus};

pub use selection::{CandidateCheck, Decision, Rejection, Selection};
pub use settings::{QpSchedule, SafetySettings};

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
    /// The delay range of the check as set up (the scenario tree's), s; the range in force may
    /// be wider ([`SafetyLayer::cover_delays_up_to`]).
    base_max_delay_s: f64,
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
            base_max_delay_s: fail_safe.as_ref().map_or(0.0, |f| f.check.max_delay_s),
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

    /// The fail-safe check's settings as they stand (its range widened to the delays measured
    /// lately), `None` without the check.
    pub fn braking_check(&self) -> Option<&crate::fail_safe::BrakingCheck> {
        self.fail_safe.as_ref().map(|fs| &fs.check)
    }

    /// Widens the fail-safe check's delay range to the longest delay measured lately,
    /// `observed_max_s` (never below the range it was set up with; see
    /// [`crate::fail_safe::BrakingCheck::covering`]). No effect without the check.
    pub fn cover_delays_up_to(&mut self, observed_max_s: Option<f64>) {
        if let Some(fs) = self.fail_safe.as_mut() {
            fs.check = fs.check.covering(self.base_max_delay_s, observed_max_s);
        }
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
}
