//! What a trace says at a glance: counts, losses, percentiles, the share above the
//! controller's largest sampling time, correlation and bursts.
//!
//! Definitions (the entries are a trace's, in probe order; a loss is [`delay::LOST_S`]):
//! - percentiles are over the delivered delays, linearly interpolated between order
//!   statistics (the `(n - 1) p` rule, numpy's default);
//! - `share_above` is the share of delivered delays `> threshold_s`, and `share_late_or_lost`
//!   the share of all entries that are above it or lost (a lost command is later than any);
//! - the lag-1 autocorrelation is over consecutive pairs of delivered delays (a pair with a
//!   loss in it is left out), about the mean of all delivered delays;
//! - a **spike** is an entry above the spike threshold ([`SpikeRule`]: by default the p90 of
//!   the delivered delays) or lost; a **run** is a maximal stretch of consecutive spikes. A
//!   link whose spikes came independently, each with the observed share `q` of spikes, would
//!   have a mean run of `1 / (1 - q)` entries (`mean_run_if_independent`): a mean run well
//!   above it is a bursty link, which a regime fit describes and an i.i.d. fit does not.

use delay::is_lost;

/// Where spikes start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SpikeRule {
    /// Above this percentile of the delivered delays (`0.9`: the p90).
    AbovePercentile(f64),
    /// Above this delay, s.
    Above(f64),
}

impl Default for SpikeRule {
    fn default() -> Self {
        SpikeRule::AbovePercentile(0.9)
    }
}

/// What [`trace_stats`] computes beyond the fixed statistics.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StatsOptions {
    /// The share above this delay, s: the scenario tree's largest sampling time (a delay
    /// above it is one the controller's tree does not cover).
    pub threshold_s: Option<f64>,
    pub spike: SpikeRule,
}

/// The runs of spikes.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Bursts {
    /// The spike threshold, s.
    pub threshold_s: f64,
    /// Entries that are spikes (above the threshold or lost).
    pub spikes: usize,
    pub runs: usize,
    pub mean_run: f64,
    pub max_run: usize,
    /// Mean run length the same share of spikes would give if they came independently.
    pub mean_run_if_independent: f64,
    /// `(run length, how many runs)`, by length.
    pub run_lengths: Vec<(usize, usize)>,
}

/// The statistics of a trace. Delays in s.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TraceStats {
    /// Entries (delivered and lost).
    pub count: usize,
    pub delivered: usize,
    pub losses: usize,
    /// `losses / count`.
    pub loss_rate: f64,
    pub mean_s: f64,
    pub min_s: f64,
    pub median_s: f64,
    pub p90_s: f64,
    pub p99_s: f64,
    pub p999_s: f64,
    pub max_s: f64,
    /// The threshold asked for, s.
    pub threshold_s: Option<f64>,
    /// Share of delivered delays above the threshold.
    pub share_above: Option<f64>,
    /// Share of entries above the threshold or lost.
    pub share_late_or_lost: Option<f64>,
    /// `None` with fewer than two consecutive delivered pairs, or no variance.
    pub lag1_autocorrelation: Option<f64>,
    pub bursts: Bursts,
}

/// Why there are no statistics.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StatsError {
    #[error("the trace holds no delivered delay ({0} entries, all lost)")]
    NothingDelivered(usize),
    #[error("entry {index}: {value} is neither a delay >= 0 nor a loss")]
    BadEntry { index: usize, value: f64 },
    #[error("{0}")]
    Option(String),
}

/// The `p` quantile (`0 <= p <= 1`) of `sorted` (ascending, not empty), interpolated.
pub fn quantile(sorted: &[f64], p: f64) -> f64 {
    let n = sorted.len();
    if n == 0 {
        return f64::NAN;
    }
    let h = (n - 1) as f64 * p.clamp(0.0, 1.0);
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(n - 1);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

/// The statistics of the entries `delays_s` (delays, s, and [`delay::LOST_S`]).
pub fn trace_stats(delays_s: &[f64], options: &StatsOptions) -> Result<TraceStats, StatsError> {
    if let Some(t) = options.threshold_s
        && !(t.is_finite() && t >= 0.0)
    {
        return Err(StatsError::Option(format!("threshold_s must be finite and >= 0, got {t}")));
    }
    let mut sorted = Vec::with_capacity(delays_s.len());
    for (index, &d) in delays_s.iter().enumerate() {
        if is_lost(d) {
            continue;
        }
        if !(d.is_finite() && d >= 0.0) {
            return Err(StatsError::BadEntry { index, value: d });
        }
        sorted.push(d);
    }
    let count = delays_s.len();
    if sorted.is_empty() {
        return Err(StatsError::NothingDelivered(count));
    }
    let delivered = sorted.len();
    let losses = count - delivered;
    let mean_s = sorted.iter().sum::<f64>() / delivered as f64;
    sorted.sort_unstable_by(f64::total_cmp);
    let q = |p| quantile(&sorted, p);
    let (share_above, share_late_or_lost) = match options.threshold_s {
        Some(t) => {
            let above = delivered - sorted.partition_point(|d| *d <= t);
            (Some(above as f64 / delivered as f64), Some((above + losses) as f64 / count as f64))
        }
        None => (None, None),
    };
    let spike_s = match options.spike {
        SpikeRule::AbovePercentile(p) if (0.0..=1.0).contains(&p) => q(p),
        SpikeRule::Above(t) if t.is_finite() && t >= 0.0 => t,
        other => {
            return Err(StatsError::Option(format!(
                "spike rule {other:?}: a percentile in [0, 1] or a delay >= 0"
            )));
        }
    };
    Ok(TraceStats {
        count,
        delivered,
        losses,
        loss_rate: losses as f64 / count as f64,
        mean_s,
        min_s: sorted[0],
        median_s: q(0.5),
        p90_s: q(0.9),
        p99_s: q(0.99),
        p999_s: q(0.999),
        max_s: sorted[delivered - 1],
        threshold_s: options.threshold_s,
        share_above,
        share_late_or_lost,
        lag1_autocorrelation: lag1(delays_s, mean_s),
        bursts: bursts(delays_s, spike_s),
    })
}

/// Lag-1 autocorrelation of consecutive delivered pairs about `mean`.
fn lag1(delays_s: &[f64], mean: f64) -> Option<f64> {
    let (mut num, mut pairs) = (0.0, 0usize);
    for w in delays_s.windows(2) {
        if !is_lost(w[0]) && !is_lost(w[1]) {
            num += (w[0] - mean) * (w[1] - mean);
            pairs += 1;
        }
    }
    let (mut var, mut n) = (0.0, 0usize);
    for d in delays_s.iter().filter(|d| !is_lost(**d)) {
        var += (d - mean) * (d - mean);
        n += 1;
    }
    (pairs >= 1 && var > 0.0).then(|| (num / pairs as f64) / (var / n as f64))
}

fn bursts(delays_s: &[f64], threshold_s: f64) -> Bursts {
    let mut lengths: Vec<usize> = Vec::new();
    let mut run = 0;
    let mut spikes = 0;
    for &d in delays_s {
        if is_lost(d) || d > threshold_s {
            run += 1;
            spikes += 1;
        } else if run > 0 {
            lengths.push(std::mem::take(&mut run));
        }
    }
    if run > 0 {
        lengths.push(run);
    }
    let runs = lengths.len();
    let share = spikes as f64 / delays_s.len().max(1) as f64;
    let mut run_lengths: Vec<(usize, usize)> = Vec::new();
    lengths.sort_unstable();
    for l in &lengths {
        match run_lengths.last_mut() {
            Some((len, n)) if len == l => *n += 1,
            _ => run_lengths.push((*l, 1)),
        }
    }
    Bursts {
        threshold_s,
        spikes,
        runs,
        mean_run: if runs == 0 { 0.0 } else { spikes as f64 / runs as f64 },
        max_run: lengths.last().copied().unwrap_or(0),
        mean_run_if_independent: if share < 1.0 { 1.0 / (1.0 - share) } else { f64::INFINITY },
        run_lengths,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use delay::LOST_S;

    #[test]
    fn quantiles_interpolate_as_numpy_does() {
        let v = [1.0, 2.0, 3.0, 4.0];
        // numpy.quantile([1, 2, 3, 4], [0, 0.5, 0.9, 1]) = [1, 2.5, 3.7, 4]
        for (p, want) in [(0.0, 1.0), (0.5, 2.5), (0.9, 3.7), (1.0, 4.0)] {
            approx::assert_relative_eq!(quantile(&v, p), want, epsilon = 1e-12);
        }
    }

    #[test]
    fn counts_shares_and_runs_of_a_small_trace_by_hand() {
        // 10 entries: 2 lost; a burst of 3 (0.5, lost, 0.4), and a lone spike at the end.
        let d = [0.1, 0.1, 0.5, LOST_S, 0.4, 0.1, 0.2, 0.1, 0.1, LOST_S];
        let s = trace_stats(&d, &StatsOptions { threshold_s: Some(0.3), spike: SpikeRule::Above(0.3) })
            .expect("stats");
        assert_eq!((s.count, s.delivered, s.losses), (10, 8, 2));
        assert_eq!((s.share_above, s.share_late_or_lost), (Some(2.0 / 8.0), Some(4.0 / 10.0)));
        assert_eq!((s.bursts.spikes, s.bursts.runs, s.bursts.max_run), (4, 2, 3));
        assert_eq!(s.bursts.run_lengths, vec![(1, 1), (3, 1)]);
        approx::assert_relative_eq!(s.bursts.mean_run_if_independent, 1.0 / 0.6, epsilon = 1e-12);
        assert_eq!((s.max_s, s.min_s), (0.5, 0.1));
    }

    #[test]
    fn lag1_is_one_for_a_slow_ramp_and_negative_for_alternation() {
        let ramp: Vec<f64> = (0..1000).map(|k| k as f64 * 1e-3).collect();
        let r = trace_stats(&ramp, &StatsOptions::default()).expect("stats").lag1_autocorrelation;
        assert!(r.is_some_and(|r| r > 0.99), "{r:?}");
        let alt: Vec<f64> = (0..1000).map(|k| if k % 2 == 0 { 0.1 } else { 0.2 }).collect();
        let r = trace_stats(&alt, &StatsOptions::default()).expect("stats").lag1_autocorrelation;
        assert!(r.is_some_and(|r| r < -0.99), "{r:?}");
    }

    #[test]
    fn all_lost_or_bad_entries_are_errors() {
        assert_eq!(
            trace_stats(&[LOST_S, LOST_S], &StatsOptions::default()),
            Err(StatsError::NothingDelivered(2))
        );
        assert!(matches!(
            trace_stats(&[0.1, f64::NAN], &StatsOptions::default()),
            Err(StatsError::BadEntry { index: 1, .. })
        ));
    }
}
