//! The bench's two choices of how to fly, one type each for every crate: how plant time moves
//! ([`TimeMode`], with [`TimeModeChoice`] for a service that may follow its plant) and which
//! controller of the paper flies ([`ControllerMode`]). Files and `summary.json` spell them with
//! serde; the command lines map their flags onto them at the edge (`hilbench_svc::args`), and
//! the wire's `hilbench.v1.TimeMode` is converted in `proto`.

use std::fmt;

/// How plant time moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TimeMode {
    /// Deterministic: time moves only through `Advance`/`Step` (paper mode, what the bench
    /// drives), faster than real time.
    #[default]
    Lockstep,
    /// The wall clock: the plant integrates in real time (with its command watchdog; plant time
    /// is the time since the last reset), netem releases on its own thread, the controller
    /// solves under a deadline once per cycle.
    RealTime,
}

impl TimeMode {
    /// As written in files, on the command line and in `summary.json`.
    pub fn name(self) -> &'static str {
        match self {
            TimeMode::Lockstep => "lockstep",
            TimeMode::RealTime => "real-time",
        }
    }
}

impl fmt::Display for TimeMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The time mode of a service that sits in front of a plant (netem, the controller): fixed, or
/// whatever the plant's `Describe` says.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum TimeModeChoice {
    /// Follow the plant behind (asked with `Describe`), so that only the plant's time mode has
    /// to be chosen.
    #[default]
    Auto,
    Fixed(TimeMode),
}

impl TimeModeChoice {
    /// The mode in force behind a plant that runs in `plant`'s.
    pub fn resolve(self, plant: TimeMode) -> TimeMode {
        match self {
            TimeModeChoice::Auto => plant,
            TimeModeChoice::Fixed(mode) => mode,
        }
    }

    /// The fixed mode; `None` for `Auto`.
    pub fn fixed(self) -> Option<TimeMode> {
        match self {
            TimeModeChoice::Auto => None,
            TimeModeChoice::Fixed(mode) => Some(mode),
        }
    }

    /// As written on the command line: `auto`, or the mode's name.
    pub fn name(self) -> &'static str {
        self.fixed().map_or("auto", TimeMode::name)
    }
}

impl fmt::Display for TimeModeChoice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl From<TimeMode> for TimeModeChoice {
    fn from(mode: TimeMode) -> Self {
        TimeModeChoice::Fixed(mode)
    }
}

/// Which controller of the paper flies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ControllerMode {
    /// Standard NMPC: one scenario at the nominal sampling time, weight 1.
    Nmpc,
    /// Multi-stage NMPC: one scenario per sampling time, weighted by delay probability.
    Multistage,
}

impl ControllerMode {
    /// As written in files (`run.modes`), on the command line, on the wire and in outputs.
    pub fn name(self) -> &'static str {
        match self {
            ControllerMode::Nmpc => "nmpc",
            ControllerMode::Multistage => "multistage",
        }
    }

    /// A name of [`ControllerMode::name`]'s (or `multi-stage`).
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "nmpc" => Some(Self::Nmpc),
            "multistage" | "multi-stage" => Some(Self::Multistage),
            _ => None,
        }
    }
}

impl fmt::Display for ControllerMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq, serde::Serialize, serde::Deserialize)]
    struct Modes {
        time_mode: TimeMode,
        modes: Vec<ControllerMode>,
    }

    #[test]
    fn names_are_the_serde_names_and_auto_follows_the_plant() -> Result<(), Box<dyn std::error::Error>> {
        let text = "time_mode = \"real-time\"\nmodes = [\"nmpc\", \"multistage\"]\n";
        let modes: Modes = toml::from_str(text)?;
        assert_eq!(
            modes,
            Modes {
                time_mode: TimeMode::RealTime,
                modes: vec![ControllerMode::Nmpc, ControllerMode::Multistage]
            }
        );
        assert_eq!(toml::to_string(&modes)?, text);
        for m in [TimeMode::Lockstep, TimeMode::RealTime] {
            assert_eq!(
                toml::to_string(&Modes { time_mode: m, modes: vec![] })?,
                format!("time_mode = \"{m}\"\nmodes = []\n")
            );
            assert_eq!(TimeModeChoice::Auto.resolve(m), m);
            assert_eq!(TimeModeChoice::Fixed(TimeMode::Lockstep).resolve(m), TimeMode::Lockstep);
            assert_eq!(TimeModeChoice::from(m).name(), m.name());
        }
        assert_eq!(TimeModeChoice::default().name(), "auto");
        for m in [ControllerMode::Nmpc, ControllerMode::Multistage] {
            assert_eq!(ControllerMode::parse(m.name()), Some(m));
        }
        assert_eq!(ControllerMode::parse("multi-stage"), Some(ControllerMode::Multistage));
        assert_eq!(ControllerMode::parse("both"), None);
        Ok(())
    }
}
