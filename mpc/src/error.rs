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
}

pub(crate) fn invalid_input(field: impl Into<String>, reason: impl Into<String>) -> MpcError {
    MpcError::InvalidInput { field: field.into(), reason: reason.into() }
}
