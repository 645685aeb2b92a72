//! Settings of the controller service, validated before anything starts.

use std::time::Duration;

use mav::Scenario;
use mpc::{ControllerMode, MpcSettings, SafetySettings};

/// Lockstep or real time; `Auto` follows what the plant's `Describe` says.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TimeModeSetting {
    #[default]
    Auto,
    Lockstep,
    RealTime,
}

#[derive(Debug, Clone)]
pub struct ControllerConfig {
    /// Plant API endpoint (`HOST:PORT` or `http://HOST:PORT`): a plant, netem, or a gateway.
    pub plant: String,
    /// Problem definition, goal and limits.
    pub scenario: Scenario,
    pub mode: ControllerMode,
    pub mpc: MpcSettings,
    /// The safety layer: cross-check of PANOC against the QP fallback and selection of the
    /// command every cycle; `None` sends PANOC's input as it is (clipped to the bounds).
    pub safety: Option<SafetySettings>,
    pub time_mode: TimeModeSetting,
    /// Reset the plant to the scenario when an episode starts (not on reconnection).
    pub reset_plant: bool,
    /// Start flying at once; otherwise wait for `SetScenario`.
    pub autostart: bool,
    /// Real time: fraction of the cycle period a solve may take before its deadline.
    pub deadline_fraction: f64,
    /// Reconnection backoff: first wait, doubled up to `backoff_max`.
    pub backoff_min: Duration,
    pub backoff_max: Duration,
    /// Telemetry items buffered per subscriber (default 4096, more than the cycles of a
    /// 60 s paper run); a subscriber that falls further behind loses the oldest items, the
    /// loop never waits for it.
    pub telemetry_buffer: usize,
}

impl ControllerConfig {
    pub fn new(plant: impl Into<String>, scenario: Scenario, mode: ControllerMode) -> Self {
        Self {
            plant: plant.into(),
            scenario,
            mode,
            mpc: MpcSettings::default(),
            safety: Some(SafetySettings::default()),
            time_mode: TimeModeSetting::Auto,
            reset_plant: true,
            autostart: true,
            deadline_fraction: 0.5,
            backoff_min: Duration::from_millis(50),
            backoff_max: Duration::from_secs(2),
            telemetry_buffer: 4096,
        }
    }

    /// Names the first invalid setting.
    pub fn validate(&self) -> Result<(), String> {
        if self.plant.trim().is_empty() {
            return Err("`plant`: an address is required".into());
        }
        self.scenario.validate().map_err(|e| e.to_string())?;
        self.mpc.validate().map_err(|e| e.to_string())?;
        if let Some(safety) = &self.safety {
            safety.validate().map_err(|e| e.to_string())?;
        }
        if !(self.deadline_fraction.is_finite()
            && self.deadline_fraction > 0.0
            && self.deadline_fraction <= 1.0)
        {
            return Err("`deadline_fraction`: must be in (0, 1]".into());
        }
        if self.telemetry_buffer == 0 {
            return Err("`telemetry_buffer`: must be > 0".into());
        }
        if self.backoff_min.is_zero() || self.backoff_max < self.backoff_min {
            return Err("`backoff_min`/`backoff_max`: need 0 < min <= max".into());
        }
        Ok(())
    }

    /// `http://` URI of the plant endpoint.
    pub fn plant_uri(&self) -> String {
        if self.plant.contains("://") { self.plant.clone() } else { format!("http://{}", self.plant) }
    }
}
