//! Pure delay profiles and delay lines for netem.
//!
//! This crate decides *what the network does* to each message: whether it is lost, duplicated,
//! and when each copy is released. It never reads a clock and never does I/O: send times are
//! passed in as integer nanoseconds (plant time in lockstep, the service's monotonic clock in
//! real time), and decisions come back as release times in the same unit. The netem service is
//! the thin shell that holds messages until those times.
//!
//! **Architecture Invariant:** no tokio, tonic or prost here; every random draw comes from a
//! [`rand_chacha::ChaCha8Rng`] seeded from the profile's seed, so the same seed, profile and
//! sequence of send times give the same decisions, bit for bit, in every time mode and with
//! every version of `rand` that keeps ChaCha8 (unlike `StdRng`, whose algorithm may change).
//!
//! - [`profile`]: the delay kinds ([`Distribution`], the one vocabulary of scenario files,
//!   netem's API and its profile files), what a direction of the network does
//!   ([`DirectionProfile`]) and both directions ([`NetworkProfile`]), validated with errors
//!   naming the field, and the named presets ([`preset`], e.g. `"paper"`).
//! - [`spec`]: the `[scenario.delays]` table of scenario files, as written, into a
//!   [`NetworkProfile`].
//! - [`line`]: the per-direction [`DelayLine`] that turns send times into [`Decision`]s.
//! - [`queue`]: a [`ReleaseQueue`] ordering held messages by release time.
//! - [`stats`]: counters, delay histogram and percentiles of one direction.
//! - [`trace`]: recorded delay traces ([`Trace`]) and their file format ([`parse_trace_file`],
//!   [`write_trace`]): delays, losses (`lost`, [`LOST_S`]) and provenance.
//! - [`record`]: one line of a delivery trace.

pub mod line;
pub mod profile;
pub mod queue;
pub mod record;
pub mod spec;
pub mod stats;
pub mod trace;

pub use line::{Decision, DelayLine, Draw, Fate, Release};
pub use profile::{
    Direction, DirectionProfile, Distribution, Dwell, MAX_DELAY_S, MAX_MEAN_DWELL, MAX_REGIME_STATES,
    NetworkProfile, Ordering, PRESETS, ProfileError, RegimeState, preset,
};
pub use queue::ReleaseQueue;
pub use record::Record;
pub use spec::{DelaysTable, SpecError};
pub use stats::{DirectionStats, Percentiles, Window};
pub use trace::{
    LOST_S, Provenance, Trace, TraceEnd, TraceEnded, TraceError, TraceFile, WriteError, is_lost, parse_trace,
    parse_trace_file, write_trace,
};

/// Nanoseconds per second.
pub const NS_PER_S: f64 = 1e9;

/// Converts a duration in nanoseconds to seconds: the bench's one such conversion (`mav`
/// re-exports it).
#[inline]
pub fn ns_to_s(ns: u64) -> f64 {
    ns as f64 / NS_PER_S
}

/// Converts a non-negative duration in seconds to nanoseconds, rounded to the nearest: the
/// bench's one such conversion (`mav` re-exports it). Negative, non-finite or too large input
/// gives `None`.
pub fn s_to_ns(s: f64) -> Option<u64> {
    if !s.is_finite() || s < 0.0 || s * NS_PER_S > u64::MAX as f64 {
        return None;
    }
    Some((s * NS_PER_S).round() as u64)
}

/// A drawn delay in seconds as nanoseconds: clamped to `[0, MAX_DELAY_S]` first (NaN: 0), so
/// that it always converts.
pub fn delay_ns(delay_s: f64) -> u64 {
    let s = if delay_s.is_nan() { 0.0 } else { delay_s.clamp(0.0, MAX_DELAY_S) };
    s_to_ns(s).unwrap_or(0)
}

/// A number as the bench's refusals show it: as Rust prints it (`0.05`, `3600`) when that is
/// short, in e-notation when its magnitude would take more than a few digits (`1e300`, not
/// the 301 digits of `{}`; `1e-300`, not 300 zeros). The one such format of every message
/// that echoes a value it refuses (`mav`, `proto`, the services re-use it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Number(pub f64);

impl std::fmt::Display for Number {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = self.0;
        if v.is_finite() && v != 0.0 && !(1e-6..1e15).contains(&v.abs()) {
            write!(f, "{v:e}")
        } else {
            write!(f, "{v}")
        }
    }
}

#[cfg(test)]
mod number_tests {
    use super::Number;

    #[test]
    fn huge_and_tiny_numbers_are_shown_in_e_notation_and_the_rest_as_written() {
        assert_eq!(Number(1e300).to_string(), "1e300");
        assert_eq!(Number(-1e300).to_string(), "-1e300");
        assert_eq!(Number(1e-300).to_string(), "1e-300");
        assert_eq!(Number(f64::MAX).to_string().len(), "1.7976931348623157e308".len());
        assert_eq!(Number(0.05).to_string(), "0.05");
        assert_eq!(Number(3600.0).to_string(), "3600");
        assert_eq!(Number(0.0).to_string(), "0");
        assert_eq!(Number(f64::NAN).to_string(), "NaN");
        assert_eq!(Number(f64::INFINITY).to_string(), "inf");
    }
}
