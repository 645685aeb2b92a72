//! Settings of the controller service, validated before anything starts.

use std::time::Duration;

use mav::{Scenario, TimeModeChoice};
use mpc::{ControllerMode, EpisodeSettings, MpcSettings, SafetySettings};

#[derive(Debug, Clone)]
pub struct ControllerConfig {
    /// Plant API endpoint (`HOST:PORT` or `http://HOST:PORT`): a plant, netem, or a gateway.
    pub plant: String,
    /// Problem definition, goal and limits.
    pub scenario: Scenario,
    /// What each episode flies with (the first one's mode; a `SetScenario` may name another):
    /// the solver, the safety layer (cross-check of PANOC against the QP fallback and selection
    /// of the command every cycle; `None` sends PANOC's input as it is, clipped to the bounds)
    /// and its fail-safe check over every scenario (`--fail-safe`; without it, only scenarios
    /// with `fail_safe` get it). `delays_expected` and `plant_watchdog_s` are each episode's,
    /// from its scenario's delay model and the plant's `Describe`: what they hold here is
    /// replaced.
    pub episode: EpisodeSettings,
    /// A floor for every scenario flown (`--min-altitude-m`), those asked for by `SetScenario`
    /// included; `None`: each scenario's own (none for the paper's).
    pub min_altitude_m: Option<f64>,
    /// Lockstep or real time; `Auto` (the default) follows what the plant's `Describe` says.
    pub time_mode: TimeModeChoice,
    /// Reset the plant to the scenario when an episode starts (not on reconnection).
    pub reset_plant: bool,
    /// Start flying at once; otherwise wait for `SetScenario`.
    pub autostart: bool,
    /// Real time: fraction of the cycle period a solve may take before its deadline.
    pub deadline_fraction: f64,
    /// Reconnection backoff: first wait of each outage, doubled up to `backoff_max`.
    pub backoff_min: Duration,
    pub backoff_max: Duration,
    /// Longest wait for one plant RPC in real time (and for `Describe`). A link that stops
    /// answering without closing (a frozen gateway, a dropped route) would otherwise hang the
    /// loop; past this the call fails, the loss is reported and the link is retried like a
    /// closed one. Lockstep calls get at least 60 s: an `Advance` integrates a whole cycle
    /// before it answers, and a loaded machine must not make a deterministic run reconnect.
    pub rpc_timeout: Duration,
    /// Real time: no completed cycle for this long is a link outage even when no call failed
    /// (a link or a plant that hangs for less than `rpc_timeout`), counted with its whole
    /// duration in the link faults. Default 500 ms, the plant watchdog's timeout: a gap that
    /// long leaves the vehicle to its failsafe.
    pub stall_timeout: Duration,
    /// Telemetry items buffered per subscriber (default 4096, more than the cycles of a
    /// 60 s paper run); a subscriber that falls further behind loses the oldest items, the
    /// loop never waits for it.
    pub telemetry_buffer: usize,
    /// `StreamTelemetry` streams open at once; one more is refused with `RESOURCE_EXHAUSTED`
    /// (`--max-streams`, default 64).
    pub max_streams: usize,
    /// TLS of the Controller API and of the link to the plant (default: plaintext both ways).
    pub tls: hilbench_svc::tls::Tls,
    /// Limits on the server's connections and on the streams one client holds
    /// (`--max-connections`, `--handshake-timeout-s`, `--idle-timeout-s`,
    /// `--max-streams-per-client`).
    pub connections: hilbench_svc::connections::ConnectionLimits,
}

impl ControllerConfig {
    /// The safety settings of an episode of `scenario`: these, with the fail-safe check over
    /// the scenario's delay range when the scenario or [`ControllerConfig::fail_safe`] asks.
    pub fn safety_for(&self, scenario: &Scenario) -> Option<SafetySettings> {
        self.episode.safety.map(|s| s.with_fail_safe(scenario, self.episode.fail_safe || scenario.fail_safe))
    }

    pub fn new(plant: impl Into<String>, scenario: Scenario, mode: ControllerMode) -> Self {
        Self {
            plant: plant.into(),
            scenario,
            episode: EpisodeSettings::new(mode, MpcSettings::default()),
            min_altitude_m: None,
            time_mode: TimeModeChoice::Auto,
            reset_plant: true,
            autostart: true,
            deadline_fraction: 0.5,
            backoff_min: Duration::from_millis(50),
            backoff_max: Duration::from_secs(2),
            rpc_timeout: Duration::from_secs(5),
            stall_timeout: Duration::from_millis(500),
            telemetry_buffer: 4096,
            max_streams: hilbench_svc::streams::DEFAULT_MAX_STREAMS,
            tls: hilbench_svc::tls::Tls::plaintext(),
            connections: hilbench_svc::connections::ConnectionLimits::default(),
        }
    }

    /// Names the first invalid setting.
    pub fn validate(&self) -> Result<(), String> {
        if self.plant.trim().is_empty() {
            return Err("`plant`: an address is required".into());
        }
        if let Err(e) = self.plant_endpoint() {
            return Err(format!("`plant`: `{}` is not a valid address ({e})", self.plant));
        }
        self.adapt(self.scenario.clone()).validate().map_err(|e| e.to_string())?;
        self.episode.mpc.validate().map_err(|e| e.to_string())?;
        if let Some(safety) = &self.episode.safety {
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
        if self.max_streams == 0 {
            return Err("`max_streams`: must be > 0".into());
        }
        if self.backoff_min.is_zero() || self.backoff_max < self.backoff_min {
            return Err("`backoff_min`/`backoff_max`: need 0 < min <= max".into());
        }
        if self.rpc_timeout.is_zero() {
            return Err("`rpc_timeout`: must be > 0".into());
        }
        if self.stall_timeout.is_zero() {
            return Err("`stall_timeout`: must be > 0".into());
        }
        Ok(())
    }

    /// `scenario` as this controller flies it: with the `min_altitude_m` floor when one is set.
    pub fn adapt(&self, scenario: Scenario) -> Scenario {
        with_floor(scenario, self.min_altitude_m)
    }

    /// The plant's endpoint: `https` with this controller's client TLS config when it has
    /// one, `http` otherwise.
    pub fn plant_endpoint(&self) -> Result<tonic::transport::Endpoint, hilbench_svc::tls::TlsError> {
        self.tls.endpoint(&self.plant)
    }
}

/// `scenario` with `floor_m` as its floor when given (see [`ControllerConfig::min_altitude_m`]).
pub(crate) fn with_floor(mut scenario: Scenario, floor_m: Option<f64>) -> Scenario {
    if floor_m.is_some() {
        scenario.min_altitude_m = floor_m;
    }
    scenario
}

#[cfg(test)]
mod tests {
    use super::*;
    use mpc::BrakingCheck;

    #[test]
    fn the_fail_safe_check_comes_from_the_flag_or_the_scenario_and_a_preset_one_stays() {
        let preset = BrakingCheck { delay_samples: 5, ..BrakingCheck::default() };
        for (flag, asks, set) in (0..8).map(|b| (b & 1 != 0, b & 2 != 0, b & 4 != 0)) {
            let scenario = Scenario { fail_safe: asks, ..Scenario::paper_2() };
            let mut config = ControllerConfig::new("plant:1", scenario.clone(), ControllerMode::Multistage);
            config.episode.fail_safe = flag;
            let base = SafetySettings { braking_check: set.then_some(preset), ..SafetySettings::default() };
            config.episode.safety = Some(base);
            let expected = match (set, flag || asks) {
                (true, _) => Some(preset),
                (false, true) => Some(BrakingCheck::for_scenario(&scenario)),
                (false, false) => None,
            };
            let got = config.safety_for(&scenario).expect("layer on");
            assert_eq!(got, SafetySettings { braking_check: expected, ..base }, "{flag} {asks} {set}");
            config.episode.safety = None;
            assert_eq!(config.safety_for(&scenario), None);
        }
    }

    #[test]
    fn validation_names_a_bad_plant_address_and_a_zero_call_timeout() {
        let ok = ControllerConfig::new("127.0.0.1:50052", Scenario::paper_2(), ControllerMode::Multistage);
        assert_eq!(ok.validate(), Ok(()));
        for plant in ["", "  ", "bad host:50052", "http://[::1"] {
            let bad = ControllerConfig { plant: plant.into(), ..ok.clone() };
            let e = bad.validate().expect_err(plant);
            assert!(e.starts_with("`plant`"), "{plant}: {e}");
        }
        let hostname = ControllerConfig { plant: "vehicle-gateway:50052".into(), ..ok.clone() };
        assert_eq!(hostname.validate(), Ok(()));
        let zero = ControllerConfig { rpc_timeout: Duration::ZERO, ..ok.clone() };
        assert!(zero.validate().is_err_and(|e| e.starts_with("`rpc_timeout`")));
        let no_streams = ControllerConfig { max_streams: 0, ..ok };
        assert!(no_streams.validate().is_err_and(|e| e.starts_with("`max_streams`")));
    }
}
