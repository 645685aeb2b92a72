//! What to solve: the obstacle formulation and the problem's definition, and the check of each
//! cycle's data (the controller mode is `mav`'s, re-exported here).

pub use mav::ControllerMode;
use mav::{Cylinder, InputBounds, ModelParams, Scenario};

use crate::error::{MpcError, invalid_input};

/// Longest [`OcpDefinition::coast_time_s`], s.
pub const MAX_COAST_TIME_S: f64 = 5.0;

/// How the cylinder constraint enters the solver.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObstacleFormulation {
    /// The paper's form: `F2 = [R^2 - dx^2 - dy^2]_+ [zo - z]_+ = 0` per point, handled by
    /// OpEn's penalty method (PM). Its units are m^3, its gradient scales with `R (zo - z)^2`
    /// (so a 1.5 m cylinder and a 0.25 m one are penalised very differently), and the penalty
    /// must grow large to push violations to zero, which makes PANOC's problem stiff.
    /// Measured on the paper loops: the penalty method either left violations or, uncapped,
    /// multiplied the penalty to 1e42 and drove the vehicle into the ground.
    PaperPenalty,
    /// `g = min(R - d, zo - z) <= 0` per point (horizontal distance `d` to the axis, or to
    /// the point's coast with [`OcpDefinition::coast_time_s`]), handled
    /// by OpEn's augmented Lagrangian (ALM) with multipliers warm-started across cycles. The
    /// same feasible set, in metres for every cylinder, and exact feasibility with a moderate
    /// penalty. The default.
    DistanceAlm,
}

/// What to solve: everything of the optimal control problem except the current state, the
/// last applied input and the scenario weights, which change every cycle.
#[derive(Debug, Clone, PartialEq)]
pub struct OcpDefinition {
    pub model: ModelParams,
    pub bounds: InputBounds,
    pub obstacles: Vec<Cylinder>,
    /// Added to every cylinder radius in the constraint, m.
    pub obstacle_margin_m: f64,
    pub formulation: ObstacleFormulation,
    pub horizon: usize,
    /// One prediction per sampling time, s.
    pub sampling_times_s: Vec<f64>,
    pub q_x: [f64; 8],
    pub q_u: [f64; 3],
    pub q_du: [f64; 3],
    pub x_ref: [f64; 8],
    pub u_ref: [f64; 3],
    /// Optional floor: every predicted point of every scenario keeps `z >= min_altitude_m`
    /// (the constraint `min_altitude_m - z <= 0`, in the same formulation as the cylinders).
    /// `None` in paper mode, whose model has no floor.
    pub min_altitude_m: Option<f64>,
    /// Dead-time compensation: scenario `i` first holds the last applied input for its own
    /// sampling time `ts_i` (the round-trip delay it stands for, during which the previous
    /// command stays on), then applies the plan. Off in paper mode (the paper predicts from
    /// the measured state at once).
    pub delay_compensation: bool,
    /// The distance form only: each predicted point keeps the cylinders' inflated radius not
    /// only where it is but along the straight line it would coast in this time at its
    /// horizontal velocity, s: a clearance that grows with the speed toward a cylinder and
    /// not with the speed past it, the room the fail-safe check wants to stop in. 0 (the
    /// default, and paper mode): the point alone.
    pub coast_time_s: f64,
}

impl OcpDefinition {
    /// The problem of `scenario` for `mode`, with the controller's `obstacle_margin_m` unless
    /// the scenario pins its own.
    pub fn from_scenario(
        scenario: &Scenario,
        mode: ControllerMode,
        obstacle_margin_m: f64,
        formulation: ObstacleFormulation,
    ) -> Self {
        let sampling_times_s = match mode {
            ControllerMode::Nmpc => vec![scenario.nmpc_sampling_time_s],
            ControllerMode::Multistage => scenario.sampling_times_s.clone(),
        };
        let g = scenario.model.gravity_mps2;
        let mut x_ref = [0.0; 8];
        x_ref[..3].copy_from_slice(&scenario.goal_m);
        Self {
            model: scenario.model,
            bounds: scenario.bounds,
            obstacles: scenario.obstacles.clone(),
            // A scenario may pin its own margin (scenario files do, with dead-time compensation).
            obstacle_margin_m: scenario.obstacle_margin_m.unwrap_or(obstacle_margin_m),
            formulation,
            horizon: scenario.horizon,
            sampling_times_s,
            q_x: scenario.q_x,
            q_u: scenario.q_u,
            q_du: scenario.q_du,
            x_ref,
            u_ref: [g, 0.0, 0.0],
            min_altitude_m: scenario.min_altitude_m,
            delay_compensation: scenario.delay_compensation,
            coast_time_s: 0.0,
        }
    }

    pub fn num_scenarios(&self) -> usize {
        self.sampling_times_s.len()
    }

    /// Number of decision variables, `3 N`.
    pub fn num_variables(&self) -> usize {
        3 * self.horizon
    }

    /// Constraint values per predicted point: one per cylinder, and the floor when set.
    pub fn constraints_per_point(&self) -> usize {
        self.obstacles.len() + usize::from(self.min_altitude_m.is_some())
    }

    /// Number of constraint values (ALM's `F1` or PM's `F2`): one per scenario, predicted point
    /// and cylinder (and the floor).
    pub fn num_constraints(&self) -> usize {
        self.num_scenarios() * self.horizon * self.constraints_per_point()
    }
}

/// Checks the per-cycle data of a problem with `m` scenarios: the state, the last applied
/// input and the scenario weights. Shared by [`crate::Mpc`] and [`crate::QpFallback`], so both
/// reject the same inputs with errors naming the same fields.
pub(crate) fn validate_instance(
    m: usize,
    x0: &[f64; 8],
    u_prev: &[f64; 3],
    weights: &[f64],
) -> Result<(), MpcError> {
    if let Some(i) = x0.iter().position(|v| !v.is_finite()) {
        return Err(invalid_input(format!("x0[{i}]"), "must be finite"));
    }
    if let Some(i) = u_prev.iter().position(|v| !v.is_finite()) {
        return Err(invalid_input(format!("u_prev[{i}]"), "must be finite"));
    }
    if weights.len() != m {
        return Err(invalid_input("weights", format!("must hold {m} values, got {}", weights.len())));
    }
    if let Some(i) = weights.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(invalid_input(format!("weights[{i}]"), "must be finite and >= 0"));
    }
    if weights.iter().sum::<f64>() <= 0.0 {
        return Err(invalid_input("weights", "must not all be zero"));
    }
    Ok(())
}
