//! Conversions of the controller API messages (see the module above for the rules).

use mav::Scenario;
use mpc::{ControllerMode, Decision, QpReport, SolveReport, SolveStatus};

use super::FieldError;
use super::plant::MAX_ABS_POSITION_M;
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
    if r.scenario.is_empty() {
        return Err(FieldError::new("scenario", "is required"));
    }
    let scenario = super::plant::scenario_by_name("scenario", &r.scenario)?;
    let mode = mode_from_pb("mode", &r.mode)?;
    Ok((scenario, mode))
}

impl From<SolveStatus> for pb::SolveStatus {
    fn from(s: SolveStatus) -> Self {
        match s {
            SolveStatus::Converged => Self::Converged,
            SolveStatus::IterationLimit => Self::IterationLimit,
            SolveStatus::Deadline => Self::Deadline,
            SolveStatus::NumericalFailure => Self::NumericalFailure,
        }
    }
}

impl From<&SolveReport> for pb::SolveStats {
    fn from(r: &SolveReport) -> Self {
        Self {
            status: pb::SolveStatus::from(r.status) as i32,
            iterations: u32::try_from(r.iterations).unwrap_or(u32::MAX),
            solve_ms: r.solve_time.as_secs_f64() * 1e3,
            cost: r.cost,
            constraint_violation: r.constraint_violation,
            min_clearance_m: if r.min_clearance_m.is_finite() { r.min_clearance_m } else { f64::MAX },
        }
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
    fn scenarios_and_modes_are_validated_by_field() {
        let r = pb::SetScenarioRequest { scenario: "paper-2".into(), mode: "nmpc".into() };
        let (s, m) = scenario_from_pb(&r).expect("valid");
        assert_eq!((s.name.as_str(), m), ("paper-2", Some(ControllerMode::Nmpc)));
        let r = pb::SetScenarioRequest { scenario: "paper-7".into(), mode: String::new() };
        assert_eq!(scenario_from_pb(&r).map_err(|e| e.field), Err("scenario".to_string()));
        let r = pb::SetScenarioRequest { scenario: "paper-1".into(), mode: "fast".into() };
        assert_eq!(scenario_from_pb(&r).map_err(|e| e.field), Err("mode".to_string()));
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
