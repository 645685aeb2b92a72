//! The hilbench CLI's library, by purpose (ARCHITECTURE.md has the map and its invariants):
//!
//! - [`cli`]: the command line's types, validated by clap; [`commands`]: one module per
//!   command, each returning how the process ends.
//! - [`run`]: what a run is ([`run::Job`]) and what is known once it flew
//!   ([`run::FinishedRun`]: summary, rows, timing, faults, delays); plain data.
//! - [`drive`]: how a run is flown (in process, over the gRPC services, an external
//!   controller); [`fly`]: flying a list of jobs with one driver.
//! - [`output`]: everything written from runs (summary.json, CSV, MCAP, report.md, plots,
//!   the terminal's tables).
//! - [`sweep`]: many runs under drawn delay processes, their statistics, shrinking, shards.
//! - [`panics`], [`progress`]: a panic ends its run; progress bars and lines.

pub mod cli;
pub mod commands;
pub mod drive;
pub mod falsification;
pub mod fly;
pub mod output;
pub mod panics;
pub mod progress;
pub mod run;
pub mod shrink;
pub mod sweep;
pub use hilbench_scenario_file as scenario_file;
