//! Statistics of one direction: counts, achieved delay histogram and percentiles, and the
//! release-time error of a real-time shell.
//!
//! Counting convention: `sent` messages enter the line; a delivered message may have a
//! `duplicated` copy; every copy is eventually `delivered` or `dropped` (lost on the way, or
//! dropped by the shell, e.g. the upstream went away). So
//! `sent + duplicated = delivered + dropped + in flight`.
//!
//! ## Memory allocation
//! Percentiles are exact over the last [`WINDOW`] deliveries (a ring buffer of `u64`, 8 MiB at
//! most, grown on demand); the histogram and the maximum cover everything since the last reset.

/// Number of most recent samples the percentiles are computed over.
pub const WINDOW: usize = 1 << 20;
/// Default histogram bin width: 1 ms.
pub const DEFAULT_BIN_NS: u64 = 1_000_000;
/// Number of histogram bins; the last one also counts every longer delay.
pub const BINS: usize = 2_000;

/// Exact percentiles of a set of durations, ns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Percentiles {
    pub p50_ns: u64,
    pub p95_ns: u64,
    pub p99_ns: u64,
    pub max_ns: u64,
}

/// Durations, ns: exact percentiles over the last [`WINDOW`] pushed, the maximum over all of
/// them (netem's delays and release errors, the services' real-time lateness).
#[derive(Debug, Clone, Default)]
pub struct Window {
    values: Vec<u64>,
    next: usize,
    max: u64,
    count: u64,
}

impl Window {
    pub fn push(&mut self, v: u64) {
        self.count += 1;
        self.max = self.max.max(v);
        if self.values.len() < WINDOW {
            self.values.push(v);
        } else {
            self.values[self.next] = v;
            self.next = (self.next + 1) % WINDOW;
        }
    }

    /// Durations pushed since the window was made.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// Nearest-rank percentiles of the last [`WINDOW`] durations and the maximum of all; `None`
    /// when nothing was pushed.
    pub fn percentiles(&self) -> Option<Percentiles> {
        if self.values.is_empty() {
            return None;
        }
        let mut v = self.values.clone();
        v.sort_unstable();
        let rank = |p: f64| v[((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
        Some(Percentiles { p50_ns: rank(0.50), p95_ns: rank(0.95), p99_ns: rank(0.99), max_ns: self.max })
    }
}

/// Statistics of one direction.
#[derive(Debug, Clone)]
pub struct DirectionStats {
    pub sent: u64,
    pub delivered: u64,
    pub dropped: u64,
    pub duplicated: u64,
    delays: Window,
    release_errors: Window,
    bin_width_ns: u64,
    histogram: Vec<u64>,
}

impl Default for DirectionStats {
    fn default() -> Self {
        Self::new(DEFAULT_BIN_NS)
    }
}

impl DirectionStats {
    /// Empty statistics with histogram bins of `bin_width_ns` (at least 1 ns).
    pub fn new(bin_width_ns: u64) -> Self {
        Self {
            sent: 0,
            delivered: 0,
            dropped: 0,
            duplicated: 0,
            delays: Window::default(),
            release_errors: Window::default(),
            bin_width_ns: bin_width_ns.max(1),
            histogram: Vec::new(),
        }
    }

    /// Back to zero (the bin width is kept).
    pub fn reset(&mut self) {
        *self = Self::new(self.bin_width_ns);
    }

    /// Counts what a [`crate::Decision`] says: one message sent, lost or not, maybe duplicated.
    pub fn record_decision(&mut self, d: &crate::Decision) {
        self.sent += 1;
        match d.fate {
            crate::Fate::Dropped => self.dropped += 1,
            crate::Fate::Delivered { duplicate, .. } => self.duplicated += u64::from(duplicate.is_some()),
        }
    }

    /// A copy held in flight was dropped by the shell (upstream gone, reset, ...).
    pub fn record_dropped(&mut self) {
        self.dropped += 1;
    }

    /// A copy was delivered after `delay_ns` (release minus send).
    pub fn record_delivered(&mut self, delay_ns: u64) {
        self.delivered += 1;
        self.delays.push(delay_ns);
        let bin = usize::try_from(delay_ns / self.bin_width_ns).unwrap_or(usize::MAX).min(BINS - 1);
        if self.histogram.len() <= bin {
            self.histogram.resize(bin + 1, 0);
        }
        self.histogram[bin] += 1;
    }

    /// A real-time release happened `error_ns` after (or before, if negative) its schedule.
    pub fn record_release_error(&mut self, error_ns: i64) {
        self.release_errors.push(error_ns.unsigned_abs());
    }

    /// Percentiles of the achieved delay of delivered copies.
    pub fn delay_percentiles(&self) -> Option<Percentiles> {
        self.delays.percentiles()
    }

    /// Percentiles of the absolute release-time error (real time only).
    pub fn release_error_percentiles(&self) -> Option<Percentiles> {
        self.release_errors.percentiles()
    }

    /// Histogram of the achieved delay: bin width, ns, and counts from 0 upwards.
    pub fn histogram(&self) -> (u64, &[u64]) {
        (self.bin_width_ns, &self.histogram)
    }
}

#[cfg(test)]
mod tests;
