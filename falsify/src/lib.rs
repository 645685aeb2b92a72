//! Falsification: search a scenario's delays for a run that fails, instead of sampling them.
//!
//! `hilbench sweep` draws delay processes at random and estimates how often a controller fails;
//! a falsifier searches for a failing run with an optimiser, driving a continuous robustness
//! score below zero (S-TaLiRo, Breach, FalStar; ARCH-COMP's falsification track), and says
//! whether one exists within a budget and what it looks like.
//!
//! - [`table`]: the `[falsify]` table of a scenario file (parsed and checked by the scenario
//!   file loader, `hilbench_scenario_file`, which also checks its family names against
//!   `[sweep]` and builds each family's [`Space`]).
//! - [`space`]: a box of named ranges and the per-cycle delay trace of each of its points: a
//!   segment-wise signal ([`Space::signal`]) or a delay family's parameters ([`Space::family`]).
//! - [`score`]: [`RunFacts`] and [`Property::robustness`], negative exactly when a run fails.
//! - [`cmaes`]: CMA-ES with IPOP restarts in the unit cube, bounds by reflection.
//! - [`search`](mod@search): the ask/tell driver over CMA-ES or random search, seeded, and
//!   [`search()`], its loop over a closure.
//! - [`in_process`] (feature `mpc`, on by default): one point flown by `mpc::run_closed_loop`
//!   and scored.
//!
//! The crate is pure: no clock, no I/O, no tokio; the evaluation is the caller's closure, so
//! that `hilbench` can fly points over whatever transport it has.

pub mod cmaes;
#[cfg(feature = "mpc")]
pub mod in_process;
pub mod score;
pub mod search;
pub mod space;
pub mod table;

pub use score::RunFacts;
pub use search::{Evaluated, Generation, Search, SearchResult, SearchSettings, search};
pub use space::{Dim, Space};
pub use table::{FalsifyTable, Interpolation, Method, Property, SignalTable};
