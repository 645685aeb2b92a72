//! Scenario definitions: everything `docs/spec.md` pins down for one run, as validated data.
//! The three paper scenarios are built in; user scenarios come from files through serde.

use crate::geometry::Cylinder;
use crate::model::{InputBounds, ModelParams, State};

use delay::{DelaysTable, NetworkProfile};

/// `docs/spec.md`'s round-trip delay: Gamma(12, 0.015), mean 0.18 s.
pub const PAPER_DELAY_GAMMA: (f64, f64) = (12.0, 0.015);

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScenarioError {
    #[error("unknown scenario {0:?} (known: paper-1, paper-2, paper-3)")]
    Unknown(String),
    #[error("invalid scenario field `{field}`: {reason}")]
    Invalid { field: String, reason: String },
}

/// Largest absolute coordinate of anything in a scenario (obstacles, start, goal, ground,
/// floor), m: a world of 20 km. Beyond it the solvers' arithmetic loses meaning (a cylinder at
/// 1e300 m made the augmented Lagrangian's norms overflow), so it is refused, not solved.
pub const MAX_ABS_POSITION_M: f64 = 1.0e4;
/// Largest absolute velocity component of a start state, m/s.
pub const MAX_ABS_VELOCITY_MPS: f64 = 1.0e3;
/// Largest absolute roll or pitch of a start state, rad (exclusive).
pub const MAX_ABS_ANGLE_RAD: f64 = std::f64::consts::FRAC_PI_2;
/// Largest cylinder radius or height, m.
pub const MAX_OBSTACLE_SIZE_M: f64 = 1.0e3;
/// Largest cost weight and model parameter.
pub const MAX_COEFFICIENT: f64 = 1.0e9;
/// Shortest `min_cycle_s`, s: the plant's integration step (`SimSettings::default()`, 1 ms).
/// In real time the plant's state moves once a step, so a shorter cycle would only sample the
/// same state again, and the fail-safe check brakes over its horizon in cycles of at least this
/// (a `min_cycle_s` of 1e-300 made it loop for ever: `t + 1e-300 == t`).
pub const MIN_CYCLE_S: f64 = 1.0e-3;
/// Longest `min_cycle_s`, s.
pub const MAX_CYCLE_S: f64 = 3600.0;
/// Longest scenario name, characters.
pub const MAX_NAME_CHARS: usize = 64;

/// Checks that `name` is an identifier: 1 to [`MAX_NAME_CHARS`] ASCII letters, digits, `-`,
/// `_`, `.` and `+`, starting with a letter or digit. Names become file names
/// (`<name>-<controller>.csv`, `<name>.scenario.toml`), so a `/`, a `..`, a space or a control
/// character is refused rather than written. The reason says what was found.
pub fn check_name(name: &str) -> Result<(), String> {
    let allowed = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.' | '+');
    let shown = || {
        let mut s: String = name.chars().take(MAX_NAME_CHARS + 1).collect();
        if s.len() < name.len() {
            s.push_str("...");
        }
        format!("{s:?}")
    };
    if name.is_empty() || name.chars().count() > MAX_NAME_CHARS {
        return Err(format!("must be 1 to {MAX_NAME_CHARS} characters, got {}", shown()));
    }
    if !name.starts_with(|c: char| c.is_ascii_alphanumeric()) || !name.chars().all(allowed) {
        return Err(format!(
            "must be an identifier (letters, digits, `-`, `_`, `.`, `+`, starting with a letter or \
             digit; it names files), got {}",
            shown()
        ));
    }
    Ok(())
}

fn invalid(field: impl Into<String>, reason: impl Into<String>) -> ScenarioError {
    ScenarioError::Invalid { field: field.into(), reason: reason.into() }
}

/// The keys of a scenario that only the bench's NMPC reads (its tuning), in file order.
pub const NMPC_KEYS: [&str; 9] = [
    "q_x",
    "q_u",
    "q_du",
    "horizon",
    "nmpc_sampling_time_s",
    "sampling_times_s",
    "nominal_weights",
    "prior_gamma",
    "delay_window",
];

/// paper-2's tuning, for a scenario that leaves it out ([`NMPC_KEYS`]).
mod paper_tuning {
    use super::Scenario;
    pub fn q_x() -> [f64; 8] {
        Scenario::paper_2().q_x
    }
    pub fn q_u() -> [f64; 3] {
        Scenario::paper_2().q_u
    }
    pub fn q_du() -> [f64; 3] {
        Scenario::paper_2().q_du
    }
    pub fn horizon() -> usize {
        Scenario::paper_2().horizon
    }
    pub fn nmpc_sampling_time_s() -> f64 {
        Scenario::paper_2().nmpc_sampling_time_s
    }
    pub fn sampling_times_s() -> Vec<f64> {
        Scenario::paper_2().sampling_times_s
    }
    pub fn nominal_weights() -> Vec<f64> {
        Scenario::paper_2().nominal_weights
    }
    pub fn prior_gamma() -> (f64, f64) {
        Scenario::paper_2().prior_gamma
    }
    pub fn delay_window() -> usize {
        Scenario::paper_2().delay_window
    }
}

/// One scenario of `docs/spec.md`: world, vehicle, controller tuning and delay process.
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
    #[serde(deserialize_with = "crate::exact::array")]
    pub start: [f64; 8],
    /// Goal position, m.
    #[serde(deserialize_with = "crate::exact::array")]
    pub goal_m: [f64; 3],
    // The bench's NMPC tuning ([`NMPC_KEYS`]): a file may leave it out (paper-2's then, a
    // file for an external controller has no use for it); the file loader says which were
    // left out, and the bench's controllers refuse such a file.
    /// State weights, diagonal of `Qx`.
    #[serde(default = "paper_tuning::q_x", deserialize_with = "crate::exact::array")]
    pub q_x: [f64; 8],
    /// Input weights, diagonal of `Qu`.
    #[serde(default = "paper_tuning::q_u", deserialize_with = "crate::exact::array")]
    pub q_u: [f64; 3],
    /// Input-rate weights, diagonal of `Qdu`.
    #[serde(default = "paper_tuning::q_du", deserialize_with = "crate::exact::array")]
    pub q_du: [f64; 3],
    /// Prediction horizon `N`.
    #[serde(default = "paper_tuning::horizon")]
    pub horizon: usize,
    /// Sampling time of the standard NMPC, s.
    #[serde(default = "paper_tuning::nmpc_sampling_time_s")]
    pub nmpc_sampling_time_s: f64,
    /// Sampling times `ts_i` of the multi-stage scenarios, s, increasing.
    #[serde(default = "paper_tuning::sampling_times_s")]
    pub sampling_times_s: Vec<f64>,
    /// Scenario weights used when the run has no delays.
    #[serde(default = "paper_tuning::nominal_weights")]
    pub nominal_weights: Vec<f64>,
    /// Gamma prior `(shape, scale_s)` used until the delay window is usable.
    #[serde(default = "paper_tuning::prior_gamma", deserialize_with = "crate::exact::pair")]
    pub prior_gamma: (f64, f64),
    /// Size of the delay window `n_max`.
    #[serde(default = "paper_tuning::delay_window")]
    pub delay_window: usize,
    /// The network's delay process as written in a scenario file's `[scenario.delays]` (see
    /// `delay::spec`): a round trip on commands, or each direction, any kind, traces and
    /// regimes included (a trace's delays inline once the file loader has read them).
    /// `None`: the scenario says nothing of the network (a run over netem keeps the profile
    /// in force; in process there is no delay).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub delays: Option<DelaysTable>,
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
    /// The safety layer judges candidate commands with the fail-safe check (every delay, the
    /// plant's braking watchdog included; see `mpc::fail_safe`) instead of by their plans'
    /// predictions. Off in paper mode, on by default in scenario files.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub fail_safe: bool,
    /// A lockstep run goes on after the vehicle's first collision (to see the rest of the
    /// flight). Off by default: a run ends at its first collision, as a real vehicle's flight
    /// does.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub continue_after_collision: bool,
    /// Whose PANOC the controller solves this scenario's problems with. `None`: the
    /// controller's own setting (`controller --solver`, OpEn's by default). The paper files pin
    /// OpEn's (the paper's toolchain); other scenario files take ours by default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub solver: Option<PanocSolver>,
}

/// Whose PANOC solves the controller's problems (`mpc::MpcSettings::solver`, and a scenario's
/// `solver`). Here rather than in `mpc` because a scenario names it and travels to the
/// controller with it; `mpc` re-exports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize)]
pub enum PanocSolver {
    /// OpEn 0.12's ALM/PM and PANOC (the paper's toolchain).
    #[default]
    #[serde(rename = "open")]
    OpEn,
    /// The bench's own PANOC (`mpc/src/solver/panoc.rs`): the Lipschitz estimate carried
    /// across calls, a scale-free stopping test; the same ALM/PM outer loop and budgets.
    #[serde(rename = "own")]
    Own,
}

impl PanocSolver {
    pub fn name(self) -> &'static str {
        match self {
            PanocSolver::OpEn => "open",
            PanocSolver::Own => "own",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "open" => Some(PanocSolver::OpEn),
            "own" => Some(PanocSolver::Own),
            _ => None,
        }
    }
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
            delays: Some(DelaysTable::gamma(PAPER_DELAY_GAMMA.0, PAPER_DELAY_GAMMA.1)),
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
            continue_after_collision: false,
            solver: None,
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
        Self { name: "paper-3".to_string(), delays: Some(DelaysTable::none()), ..Self::paper_2() }
    }

    /// The initial state as a vector.
    pub fn start_state(&self) -> State {
        State::from(self.start)
    }

    /// The network of [`Scenario::delays`], seeded with [`Scenario::seed`]; `None` when the
    /// scenario does not describe it. A trace must be loaded (inline): this reads no file.
    pub fn network(&self) -> Result<Option<NetworkProfile>, ScenarioError> {
        let Some(table) = &self.delays else { return Ok(None) };
        let mut unread = |file: &str| {
            Err(format!("trace file {file:?} is not loaded (a scenario file's loader reads its traces)"))
        };
        table
            .to_network(self.seed, &mut unread)
            .map(Some)
            .map_err(|e| invalid(format!("delays.{}", e.field), e.reason))
    }

    /// A controller expects delays, and fits their law, unless the scenario says its network
    /// delays nothing (an undescribed network may delay anything: its delays are measured).
    pub fn delays_expected(&self) -> bool {
        !matches!(self.network(), Ok(Some(n)) if !n.has_delays())
    }

    /// The `(shape, scale_s)` of a Gamma round trip on commands, when that is the process.
    pub fn gamma_round_trip(&self) -> Option<(f64, f64)> {
        let network = self.network().ok()??;
        if network.to_controller.delay.is_zero()
            && let delay::Distribution::Gamma { shape, scale_s } = network.to_plant.delay
        {
            return Some((shape, scale_s));
        }
        None
    }

    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        check_name(&self.name).map_err(|reason| invalid("name", reason))?;
        self.model.validate().map_err(|f| invalid(format!("model.{f}"), "must be finite and positive"))?;
        let m = &self.model;
        for (name, v) in [
            ("gravity_mps2", m.gravity_mps2),
            ("drag_x_per_s", m.drag_x_per_s),
            ("drag_y_per_s", m.drag_y_per_s),
            ("drag_z_per_s", m.drag_z_per_s),
            ("tau_roll_s", m.tau_roll_s),
            ("tau_pitch_s", m.tau_pitch_s),
            ("gain_roll", m.gain_roll),
            ("gain_pitch", m.gain_pitch),
        ] {
            if v > MAX_COEFFICIENT {
                return Err(invalid(format!("model.{name}"), format!("must be at most {MAX_COEFFICIENT}")));
            }
        }
        self.bounds
            .validate()
            .map_err(|f| invalid(format!("bounds.{f}"), "must be finite with min <= max"))?;
        for (side, values) in [("min", self.bounds.min), ("max", self.bounds.max)] {
            if values[0].abs() > MAX_COEFFICIENT {
                return Err(invalid(
                    format!("bounds.{side}[0]"),
                    format!("must be within +-{MAX_COEFFICIENT}"),
                ));
            }
            for (k, angle) in values.iter().enumerate().skip(1) {
                if angle.abs() >= MAX_ABS_ANGLE_RAD {
                    return Err(invalid(
                        format!("bounds.{side}[{k}]"),
                        "must be within +-pi/2 rad (exclusive)",
                    ));
                }
            }
        }
        for (i, c) in self.obstacles.iter().enumerate() {
            c.validate()
                .map_err(|f| invalid(format!("obstacles[{i}].{f}"), "must be finite and positive"))?;
            for (name, v, limit) in [
                ("x_m", c.x_m.abs(), MAX_ABS_POSITION_M),
                ("y_m", c.y_m.abs(), MAX_ABS_POSITION_M),
                ("radius_m", c.radius_m, MAX_OBSTACLE_SIZE_M),
                ("height_m", c.height_m, MAX_OBSTACLE_SIZE_M),
            ] {
                if v > limit {
                    return Err(invalid(
                        format!("obstacles[{i}].{name}"),
                        format!("must be within {limit} m"),
                    ));
                }
            }
        }
        if self.obstacles.len() > 1000 {
            return Err(invalid("obstacles", "must hold at most 1000 cylinders"));
        }
        for (i, v) in self.start.iter().enumerate() {
            let limit = match i {
                0..3 => MAX_ABS_POSITION_M,
                3..6 => MAX_ABS_VELOCITY_MPS,
                _ => MAX_ABS_ANGLE_RAD,
            };
            if !v.is_finite() {
                return Err(invalid(format!("start[{i}]"), "must be finite"));
            }
            if v.abs() > limit || (i >= 6 && v.abs() >= limit) {
                return Err(invalid(format!("start[{i}]"), format!("must be within +-{limit}")));
            }
        }
        if !self.ground_z_m.is_finite() || self.ground_z_m.abs() > MAX_ABS_POSITION_M {
            return Err(invalid("ground_z_m", format!("must be finite and within +-{MAX_ABS_POSITION_M} m")));
        }
        if self.start[2] < self.ground_z_m {
            return Err(invalid(
                "start[2]",
                format!("is below the ground (ground_z_m = {} m)", self.ground_z_m),
            ));
        }
        if self.min_altitude_m.is_some_and(|z| !z.is_finite() || z.abs() > MAX_ABS_POSITION_M) {
            return Err(invalid(
                "min_altitude_m",
                format!("must be finite and within +-{MAX_ABS_POSITION_M} m"),
            ));
        }
        self.check_goal(self.goal_m)?;
        let weights = [("q_x", &self.q_x[..]), ("q_u", &self.q_u[..]), ("q_du", &self.q_du[..])];
        for (name, w) in weights {
            if let Some(i) = w.iter().position(|v| !v.is_finite() || *v < 0.0 || *v > MAX_COEFFICIENT) {
                return Err(invalid(
                    format!("{name}[{i}]"),
                    format!("must be finite and in [0, {MAX_COEFFICIENT}]"),
                ));
            }
        }
        if self.horizon == 0 || self.horizon > 1000 {
            return Err(invalid("horizon", "must be in 1..=1000"));
        }
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(self.nmpc_sampling_time_s) || self.nmpc_sampling_time_s > 60.0 {
            return Err(invalid("nmpc_sampling_time_s", "must be in (0, 60] s"));
        }
        if self.sampling_times_s.is_empty() || self.sampling_times_s.len() > 16 {
            return Err(invalid("sampling_times_s", "must hold 1 to 16 values"));
        }
        for (i, w) in self.sampling_times_s.windows(2).enumerate() {
            if w[1] <= w[0] {
                return Err(invalid(format!("sampling_times_s[{}]", i + 1), "must be increasing"));
            }
        }
        if let Some(i) = self.sampling_times_s.iter().position(|v| !positive(*v) || *v > 60.0) {
            return Err(invalid(format!("sampling_times_s[{i}]"), "must be in (0, 60] s"));
        }
        if self.nominal_weights.len() != self.sampling_times_s.len() {
            return Err(invalid("nominal_weights", "needs one weight per sampling time"));
        }
        if let Some(i) =
            self.nominal_weights.iter().position(|v| !v.is_finite() || *v < 0.0 || *v > MAX_COEFFICIENT)
        {
            return Err(invalid(
                format!("nominal_weights[{i}]"),
                format!("must be finite and in [0, {MAX_COEFFICIENT}]"),
            ));
        }
        // Every weight is finite and >= 0 here, so the sum cannot be NaN.
        if self.nominal_weights.iter().sum::<f64>() <= 0.0 {
            return Err(invalid("nominal_weights", "must not all be zero"));
        }
        if !positive(self.prior_gamma.0)
            || !positive(self.prior_gamma.1)
            || self.prior_gamma.0 > MAX_COEFFICIENT
            || self.prior_gamma.1 > 3600.0
        {
            return Err(invalid("prior_gamma", "shape and scale must be finite and > 0"));
        }
        if !(2..=100_000).contains(&self.delay_window) {
            return Err(invalid("delay_window", "must be in 2..=100000"));
        }
        self.network()?;
        if !(self.min_cycle_s.is_finite() && (MIN_CYCLE_S..=MAX_CYCLE_S).contains(&self.min_cycle_s)) {
            return Err(invalid(
                "min_cycle_s",
                format!(
                    "must be in [{MIN_CYCLE_S}, {MAX_CYCLE_S}] s (at least the plant's 1 ms integration step), got {}",
                    delay::Number(self.min_cycle_s)
                ),
            ));
        }
        if !positive(self.goal_tolerance_m) || self.goal_tolerance_m > MAX_ABS_POSITION_M {
            return Err(invalid("goal_tolerance_m", format!("must be in (0, {MAX_ABS_POSITION_M}] m")));
        }
        if !positive(self.goal_speed_tolerance_mps) || self.goal_speed_tolerance_mps > MAX_ABS_VELOCITY_MPS {
            return Err(invalid(
                "goal_speed_tolerance_mps",
                format!("must be in (0, {MAX_ABS_VELOCITY_MPS}] m/s"),
            ));
        }
        if !positive(self.max_duration_s) || self.max_duration_s > 86_400.0 {
            return Err(invalid("max_duration_s", "must be in (0, 86400]"));
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
        if let Some(i) = goal_m.iter().position(|v| v.abs() > MAX_ABS_POSITION_M) {
            return Err(invalid(format!("goal_m[{i}]"), format!("must be within +-{MAX_ABS_POSITION_M} m")));
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

    /// The end condition of `docs/spec.md`: close to the goal and nearly at rest.
    /// `max_duration_s` in plant-time nanoseconds (validated scenarios hold at most a day, so
    /// this never saturates; an unvalidated one past `u64::MAX` ns gives `u64::MAX`).
    pub fn max_duration_ns(&self) -> u64 {
        crate::s_to_ns(self.max_duration_s).unwrap_or(u64::MAX)
    }

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
    fn magnitudes_no_solver_can_mean_are_refused_with_the_field_named() {
        let field = |s: &Scenario| match s.validate() {
            Err(ScenarioError::Invalid { field, .. }) => field,
            other => format!("{other:?}"),
        };
        let base = Scenario::paper_2();
        let mut s = base.clone();
        s.obstacles[0].x_m = 1e300;
        assert_eq!(field(&s), "obstacles[0].x_m");
        let mut s = base.clone();
        s.obstacles[0].radius_m = 5e3;
        assert_eq!(field(&s), "obstacles[0].radius_m");
        let mut s = base.clone();
        s.start[1] = -2e4;
        assert_eq!(field(&s), "start[1]");
        let mut s = base.clone();
        s.start[4] = 5e3;
        assert_eq!(field(&s), "start[4]");
        let mut s = base.clone();
        s.goal_m[0] = 1e5;
        assert_eq!(field(&s), "goal_m[0]");
        let mut s = base.clone();
        s.q_x[2] = 1e12;
        assert_eq!(field(&s), "q_x[2]");
        let mut s = base.clone();
        s.ground_z_m = -1e6;
        assert_eq!(field(&s), "ground_z_m");
        let mut s = base.clone();
        s.bounds.max[1] = 2.0;
        assert_eq!(field(&s), "bounds.max[1]");
        let mut s = base.clone();
        s.sampling_times_s[4] = 1e3;
        assert_eq!(field(&s), "sampling_times_s[4]");
        for name in Scenario::BUILT_IN {
            assert_eq!(Scenario::by_name(name).expect("built in").validate(), Ok(()), "{name}");
        }
    }

    #[test]
    fn a_name_that_is_not_an_identifier_is_refused_since_names_become_file_names() {
        let named = |name: &str| Scenario { name: name.into(), ..Scenario::paper_2() }.validate();
        for bad in ["../../escape", "a/b", "..", ".hidden", "", "a b", "tab\there", "x\u{7}", "é", "a\\b"] {
            assert!(
                matches!(named(bad), Err(ScenarioError::Invalid { field, .. }) if field == "name"),
                "{bad:?} accepted"
            );
        }
        assert!(named(&"a".repeat(MAX_NAME_CHARS + 1)).is_err());
        for good in ["paper-2", "slalom_4", "wifi.trace", "paper-2+floor+compensation", "X1"] {
            assert_eq!(named(good), Ok(()), "{good:?}");
        }
        let e = named("../../escape").expect_err("refused").to_string();
        assert!(e.contains("identifier") && e.contains("\"../../escape\""), "{e}");
    }

    #[test]
    fn min_cycle_s_below_the_plants_step_or_huge_is_refused_and_shown_short() {
        let cycle = |min_cycle_s| Scenario { min_cycle_s, ..Scenario::paper_2() }.validate();
        assert_eq!(MIN_CYCLE_S, crate::ns_to_s(crate::SimSettings::default().step_ns));
        assert_eq!(cycle(MIN_CYCLE_S), Ok(()));
        assert_eq!(cycle(MAX_CYCLE_S), Ok(()));
        for bad in [1e-6, 1e-300, 0.0, -0.05, 3601.0, 1e300, f64::NAN, f64::INFINITY] {
            match cycle(bad) {
                Err(ScenarioError::Invalid { field, reason }) => {
                    assert_eq!(field, "min_cycle_s", "{bad}");
                    assert!(reason.len() < 160, "{bad}: {reason}");
                }
                other => panic!("{bad}: {other:?}"),
            }
        }
    }

    #[test]
    fn built_in_scenarios_are_valid_and_match_the_spec() {
        for name in Scenario::BUILT_IN {
            let s = Scenario::by_name(name).expect("built in");
            s.validate().expect("valid");
            assert_eq!(s.horizon, 40);
        }
        let p2 = Scenario::paper_2();
        assert_eq!(p2.q_du, [40.0, 165.0, 165.0]);
        assert_eq!(Scenario::paper_3().delays, Some(DelaysTable::none()));
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
        assert_eq!(s.validate(), Err(invalid("q_x[3]", "must be finite and in [0, 1000000000]")));
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
