//! The whole-scenario message (`hilbench.v1.Scenario`) both ways: what `Reset`,
//! `SetScenario`, `Describe` and `GetStatus` carry, so that a scenario of the user's own
//! reaches the plant and the controller exactly as a built-in one does. Validation is
//! `mav::Scenario::validate`, the scenario file loader's too, with the field named as a path
//! into the message (`definition.obstacles[2].radius_m`).

use delay::DelaysTable;
use mav::{Scenario, ScenarioError};

use super::{FieldError, finite_array, required};
use crate::pb;

impl From<&Scenario> for pb::Scenario {
    fn from(s: &Scenario) -> Self {
        Self {
            name: s.name.clone(),
            model: Some((&s.model).into()),
            limits: Some((&s.bounds).into()),
            obstacles: s.obstacles.iter().map(Into::into).collect(),
            start: Some(pb::MavState { x: s.start.to_vec() }),
            goal_m: s.goal_m.to_vec(),
            q_x: s.q_x.to_vec(),
            q_u: s.q_u.to_vec(),
            q_du: s.q_du.to_vec(),
            horizon: u32::try_from(s.horizon).unwrap_or(u32::MAX),
            nmpc_sampling_time_s: s.nmpc_sampling_time_s,
            sampling_times_s: s.sampling_times_s.clone(),
            nominal_weights: s.nominal_weights.clone(),
            prior_gamma_shape: s.prior_gamma.0,
            prior_gamma_scale_s: s.prior_gamma.1,
            delay_window: u32::try_from(s.delay_window).unwrap_or(u32::MAX),
            // A validated scenario's network always converts (its traces are inline).
            delays: s.delays.is_none().then(|| pb::RoundTripDelay {
                kind: "measured".into(),
                shape: 0.0,
                scale_s: 0.0,
            }),
            network: s.network().ok().flatten().map(|n| pb::NetworkDelays {
                to_plant: Some((&n.to_plant).into()),
                to_controller: Some((&n.to_controller).into()),
            }),
            seed: s.seed,
            min_cycle_s: s.min_cycle_s,
            goal_tolerance_m: s.goal_tolerance_m,
            goal_speed_tolerance_mps: s.goal_speed_tolerance_mps,
            max_duration_s: s.max_duration_s,
            ground_z_m: s.ground_z_m,
            min_altitude_m: s.min_altitude_m,
            delay_compensation: s.delay_compensation,
            obstacle_margin_m: s.obstacle_margin_m,
            fail_safe: s.fail_safe,
            continue_after_collision: s.continue_after_collision,
            solver: s.solver.map(|v| v.name().to_string()).unwrap_or_default(),
        }
    }
}

/// The scenario's delay process from the wire: `network` when set (validated as netem's
/// profiles are; its seeds are the scenario's), else the round trip of `delays`.
fn delays_from_pb(
    d: Option<&pb::RoundTripDelay>,
    network: Option<&pb::NetworkDelays>,
) -> Result<Option<DelaysTable>, FieldError> {
    if let Some(n) = network {
        let to_plant = super::netem::profile_from_pb(required("network.to_plant", &n.to_plant)?)
            .map_err(|e| e.within("network.to_plant"))?;
        let to_controller =
            super::netem::profile_from_pb(required("network.to_controller", &n.to_controller)?)
                .map_err(|e| e.within("network.to_controller"))?;
        return Ok(Some(DelaysTable::from_network(&delay::NetworkProfile { to_plant, to_controller })));
    }
    let Some(d) = d else { return Ok(Some(DelaysTable::none())) };
    match d.kind.as_str() {
        "" | "none" => Ok(Some(DelaysTable::none())),
        "gamma" => Ok(Some(DelaysTable::gamma(d.shape, d.scale_s))),
        "measured" => Ok(None),
        other => Err(FieldError::new(
            "delays.kind",
            format!(
                "unknown kind {other:?} (known: none, gamma, measured; any other kind goes in `network`)"
            ),
        )),
    }
}

/// The message's wire path of a field that `Scenario::validate` names.
fn wire_field(field: &str) -> String {
    match field.strip_prefix("bounds") {
        Some(rest) => format!("limits{rest}"),
        None => field.to_string(),
    }
}

impl TryFrom<&pb::Scenario> for Scenario {
    type Error = FieldError;

    /// Every field checked (lengths, finiteness, magnitudes, consistency); the error's field is
    /// relative to the message.
    fn try_from(m: &pb::Scenario) -> Result<Self, FieldError> {
        let name = m.name.trim();
        if name.is_empty() || name != m.name || name.len() > 256 {
            return Err(FieldError::new(
                "name",
                format!("must be a non-empty name of at most 256 characters, got {:?}", m.name),
            ));
        }
        let model =
            mav::ModelParams::try_from(required("model", &m.model)?).map_err(|e| e.within("model"))?;
        let bounds =
            mav::InputBounds::try_from(required("limits", &m.limits)?).map_err(|e| e.within("limits"))?;
        let obstacles = m
            .obstacles
            .iter()
            .enumerate()
            .map(|(i, c)| mav::Cylinder::try_from(c).map_err(|e| e.within(&format!("obstacles[{i}]"))))
            .collect::<Result<Vec<_>, _>>()?;
        let scenario = Scenario {
            name: m.name.clone(),
            model,
            bounds,
            obstacles,
            start: finite_array::<8>("start.x", &required("start", &m.start)?.x)?,
            goal_m: finite_array::<3>("goal_m", &m.goal_m)?,
            q_x: finite_array::<8>("q_x", &m.q_x)?,
            q_u: finite_array::<3>("q_u", &m.q_u)?,
            q_du: finite_array::<3>("q_du", &m.q_du)?,
            horizon: m.horizon as usize,
            nmpc_sampling_time_s: m.nmpc_sampling_time_s,
            sampling_times_s: m.sampling_times_s.clone(),
            nominal_weights: m.nominal_weights.clone(),
            prior_gamma: (m.prior_gamma_shape, m.prior_gamma_scale_s),
            delay_window: m.delay_window as usize,
            delays: delays_from_pb(m.delays.as_ref(), m.network.as_ref())?,
            seed: m.seed,
            min_cycle_s: m.min_cycle_s,
            goal_tolerance_m: m.goal_tolerance_m,
            goal_speed_tolerance_mps: m.goal_speed_tolerance_mps,
            max_duration_s: m.max_duration_s,
            ground_z_m: m.ground_z_m,
            min_altitude_m: m.min_altitude_m,
            delay_compensation: m.delay_compensation,
            obstacle_margin_m: m.obstacle_margin_m,
            fail_safe: m.fail_safe,
            continue_after_collision: m.continue_after_collision,
            solver: match m.solver.as_str() {
                "" => None,
                name => Some(mav::PanocSolver::parse(name).ok_or_else(|| {
                    FieldError::new("solver", format!("must be empty, \"open\" or \"own\", got {name:?}"))
                })?),
            },
        };
        scenario.validate().map_err(|e| match e {
            ScenarioError::Invalid { field, reason } => FieldError::new(wire_field(&field), reason),
            other => FieldError::new("name", other.to_string()),
        })?;
        Ok(scenario)
    }
}

/// The scenario a request names: a whole `definition` when given (a `name` beside it must be
/// its name), else the built-in `name`, else `None` (keep the current one). Errors name
/// `name_field` or `definition_field.<path>`.
pub fn scenario_choice(
    name_field: &str,
    name: &str,
    definition_field: &str,
    definition: Option<&pb::Scenario>,
) -> Result<Option<Scenario>, FieldError> {
    match definition {
        Some(d) => {
            let scenario = Scenario::try_from(d).map_err(|e| e.within(definition_field))?;
            if !name.is_empty() && name != scenario.name {
                return Err(FieldError::new(
                    name_field,
                    format!("{name:?} differs from {definition_field}.name {:?}", scenario.name),
                ));
            }
            Ok(Some(scenario))
        }
        None if name.is_empty() => Ok(None),
        None if name.trim() != name || name.len() > 256 => {
            Err(FieldError::new(name_field, format!("is not a scenario name: {name:?}")))
        }
        None => Scenario::by_name(name).map(Some).map_err(|e| FieldError::new(name_field, e.to_string())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_built_in_scenario_and_a_file_like_one_round_trip_exactly() {
        let mut custom = Scenario::paper_2();
        custom.name = "custom".into();
        custom.min_altitude_m = Some(0.3);
        custom.obstacle_margin_m = Some(0.2);
        custom.delay_compensation = true;
        custom.fail_safe = true;
        custom.continue_after_collision = true;
        custom.solver = Some(mav::PanocSolver::Own);
        custom.delays = Some(DelaysTable::none());
        let mut measured = custom.clone();
        measured.delays = None;
        let mut bursty = custom.clone();
        let regime = "kind = \"regime\"\nloss_probability = 0.05\n[[states]]\nkind = \"constant\"\ndelay_s = 0.02\nmean_dwell_messages = 20.0\n[[states]]\nkind = \"lognormal\"\nmean_s = 0.2\nstd_s = 0.1\nmean_dwell_s = 1.5";
        bursty.delays = Some(toml::from_str(regime).expect("a delays table"));
        let mut split = custom.clone();
        let both = "[to_plant]\nkind = \"trace\"\nfile = \"wifi.csv\"\ndelays_s = [0.1, 0.25]\n[to_controller]\nkind = \"uniform\"\nmin_s = 0.0\nmax_s = 0.1\nordering = \"independent\"";
        split.delays = Some(toml::from_str(both).expect("a delays table"));
        let built_in = Scenario::BUILT_IN.iter().map(|n| Scenario::by_name(n).expect("built in"));
        for s in built_in.chain([custom, measured, bursty, split]) {
            assert_eq!(s.validate(), Ok(()));
            let back = Scenario::try_from(&pb::Scenario::from(&s)).expect("valid");
            assert_eq!(back, s);
        }
    }

    #[test]
    fn wire_arrays_of_another_length_and_names_with_paths_are_invalid_arguments_naming_the_field() {
        let refused = |m: &pb::Scenario| -> (String, String) {
            let e = scenario_choice("scenario", "", "definition", Some(m)).map(|_| ()).expect_err("refused");
            let status = tonic::Status::from(e.clone());
            assert_eq!(status.code(), tonic::Code::InvalidArgument, "{e}");
            (e.field, e.reason)
        };
        let good = pb::Scenario::from(&Scenario::paper_2());
        let mut m = good.clone();
        if let Some(start) = m.start.as_mut() {
            start.x.push(0.0);
        }
        assert_eq!(refused(&m), ("definition.start.x".into(), "must hold exactly 8 values, got 9".into()));
        let mut m = good.clone();
        m.goal_m.extend([0.0, 0.0]);
        assert_eq!(refused(&m).0, "definition.goal_m");
        let mut m = good.clone();
        m.q_u.push(1.0);
        assert_eq!(refused(&m), ("definition.q_u".into(), "must hold exactly 3 values, got 4".into()));
        let mut m = good.clone();
        m.q_du.truncate(2);
        assert_eq!(refused(&m).0, "definition.q_du");
        for name in ["../../escape", "a/b", "x y"] {
            let mut m = good.clone();
            m.name = name.into();
            assert_eq!(refused(&m).0, "definition.name", "{name}");
        }
        let mut m = good.clone();
        m.min_cycle_s = 1e-300;
        assert_eq!(refused(&m).0, "definition.min_cycle_s");
        // A huge value is echoed short, not as 301 digits.
        let mut m = good.clone();
        m.min_cycle_s = 1e300;
        let (field, reason) = refused(&m);
        assert_eq!(field, "definition.min_cycle_s");
        assert!(reason.contains("1e300") && reason.len() < 160, "{reason}");
    }

    #[test]
    fn a_bad_scenario_is_refused_with_the_path_of_the_field() {
        let field = |m: &pb::Scenario| {
            scenario_choice("scenario", "", "definition", Some(m)).map(|_| ()).map_err(|e| e.field)
        };
        let good = pb::Scenario::from(&Scenario::paper_2());
        let mut m = good.clone();
        m.obstacles[0].x_m = 1e300;
        assert_eq!(field(&m), Err("definition.obstacles[0].x_m".into()));
        let mut m = good.clone();
        m.obstacles[0].radius_m = -1.0;
        assert_eq!(field(&m), Err("definition.obstacles[0].radius_m".into()));
        let mut m = good.clone();
        m.q_x.pop();
        assert_eq!(field(&m), Err("definition.q_x".into()));
        let mut m = good.clone();
        m.goal_m[1] = f64::NAN;
        assert_eq!(field(&m), Err("definition.goal_m[1]".into()));
        let mut m = good.clone();
        m.limits = None;
        assert_eq!(field(&m), Err("definition.limits".into()));
        let mut m = good.clone();
        m.network = None;
        m.delays = Some(pb::RoundTripDelay { kind: "lognormal".into(), shape: 1.0, scale_s: 1.0 });
        assert_eq!(field(&m), Err("definition.delays.kind".into()));
        let mut m = good.clone();
        if let Some(p) = m.network.as_mut().and_then(|n| n.to_plant.as_mut()) {
            p.loss_probability = 1.5;
        }
        assert_eq!(field(&m), Err("definition.network.to_plant.loss_probability".into()));
        let mut m = good.clone();
        if let Some(start) = m.start.as_mut() {
            start.x[2] = -1.0;
        }
        assert_eq!(field(&m), Err("definition.start[2]".into()));
        let mut m = good.clone();
        m.horizon = 0;
        assert_eq!(field(&m), Err("definition.horizon".into()));
        let mut m = good.clone();
        m.name = String::new();
        assert_eq!(field(&m), Err("definition.name".into()));
        let mut m = good.clone();
        m.solver = "OpEn".into();
        assert_eq!(field(&m), Err("definition.solver".into()));
        // A name beside a definition must agree with it.
        let r = scenario_choice("scenario", "paper-1", "definition", Some(&good));
        assert_eq!(r.map(|_| ()).map_err(|e| e.field), Err("scenario".into()));
        assert_eq!(scenario_choice("scenario", "", "definition", None), Ok(None));
        assert!(scenario_choice("scenario", "paper-9", "definition", None).is_err());
    }
}
