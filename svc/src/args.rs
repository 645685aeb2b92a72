//! The core's enums on the command line: one clap value parser per type, so that every binary's
//! flag holds the core type itself (`mav::TimeMode`, `TimeModeChoice`, `ControllerMode`) and
//! no crate below the binaries derives a clap type.
//!
//! ```ignore
//! #[arg(long, value_parser = hilbench_svc::args::time_mode(), default_value_t = TimeMode::RealTime)]
//! time_mode: TimeMode,
//! ```
//!
//! A default is written with `default_value_t`: each type's `Display` is the name parsed here.

use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use mav::{ControllerMode, TimeMode, TimeModeChoice};

/// `lockstep` or `real-time`.
pub fn time_mode() -> impl TypedValueParser<Value = TimeMode> {
    one_of(&TIME_MODES)
}

/// `auto`, `lockstep` or `real-time`.
pub fn time_mode_choice() -> impl TypedValueParser<Value = TimeModeChoice> {
    one_of(&TIME_MODE_CHOICES)
}

/// `nmpc` or `multistage`.
pub fn controller_mode() -> impl TypedValueParser<Value = ControllerMode> {
    one_of(&CONTROLLER_MODES)
}

const LOCKSTEP_HELP: &str = "Time moves only through Advance/Step (deterministic; what the bench drives)";
const REAL_TIME_HELP: &str = "The wall clock";

/// Each value with its name (the type's `name()`, checked by the tests) and its help line.
const TIME_MODES: [(TimeMode, &str, &str); 2] =
    [(TimeMode::Lockstep, "lockstep", LOCKSTEP_HELP), (TimeMode::RealTime, "real-time", REAL_TIME_HELP)];

const TIME_MODE_CHOICES: [(TimeModeChoice, &str, &str); 3] = [
    (TimeModeChoice::Auto, "auto", "Follow the plant behind (asked with Describe)"),
    (TimeModeChoice::Fixed(TimeMode::Lockstep), "lockstep", LOCKSTEP_HELP),
    (TimeModeChoice::Fixed(TimeMode::RealTime), "real-time", REAL_TIME_HELP),
];

const CONTROLLER_MODES: [(ControllerMode, &str, &str); 2] = [
    (ControllerMode::Nmpc, "nmpc", "Standard NMPC: one scenario at the nominal sampling time"),
    (
        ControllerMode::Multistage,
        "multistage",
        "Multi-stage NMPC: one scenario per sampling time, weighted by delay probability",
    ),
];

/// A parser of exactly `values`' names (clap lists them, with their help, and refuses others).
fn one_of<T: Copy + Send + Sync + 'static>(
    values: &'static [(T, &'static str, &'static str)],
) -> impl TypedValueParser<Value = T> {
    PossibleValuesParser::new(values.iter().map(|(_, name, help)| PossibleValue::new(*name).help(*help)))
        .try_map(|name| {
            values
                .iter()
                .find(|(_, n, _)| *n == name)
                .map(|(v, ..)| *v)
                .ok_or("not one of the possible values")
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Flags {
        #[arg(long, value_parser = time_mode(), default_value_t = TimeMode::RealTime)]
        time_mode: TimeMode,
        #[arg(long, value_parser = time_mode_choice(), default_value_t = TimeModeChoice::Auto)]
        follow: TimeModeChoice,
        #[arg(long, value_parser = controller_mode())]
        mode: Option<ControllerMode>,
    }

    #[test]
    fn every_value_parses_by_its_name_and_defaults_round_trip_through_display() {
        assert!(TIME_MODES.iter().all(|(v, name, _)| v.name() == *name));
        assert!(TIME_MODE_CHOICES.iter().all(|(v, name, _)| v.name() == *name));
        assert!(CONTROLLER_MODES.iter().all(|(v, name, _)| v.name() == *name));
        let flags = Flags::try_parse_from(["x"]).expect("defaults");
        assert_eq!(
            (flags.time_mode, flags.follow, flags.mode),
            (TimeMode::RealTime, TimeModeChoice::Auto, None)
        );
        let flags = Flags::try_parse_from([
            "x",
            "--time-mode",
            "lockstep",
            "--follow",
            "real-time",
            "--mode",
            "multistage",
        ])
        .expect("valid");
        assert_eq!(flags.time_mode, TimeMode::Lockstep);
        assert_eq!(flags.follow, TimeModeChoice::Fixed(TimeMode::RealTime));
        assert_eq!(flags.mode, Some(ControllerMode::Multistage));
        let e = Flags::try_parse_from(["x", "--time-mode", "fast"]).expect_err("refused").to_string();
        assert!(e.contains("--time-mode") && e.contains("lockstep") && e.contains("real-time"), "{e}");
    }
}
