//! The bench's laboratory: the aids that tuned, diagnosed and profiled the controller, and
//! netem's load benchmark. None of it is the product (`hilbench` is) and nothing here asserts a
//! result: each subcommand prints what it measured (BENCHMARKS.md and `docs/` quote them).
//! `cargo run --release -p lab -- --help` lists them; every setting is a flag, most also an
//! environment variable (`--help` names it), and a value that does not parse is an error.

mod accuracy;
mod budget_sweep;
mod cycles;
mod delay_diagnose;
mod delay_probe;
mod delay_robustness;
mod eval_bits;
mod falsify_bench;
mod fixed_instances;
mod fmt;
mod fresh;
mod inner_trace;
mod iter_profile;
mod load;
mod paper;
mod profile_eval;
mod profile_fail_safe;
mod profile_qp;
mod profile_solve;
mod qp_states;
mod settings;
mod tail;
#[cfg(test)]
mod tests;
mod traces;

use clap::{Parser, Subcommand};
use mpc::ControllerMode;

#[derive(Debug, Parser)]
#[command(
    name = "lab",
    about = "Tuning, diagnosis and profiling aids for hilbench's controller; netem's load benchmark"
)]
struct Args {
    #[command(subcommand)]
    aid: Aid,
}

#[derive(Debug, Subcommand)]
enum Aid {
    /// The closed loops' own warm-started solves against the careful reference.
    Accuracy(accuracy::Args),
    /// How cost, violation and clearance of chosen loop solves evolve with the budget.
    BudgetSweep(budget_sweep::Args),
    /// Per-cycle solver statistics of one paper run and what the safety layer chose.
    Cycles(cycles::Args),
    /// Logged loop states solved fresh from their warm start by both PANOCs, against the
    /// careful reference (`controller solve`'s sample).
    Fresh(fresh::Args),
    /// Solver settings compared on the same problems (the paper loops' instances).
    FixedInstances(fixed_instances::Args),
    /// Falsification (CMA-ES) against random search on a scenario file's `[falsify]` spaces.
    Falsify(falsify_bench::Args),
    /// PANOC's progress on one inner problem of a loop solve.
    InnerTrace(inner_trace::Args),
    /// What one PANOC iteration costs in the multi-stage paper loops.
    IterProfile,
    /// The three paper scenarios in process with both controllers, a line per run.
    Paper(paper::Args),
    /// The slowest solves of the multi-stage paper loops, with their ALM statistics.
    Tail,
    /// paper-2 under a constant delay or a trace, with and without the safety layer.
    DelayProbe(delay_probe::Args),
    /// Robustness survey: paper-2, multi-stage, under many random delay traces.
    DelayRobustness(delay_robustness::Args),
    /// One trace of the survey, cycle by cycle: the plant's clearance and the prediction error.
    DelayDiagnose(delay_diagnose::Args),
    /// Bit-level fingerprint of the evaluator and the closed loops (diff before and after).
    EvalBits(eval_bits::Args),
    /// Profiling target: the `cost_and_gradient` bench's loop.
    ProfileEval(profile_eval::Args),
    /// Profiling target: the fail-safe check's envelopes of `benches/cycle.rs`.
    ProfileFailSafe(profile_fail_safe::Args),
    /// Profiling target: the QP fallback's problems of `benches/qp.rs`.
    ProfileQp(profile_qp::Args),
    /// Profiling target: the paper-2 closed loop.
    ProfileSolve(profile_solve::Args),
    /// The QP fallback on every cycle of the multi-stage paper loops, timed.
    QpStates(qp_states::Args),
    /// Load benchmarks of netem on loopback.
    Load(load::Args),
}

/// A built-in scenario by name (`paper-1`, `paper-2`, `paper-3`).
fn scenario(name: &str) -> Result<mav::Scenario, String> {
    mav::Scenario::by_name(name).map_err(|e| e.to_string())
}

/// A controller: `nmpc` or `multistage`.
fn mode(name: &str) -> Result<ControllerMode, String> {
    ControllerMode::parse(name).ok_or_else(|| format!("`{name}`: nmpc or multistage"))
}

fn main() -> anyhow::Result<()> {
    match Args::parse().aid {
        Aid::Accuracy(a) => accuracy::run(&a),
        Aid::BudgetSweep(a) => budget_sweep::run(&a),
        Aid::Cycles(a) => cycles::run(&a),
        Aid::Fresh(a) => fresh::run(&a),
        Aid::FixedInstances(a) => fixed_instances::run(&a),
        Aid::Falsify(a) => falsify_bench::run(&a),
        Aid::InnerTrace(a) => inner_trace::run(&a),
        Aid::IterProfile => iter_profile::run(),
        Aid::Paper(a) => paper::run(&a),
        Aid::Tail => tail::run(),
        Aid::DelayProbe(a) => delay_probe::run(&a),
        Aid::DelayRobustness(a) => delay_robustness::run(&a),
        Aid::DelayDiagnose(a) => delay_diagnose::run(&a),
        Aid::EvalBits(a) => eval_bits::run(&a),
        Aid::ProfileEval(a) => profile_eval::run(&a),
        Aid::ProfileFailSafe(a) => profile_fail_safe::run(&a),
        Aid::ProfileQp(a) => profile_qp::run(&a),
        Aid::ProfileSolve(a) => profile_solve::run(&a),
        Aid::QpStates(a) => qp_states::run(&a),
        Aid::Load(a) => load::run(a),
    }
}
