//! How sure a sweep is: the Clopper–Pearson interval of a failure rate, and the stopping rule
//! of `--until-bound P` (run until the interval's upper end is below `P`).
//!
//! Clopper–Pearson is the exact binomial interval: with `k` failures in `n` runs, the two
//! ends are the rates at which seeing `k` or more (the lower end), or `k` or fewer (the
//! upper end), has probability `(1 - level) / 2`. They are quantiles of Beta laws
//! (statrs' `Beta::inverse_cdf`), except at `k = 0` and `k = n`, where they are written in
//! closed form (`1 - (a/2)^(1/n)` and `(a/2)^(1/n)`, `a = 1 - level`), exact where a Beta with
//! a zero parameter does not exist. It never undercovers, so "fewer than 0.23 % of runs fail"
//! after 0 failures in 1600 runs is a claim that holds at least 95 % of the time.

use statrs::distribution::{Beta, ContinuousCDF};

/// A two-sided interval of a rate.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RateInterval {
    /// `failures / runs`.
    pub rate: f64,
    pub lower: f64,
    pub upper: f64,
    /// Confidence level, e.g. 0.95.
    pub level: f64,
}

/// A question that has no answer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfidenceError {
    #[error("{failures} failures in {runs} runs: failures must be <= runs and runs > 0")]
    Counts { failures: u64, runs: u64 },
    #[error("level must be in (0, 1), got {0}")]
    Level(f64),
    #[error("the bound must be in (0, 1), got {0}")]
    Bound(f64),
}

fn check(failures: u64, runs: u64, level: f64) -> Result<(), ConfidenceError> {
    if runs == 0 || failures > runs {
        return Err(ConfidenceError::Counts { failures, runs });
    }
    if !(level > 0.0 && level < 1.0) {
        return Err(ConfidenceError::Level(level));
    }
    Ok(())
}

/// The Clopper–Pearson interval of `failures` in `runs` at `level` (0.95 for 95 %).
pub fn clopper_pearson(failures: u64, runs: u64, level: f64) -> Result<RateInterval, ConfidenceError> {
    check(failures, runs, level)?;
    let (k, n) = (failures as f64, runs as f64);
    let tail = (1.0 - level) / 2.0;
    let lower = if failures == 0 {
        0.0
    } else if failures == runs {
        tail.powf(1.0 / n)
    } else {
        beta(k, n - k + 1.0).inverse_cdf(tail)
    };
    let upper = if failures == runs {
        1.0
    } else if failures == 0 {
        // 1 - tail^(1/n), without the cancellation of 1 - (something near 1).
        -(tail.ln() / n).exp_m1()
    } else {
        beta(k + 1.0, n - k).inverse_cdf(1.0 - tail)
    };
    Ok(RateInterval { rate: k / n, lower, upper, level })
}

/// A Beta law with parameters > 0 (the callers' `k >= 1`, `n - k >= 1` make them so).
fn beta(a: f64, b: f64) -> Beta {
    Beta::new(a, b).unwrap_or_else(|_| unreachable!("Beta({a}, {b}) with both parameters >= 1"))
}

/// What `--until-bound P` does after `runs` runs with `failures`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub enum UntilBound {
    /// The upper end is below `P`: stop, the failure rate is below `P` (at the level).
    Below(RateInterval),
    /// The lower end is above `P`: stop, the failure rate is above `P` however many runs
    /// follow (at the level).
    Above(RateInterval),
    /// Undecided: go on. `runs_at_least` is the least total number of runs that would end it
    /// `Below` if none of the runs to come failed (a lower bound on what is left to do).
    Continue { interval: RateInterval, runs_at_least: u64 },
}

/// The stopping decision of `--until-bound bound` after `failures` in `runs` (`runs = 0`:
/// nothing run yet, always `Continue`).
pub fn until_bound(failures: u64, runs: u64, bound: f64, level: f64) -> Result<UntilBound, ConfidenceError> {
    if !(bound > 0.0 && bound < 1.0) {
        return Err(ConfidenceError::Bound(bound));
    }
    if runs == 0 {
        check(0, 1, level)?;
        let need = runs_needed(0, bound, level)?;
        let interval = RateInterval { rate: 0.0, lower: 0.0, upper: 1.0, level };
        return Ok(UntilBound::Continue { interval, runs_at_least: need });
    }
    let interval = clopper_pearson(failures, runs, level)?;
    Ok(if interval.upper < bound {
        UntilBound::Below(interval)
    } else if interval.lower > bound {
        UntilBound::Above(interval)
    } else {
        UntilBound::Continue { interval, runs_at_least: runs_needed(failures, bound, level)?.max(runs + 1) }
    })
}

/// The least number of runs `n` whose Clopper–Pearson upper end with `failures` failures is
/// below `bound` (the upper end falls as `n` grows with `failures` fixed, so this is where a
/// sweep that sees no more failures can stop). Zero failures: `0.05` needs 72 runs at 95 %,
/// `0.0023` needs 1603.
pub fn runs_needed(failures: u64, bound: f64, level: f64) -> Result<u64, ConfidenceError> {
    if !(bound > 0.0 && bound < 1.0) {
        return Err(ConfidenceError::Bound(bound));
    }
    check(0, 1, level)?;
    let below = |n: u64| clopper_pearson(failures, n, level).map(|i| i.upper < bound);
    let mut hi = failures.max(1);
    while !below(hi)? {
        if hi > u64::MAX / 4 {
            return Ok(u64::MAX);
        }
        hi *= 2;
    }
    let mut lo = failures.max(1); // may be below too; search the first n that is
    if below(lo)? {
        return Ok(lo);
    }
    // below(lo) is false, below(hi) is true.
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if below(mid)? {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Ok(hi)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// References: scipy's `binomtest(k, n).proportion_ci(0.95, 'exact')` (scipy 1.x, run once
    /// in a throwaway venv; the values are pasted here).
    #[test]
    fn intervals_match_scipys_exact_binomial_interval() {
        for (k, n, lo, hi) in [
            (0, 1600, 0.0, 0.002302893920579882),
            (0, 10, 0.0, 0.30849710781876294),
            (10, 10, 0.6915028921812371, 1.0),
            (3, 100, 0.006229971538306227, 0.08517605297428028),
            (50, 100, 0.39832112950330095, 0.6016788704966991),
            (1, 1600, 1.5823504798413672e-05, 0.0034773062758037946),
        ] {
            let i = clopper_pearson(k, n, 0.95).expect("an interval");
            assert_relative_eq!(i.lower, lo, max_relative = 1e-9, epsilon = 1e-15);
            assert_relative_eq!(i.upper, hi, max_relative = 1e-9);
        }
    }

    #[test]
    fn runs_needed_is_the_first_n_below_the_bound() {
        for (k, bound) in [(0, 0.05), (0, 0.0023), (2, 0.01), (5, 0.1)] {
            let n = runs_needed(k, bound, 0.95).expect("n");
            let at = |n| clopper_pearson(k, n, 0.95).expect("interval").upper;
            assert!(at(n) < bound && at(n - 1) >= bound, "k {k} bound {bound}: n {n}");
        }
        assert_eq!(runs_needed(0, 0.05, 0.95), Ok(72));
    }

    #[test]
    fn until_bound_stops_below_above_or_says_how_far_to_go() {
        assert!(matches!(until_bound(0, 1600, 0.0025, 0.95), Ok(UntilBound::Below(_))));
        assert!(matches!(until_bound(40, 100, 0.2, 0.95), Ok(UntilBound::Above(_))));
        match until_bound(0, 100, 0.0025, 0.95) {
            Ok(UntilBound::Continue { runs_at_least, .. }) => assert_eq!(runs_at_least, 1474),
            other => panic!("{other:?}"),
        }
        assert!(matches!(until_bound(0, 0, 0.05, 0.95), Ok(UntilBound::Continue { runs_at_least: 72, .. })));
        assert_eq!(clopper_pearson(3, 2, 0.95), Err(ConfidenceError::Counts { failures: 3, runs: 2 }));
        assert_eq!(until_bound(0, 10, 1.0, 0.95), Err(ConfidenceError::Bound(1.0)));
    }
}
