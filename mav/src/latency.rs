//! A latency histogram allocated once (fixed bins; percentiles to the bin's width), for the
//! latencies the bench's vehicles measure on their links: bfsim's state packet to motor packet,
//! the MSP gateway's command to RC frame.

/// Width of a latency bin, ns (10 us).
pub const BIN_NS: u64 = 10_000;
/// Number of bins: latencies up to 100 ms; longer ones land in the last bin.
pub const BINS: usize = 10_000;

/// Latencies in bins of [`BIN_NS`], with the exact minimum, maximum and mean.
#[derive(Debug, Clone, PartialEq)]
pub struct Latency {
    bins: Vec<u32>,
    count: u64,
    sum_ns: u128,
    min_ns: u64,
    max_ns: u64,
}

impl Default for Latency {
    fn default() -> Self {
        Self { bins: vec![0; BINS], count: 0, sum_ns: 0, min_ns: u64::MAX, max_ns: 0 }
    }
}

impl Latency {
    pub fn record(&mut self, ns: u64) {
        let bin = usize::try_from(ns / BIN_NS).unwrap_or(BINS - 1).min(BINS - 1);
        self.bins[bin] = self.bins[bin].saturating_add(1);
        self.count += 1;
        self.sum_ns += u128::from(ns);
        self.min_ns = self.min_ns.min(ns);
        self.max_ns = self.max_ns.max(ns);
    }

    pub fn count(&self) -> u64 {
        self.count
    }

    /// The upper edge of the bin holding quantile `q` in `[0, 1]`, ns (`None` when empty).
    pub fn quantile_ns(&self, q: f64) -> Option<u64> {
        if self.count == 0 {
            return None;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.count as f64).ceil() as u64).max(1);
        let mut seen = 0u64;
        for (i, n) in self.bins.iter().enumerate() {
            seen += u64::from(*n);
            if seen >= rank {
                // The last bin is open-ended: its upper edge is the maximum.
                let edge = if i == BINS - 1 { self.max_ns } else { (i as u64 + 1) * BIN_NS };
                return Some(edge.min(self.max_ns));
            }
        }
        Some(self.max_ns)
    }

    pub fn min_ns(&self) -> Option<u64> {
        (self.count > 0).then_some(self.min_ns)
    }

    pub fn max_ns(&self) -> Option<u64> {
        (self.count > 0).then_some(self.max_ns)
    }

    pub fn mean_ns(&self) -> Option<u64> {
        (self.count > 0).then(|| (self.sum_ns / u128::from(self.count)) as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_come_to_the_bin_s_width() {
        let mut l = Latency::default();
        assert_eq!(l.quantile_ns(0.5), None);
        for us in 1..=100u64 {
            l.record(us * 1_000);
        }
        assert_eq!(l.min_ns(), Some(1_000));
        assert_eq!(l.max_ns(), Some(100_000));
        // 50 us is in the bin [50, 60) us: the upper edge, within one bin width.
        assert_eq!(l.quantile_ns(0.5), Some(60_000));
        assert_eq!(l.quantile_ns(0.99), Some(100_000));
        l.record(u64::MAX / 2);
        assert_eq!(l.quantile_ns(1.0), Some(u64::MAX / 2), "the last bin holds the outliers");
    }
}
