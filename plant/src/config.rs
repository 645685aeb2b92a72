//! Settings of the plant service: validated data with documented defaults and units.

use hilbench_svc::streams::DEFAULT_MAX_STREAMS;
use mav::{Scenario, SimSettings, TimeMode, WatchdogAction};

/// An invalid setting.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid plant setting `{field}`: {reason}")]
pub struct ConfigError {
    pub field: String,
    pub reason: String,
}

impl ConfigError {
    fn new(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self { field: field.into(), reason: reason.into() }
    }
}

/// Default of [`PlantConfig::stream_buffer`], samples: a quarter second of steps at 1 kHz,
/// so that a lockstep `Advance` of up to 255 ms reaches a period-0 subscriber whole (the
/// bench's cycles are 50 ms); at most about 80 KB for a subscriber that stopped reading.
pub const DEFAULT_STREAM_BUFFER: usize = 256;

/// Default watchdog timeout, ns (500 ms), in both time modes.
pub const DEFAULT_WATCHDOG_NS: u64 = mav::DEFAULT_WATCHDOG_TIMEOUT_NS;

/// Settings of one plant service.
#[derive(Debug, Clone, PartialEq)]
pub struct PlantConfig {
    /// Scenario loaded at start, and by a `Reset` that names no scenario (default: paper-1).
    pub scenario: Scenario,
    /// How plant time moves (default: lockstep).
    pub time_mode: TimeMode,
    /// RK4 integration rate, Hz; the step is `round(1e9 / rate_hz)` ns (default 1000, i.e. 1 ms).
    /// In real time it is also the rate of the integration task.
    pub rate_hz: f64,
    /// With no command for this long, ns, the watchdog takes over until the next command and
    /// the samples say so (`watchdog_hover`); `None` = off. Default 500 ms in both time modes:
    /// in lockstep only a delay that long fires it (a heavy-tailed delay process), and the
    /// vehicle must then behave as it would on a real link.
    pub watchdog_timeout_ns: Option<u64>,
    /// What the watchdog does: brake to a standstill (default, as PX4's Hold failsafe) or hold
    /// level hover.
    pub watchdog_action: WatchdogAction,
    /// Samples queued per `StreamState` subscriber; when the queue is full, its oldest sample
    /// is discarded for the newest (the subscriber sees a gap in `seq`, finds the freshest
    /// state when it reads again, and the plant never waits for it), counted and logged.
    /// Default [`DEFAULT_STREAM_BUFFER`].
    pub stream_buffer: usize,
    /// `StreamState` streams open at once; one more is refused with `RESOURCE_EXHAUSTED`
    /// (`--max-streams`, default 64).
    pub max_streams: usize,
    /// TLS of the Plant API (default: plaintext).
    pub tls: hilbench_svc::tls::Tls,
    /// Limits on the server's connections and on the streams one client holds
    /// (`--max-connections`, `--handshake-timeout-s`, `--idle-timeout-s`,
    /// `--max-streams-per-client`).
    pub connections: hilbench_svc::connections::ConnectionLimits,
}

impl Default for PlantConfig {
    fn default() -> Self {
        Self::lockstep(Scenario::paper_1())
    }
}

impl PlantConfig {
    /// Lockstep on `scenario`, 1 kHz, the braking watchdog at 500 ms.
    pub fn lockstep(scenario: Scenario) -> Self {
        Self {
            scenario,
            time_mode: TimeMode::Lockstep,
            rate_hz: 1000.0,
            watchdog_timeout_ns: Some(DEFAULT_WATCHDOG_NS),
            watchdog_action: WatchdogAction::Brake,
            stream_buffer: DEFAULT_STREAM_BUFFER,
            max_streams: DEFAULT_MAX_STREAMS,
            tls: hilbench_svc::tls::Tls::plaintext(),
            connections: hilbench_svc::connections::ConnectionLimits::default(),
        }
    }

    /// Real time on `scenario`, 1 kHz, the braking watchdog at 500 ms.
    pub fn real_time(scenario: Scenario) -> Self {
        Self { time_mode: TimeMode::RealTime, ..Self::lockstep(scenario) }
    }

    /// Checks every setting and returns the truth simulation's settings.
    pub fn validate(&self) -> Result<SimSettings, ConfigError> {
        self.scenario.validate().map_err(|e| ConfigError::new("scenario", e.to_string()))?;
        let mut settings = SimSettings::with_rate_hz(self.rate_hz)
            .map_err(|e| ConfigError::new("rate_hz", e.to_string()))?;
        if self.watchdog_timeout_ns == Some(0) {
            return Err(ConfigError::new(
                "watchdog_timeout_ns",
                "must be > 0 when set (use None to turn it off)",
            ));
        }
        settings.watchdog_timeout_ns = self.watchdog_timeout_ns;
        settings.watchdog_action = self.watchdog_action;
        if self.stream_buffer == 0 {
            return Err(ConfigError::new("stream_buffer", "must be at least 1"));
        }
        if self.max_streams == 0 {
            return Err(ConfigError::new("max_streams", "must be at least 1"));
        }
        Ok(settings)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_bad_settings_are_named() {
        let s = PlantConfig::default().validate().expect("valid");
        assert_eq!(s.step_ns, 1_000_000);
        assert_eq!((s.watchdog_timeout_ns, s.watchdog_action), (Some(500_000_000), WatchdogAction::Brake));
        let rt = PlantConfig::real_time(Scenario::paper_2()).validate().expect("valid");
        assert_eq!((rt.watchdog_timeout_ns, rt.watchdog_action), (Some(500_000_000), WatchdogAction::Brake));
        let bad = PlantConfig { rate_hz: f64::NAN, ..Default::default() };
        assert_eq!(bad.validate().map_err(|e| e.field), Err("rate_hz".to_string()));
        let bad = PlantConfig { watchdog_timeout_ns: Some(0), ..Default::default() };
        assert_eq!(bad.validate().map_err(|e| e.field), Err("watchdog_timeout_ns".to_string()));
        let bad = PlantConfig { stream_buffer: 0, ..Default::default() };
        assert_eq!(bad.validate().map_err(|e| e.field), Err("stream_buffer".to_string()));
        let bad = PlantConfig { max_streams: 0, ..Default::default() };
        assert_eq!(bad.validate().map_err(|e| e.field), Err("max_streams".to_string()));
    }
}
