//! Scenario definitions: everything `SPEC.md` pins down for one run, as validated data.
//! The three paper scenarios are built in; user scenarios come from files through serde.

use crate::geometry::Cylinder;
use crate::model::{InputBounds, ModelParams, State};

/// The round-trip delay process of a scenario.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum DelayModel {
    /// No communication delay (`d_k = 0`).
    None,
    /// `d_k ~ Gamma(shape, scale_s)`.
    Gamma { shape: f64, scale_s: f64 },
}

impl DelayModel {
    /// `SPEC.md`: Gamma(12, 0.015), mean 0.18 s.
    pub const PAPER: DelayModel = DelayModel::Gamma { shape: 12.0, scale_s: 0.015 };
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScenarioError {
    #[error("unknown scenario {0:?} (known: paper-1, paper-2, paper-3)")]
    Unknown(String),
    #[error("invalid scenario field `{field}`: {reason}")]
    Invalid { field: String, reason: String },
}

fn invalid(field: impl Into<String>, reason: impl Into<String>) -> ScenarioError {
    ScenarioError::Invalid { field: field.into(), reason: reason.into() }
}

/// One scenario of `SPEC.md`: world, vehicle, controller tuning and delay process.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Identifier, e.g. `paper-1`.
    pub name: String,
    /// Vehicle model parameters.
    #[serde(default)]
    pub model: ModelParams,
    /// Actuator limits (also the controller's input bounds).
    pub bounds: InputBounds,
    /// Vertical cylinders.
    #[serde(default)]
    pub obstacles: Vec<Cylinder>,
    /// Initial state `[px, py, pz, vx, vy, vz, phi, theta]`.
    pub start: [f64; 8],
    /// Goal position, m.
    pub goal_m: [f64; 3],
    /// State weights, diagonal of `Qx`.
    pub q_x: [f64; 8],
    /// Input weights, diagonal of `Qu`.
    pub q_u: [f64; 3],
    /// Input-rate weights, diagonal of `Qdu`.
    pub q_du: [f64; 3],
    /// Prediction horizon `N`.
    pub horizon: usize,
    /// Sampling time of the standard NMPC, s.
    pub nmpc_sampling_time_s: f64,
    /// Sampling times `ts_i` of the multi-stage scenarios, s, increasing.
    pub sampling_times_s: Vec<f64>,
    /// Scenario weights used when the run has no delays.
    pub nominal_weights: Vec<f64>,
    /// Gamma prior `(shape, scale_s)` used until the delay window is usable.
    pub prior_gamma: (f64, f64),
    /// Size of the delay window `n_max`.
    pub delay_window: usize,
    /// Round-trip delay process.
    pub delays: DelayModel,
    /// Seed of the delay generator.
    pub seed: u64,
    /// Shortest cycle period, s (`t_{k+1} = t_k + max(this, d_k)`).
    pub min_cycle_s: f64,
    /// Goal reached when `|p - p_goal|` is below this, m...
    pub goal_tolerance_m: f64,
    /// ...and `|v|` below this, m/s.
    pub goal_speed_tolerance_mps: f64,
    /// A run ends unreached after this much simulated time, s.
    pub max_duration_s: f64,
    /// Altitude of the ground, m.
    pub ground_z_m: f64,
    /// Optional floor for the controller: every predicted point keeps `z >= min_altitude_m`,
    /// m. `None` in paper mode (the paper's problem has none); scenario files turn it on at
    /// the ground by default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_altitude_m: Option<f64>,
    /// Dead-time compensation in the controller's predictions (see `mpc::OcpDefinition`).
    /// Off in paper mode; scenario files turn it on by default.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub delay_compensation: bool,
    /// Safety margin the controller adds to every cylinder radius for this scenario, m.
    /// `None`: the controller's own setting (0.1 m by default, as in paper mode).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub obstacle_margin_m: Option<f64>,
    /// The safety layer judges candidate commands with the fail-safe check over this
    /// scenario's delay range (its largest sampling time; see `mpc::fail_safe`) instead of by
    /// their plans' predictions. Off in paper mode and by default in scenario files.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub fail_safe: bool,
}

impl Scenario {
    /// Names of the built-in scenarios.
    pub const BUILT_IN: [&'static str; 3] = ["paper-1", "paper-2", "paper-3"];

    /// A built-in scenario by name.
    pub fn by_name(name: &str) -> Result<Self, ScenarioError> {
        match name {
            "paper-1" => Ok(Self::paper_1()),
            "paper-2" => Ok(Self::paper_2()),
            "paper-3" => Ok(Self::paper_3()),
            other => Err(ScenarioError::Unknown(other.to_string())),
        }
    }

    fn paper_common(name: &str) -> Self {
        let model = ModelParams::default();
        Self {
            name: name.to_string(),
            model,
            bounds: InputBounds::paper(model.gravity_mps2),
            obstacles: Vec::new(),
            start: [0.0; 8],
            goal_m: [0.0; 3],
            q_x: [0.0; 8],
            q_u: [20.0, 20.0, 20.0],
            q_du: [0.0; 3],
            horizon: 40,
            nmpc_sampling_time_s: 0.05,
            sampling_times_s: vec![0.05, 0.07, 0.1, 0.2, 0.33],
            nominal_weights: vec![0.05, 0.15, 0.45, 0.30, 0.05],
            prior_gamma: (12.0, 0.015),
            delay_window: 50,
            delays: DelayModel::PAPER,
            seed: 42,
            min_cycle_s: 0.05,
            goal_tolerance_m: 0.15,
            goal_speed_tolerance_mps: 0.2,
            max_duration_s: 60.0,
            ground_z_m: 0.0,
            min_altitude_m: None,
            delay_compensation: false,
            obstacle_margin_m: None,
            fail_safe: false,
        }
    }

    /// One large cylinder across the straight path.
    pub fn paper_1() -> Self {
        Self {
            obstacles: vec![Cylinder::new(0.0, 6.0, 1.5)],
            goal_m: [0.0, 9.0, 1.0],
            q_x: [6.0, 6.0, 20.0, 50.0, 50.0, 10.0, 20.0, 20.0],
            q_du: [40.0, 65.0, 65.0],
            ..Self::paper_common("paper-1")
        }
    }

    /// Three cylinders of different sizes, with delays.
    pub fn paper_2() -> Self {
        let mut start = [0.0; 8];
        start[0] = 3.2;
        Self {
            obstacles: vec![
                Cylinder::new(3.5, 1.5, 0.25),
                Cylinder::new(2.8, 3.0, 0.4),
                Cylinder::new(4.3, 4.1, 0.5),
            ],
            start,
            goal_m: [3.2, 5.0, 1.0],
            q_x: [12.5, 12.5, 20.0, 30.0, 30.0, 10.0, 20.0, 20.0],
            q_du: [40.0, 165.0, 165.0],
            ..Self::paper_common("paper-2")
        }
    }

    /// As paper-2, without delays.
    pub fn paper_3() -> Self {
        Self { name: "paper-3".to_string(), delays: DelayModel::None, ..Self::paper_2() }
    }

    /// The initial state as a vector.
    pub fn start_state(&self) -> State {
        State::from(self.start)
    }

    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        self.model.validate().map_err(|f| invalid(format!("model.{f}"), "must be finite and positive"))?;
        self.bounds
            .validate()
            .map_err(|f| invalid(format!("bounds.{f}"), "must be finite with min <= max"))?;
        for (i, c) in self.obstacles.iter().enumerate() {
            c.validate()
                .map_err(|f| invalid(format!("obstacles[{i}].{f}"), "must be finite and positive"))?;
        }
        if let Some(i) = self.start.iter().position(|v| !v.is_finite()) {
            return Err(invalid(format!("start[{i}]"), "must be finite"));
        }
        self.check_goal(self.goal_m)?;
        let weights = [("q_x", &self.q_x[..]), ("q_u", &self.q_u[..]), ("q_du", &self.q_du[..])];
        for (name, w) in weights {
            if let Some(i) = w.iter().position(|v| !v.is_finite() || *v < 0.0) {
                return Err(invalid(format!("{name}[{i}]"), "must be finite and >= 0"));
            }
        }
        if self.horizon == 0 || self.horizon > 1000 {
            return Err(invalid("horizon", "must be in 1..=1000"));
        }
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(self.nmpc_sampling_time_s) {
            return Err(invalid("nmpc_sampling_time_s", "must be finite and > 0"));
        }
        if self.sampling_times_s.is_empty() || self.sampling_times_s.len() > 16 {
            return Err(invalid("sampling_times_s", "must hold 1 to 16 values"));
        }
        for (i, w) in self.sampling_times_s.windows(2).enumerate() {
            if w[1] <= w[0] {
                return Err(invalid(format!("sampling_times_s[{}]", i + 1), "must be increasing"));
            }
        }
        if let Some(i) = self.sampling_times_s.iter().position(|v| !positive(*v)) {
            return Err(invalid(format!("sampling_times_s[{i}]"), "must be finite and > 0"));
        }
        if self.nominal_weights.len() != self.sampling_times_s.len() {
            return Err(invalid("nominal_weights", "needs one weight per sampling time"));
        }
        if let Some(i) = self.nominal_weights.iter().position(|v| !v.is_finite() || *v < 0.0) {
            return Err(invalid(format!("nominal_weights[{i}]"), "must be finite and >= 0"));
        }
        // Every weight is finite and >= 0 here, so the sum cannot be NaN.
        if self.nominal_weights.iter().sum::<f64>() <= 0.0 {
            return Err(invalid("nominal_weights", "must not all be zero"));
        }
        if !positive(self.prior_gamma.0) || !positive(self.prior_gamma.1) {
            return Err(invalid("prior_gamma", "shape and scale must be finite and > 0"));
        }
        if self.delay_window < 2 {
            return Err(invalid("delay_window", "must be at least 2"));
        }
        if let DelayModel::Gamma { shape, scale_s } = self.delays {
            if !positive(shape) {
                return Err(invalid("delays.shape", "must be finite and > 0"));
            }
            if !positive(scale_s) {
                return Err(invalid("delays.scale_s", "must be finite and > 0"));
            }
        }
        if !positive(self.min_cycle_s) {
            return Err(invalid("min_cycle_s", "must be finite and > 0"));
        }
        if !positive(self.goal_tolerance_m) {
            return Err(invalid("goal_tolerance_m", "must be finite and > 0"));
        }
        if !positive(self.goal_speed_tolerance_mps) {
            return Err(invalid("goal_speed_tolerance_mps", "must be finite and > 0"));
        }
        if !positive(self.max_duration_s) || self.max_duration_s > 86_400.0 {
            return Err(invalid("max_duration_s", "must be in (0, 86400]"));
        }
        if !self.ground_z_m.is_finite() {
            return Err(invalid("ground_z_m", "must be finite"));
        }
        if self.min_altitude_m.is_some_and(|z| !z.is_finite()) {
            return Err(invalid("min_altitude_m", "must be finite"));
        }
        if self.obstacle_margin_m.is_some_and(|m| !(m.is_finite() && (0.0..=10.0).contains(&m))) {
            return Err(invalid("obstacle_margin_m", "must be in [0, 10]"));
        }
        Ok(())
    }

    /// Checks that `goal_m` can be this scenario's goal: finite, not below the ground (nor
    /// below the floor when there is one), and outside every cylinder (a goal inside one can
    /// only be reached through it). The error names `goal_m` or the element.
    pub fn check_goal(&self, goal_m: [f64; 3]) -> Result<(), ScenarioError> {
        if let Some(i) = goal_m.iter().position(|v| !v.is_finite()) {
            return Err(invalid(format!("goal_m[{i}]"), "must be finite"));
        }
        let lowest = self.min_altitude_m.map_or(self.ground_z_m, |floor| floor.max(self.ground_z_m));
        if goal_m[2] < lowest {
            return Err(invalid("goal_m[2]", format!("must be at or above {lowest} m (ground or floor)")));
        }
        let (clearance, nearest) =
            crate::geometry::min_clearance(&self.obstacles, goal_m[0], goal_m[1], goal_m[2]);
        if let Some(k) = nearest.filter(|_| clearance <= 0.0) {
            return Err(invalid("goal_m", format!("lies inside obstacles[{k}] ({clearance:.3} m)")));
        }
        Ok(())
    }

    /// The end condition of `SPEC.md`: close to the goal and nearly at rest.
    pub fn goal_reached(&self, x: &State) -> bool {
        let dp = ((x[0] - self.goal_m[0]).powi(2)
            + (x[1] - self.goal_m[1]).powi(2)
            + (x[2] - self.goal_m[2]).powi(2))
        .sqrt();
        let speed = (x[3] * x[3] + x[4] * x[4] + x[5] * x[5]).sqrt();
        dp < self.goal_tolerance_m && speed < self.goal_speed_tolerance_mps
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_in_scenarios_are_valid_and_match_the_spec() {
        for name in Scenario::BUILT_IN {
            let s = Scenario::by_name(name).expect("built in");
            s.validate().expect("valid");
            assert_eq!(s.horizon, 40);
        }
        let p2 = Scenario::paper_2();
        assert_eq!(p2.q_du, [40.0, 165.0, 165.0]);
        assert_eq!(Scenario::paper_3().delays, DelayModel::None);
        assert_eq!(Scenario::paper_3().obstacles, p2.obstacles);
        assert!(matches!(Scenario::by_name("paper-9"), Err(ScenarioError::Unknown(_))));
    }

    #[test]
    fn a_goal_must_be_finite_above_the_ground_and_floor_and_outside_every_cylinder() {
        let s = Scenario::paper_1(); // cylinder (0, 6), r 1.5, 10 m high
        let field = |r: Result<(), ScenarioError>| match r {
            Err(ScenarioError::Invalid { field, .. }) => field,
            other => format!("{other:?}"),
        };
        assert_eq!(s.check_goal([0.0, 9.0, 1.0]), Ok(()));
        assert_eq!(s.check_goal([0.0, 9.0, 0.0]), Ok(()), "on the ground");
        assert_eq!(field(s.check_goal([0.0, 9.0, f64::NAN])), "goal_m[2]");
        assert_eq!(field(s.check_goal([0.0, 9.0, -0.1])), "goal_m[2]");
        assert_eq!(field(s.check_goal([0.5, 6.0, 1.0])), "goal_m");
        assert_eq!(field(s.check_goal([0.0, 4.5, 1.0])), "goal_m", "on the surface");
        assert_eq!(s.check_goal([0.0, 6.0, 10.5]), Ok(()), "above the cylinder");
        let floored = Scenario { min_altitude_m: Some(0.5), ..Scenario::paper_1() };
        assert_eq!(field(floored.check_goal([0.0, 9.0, 0.3])), "goal_m[2]");
        // The scenario's own goal is checked by `validate`.
        let inside = Scenario { goal_m: [0.0, 6.0, 1.0], ..Scenario::paper_1() };
        assert_eq!(field(inside.validate()), "goal_m");
    }

    #[test]
    fn validation_names_the_field() {
        let mut s = Scenario::paper_1();
        s.q_x[3] = f64::NAN;
        assert_eq!(s.validate(), Err(invalid("q_x[3]", "must be finite and >= 0")));
        let mut s = Scenario::paper_1();
        s.sampling_times_s[2] = 0.01;
        assert!(
            matches!(s.validate(), Err(ScenarioError::Invalid { field, .. }) if field == "sampling_times_s[2]")
        );
        let mut s = Scenario::paper_1();
        s.obstacles[0].radius_m = -1.0;
        assert!(
            matches!(s.validate(), Err(ScenarioError::Invalid { field, .. }) if field == "obstacles[0].radius_m")
        );
    }
}
