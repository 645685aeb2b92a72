//! Recorded delay traces: the [`Trace`] a delay line replays, and its file format.
//!
//! The format other tools write: one delay in seconds per line, an optional first line
//! `delay_s` (a CSV header), `#` starts a comment and blank lines are skipped. Message `k` of a
//! line (cycle `k`'s command when the trace is a scenario's round trip) takes delay `k`.
//!
//! Two additions, both invisible to a file without them:
//! - **Losses.** A line `lost` is a message that never arrived (a ping without an answer). It
//!   takes its place in the sequence: message `k` of a replay is dropped, counted as a loss
//!   like any other, not skipped. Among the delays in memory ([`Trace::delays_s`], a scenario's
//!   inline `delays_s`, the wire's `TraceDelay.delays_s`) a loss is [`LOST_S`] (`-1.0`), a
//!   value no delay can take: every carrier of delays is an array of numbers, and `-1.0`
//!   survives TOML, JSON and protobuf unchanged, where NaN and infinities do not all do.
//! - **Provenance.** Comment lines `# key: value` before the first delay (or `lost`) say where
//!   the trace comes from ([`Provenance`]: `source`, `when`, `rate_hz`, `probe_bytes`,
//!   `losses`, `tool`, and any other key kept as written). [`write_trace`] writes them;
//!   [`parse_trace_file`] returns them. A key is letters, digits and `_` only, so prose
//!   comments (`# Recorded on a Wi-Fi link: ...`) stay comments.
//!
//! ```text
//! # source: drone-wifi-ap3
//! # when: 2026-11-27T20:57:40Z
//! # rate_hz: 100
//! # probe_bytes: 56
//! # losses: 1
//! # tool: ping (iputils)
//! delay_s
//! 0.0123
//! lost
//! 0.0151
//! ```

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

    /// The delay of message `k` ([`LOST_S`] for a lost one), or `None` when a
    /// [`TraceEnd::Stop`] trace has none left. The trace holds at least one entry (see
    /// [`crate::Distribution::validate`]).
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

    /// How many of the trace's entries are losses.
    pub fn losses(&self) -> usize {
        self.delays_s.iter().filter(|d| is_lost(**d)).count()
    }
}

/// A lost message among a trace's delays: not a delay (every delay is `>= 0`), so no delay
/// can be mistaken for it. A file writes it as the line `lost`.
pub const LOST_S: f64 = -1.0;

/// Whether a trace entry is a lost message ([`LOST_S`]).
#[inline]
pub fn is_lost(delay_s: f64) -> bool {
    delay_s == LOST_S
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

/// Where a trace comes from: the `# key: value` comment lines before its first delay.
///
/// The known keys are typed (a value that does not parse is an error naming its line); any
/// other key is kept in `other`, in file order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Provenance {
    /// Where it was recorded: the link, the host probed (`source`).
    pub source: Option<String>,
    /// When it was recorded, as written (ISO 8601 recommended).
    pub when: Option<String>,
    /// Probes (or messages) per second.
    pub rate_hz: Option<f64>,
    /// Size of each probe, bytes (a ping's data bytes, irtt's packet length).
    pub probe_bytes: Option<u64>,
    /// Lost probes, as the recording tool counted them (the `lost` lines are what a replay
    /// uses; [`TraceFile::losses`] counts those).
    pub losses: Option<u64>,
    /// The tool and how it was run (`ping (iputils)`, `irtt 0.9.0`, ...).
    pub tool: Option<String>,
    /// Any other `key: value`, in file order.
    pub other: Vec<(String, String)>,
}

impl Provenance {
    /// The provenance as `(key, value)` lines, known keys first, in the order above.
    pub fn entries(&self) -> Vec<(String, String)> {
        let mut out = Vec::new();
        let mut put = |k: &str, v: Option<String>| {
            if let Some(v) = v {
                out.push((k.to_string(), v));
            }
        };
        put("source", self.source.clone());
        put("when", self.when.clone());
        put("rate_hz", self.rate_hz.map(|v| v.to_string()));
        put("probe_bytes", self.probe_bytes.map(|v| v.to_string()));
        put("losses", self.losses.map(|v| v.to_string()));
        put("tool", self.tool.clone());
        out.extend(self.other.iter().cloned());
        out
    }

    /// Sets `key` from its written `value`; `Err` says why the value does not fit the key.
    fn set(&mut self, key: &str, value: &str) -> Result<(), String> {
        let text = || Some(value.to_string());
        match key {
            "source" => self.source = text(),
            "when" => self.when = text(),
            "tool" => self.tool = text(),
            "rate_hz" => {
                let v: f64 = value.parse().map_err(|_| format!("rate_hz `{value}` is not a number"))?;
                if !v.is_finite() || v <= 0.0 {
                    return Err(format!("rate_hz must be finite and > 0, got {value}"));
                }
                self.rate_hz = Some(v);
            }
            "probe_bytes" | "losses" => {
                let v: u64 =
                    value.parse().map_err(|_| format!("{key} `{value}` is not a whole number >= 0"))?;
                if key == "losses" {
                    self.losses = Some(v);
                } else {
                    self.probe_bytes = Some(v);
                }
            }
            _ => self.other.push((key.to_string(), value.to_string())),
        }
        Ok(())
    }
}

/// A trace file read whole: its entries (delays, s, and [`LOST_S`] for each `lost` line) and
/// its provenance.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TraceFile {
    pub delays_s: Vec<f64>,
    pub provenance: Provenance,
}

impl TraceFile {
    /// How many entries are losses.
    pub fn losses(&self) -> usize {
        self.delays_s.iter().filter(|d| is_lost(**d)).count()
    }

    /// The delays of the messages that arrived, in order.
    pub fn delivered(&self) -> impl Iterator<Item = f64> + '_ {
        self.delays_s.iter().copied().filter(|d| !is_lost(*d))
    }
}

/// A trace line that could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TraceError {
    #[error("line {line}: {reason}")]
    Line { line: usize, reason: String },
    #[error("holds no delay")]
    Empty,
}

/// A trace that [`write_trace`] cannot write as it is.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WriteError {
    /// `delays_s[index]` is neither a delay in `[0, MAX_DELAY_S]` nor [`LOST_S`].
    #[error("delays_s[{index}]: {reason}")]
    Delay { index: usize, reason: String },
    /// A provenance key or value that would not read back as written.
    #[error("provenance `{key}`: {reason}")]
    Provenance { key: String, reason: String },
    #[error("holds no delay")]
    Empty,
}

/// The provenance keys with a field of their own in [`Provenance`].
pub const PROVENANCE_KEYS: [&str; 6] = ["source", "when", "rate_hz", "probe_bytes", "losses", "tool"];

/// A provenance key: a letter, then letters, digits and `_`.
fn is_key(k: &str) -> bool {
    let mut c = k.chars();
    c.next().is_some_and(|f| f.is_ascii_alphabetic()) && c.all(|ch| ch.is_ascii_alphanumeric() || ch == '_')
}

/// The `(key, value)` of a provenance comment (`content` is the line without its `#`).
fn provenance_line(content: &str) -> Option<(&str, &str)> {
    let (k, v) = content.split_once(':')?;
    let k = k.trim();
    is_key(k).then_some((k, v.trim()))
}

/// Parses a delay trace: its entries, delays in s and [`LOST_S`] for each `lost` line (see
/// [`parse_trace_file`] for the provenance too). Errors name the 1-based line.
///
/// ```
/// let t = delay::parse_trace("delay_s\n# a Wi-Fi link\n0.012\n0.020 # retry\n\nlost\n0.015\n").unwrap();
/// assert_eq!(t, vec![0.012, 0.020, delay::LOST_S, 0.015]);
/// ```
pub fn parse_trace(text: &str) -> Result<Vec<f64>, TraceError> {
    parse_trace_file(text).map(|f| f.delays_s)
}

/// Parses a delay trace with its provenance. Errors name the 1-based line: a line that is
/// neither a delay nor `lost`, a delay out of `[0, MAX_DELAY_S]`, a provenance value that does
/// not fit its key, a provenance key given twice.
pub fn parse_trace_file(text: &str) -> Result<TraceFile, TraceError> {
    let mut out = TraceFile::default();
    let mut first = true;
    let mut seen: Vec<(String, usize)> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let (content, comment) = match raw.split_once('#') {
            Some((c, rest)) => (c.trim(), Some(rest)),
            None => (raw.trim(), None),
        };
        if content.is_empty() {
            // Provenance: whole-line comments before the first entry.
            if out.delays_s.is_empty()
                && let Some((key, value)) = comment.and_then(provenance_line)
            {
                if let Some((_, at)) = seen.iter().find(|(k, _)| k == key) {
                    return Err(TraceError::Line {
                        line,
                        reason: format!("provenance key `{key}` given twice (first on line {at})"),
                    });
                }
                seen.push((key.to_string(), line));
                out.provenance.set(key, value).map_err(|reason| TraceError::Line { line, reason })?;
            }
            continue;
        }
        // The optional header, only before the first delay.
        if std::mem::take(&mut first) && content == "delay_s" {
            continue;
        }
        if content == "lost" {
            out.delays_s.push(LOST_S);
            continue;
        }
        let v: f64 = content.parse().map_err(|_| TraceError::Line {
            line,
            reason: format!("`{content}` is not a number of seconds (nor `lost`)"),
        })?;
        if !v.is_finite() || v < 0.0 {
            return Err(TraceError::Line {
                line,
                reason: format!("delay must be finite and >= 0, got {}", crate::Number(v)),
            });
        }
        if v > crate::MAX_DELAY_S {
            return Err(TraceError::Line {
                line,
                reason: format!("delay must be at most {} s, got {}", crate::MAX_DELAY_S, crate::Number(v)),
            });
        }
        out.delays_s.push(v);
    }
    if out.delays_s.is_empty() { Err(TraceError::Empty) } else { Ok(out) }
}

/// Writes a trace in the format [`parse_trace_file`] reads: the provenance as `# key: value`
/// lines, the header `delay_s`, then one entry per line (a delay in s, in the shortest form
/// that reads back to the same number, or `lost` for [`LOST_S`]). What it writes reads back
/// equal.
pub fn write_trace(delays_s: &[f64], provenance: &Provenance) -> Result<String, WriteError> {
    use std::fmt::Write as _;
    if delays_s.is_empty() {
        return Err(WriteError::Empty);
    }
    let mut out = String::with_capacity(12 * delays_s.len() + 256);
    let entries = provenance.entries();
    for (i, (key, value)) in entries.iter().enumerate() {
        let key = key.clone();
        let bad = |reason: &str| WriteError::Provenance { key: key.clone(), reason: reason.to_string() };
        if !is_key(&key) {
            return Err(bad("a key is a letter, then letters, digits and `_`"));
        }
        if value.contains(['\n', '\r']) {
            return Err(bad("a value is one line"));
        }
        if value.trim() != value || value.is_empty() {
            return Err(bad("a value is not empty and has no leading or trailing blanks"));
        }
        if entries[..i].iter().any(|(k, _)| *k == key) {
            return Err(bad("given twice"));
        }
        if i >= entries.len() - provenance.other.len() && PROVENANCE_KEYS.contains(&key.as_str()) {
            return Err(bad("a known key goes in its own field, not in `other`"));
        }
        let _ = writeln!(out, "# {key}: {value}");
    }
    out.push_str("delay_s\n");
    for (index, &d) in delays_s.iter().enumerate() {
        if is_lost(d) {
            out.push_str("lost\n");
        } else if d.is_finite() && (0.0..=crate::MAX_DELAY_S).contains(&d) {
            let _ = writeln!(out, "{d}");
        } else {
            return Err(WriteError::Delay {
                index,
                reason: format!("must be a delay in [0, {}] s or LOST_S, got {d}", crate::MAX_DELAY_S),
            });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests;
