//! Real links in: delay traces imported from what measuring tools write, their statistics,
//! maximum-likelihood fits with bootstrap intervals, and how sure a sweep's failure rate is.
//!
//! The pure core of `hilbench trace import|stats|fit` and of the sweep report's confidence:
//! text in (the caller reads the files), values and TOML out; no I/O, no clock, every random
//! draw from a seeded ChaCha8 generator. The trace file format is `delay`'s
//! ([`delay::parse_trace_file`], [`delay::write_trace`]): delays in s, `lost` lines,
//! provenance comments.
//!
//! - [`import`]: ping (Linux iputils, macOS), irtt's JSON, a CSV column into a
//!   [`delay::TraceFile`].
//! - [`stats`]: count, losses, percentiles, the share above a threshold, lag-1
//!   autocorrelation, runs of spikes.
//! - [`fit`]: Gamma, lognormal, Pareto, Weibull and a two-state regime, ranked by AIC and KS,
//!   with 95 % intervals; the best as a `[scenario.delays]` and a `[[sweep.families]]` table.
//! - [`probe`]: recording a live link: the probe datagram, matching replies, losses, the two
//!   directions from the clock offset.
//! - [`confidence`]: the Clopper–Pearson interval of a failure rate and the `--until-bound`
//!   stopping rule.

pub mod confidence;
pub mod fit;
pub mod import;
pub mod probe;
pub mod stats;

pub use confidence::{RateInterval, UntilBound, clopper_pearson, runs_needed, until_bound};
pub use fit::{
    Candidate, FitError, FitOptions, FitReport, Kind, Model, Param, RegimeModel, TableError, fit,
    ks_distance, ks_limit_95,
};
pub use import::{Format, ImportError, ImportOptions, Imported, IrttDelay, Unit, import};
pub use stats::{SpikeRule, StatsOptions, TraceStats, trace_stats};
