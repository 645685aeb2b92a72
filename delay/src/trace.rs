//! Recorded delay traces: the [`Trace`] a delay line replays, and its file format.
//!
//! The format other tools write: one delay in seconds per line, an optional first line
//! `delay_s` (a CSV header), `#` starts a comment and blank lines are skipped. Message `k` of a
//! line (cycle `k`'s command when the trace is a scenario's round trip) takes delay `k`.

use std::sync::Arc;

/// What a trace does once every delay has been used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TraceEnd {
    /// Start again from the first delay.
    Loop,
    /// Keep giving the last delay (what netem's API does with `looping = false`).
    Hold,
    /// Give no delay: the message is dropped with a reason naming the trace
    /// ([`crate::Decision::trace_ended`]), and a run must stop there. Scenario files' traces
    /// without `looping = true` end this way, so that a run that outlasts its trace is an
    /// error, never a silent wrap or a made-up delay.
    Stop,
}

/// A recorded sequence of delays, replayed in order.
#[derive(Debug, Clone, PartialEq)]
pub struct Trace {
    /// The delays, s (each finite, in `[0, MAX_DELAY_S]`).
    pub delays_s: Arc<[f64]>,
    pub end: TraceEnd,
    /// Where the delays come from (a file name), for errors; may be empty.
    pub name: Arc<str>,
}

impl Trace {
    /// A trace replayed over and over.
    pub fn looping(delays_s: impl Into<Arc<[f64]>>) -> Self {
        Self { delays_s: delays_s.into(), end: TraceEnd::Loop, name: Arc::from("") }
    }

    /// A trace that keeps its last delay once used up.
    pub fn holding(delays_s: impl Into<Arc<[f64]>>) -> Self {
        Self { delays_s: delays_s.into(), end: TraceEnd::Hold, name: Arc::from("") }
    }

    /// A trace read from `name` that ends the run once used up (or loops if `looping`).
    pub fn from_file(name: &str, delays_s: impl Into<Arc<[f64]>>, looping: bool) -> Self {
        let end = if looping { TraceEnd::Loop } else { TraceEnd::Stop };
        Self { delays_s: delays_s.into(), end, name: Arc::from(name) }
    }

    /// The delay of message `k`, or `None` when a [`TraceEnd::Stop`] trace has none left.
    /// The trace holds at least one delay (see [`crate::Distribution::validate`]).
    pub fn delay_of(&self, k: usize) -> Option<f64> {
        let n = self.delays_s.len();
        let i = match self.end {
            TraceEnd::Loop => k % n.max(1),
            TraceEnd::Hold => k.min(n.saturating_sub(1)),
            TraceEnd::Stop if k < n => k,
            TraceEnd::Stop => return None,
        };
        self.delays_s.get(i).copied()
    }
}

/// A message past the end of a trace that ends the run ([`TraceEnd::Stop`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "delay trace {name} holds {delays} delays and message {message} has none: the run outlasts the trace (set `looping = true` to replay it)"
)]
pub struct TraceEnded {
    /// The trace's name (its file).
    pub name: String,
    /// How many delays the trace holds.
    pub delays: usize,
    /// Number of the message that found no delay (0-based: the first has number 0).
    pub message: u64,
}

/// A trace line that could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TraceError {
    #[error("line {line}: {reason}")]
    Line { line: usize, reason: String },
    #[error("holds no delay")]
    Empty,
}

/// Parses a delay trace. Errors name the 1-based line.
///
/// ```
/// let t = delay::parse_trace("delay_s\n# a Wi-Fi link\n0.012\n0.020 # retry\n\n0.015\n").unwrap();
/// assert_eq!(t, vec![0.012, 0.020, 0.015]);
/// ```
pub fn parse_trace(text: &str) -> Result<Vec<f64>, TraceError> {
    let mut out = Vec::new();
    let mut first = true;
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let content = raw.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        // The optional header, only before the first delay.
        if std::mem::take(&mut first) && content == "delay_s" {
            continue;
        }
        let v: f64 = content.parse().map_err(|_| TraceError::Line {
            line,
            reason: format!("`{content}` is not a number of seconds"),
        })?;
        if !v.is_finite() || v < 0.0 {
            return Err(TraceError::Line { line, reason: format!("delay must be finite and >= 0, got {v}") });
        }
        if v > crate::MAX_DELAY_S {
            return Err(TraceError::Line {
                line,
                reason: format!("delay must be at most {} s, got {v}", crate::MAX_DELAY_S),
            });
        }
        out.push(v);
    }
    if out.is_empty() { Err(TraceError::Empty) } else { Ok(out) }
}

#[cfg(test)]
mod tests;
