//! The crate's one error type: what was wrong with the input or the settings. A solve that ran
//! and ended badly is not an error but an outcome (`SolveStatus`, `QpStatus`, `Decision`).

/// Bad input or settings: no solve was attempted and nothing changed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MpcError {
    #[error("invalid setting `{field}`: {reason}")]
    InvalidSetting { field: &'static str, reason: &'static str },
    #[error("invalid problem: {0}")]
    InvalidProblem(String),
    #[error("invalid `{field}`: {reason}")]
    InvalidInput { field: String, reason: String },
    /// The sample belongs to another flight of the plant than the episode's first one: the
    /// plant was reset or restarted under the episode, whose state no longer describes it.
    #[error(
        "the plant was reset or restarted during the episode: its sample at {time_s} s of plant time belongs to another flight than the episode's (the last sample of the episode's flight was at {last_time_s} s)"
    )]
    PlantReset { last_time_s: f64, time_s: f64 },
    /// The delays ran out before the run's end (a trace shorter than the flight): an error
    /// naming the cycle, never a made-up delay.
    #[error("invalid `delays`: cycle {cycle}: {reason}")]
    TraceEnded { cycle: usize, reason: String },
}

pub(crate) fn invalid_input(field: impl Into<String>, reason: impl Into<String>) -> MpcError {
    MpcError::InvalidInput { field: field.into(), reason: reason.into() }
}
