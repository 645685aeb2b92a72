//! The safety layer's settings (validated data with documented defaults) and the QP's
//! schedule.

use mav::Scenario;

use crate::error::MpcError;
use crate::fail_safe::BrakingCheck;
use crate::qp::QpSettings;

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

/// Settings of the safety layer (validated in [`SafetyLayer::new`](super::SafetyLayer::new)).
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
            brake_gain_per_s: crate::command::DEFAULT_BRAKE_GAIN_PER_S,
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

    /// These settings with the fail-safe check (if any) counting on the plant's braking
    /// watchdog `plant_watchdog_s` (see [`BrakingCheck::plant_watchdog_s`]).
    pub fn with_plant_watchdog(mut self, plant_watchdog_s: Option<f64>) -> Self {
        if let Some(check) = self.braking_check.as_mut() {
            check.plant_watchdog_s = plant_watchdog_s;
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
