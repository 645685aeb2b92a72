//! One control cycle as the bench runs it: PANOC solves, the safety layer cross-checks and
//! selects, and the command leaves finite and inside the bounds. The in-process closed loop
//! and the controller service both call [`CycleController::step`], so that their decisions,
//! and hence their trajectories, are the same bit for bit.

use crate::command::sanitize_command;
use crate::error::MpcError;
use crate::problem::{OcpDefinition, validate_instance};
use crate::qp::QpBudget;
use crate::safety::{SafetyLayer, SafetySettings, Selection};
use crate::solver::{Mpc, MpcSettings, SolveBudget, SolveReport};

/// A fault forced on PANOC, to test that the fallbacks take over. Only tests set one
/// ([`CycleController::with_fault`]); no setting of the services or the CLI reaches it. It is
/// compiled always, not behind a cargo feature, so that a package build and a workspace build
/// resolve `mpc` alike (README's two commands share one build).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PanocFault {
    /// PANOC gets an iteration budget of zero: its plan is the warm start, unsolved.
    ZeroBudget,
    /// PANOC's plan is replaced by NaN after the solve (a corrupted solver output).
    NanPlan,
}

/// A fault on the cycles `first_cycle..first_cycle + cycles`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct FaultInjection {
    pub fault: PanocFault,
    pub first_cycle: u64,
    pub cycles: u64,
}

impl FaultInjection {
    pub fn active(&self, cycle: u64) -> bool {
        cycle >= self.first_cycle && cycle - self.first_cycle < self.cycles
    }
}

/// What one cycle decided.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CycleOutcome {
    /// The command to send: finite and inside the input bounds.
    pub command: [f64; 3],
    /// PANOC's report.
    pub report: SolveReport,
    /// The safety layer's decision and checks (`None` when the layer is off).
    pub selection: Option<Selection>,
    /// The fault forced on this cycle, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fault: Option<PanocFault>,
}

/// PANOC plus the optional safety layer, with the plan that was actually selected.
///
/// ## Memory allocation
/// The solver's and the layer's workspaces (see [`Mpc`], [`SafetyLayer`]) and two `3N`
/// buffers, allocated in [`CycleController::new`].
pub struct CycleController {
    mpc: Mpc,
    safety: Option<SafetyLayer>,
    fault: Option<FaultInjection>,
    /// The selected plan of the last cycle (`N x 3`).
    plan: Vec<f64>,
    scratch: Vec<f64>,
    /// Time of the last cycle's state sample, ns (`None` before the first cycle).
    last_sample_ns: Option<u64>,
}

impl CycleController {
    /// `safety: None` sends PANOC's input as it is (clipped), like the paper's controller.
    pub fn new(
        def: OcpDefinition,
        mpc: MpcSettings,
        safety: Option<SafetySettings>,
    ) -> Result<Self, MpcError> {
        let safety = safety.map(|s| SafetyLayer::new(&def, s)).transpose()?;
        let mpc = Mpc::new(def, mpc)?;
        let plan = mpc.solution().to_vec();
        let mut controller =
            Self { scratch: plan.clone(), plan, mpc, safety, fault: None, last_sample_ns: None };
        controller.follow_the_checks_coast();
        Ok(controller)
    }

    /// With the fail-safe check and its `plan_coast_s`, the problem's coast is the check's
    /// ([`crate::fail_safe::BrakingCheck::plan_coast_time_s`]; the distance form only, the
    /// penalty form has none); otherwise the definition's stays.
    fn follow_the_checks_coast(&mut self) {
        let formulation = self.mpc.definition().formulation;
        let check = self.safety.as_ref().and_then(|layer| layer.braking_check());
        if let Some(coast_s) = check.and_then(|c| c.coast_for(formulation)) {
            self.mpc.set_coast_time(coast_s).expect("plan_coast_time_s is in [0, MAX_COAST_TIME_S]");
        }
    }

    /// Forces `fault` on PANOC on the given cycles (tests of the fallbacks).
    pub fn with_fault(mut self, fault: Option<FaultInjection>) -> Self {
        self.fault = fault;
        self
    }

    pub fn mpc(&self) -> &Mpc {
        &self.mpc
    }

    pub fn safety(&self) -> Option<&SafetyLayer> {
        self.safety.as_ref()
    }

    pub fn definition(&self) -> &OcpDefinition {
        self.mpc.definition()
    }

    /// The plan selected in the last cycle (`N x 3`, flattened): PANOC's, or the fallback's.
    pub fn plan(&self) -> &[f64] {
        &self.plan
    }

    /// Predicted states of every scenario under the plan selected in the last cycle (PANOC's or
    /// the fallback's: the one flown), from that cycle's state: `M` trajectories of `N + 1`.
    pub fn predictions(&self) -> Vec<Vec<[f64; 8]>> {
        self.mpc.predictions_of(&self.plan)
    }

    /// The longest delay measured lately, for the safety layer's fail-safe check
    /// ([`SafetyLayer::cover_delays_up_to`]). The plans' coast follows the check's range
    /// ([`crate::fail_safe::BrakingCheck::plan_coast_time_s`]; the distance form only).
    pub fn cover_delays_up_to(&mut self, observed_max_s: Option<f64>) {
        if let Some(layer) = self.safety.as_mut() {
            layer.cover_delays_up_to(observed_max_s);
        }
        self.follow_the_checks_coast();
    }

    /// See [`SafetyLayer::set_in_flight`] (nothing without the layer).
    pub fn set_in_flight(&mut self, in_flight: Option<&[crate::fail_safe::InFlight]>) {
        if let Some(layer) = self.safety.as_mut() {
            layer.set_in_flight(in_flight);
        }
    }

    /// Solves cycle `cycle` from state `x0`, sampled at `sample_ns`, with last applied input
    /// `u_prev` and the scenario weights, and selects the command. `Err` only for an invalid
    /// instance (nothing changes).
    ///
    /// Warm start: the last plan shifted by one step. With
    /// [`MpcSettings::warm_start_by_elapsed_time`], a single-scenario plan (standard NMPC, one
    /// 0.05 s sampling time) is shifted by the steps elapsed since the last cycle's sample
    /// instead: under the delays a cycle lasts `max(T, d)`, ~0.18 s with the paper's, so a
    /// one-step shift starts the solve from inputs meant for 0.13 s ago. A multi-stage plan is
    /// always shifted by one step: its inputs are shared by scenarios whose steps last
    /// 0.05-0.33 s, and one step is the shift of the scenario whose sampling time matches the
    /// cycle (the tree's premise).
    pub fn step(
        &mut self,
        cycle: u64,
        sample_ns: u64,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        weights: &[f64],
        budget: &SolveBudget,
    ) -> Result<CycleOutcome, MpcError> {
        // Refused before anything changes (the warm start's shift included).
        validate_instance(self.mpc.definition().num_scenarios(), x0, u_prev, weights)?;
        if let Some(last_ns) = self.last_sample_ns.replace(sample_ns) {
            let ts = self.mpc.definition().sampling_times_s[0];
            if self.mpc.settings().warm_start_by_elapsed_time && self.mpc.definition().num_scenarios() == 1 {
                let steps = (mav::ns_to_s(sample_ns.saturating_sub(last_ns)) / ts).round();
                if steps >= 2.0 {
                    self.mpc.advance_warm_start(steps as usize - 1);
                }
            }
        }
        let fault = self.fault.filter(|f| f.active(cycle)).map(|f| f.fault);
        let zero = SolveBudget { max_inner_iterations: Some(0), ..*budget };
        let budget = if fault == Some(PanocFault::ZeroBudget) { &zero } else { budget };
        let report = self.mpc.solve(x0, u_prev, weights, budget)?;
        let def = self.mpc.definition();
        let Some(layer) = self.safety.as_mut() else {
            self.plan.copy_from_slice(self.mpc.solution());
            if fault == Some(PanocFault::NanPlan) {
                self.plan.iter_mut().for_each(|u| *u = f64::NAN);
            }
            let first = [self.plan[0], self.plan[1], self.plan[2]];
            let command = sanitize_command(&def.model, &def.bounds, first);
            return Ok(CycleOutcome { command, report, selection: None, fault });
        };
        // The deadline is the cycle's: the QP gets what PANOC left of it.
        let qp_deadline = budget.deadline.map(|d| d.saturating_sub(report.solve_time));
        layer.set_qp_budget(QpBudget { max_iterations: None, deadline: qp_deadline });
        let selection = if fault == Some(PanocFault::NanPlan) {
            self.scratch.iter_mut().for_each(|u| *u = f64::NAN);
            layer.select_plan(x0, u_prev, weights, Ok((&self.scratch, report.status)))
        } else {
            layer.select(x0, u_prev, weights, &self.mpc, &report)
        };
        if let Some(plan) = layer.plan() {
            self.plan.copy_from_slice(plan);
        }
        if selection.decision.is_fallback() {
            // PANOC starts the next cycle from the plan that was flown, shifted by one step,
            // not from its own rejected one.
            crate::solver::shift_plan_into(&self.plan, &mut self.scratch);
            self.mpc.set_warm_start(&self.scratch)?;
        }
        Ok(CycleOutcome { command: selection.command, report, selection: Some(selection), fault })
    }
}

#[cfg(test)]
mod tests;
