//! Recorded delay traces as CSV text: one delay in seconds per line, `#` starts a comment,
//! blank lines are skipped.

/// A trace line that could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TraceError {
    #[error("trace line {line}: {reason}")]
    Line { line: usize, reason: String },
    #[error("trace holds no delay")]
    Empty,
}

/// Parses a delay trace. Errors name the 1-based line.
///
/// ```
/// let t = delay::parse_trace("# delays of a Wi-Fi link\n0.012\n0.020 # retry\n\n0.015\n").unwrap();
/// assert_eq!(t, vec![0.012, 0.020, 0.015]);
/// ```
pub fn parse_trace(text: &str) -> Result<Vec<f64>, TraceError> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let content = raw.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
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
mod tests {
    use super::*;

    #[test]
    fn errors_name_the_line() {
        assert_eq!(
            parse_trace("0.1\n# c\nabc\n"),
            Err(TraceError::Line { line: 3, reason: "`abc` is not a number of seconds".into() })
        );
        assert!(matches!(parse_trace("0.1\r\n-0.2\r\n"), Err(TraceError::Line { line: 2, .. })));
        assert!(matches!(parse_trace("0.1\nNaN\n"), Err(TraceError::Line { line: 2, .. })));
        assert!(matches!(parse_trace("0.1, 0.2\n"), Err(TraceError::Line { line: 1, .. })));
        assert_eq!(parse_trace("# only a comment\n\n"), Err(TraceError::Empty));
        assert_eq!(parse_trace("1e-3\r\n2.5e-2\n"), Ok(vec![0.001, 0.025]));
    }
}
