//! Conversions of the controller API messages (see the module above for the rules).

use mav::{PlantSample, Scenario};
use mpc::{
    ControllerMode, CycleRecord, Decision, PredictedPath, QpReport, RunEnd, SolveReport, SolveStats,
    SolveStatus,
};

use super::plant::MAX_ABS_POSITION_M;
use super::{FieldError, finite_array, required};
use crate::pb;

/// A validated `SetGoalRequest`: the new goal position, m.
pub fn goal_from_pb(r: &pb::SetGoalRequest) -> Result<[f64; 3], FieldError> {
    let goal = super::finite_array::<3>("goal_m", &r.goal_m)?;
    if let Some(i) = goal.iter().position(|v| v.abs() > MAX_ABS_POSITION_M) {
        return Err(FieldError::new(
            format!("goal_m[{i}]"),
            format!("must be within +-{MAX_ABS_POSITION_M} m"),
        ));
    }
    Ok(goal)
}

/// A controller mode by name (`nmpc`, `multistage`); empty means "keep the current one".
pub fn mode_from_pb(field: &str, name: &str) -> Result<Option<ControllerMode>, FieldError> {
    if name.is_empty() {
        return Ok(None);
    }
    ControllerMode::parse(name)
        .map(Some)
        .ok_or_else(|| FieldError::new(field, format!("unknown mode {name:?} (known: nmpc, multistage)")))
}

/// A validated `SetScenarioRequest`.
pub fn scenario_from_pb(
    r: &pb::SetScenarioRequest,
) -> Result<(Scenario, Option<ControllerMode>), FieldError> {
    let scenario =
        super::scenario::scenario_choice("scenario", &r.scenario, "definition", r.definition.as_ref())?
            .ok_or_else(|| FieldError::new("scenario", "is required (a built-in name or a definition)"))?;
    let mode = mode_from_pb("mode", &r.mode)?;
    Ok((scenario, mode))
}

/// `ControllerStatus.finish_reason` of an episode that ended with `end` (`None`: it runs).
pub fn finish_reason_to_pb(end: Option<RunEnd>) -> pb::FinishReason {
    match end {
        None => pb::FinishReason::Unspecified,
        Some(RunEnd::Reached { .. }) => pb::FinishReason::Reached,
        Some(RunEnd::TimeLimit) => pb::FinishReason::TimeLimit,
        Some(RunEnd::Collided) => pb::FinishReason::Collided,
        Some(RunEnd::Error) => pb::FinishReason::Error,
    }
}

/// How the episode of a `ControllerStatus` ended (`None`: it runs), its goal reached at
/// `final_time_ns` (the wire carries no time: the client's final sample has it).
pub fn finish_reason_from_pb(code: i32, final_time_ns: u64) -> Result<Option<RunEnd>, FieldError> {
    match pb::FinishReason::try_from(code) {
        Ok(pb::FinishReason::Unspecified) => Ok(None),
        Ok(pb::FinishReason::Reached) => Ok(Some(RunEnd::Reached { time_ns: final_time_ns })),
        Ok(pb::FinishReason::TimeLimit) => Ok(Some(RunEnd::TimeLimit)),
        Ok(pb::FinishReason::Collided) => Ok(Some(RunEnd::Collided)),
        Ok(pb::FinishReason::Error) => Ok(Some(RunEnd::Error)),
        Err(_) => Err(FieldError::new("finish_reason", format!("unknown finish reason {code}"))),
    }
}

impl From<SolveStatus> for pb::SolveStatus {
    fn from(s: SolveStatus) -> Self {
        match s {
            SolveStatus::Converged => Self::Converged,
            SolveStatus::IterationLimit => Self::IterationLimit,
            SolveStatus::InfeasibleAtLimit => Self::InfeasibleAtLimit,
            SolveStatus::Deadline => Self::Deadline,
            SolveStatus::NumericalFailure => Self::NumericalFailure,
        }
    }
}

/// The solve status a `SolveStatus` on the wire stands for.
pub fn solve_status_from_pb(field: &str, code: i32) -> Result<SolveStatus, FieldError> {
    match pb::SolveStatus::try_from(code) {
        Ok(pb::SolveStatus::Converged) => Ok(SolveStatus::Converged),
        Ok(pb::SolveStatus::IterationLimit) => Ok(SolveStatus::IterationLimit),
        Ok(pb::SolveStatus::InfeasibleAtLimit) => Ok(SolveStatus::InfeasibleAtLimit),
        Ok(pb::SolveStatus::Deadline) => Ok(SolveStatus::Deadline),
        Ok(pb::SolveStatus::NumericalFailure) => Ok(SolveStatus::NumericalFailure),
        _ => Err(FieldError::new(field, format!("unknown solve status {code}"))),
    }
}

impl From<&SolveStats> for pb::SolveStats {
    fn from(s: &SolveStats) -> Self {
        Self {
            status: pb::SolveStatus::from(s.status) as i32,
            iterations: u32::try_from(s.iterations).unwrap_or(u32::MAX),
            solve_ms: s.solve_ms,
            cost: s.cost,
            constraint_violation: s.constraint_violation,
            // +inf (no obstacle) travels as the largest double, which JSON can carry.
            min_clearance_m: if s.min_clearance_m.is_finite() { s.min_clearance_m } else { f64::MAX },
        }
    }
}

impl From<&SolveReport> for pb::SolveStats {
    fn from(r: &SolveReport) -> Self {
        pb::SolveStats::from(&SolveStats::from(r))
    }
}

impl TryFrom<&pb::SolveStats> for SolveStats {
    type Error = FieldError;

    fn try_from(s: &pb::SolveStats) -> Result<Self, FieldError> {
        if s.min_clearance_m.is_nan() || s.cost.is_nan() {
            return Err(FieldError::new("min_clearance_m", "must not be NaN"));
        }
        Ok(Self {
            status: solve_status_from_pb("status", s.status)?,
            iterations: u64::from(s.iterations),
            solve_ms: super::finite("solve_ms", s.solve_ms)?,
            cost: s.cost,
            constraint_violation: s.constraint_violation,
            min_clearance_m: if s.min_clearance_m == f64::MAX { f64::INFINITY } else { s.min_clearance_m },
        })
    }
}

/// The telemetry of one cycle: `record` with the wire sample it solved from, the episode it
/// belongs to, and the QP fallback's solve when it ran.
pub fn telemetry_of(
    record: &CycleRecord,
    sample: &pb::StateSample,
    episode: u64,
    qp: Option<&QpReport>,
) -> pb::CycleTelemetry {
    let [thrust_mps2, roll_rad, pitch_rad] = record.command;
    pb::CycleTelemetry {
        cycle: record.cycle,
        sample: Some(sample.clone()),
        command: Some(pb::ControlInput { thrust_mps2, roll_rad, pitch_rad }),
        command_seq: record.command_seq,
        scenario_weights: record.weights.clone(),
        solve: Some(pb::SolveStats::from(&record.solve)),
        solver: solver_kind(record) as i32,
        predictions: record
            .predictions
            .iter()
            .map(|p| pb::PredictedTrajectory {
                sampling_time_s: p.sampling_time_s,
                weight: p.weight,
                positions_m: p.positions_m.iter().flatten().copied().collect(),
            })
            .collect(),
        measured_delay_s: record.known_delay_s,
        injected_delay_s: record.injected_delay_s,
        command_lost: record.command_lost,
        episode,
        decision_reason: record.reason.clone(),
        best_effort: record.best_effort,
        cost_gap: record.cost_gap,
        qp: qp.map(pb::QpStats::from),
    }
}

/// What the cycle sent, as the wire names it: the safety layer's decision, or without the
/// layer PANOC (the previous plan shifted when it failed numerically).
fn solver_kind(record: &CycleRecord) -> pb::SolverKind {
    match record.decision {
        Some(d) => d.into(),
        None if record.solve.status == SolveStatus::NumericalFailure => pb::SolverKind::ShiftedPlan,
        None => pb::SolverKind::Panoc,
    }
}

impl TryFrom<&pb::CycleTelemetry> for CycleRecord {
    type Error = FieldError;

    fn try_from(t: &pb::CycleTelemetry) -> Result<Self, FieldError> {
        let sample = PlantSample::try_from(required("sample", &t.sample)?).map_err(|e| e.within("sample"))?;
        let command = required("command", &t.command)?;
        let command =
            finite_array::<3>("command", &[command.thrust_mps2, command.roll_rad, command.pitch_rad])?;
        let solve = SolveStats::try_from(required("solve", &t.solve)?).map_err(|e| e.within("solve"))?;
        // The layer gives every decision a reason; without one the layer was off.
        let decision = if t.decision_reason.is_empty() {
            None
        } else {
            Some(decision_from_pb(t.solver).ok_or_else(|| {
                FieldError::new("solver", format!("unknown decision {} with a reason", t.solver))
            })?)
        };
        let predictions = t
            .predictions
            .iter()
            .enumerate()
            .map(|(i, p)| {
                if p.positions_m.len() % 3 != 0 {
                    return Err(FieldError::new(
                        format!("predictions[{i}].positions_m"),
                        "must hold whole [x, y, z] points",
                    ));
                }
                Ok(PredictedPath {
                    sampling_time_s: p.sampling_time_s,
                    weight: p.weight,
                    positions_m: p.positions_m.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            cycle: t.cycle,
            sample_time_ns: sample.time_ns,
            state: sample.state.into(),
            watchdog_hover: sample.watchdog_hover,
            command,
            command_seq: t.command_seq,
            known_delay_s: t.measured_delay_s,
            injected_delay_s: t.injected_delay_s,
            command_lost: t.command_lost,
            weights: t.scenario_weights.clone(),
            solve,
            decision,
            best_effort: decision.is_some() && t.best_effort,
            reason: t.decision_reason.clone(),
            cost_gap: t.cost_gap,
            predictions,
        })
    }
}

impl From<Decision> for pb::SolverKind {
    fn from(d: Decision) -> Self {
        match d {
            Decision::Panoc => Self::Panoc,
            Decision::Qp => Self::QpFallback,
            Decision::ShiftedPlan => Self::ShiftedPlan,
            Decision::Brake => Self::Hover,
        }
    }
}

/// The decision a `SolverKind` on the wire stands for (`None` for `UNSPECIFIED` and unknown
/// values).
pub fn decision_from_pb(kind: i32) -> Option<Decision> {
    match pb::SolverKind::try_from(kind).ok()? {
        pb::SolverKind::Unspecified => None,
        pb::SolverKind::Panoc => Some(Decision::Panoc),
        pb::SolverKind::QpFallback => Some(Decision::Qp),
        pb::SolverKind::ShiftedPlan => Some(Decision::ShiftedPlan),
        pb::SolverKind::Hover => Some(Decision::Brake),
    }
}

impl From<&QpReport> for pb::QpStats {
    fn from(r: &QpReport) -> Self {
        Self {
            status: r.status.name().to_string(),
            iterations: r.iterations,
            solve_ms: r.solve_time.as_secs_f64() * 1e3,
            cost: r.cost,
            min_clearance_m: r.min_clearance_m,
            half_planes: u32::try_from(r.num_half_planes).unwrap_or(u32::MAX),
            elastic_violation_m: r.elastic_violation_m,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn goals_are_validated_by_field() {
        let ok = pb::SetGoalRequest { goal_m: vec![1.0, 2.0, 3.0] };
        assert_eq!(goal_from_pb(&ok), Ok([1.0, 2.0, 3.0]));
        let nan = pb::SetGoalRequest { goal_m: vec![1.0, f64::NAN, 3.0] };
        assert_eq!(goal_from_pb(&nan).map_err(|e| e.field), Err("goal_m[1]".to_string()));
        let short = pb::SetGoalRequest { goal_m: vec![1.0] };
        assert_eq!(goal_from_pb(&short).map_err(|e| e.field), Err("goal_m".to_string()));
        let far = pb::SetGoalRequest { goal_m: vec![1.0, 2.0, 1e9] };
        assert_eq!(goal_from_pb(&far).map_err(|e| e.field), Err("goal_m[2]".to_string()));
    }

    #[test]
    fn every_solve_status_crosses_the_wire_and_back_and_an_unknown_one_is_refused() {
        for status in SolveStatus::ALL {
            let code = pb::SolveStatus::from(status) as i32;
            assert_eq!(solve_status_from_pb("status", code), Ok(status));
        }
        assert_eq!(pb::SolveStatus::from(SolveStatus::InfeasibleAtLimit), pb::SolveStatus::InfeasibleAtLimit);
        assert!(solve_status_from_pb("status", 0).is_err());
        assert!(solve_status_from_pb("status", 99).is_err());
    }

    #[test]
    fn scenarios_and_modes_are_validated_by_field() {
        let r = pb::SetScenarioRequest { scenario: "paper-2".into(), mode: "nmpc".into(), definition: None };
        let (s, m) = scenario_from_pb(&r).expect("valid");
        assert_eq!((s.name.as_str(), m), ("paper-2", Some(ControllerMode::Nmpc)));
        let r = pb::SetScenarioRequest { scenario: "paper-7".into(), mode: String::new(), definition: None };
        assert_eq!(scenario_from_pb(&r).map_err(|e| e.field), Err("scenario".to_string()));
        let r = pb::SetScenarioRequest { scenario: "paper-1".into(), mode: "fast".into(), definition: None };
        assert_eq!(scenario_from_pb(&r).map_err(|e| e.field), Err("mode".to_string()));
    }

    /// Flies paper-2 from 5 cm off its first cylinder with a safety check that asks for 0.2 m of
    /// clearance, so that the first cycles are best effort, and sends every record through the
    /// wire and back.
    #[test]
    fn every_cycle_record_survives_the_wire_best_effort_and_reason_included() {
        use mav::{Input, PlantSim, Scenario, SimSettings};
        use mpc::{CycleTiming, Episode, EpisodeSettings, MpcSettings};

        let mut scenario = Scenario::paper_2();
        let c = scenario.obstacles[0];
        scenario.start = [c.x_m + c.radius_m + 0.05, c.y_m, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let mut settings = EpisodeSettings::new(ControllerMode::Multistage, MpcSettings::default());
        settings.safety.as_mut().expect("the default safety layer").required_clearance_m = 0.2;
        let mut episode = Episode::new(scenario.clone(), settings).expect("valid");
        let mut sim = PlantSim::new(&scenario, SimSettings::default()).expect("valid");
        let mut best_effort = 0;
        for _ in 0..20 {
            let sample = sim.sample();
            let out = episode.on_sample(&sample, &CycleTiming::Lockstep).expect("valid sample");
            let wire = telemetry_of(&out.record, &pb::StateSample::from(&sample), 1, None);
            let back = CycleRecord::try_from(&wire).expect("our own telemetry decodes");
            assert_eq!(back, out.record, "cycle {}", out.record.cycle);
            best_effort += usize::from(back.best_effort);
            sim.apply(Input::from(out.record.command), out.meta).expect("a sanitised command is valid");
            sim.advance(episode.min_cycle_ns(), |_| {});
        }
        assert!(best_effort > 0, "the set-up must give best-effort cycles");
    }

    #[test]
    fn decisions_round_trip_through_the_solver_kind() {
        for d in [Decision::Panoc, Decision::Qp, Decision::ShiftedPlan, Decision::Brake] {
            assert_eq!(decision_from_pb(pb::SolverKind::from(d) as i32), Some(d));
        }
        assert_eq!(decision_from_pb(0), None);
        assert_eq!(decision_from_pb(99), None);
    }
}
