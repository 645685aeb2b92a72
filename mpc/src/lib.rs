//! `mpc` owns the paper's controller as pure numerics: the multi-stage nonlinear MPC whose
//! scenario tree branches over sampling times (standard NMPC is the same code with one
//! scenario), solved with PANOC inside OpEn's penalty method; the hand-derived adjoint
//! gradient; the delay statistics that weight the scenarios; the QP-linearised fallback
//! (clarabel) and the safety layer that cross-checks PANOC against it and picks each cycle's
//! command (`cycle::CycleController`, shared by the in-process loop and the controller
//! service); and the deterministic in-process closed loop of `docs/spec.md`'s paper mode.
//!
//! No clock is read here except by the solvers' own timers and optional wall-clock deadlines
//! (OpEn's, clarabel's); no I/O, no async. Services wrap it.

// The numerical kernels index several arrays with one index (state, reference, weight); that
// reads closer to the maths than zipped iterators.
#![allow(clippy::needless_range_loop)]

pub mod accuracy;
pub mod closed_loop;
pub mod command {
    //! The commands every part of the controller falls back on (the sanitiser and braking):
    //! `mav`'s, the ones the plant's watchdog brakes with too.
    pub use mav::command::{DEFAULT_BRAKE_GAIN_PER_S, braking_command, sanitize_command};
}
pub mod cycle;
pub mod delays;
pub mod end;
pub mod episode;
pub mod error;
pub mod fail_safe;
#[doc(hidden)]
pub mod fixtures;
pub mod problem;
pub mod qp;
pub mod record;
pub mod safety;
pub mod solver;

pub use closed_loop::{ClosedLoopSettings, CycleTrace, DelaySource, run_closed_loop};
pub use command::{braking_command, sanitize_command};
pub use cycle::{CycleController, CycleOutcome};
pub use cycle::{FaultInjection, PanocFault};
pub use delays::{DelayWindow, GammaParams, ScenarioWeights, WeightSettings, WeightSource};
pub use end::RunEnd;
pub use episode::{CycleOutput, CycleTiming, Episode, EpisodeSettings};
pub use error::MpcError;
pub use fail_safe::{BrakingCheck, Envelope, FailSafe, InFlight};
pub use problem::{
    ControllerMode, Evaluator, MAX_COAST_TIME_S, ObstacleFormulation, OcpDefinition, PassCounts,
};
pub use qp::{QpBudget, QpFallback, QpReport, QpSettings, QpStatus};
pub use record::{CycleRecord, PredictedPath, RunOutcome, RunSummary, SolveStats, summarize};
pub use safety::{Decision, QpSchedule, Rejection, SafetyLayer, SafetySettings, Selection};
pub use solver::{
    INSIDE_TOLERANCE_M, InactiveSetTolerances, Mpc, MpcSettings, PanocSolver, SolveBudget, SolveReport,
    SolveStatus, shift_plan_into, shifted_plan,
};
