//! What a run leaves behind, whichever way it flew: one [`CycleRecord`] per control cycle (what
//! the controller service streams as telemetry, and what the in-process loop keeps), and the
//! one function that turns records and the plant's last sample into a [`RunSummary`].
//!
//! Both drivers produce the same records from the same [`crate::Episode`], and `proto`'s
//! convert module carries them over the wire, so a summary computed from a gRPC run and one
//! computed in process are the same numbers (but for solve times, a wall-clock measurement).

use std::collections::BTreeMap;

use mav::{CollisionKind, PlantSample, ns_to_s};

use crate::cycle::CycleOutcome;
use crate::end::RunEnd;
use crate::safety::Decision;
use crate::solver::{SolveReport, SolveStatus};

/// PANOC's solve of one cycle, as logged.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SolveStats {
    pub status: SolveStatus,
    /// PANOC iterations, summed over the outer iterations.
    pub iterations: u64,
    /// Wall-clock time of the solve, ms.
    pub solve_ms: f64,
    /// The spec's objective at the returned inputs.
    pub cost: f64,
    pub constraint_violation: f64,
    /// Smallest true clearance of any predicted point (+inf: no obstacle), m.
    pub min_clearance_m: f64,
}

impl From<&SolveReport> for SolveStats {
    fn from(r: &SolveReport) -> Self {
        Self {
            status: r.status,
            iterations: r.iterations as u64,
            solve_ms: r.solve_time.as_secs_f64() * 1e3,
            cost: r.cost,
            constraint_violation: r.constraint_violation,
            min_clearance_m: r.min_clearance_m,
        }
    }
}

/// One scenario's predicted positions under the plan flown.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PredictedPath {
    pub sampling_time_s: f64,
    /// The scenario's weight in the solve.
    pub weight: f64,
    /// `N + 1` positions from the cycle's state, m.
    pub positions_m: Vec<[f64; 3]>,
}

/// One control cycle.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CycleRecord {
    pub cycle: u64,
    /// Plant time of the sample the controller solved from, ns.
    pub sample_time_ns: u64,
    /// The sampled state.
    pub state: [f64; 8],
    /// The plant's watchdog held hover when the sample was taken (no command for longer than its
    /// timeout).
    pub watchdog_hover: bool,
    /// The command sent: finite and inside the input bounds.
    pub command: [f64; 3],
    pub command_seq: u64,
    /// The round-trip delay the controller knew at this cycle (the last one measured from plant
    /// stamps), s; `None` before the first measurement.
    pub known_delay_s: Option<f64>,
    /// The delay the network put on this cycle's command, s: from netem's stamps over gRPC,
    /// the delay line's draw in process; `None` when the command was lost, or when nothing
    /// between the controller and the plant stamps it (no netem).
    pub injected_delay_s: Option<f64>,
    /// The network dropped this cycle's command (the delay line's draw in process, netem's
    /// stamp over gRPC): it never reached the plant.
    pub command_lost: bool,
    /// The scenario weights the solve used.
    pub weights: Vec<f64>,
    pub solve: SolveStats,
    /// What the safety layer sent (`None` when the layer is off).
    pub decision: Option<Decision>,
    /// No candidate passed the safety layer's checks and it sent the one that came closest
    /// (`decision` names which): the command was not verified safe.
    pub best_effort: bool,
    /// Why (empty when the layer is off).
    pub reason: String,
    /// QP cost minus PANOC cost on the nonlinear model, when the cross-check ran.
    pub cost_gap: Option<f64>,
    /// Predicted positions per scenario, when asked for.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub predictions: Vec<PredictedPath>,
}

impl CycleRecord {
    /// The record of a cycle that solved from `sample` and sent `command`.
    pub fn of_cycle(
        cycle: u64,
        sample: &PlantSample,
        command: [f64; 3],
        command_seq: u64,
        known_delay_s: Option<f64>,
        weights: Vec<f64>,
        outcome: &CycleOutcome,
    ) -> Self {
        Self {
            cycle,
            sample_time_ns: sample.time_ns,
            state: sample.state.into(),
            watchdog_hover: sample.watchdog_hover,
            command,
            command_seq,
            known_delay_s,
            injected_delay_s: None,
            command_lost: false,
            weights,
            solve: SolveStats::from(&outcome.report),
            decision: outcome.selection.as_ref().map(|s| s.decision),
            best_effort: outcome.selection.as_ref().is_some_and(|s| !s.verified_safe),
            reason: outcome.selection.as_ref().map(|s| s.reason()).unwrap_or_default(),
            cost_gap: outcome.selection.as_ref().and_then(|s| s.cost_gap),
            predictions: Vec::new(),
        }
    }

    /// Plant time of the sample, s.
    pub fn t_s(&self) -> f64 {
        ns_to_s(self.sample_time_ns)
    }

    /// True when the cycle did not send a verified PANOC plan: the safety layer chose a
    /// fallback or sent a best-effort candidate (or, without the layer, PANOC failed
    /// numerically and the previous plan was flown).
    pub fn is_fallback(&self) -> bool {
        match self.decision {
            Some(d) => self.best_effort || d.is_fallback(),
            None => self.solve.status == SolveStatus::NumericalFailure,
        }
    }

    /// What the cycle sent as `decisions` and the per-cycle CSV name it: `panoc`, `qp`,
    /// `shifted_plan`, `brake`, or `best_effort` when no candidate passed the checks (empty
    /// when the safety layer is off).
    pub fn decision_label(&self) -> &'static str {
        match self.decision {
            None => "",
            Some(_) if self.best_effort => BEST_EFFORT,
            Some(d) => d.name(),
        }
    }
}

/// What `docs/spec.md` asks to report per run.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RunSummary {
    pub scenario: String,
    pub controller: String,
    pub reached: bool,
    pub collided: bool,
    /// Why the run ended (`summary.json`'s `end_reason`): decided once, by
    /// [`crate::end::finish_at`] or the driver's error.
    pub end_reason: RunEnd,
    pub time_to_goal_s: Option<f64>,
    pub end_time_s: f64,
    pub path_length_m: f64,
    /// Smallest true clearance to any cylinder surface on the plant, m (negative: collision).
    pub min_clearance_m: f64,
    pub cycles: u64,
    pub solve_ms_mean: f64,
    /// The solve times summed over the records, s (0 without records, as for an external
    /// controller, whose solver the bench cannot see): the one definition of a run's solver
    /// time.
    pub solver_s: f64,
    pub solve_ms_median: f64,
    pub solve_ms_p95: f64,
    pub solve_ms_max: f64,
    pub iterations_median: f64,
    /// Cycles that did not send a verified PANOC plan (see [`CycleRecord::is_fallback`]).
    pub fallbacks: u64,
    /// Cycles per decision of the safety layer (`panoc`, `qp`, `shifted_plan`, `brake`,
    /// `best_effort`; every one listed, zeros included, when the layer was on; empty when it
    /// was off). They sum to `cycles`.
    pub decisions: BTreeMap<String, u64>,
    /// Cycles that sent a command no check verified (`decisions["best_effort"]`).
    pub best_effort_cycles: u64,
    /// Commands the network dropped (each cycle's own, [`CycleRecord::command_lost`]); `None`
    /// where the bench does not see the commands (an external controller: its own and
    /// netem's counts are its run's `external` facts).
    pub commands_lost: Option<u64>,
    /// Why the run went as it did, when it did not simply reach its goal with verified
    /// commands: one sentence per finding (best-effort streaks with their reason, solves at
    /// the iteration limit, a vehicle that never moved). Empty for a clean run.
    pub explanation: Vec<String>,
    /// QP cost minus PANOC cost on the nonlinear model, over the cycles where both were
    /// evaluated (positive: PANOC's plan is cheaper).
    pub cost_gap: GapSummary,
    /// Cycles that stopped at the iteration limit, their plans clear or not.
    pub iteration_limits: u64,
    /// Of `iteration_limits`, the cycles whose plan was predicted inside a cylinder
    /// ([`SolveStatus::InfeasibleAtLimit`]).
    pub infeasible_at_limit: u64,
    pub final_position_m: [f64; 3],
    /// The plant's last state (position, velocity, roll, pitch): where the MCAP log's last
    /// pose comes from. Not a `summary.json` key (`final_position_m` is).
    #[serde(skip)]
    pub final_state: [f64; 8],
    /// Every entry into a cylinder or the ground.
    pub collisions: Vec<CollisionSummary>,
}

/// What a run that flew to its end amounts to when runs are counted (the bench's verdict names
/// it): a collision first, whatever ended the run, then the goal; anything else missed it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunOutcome {
    Collided,
    Reached,
    Missed,
}

impl RunSummary {
    /// Every collision of the run, described (kind, depth, time, place), `; `-separated.
    pub fn collisions_text(&self) -> String {
        self.collisions.iter().map(|c| c.describe()).collect::<Vec<_>>().join("; ")
    }

    /// The run counted (see [`RunOutcome`]).
    pub fn outcome(&self) -> RunOutcome {
        if self.collided {
            RunOutcome::Collided
        } else if self.reached {
            RunOutcome::Reached
        } else {
            RunOutcome::Missed
        }
    }
}

/// Statistics of the cross-check's cost gap.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct GapSummary {
    /// Cycles where both costs were evaluated.
    pub cycles: u64,
    pub median: Option<f64>,
    pub min: Option<f64>,
    pub max: Option<f64>,
}

impl GapSummary {
    pub fn of(gaps: &[f64]) -> Self {
        let mut g = gaps.to_vec();
        let stat = |g: &mut [f64], p: f64| (!g.is_empty()).then(|| percentile(g, p));
        Self {
            cycles: g.len() as u64,
            median: stat(&mut g, 50.0),
            min: g.iter().copied().reduce(f64::min),
            max: stat(&mut g, 100.0),
        }
    }
}

/// One collision event of a run.
#[derive(Debug, Clone, serde::Serialize)]
pub struct CollisionSummary {
    /// `cylinder` or `ground`.
    pub kind: String,
    /// Index of the cylinder (none for the ground).
    pub obstacle_index: Option<u32>,
    pub time_s: f64,
    pub position_m: [f64; 3],
    /// The deepest it went during this contact, m.
    pub depth_m: f64,
}

impl CollisionSummary {
    /// One phrase: what was hit, how deep, when and where, e.g. "cylinder 1, 52.0 mm deep, at
    /// 3.61 s, at [1.02, 3.40, 0.98] m".
    pub fn describe(&self) -> String {
        let what = match self.obstacle_index {
            Some(i) => format!("{} {i}", self.kind),
            None => self.kind.clone(),
        };
        let p = self.position_m;
        format!(
            "{what}, {} deep, at {:.2} s, at [{:.2}, {:.2}, {:.2}] m",
            Millimetres(self.depth_m),
            self.time_s,
            p[0],
            p[1],
            p[2]
        )
    }
}

/// A length given in m, printed in mm: to 0.1 mm from 0.1 mm up, below that in two significant
/// digits (`2.3e-4 mm`: a graze is never printed as `0.000`), `0` for zero; `{:+}` signs it.
/// Depths and clearances are millimetres to centimetres, where metres to three decimals print
/// a touch as `0.000 m deep` and a graze as `-0.000`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Millimetres(pub f64);

impl std::fmt::Display for Millimetres {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mm = self.0 * 1000.0;
        let sign = if mm.is_sign_negative() && mm != 0.0 {
            "-"
        } else if f.sign_plus() && mm != 0.0 {
            "+"
        } else {
            ""
        };
        let text = if !mm.is_finite() {
            format!("{}", mm.abs())
        } else if mm == 0.0 {
            "0".to_string()
        } else if mm.abs() >= 0.1 {
            format!("{:.1}", mm.abs())
        } else {
            format!("{:.1e}", mm.abs())
        };
        f.pad(&format!("{sign}{text} mm"))
    }
}

/// Nearest-rank percentile of a slice (sorted in place); NaN when empty.
pub fn percentile(values: &mut [f64], p: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    let rank = ((p / 100.0) * values.len() as f64).ceil() as usize;
    values[rank.clamp(1, values.len()) - 1]
}

/// The decision label of a cycle that sent a candidate no check verified.
pub const BEST_EFFORT: &str = "best_effort";

/// Cycles per decision label (every label listed, zeros included, when the layer was on).
pub fn decision_counts(records: &[CycleRecord]) -> BTreeMap<String, u64> {
    let mut counts = BTreeMap::new();
    for r in records.iter().filter(|r| r.decision.is_some()) {
        if counts.is_empty() {
            for d in [Decision::Panoc, Decision::Qp, Decision::ShiftedPlan, Decision::Brake] {
                counts.insert(d.name().to_string(), 0);
            }
            counts.insert(BEST_EFFORT.to_string(), 0);
        }
        *counts.entry(r.decision_label().to_string()).or_insert(0) += 1;
    }
    counts
}

/// A path shorter than this means the vehicle never left its start, m.
const NEVER_MOVED_M: f64 = 0.05;

/// Cycles in a row that [`sinking_under_hover`] needs.
const SINKING_CYCLES: usize = 5;
/// A vertical speed below this is sinking, m/s.
const SINKING_MPS: f64 = -0.3;

/// The vehicle sinking for [`SINKING_CYCLES`] sampled cycles in a row while each command asked
/// for at least hover (the thrust's vertical part at least gravity): what a vehicle does whose
/// hover thrust is not the one the gateway maps `T = g` to. The model's plant cannot do it
/// (its thrust is the model's), so on a simulated plant this finding never appears.
fn sinking_under_hover(records: &[CycleRecord]) -> Option<String> {
    let g = mav::ModelParams::default().gravity_mps2;
    let mut streak = 0;
    for r in records {
        let [t, roll, pitch] = r.command;
        let lifts = t * roll.cos() * pitch.cos() >= g;
        streak = if lifts && r.state[5] < SINKING_MPS { streak + 1 } else { 0 };
        if streak == SINKING_CYCLES {
            return Some(format!(
                "the vehicle sank ({:.2} m/s at {:.2} s) while {SINKING_CYCLES} commands in a row asked \
                 for at least hover thrust: a vehicle does this when its hover thrust is not the \
                 gateway's --hover-thrust (docs/gateway.md, \"What to check first\")",
                r.state[5],
                r.t_s()
            ));
        }
    }
    None
}

/// A ground contact within [`EARLY_GROUND_S`] of the start, before the controller could have
/// flown anywhere, while the first command asked for at least hover: the vehicle was already
/// sinking when the run began (armed on a hover thrust other than the gateway's), which ends
/// the run before [`sinking_under_hover`] has its cycles.
fn ground_at_the_start(records: &[CycleRecord], last: &PlantSample) -> Option<String> {
    let g = mav::ModelParams::default().gravity_mps2;
    let contact = last.collisions.iter().find(|c| c.obstacle_index == mav::GROUND_INDEX)?;
    let at_s = mav::ns_to_s(contact.time_ns);
    let first = records.first()?;
    let [t, roll, pitch] = first.command;
    (at_s <= EARLY_GROUND_S && t * roll.cos() * pitch.cos() >= g).then(|| {
        format!(
            "the vehicle touched the ground {at_s:.2} s after the start while the first command asked \
             for at least hover thrust (vertical speed {:.2} m/s at the first sample): a vehicle \
             already sinking when the run began does this, when its hover thrust is not the \
             gateway's --hover-thrust (docs/gateway.md, \"What to check first\")",
            first.state[5]
        )
    })
}

/// A ground contact this soon after the start is the vehicle's doing, not the controller's, s.
const EARLY_GROUND_S: f64 = 0.5;

/// The findings of [`RunSummary::explanation`], from the records and the plant's last sample.
pub fn explain(records: &[CycleRecord], last: &PlantSample, reached: bool) -> Vec<String> {
    let mut out = Vec::new();
    let cycles = records.len();
    let best_effort = records.iter().filter(|r| r.best_effort).count();
    if best_effort > 0 {
        // The longest streak of unverified cycles, and the reason of its last cycle: the
        // stretch in which the vehicle flew on commands nothing had checked.
        let (mut longest, mut current, mut end) = (0usize, 0usize, 0usize);
        for (i, r) in records.iter().enumerate() {
            current = if r.best_effort { current + 1 } else { 0 };
            if current > longest {
                (longest, end) = (current, i);
            }
        }
        let r = &records[end];
        out.push(format!(
            "{best_effort} of {cycles} cycles sent a command that failed the safety check (best effort); \
             the longest streak, {longest} cycles, ended at {:.2} s with {}",
            r.t_s(),
            r.reason
        ));
    }
    let limits = records.iter().filter(|r| r.solve.status.at_iteration_limit()).count();
    if limits > 0 && (2 * limits >= cycles || !reached || last.collided) {
        let inside = records.iter().filter(|r| r.solve.status == SolveStatus::InfeasibleAtLimit).count();
        let of_them =
            if inside > 0 { format!(", {inside} with plans inside a cylinder") } else { String::new() };
        out.push(format!("{limits} of {cycles} solves stopped at the iteration limit{of_them}"));
    }
    let numerical = records.iter().filter(|r| r.solve.status == SolveStatus::NumericalFailure).count();
    if numerical > 0 {
        out.push(format!("{numerical} of {cycles} solves failed numerically"));
    }
    if last.collided && best_effort == 0 && records.iter().any(|r| r.decision.is_some()) {
        out.push(
            "every command sent had passed the safety check against the controller's predictions".to_string(),
        );
    }
    if !reached && last.path_length_m < NEVER_MOVED_M {
        out.push(format!("the vehicle never left its start (path {:.2} m)", last.path_length_m));
    }
    if let Some(sink) = sinking_under_hover(records) {
        out.push(sink);
    } else if let Some(early) = ground_at_the_start(records, last) {
        out.push(early);
    }
    if let Some(r) = records.iter().find(|r| r.watchdog_hover) {
        let n = records.iter().filter(|r| r.watchdog_hover).count();
        out.push(format!(
            "the plant's watchdog held hover at {n} sampled cycles (the first at {:.2} s): commands \
             arrived late or not at all",
            r.t_s()
        ));
    }
    out
}

/// The run's numbers: the trajectory's from the plant's last sample (`last`), the solver's from
/// the records; `end` is how the run ended (from [`crate::end::finish_at`], or
/// [`RunEnd::Error`] for a run that failed). `controller` names what flew it (a mode's name,
/// or the bench's name for a controller that is not ours).
pub fn summarize(
    scenario: &str,
    controller: &str,
    records: &[CycleRecord],
    last: &PlantSample,
    end: RunEnd,
) -> RunSummary {
    let time_to_goal_ns = end.time_to_goal_ns();
    let mut solve_ms: Vec<f64> = records.iter().map(|r| r.solve.solve_ms).collect();
    let mut iterations: Vec<f64> = records.iter().map(|r| r.solve.iterations as f64).collect();
    let mean =
        if solve_ms.is_empty() { f64::NAN } else { solve_ms.iter().sum::<f64>() / solve_ms.len() as f64 };
    let x = &last.state;
    RunSummary {
        scenario: scenario.to_string(),
        controller: controller.to_string(),
        reached: time_to_goal_ns.is_some(),
        end_reason: end,
        collided: last.collided,
        time_to_goal_s: time_to_goal_ns.map(ns_to_s),
        end_time_s: ns_to_s(last.time_ns),
        path_length_m: last.path_length_m,
        min_clearance_m: last.min_clearance_m,
        cycles: records.len() as u64,
        solve_ms_mean: mean,
        solver_s: solve_ms.iter().sum::<f64>() * 1e-3,
        solve_ms_median: percentile(&mut solve_ms, 50.0),
        solve_ms_p95: percentile(&mut solve_ms, 95.0),
        solve_ms_max: percentile(&mut solve_ms, 100.0),
        iterations_median: percentile(&mut iterations, 50.0),
        fallbacks: records.iter().filter(|r| r.is_fallback()).count() as u64,
        decisions: decision_counts(records),
        best_effort_cycles: records.iter().filter(|r| r.best_effort).count() as u64,
        commands_lost: Some(records.iter().filter(|r| r.command_lost).count() as u64),
        explanation: explain(records, last, time_to_goal_ns.is_some()),
        cost_gap: GapSummary::of(&records.iter().filter_map(|r| r.cost_gap).collect::<Vec<_>>()),
        iteration_limits: records.iter().filter(|r| r.solve.status.at_iteration_limit()).count() as u64,
        infeasible_at_limit: records
            .iter()
            .filter(|r| r.solve.status == SolveStatus::InfeasibleAtLimit)
            .count() as u64,
        final_position_m: [x[0], x[1], x[2]],
        final_state: last.state.into(),
        collisions: last
            .collisions
            .iter()
            .map(|c| CollisionSummary {
                kind: match c.kind {
                    CollisionKind::Cylinder => "cylinder".to_string(),
                    CollisionKind::Ground => "ground".to_string(),
                },
                obstacle_index: (c.kind == CollisionKind::Cylinder).then_some(c.obstacle_index),
                time_s: ns_to_s(c.time_ns),
                position_m: c.position_m,
                depth_m: c.depth_m,
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::ControllerMode;

    #[test]
    fn millimetres_print_a_graze_in_two_digits_never_as_zero_and_sign_on_request() {
        let mm = |m: f64| format!("{}", Millimetres(m));
        let signed = |m: f64| format!("{:+}", Millimetres(m));
        assert_eq!(mm(0.052), "52.0 mm");
        assert_eq!(mm(0.0001), "0.1 mm");
        assert_eq!(mm(2.3e-7), "2.3e-4 mm");
        assert_eq!(mm(0.0), "0 mm");
        assert_eq!(mm(-0.0), "0 mm");
        assert_eq!(signed(-4e-8), "-4.0e-5 mm", "a graze inside keeps its sign");
        assert_eq!(signed(0.123), "+123.0 mm");
        assert_eq!(signed(0.0), "0 mm");
        assert_eq!(mm(f64::INFINITY), "inf mm");
        assert_eq!(format!("{:>10}", Millimetres(0.001)), "    1.0 mm", "pads as a column");
        let touch = CollisionSummary {
            kind: "ground".into(),
            obstacle_index: None,
            time_s: 4.25,
            position_m: [1.0, 2.0, -1e-9],
            depth_m: 1e-9,
        };
        assert_eq!(touch.describe(), "ground, 1.0e-6 mm deep, at 4.25 s, at [1.00, 2.00, -0.00] m");
    }

    /// A cycle at `t_s` that sent `command` from a state sinking at `vz_mps`.
    fn cycle(k: u64, vz_mps: f64, command: [f64; 3]) -> CycleRecord {
        let mut state = [0.0; 8];
        state[2] = 1.0;
        state[5] = vz_mps;
        CycleRecord {
            cycle: k,
            sample_time_ns: k * 50_000_000,
            state,
            watchdog_hover: false,
            command,
            command_seq: k + 1,
            known_delay_s: None,
            injected_delay_s: None,
            command_lost: false,
            weights: vec![],
            solve: SolveStats {
                status: SolveStatus::Converged,
                iterations: 1,
                solve_ms: 0.1,
                cost: 0.0,
                constraint_violation: 0.0,
                min_clearance_m: f64::INFINITY,
            },
            decision: None,
            best_effort: false,
            reason: String::new(),
            cost_gap: None,
            predictions: vec![],
        }
    }

    #[test]
    fn solves_at_the_limit_inside_a_cylinder_are_counted_apart_and_among_the_iteration_limits() {
        let mut records: Vec<CycleRecord> = (0..6).map(|k| cycle(k, 0.0, [9.81, 0.0, 0.0])).collect();
        records[1].solve.status = SolveStatus::IterationLimit;
        records[2].solve.status = SolveStatus::InfeasibleAtLimit;
        records[2].solve.min_clearance_m = -0.04;
        records[3].solve.status = SolveStatus::InfeasibleAtLimit;
        records[4].solve.status = SolveStatus::Deadline;
        let scenario = mav::Scenario::paper_1();
        let mut last = mav::PlantSim::new(&scenario, mav::SimSettings::default()).expect("valid").sample();
        last.path_length_m = 1.0;
        let s = summarize("paper-1", ControllerMode::Multistage.name(), &records, &last, RunEnd::TimeLimit);
        assert_eq!((s.iteration_limits, s.infeasible_at_limit), (3, 2));
        assert!(
            s.explanation
                .iter()
                .any(|e| e == "3 of 6 solves stopped at the iteration limit, 2 with plans inside a cylinder"),
            "{:?}",
            s.explanation
        );
    }

    #[test]
    fn sinking_while_commanded_at_least_hover_points_at_the_hover_thrust_and_sinking_on_less_does_not() {
        let hover = [9.9, 0.0, 0.0];
        let sinking: Vec<CycleRecord> = (0..8).map(|k| cycle(k, -0.5 - 0.1 * k as f64, hover)).collect();
        let said = sinking_under_hover(&sinking).expect("a finding");
        assert!(said.contains("--hover-thrust") && said.contains("0.20 s"), "{said}");
        // Commanded below hover (the controller asked to descend): no finding.
        let descending: Vec<CycleRecord> = (0..8).map(|k| cycle(k, -0.5, [8.0, 0.0, 0.0])).collect();
        assert_eq!(sinking_under_hover(&descending), None);
        // Four cycles in a row are not enough; a tilt that takes the vertical part under g neither.
        let short: Vec<CycleRecord> =
            (0..8).map(|k| cycle(k, if k == 4 { 0.0 } else { -0.5 }, hover)).collect();
        assert_eq!(sinking_under_hover(&short), None);
        let tilted: Vec<CycleRecord> = (0..8).map(|k| cycle(k, -0.5, [9.9, 0.3, 0.0])).collect();
        assert_eq!(sinking_under_hover(&tilted), None);
    }

    #[test]
    fn a_ground_contact_right_after_the_start_under_hover_thrust_points_at_the_hover_thrust() {
        let mut sim =
            mav::PlantSim::new(&mav::Scenario::paper_2(), mav::SimSettings::default()).expect("sim");
        let mut last = sim.sample();
        let ground = |time_ns| mav::CollisionEvent {
            kind: mav::CollisionKind::Ground,
            obstacle_index: mav::GROUND_INDEX,
            time_ns,
            position_m: [3.2, 0.0, -0.01],
            penetration_m: 0.01,
            depth_m: 0.01,
        };
        last.collisions = vec![ground(100_000_000)];
        let first = vec![cycle(0, -0.6, [9.9, 0.0, 0.0])];
        let said = ground_at_the_start(&first, &last).expect("a finding");
        assert!(said.contains("0.10 s after the start") && said.contains("--hover-thrust"), "{said}");
        assert!(explain(&first, &last, false).iter().any(|f| f.contains("--hover-thrust")));
        // Later, or on a command below hover (the controller landed it): the controller's doing.
        last.collisions = vec![ground(2_000_000_000)];
        assert_eq!(ground_at_the_start(&first, &last), None);
        last.collisions = vec![ground(100_000_000)];
        assert_eq!(ground_at_the_start(&[cycle(0, -0.6, [8.0, 0.0, 0.0])], &last), None);
    }
}
