//! The MAV model of `docs/spec.md`: continuous dynamics and the two integrators.

use nalgebra::SVector;

/// `[px, py, pz, vx, vy, vz, phi, theta]` in m, m/s, rad.
pub type State = SVector<f64, 8>;
/// `[T, phi_d, theta_d]`: mass-normalised thrust in m/s^2, desired roll and pitch in rad.
pub type Input = SVector<f64, 3>;

/// Physical parameters of the model (defaults from `docs/spec.md`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ModelParams {
    /// Gravitational acceleration, m/s^2.
    pub gravity_mps2: f64,
    /// Mass-normalised linear drag in x, 1/s.
    pub drag_x_per_s: f64,
    /// Mass-normalised linear drag in y, 1/s.
    pub drag_y_per_s: f64,
    /// Mass-normalised linear drag in z, 1/s.
    pub drag_z_per_s: f64,
    /// Time constant of the roll response, s.
    pub tau_roll_s: f64,
    /// Time constant of the pitch response, s.
    pub tau_pitch_s: f64,
    /// Static gain of the roll response.
    pub gain_roll: f64,
    /// Static gain of the pitch response.
    pub gain_pitch: f64,
}

impl Default for ModelParams {
    fn default() -> Self {
        Self {
            gravity_mps2: 9.81,
            drag_x_per_s: 0.1,
            drag_y_per_s: 0.1,
            drag_z_per_s: 0.2,
            tau_roll_s: 0.5,
            tau_pitch_s: 0.5,
            gain_roll: 1.0,
            gain_pitch: 1.0,
        }
    }
}

impl ModelParams {
    /// Checks that every parameter is finite and physically meaningful; names the first bad one.
    pub fn validate(&self) -> Result<(), &'static str> {
        let checks: [(&'static str, f64, bool); 8] = [
            ("gravity_mps2", self.gravity_mps2, self.gravity_mps2 > 0.0),
            ("drag_x_per_s", self.drag_x_per_s, self.drag_x_per_s >= 0.0),
            ("drag_y_per_s", self.drag_y_per_s, self.drag_y_per_s >= 0.0),
            ("drag_z_per_s", self.drag_z_per_s, self.drag_z_per_s >= 0.0),
            ("tau_roll_s", self.tau_roll_s, self.tau_roll_s > 0.0),
            ("tau_pitch_s", self.tau_pitch_s, self.tau_pitch_s > 0.0),
            ("gain_roll", self.gain_roll, self.gain_roll > 0.0),
            ("gain_pitch", self.gain_pitch, self.gain_pitch > 0.0),
        ];
        for (name, value, ok) in checks {
            if !value.is_finite() || !ok {
                return Err(name);
            }
        }
        Ok(())
    }

    /// The hover input `[g, 0, 0]`.
    pub fn hover_input(&self) -> Input {
        Input::new(self.gravity_mps2, 0.0, 0.0)
    }
}

/// Box bounds on the input.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputBounds {
    /// `[T_min, phi_min, theta_min]`.
    #[serde(deserialize_with = "crate::exact::array")]
    pub min: [f64; 3],
    /// `[T_max, phi_max, theta_max]`.
    #[serde(deserialize_with = "crate::exact::array")]
    pub max: [f64; 3],
}

impl InputBounds {
    /// `docs/spec.md`: `T in [0, 2g]`, angles in `[-pi/18, pi/18]` rad.
    pub fn paper(gravity_mps2: f64) -> Self {
        let a = std::f64::consts::PI / 18.0;
        Self { min: [0.0, -a, -a], max: [2.0 * gravity_mps2, a, a] }
    }

    /// Names the first non-finite or inverted bound.
    pub fn validate(&self) -> Result<(), &'static str> {
        const NAMES: [&str; 3] = ["thrust", "roll", "pitch"];
        for (i, name) in NAMES.iter().enumerate() {
            if !self.min[i].is_finite() || !self.max[i].is_finite() || self.min[i] > self.max[i] {
                return Err(name);
            }
        }
        Ok(())
    }

    /// Clips `u` into the box; says whether anything was clipped.
    pub fn saturate(&self, u: &Input) -> (Input, bool) {
        let mut out = *u;
        let mut clipped = false;
        for i in 0..3 {
            let c = u[i].clamp(self.min[i], self.max[i]);
            clipped |= c != u[i];
            out[i] = c;
        }
        (out, clipped)
    }

    /// True when every component lies inside the box.
    pub fn contains(&self, u: &Input) -> bool {
        (0..3).all(|i| u[i] >= self.min[i] && u[i] <= self.max[i])
    }
}

/// A continuous-time model `x' = f(x, u)`, small enough that the integrators and tests can be
/// written once for the MAV and for textbook systems with known solutions.
pub trait Dynamics<const NX: usize, const NU: usize> {
    fn derivative(&self, x: &SVector<f64, NX>, u: &SVector<f64, NU>) -> SVector<f64, NX>;
}

/// The MAV of `docs/spec.md` with its parameters.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MavModel {
    pub params: ModelParams,
}

impl MavModel {
    pub fn new(params: ModelParams) -> Self {
        Self { params }
    }
}

impl Dynamics<8, 3> for MavModel {
    #[inline]
    fn derivative(&self, x: &State, u: &Input) -> State {
        let p = &self.params;
        let (s_phi, c_phi) = x[6].sin_cos();
        let (s_theta, c_theta) = x[7].sin_cos();
        let thrust = u[0];
        State::from([
            x[3],
            x[4],
            x[5],
            thrust * c_phi * s_theta - p.drag_x_per_s * x[3],
            -thrust * s_phi - p.drag_y_per_s * x[4],
            thrust * c_phi * c_theta - p.gravity_mps2 - p.drag_z_per_s * x[5],
            (p.gain_roll * u[1] - x[6]) / p.tau_roll_s,
            (p.gain_pitch * u[2] - x[7]) / p.tau_pitch_s,
        ])
    }
}

/// One explicit Euler step: the controller's prediction model.
#[inline]
pub fn euler_step<const NX: usize, const NU: usize, D: Dynamics<NX, NU>>(
    model: &D,
    x: &SVector<f64, NX>,
    u: &SVector<f64, NU>,
    dt_s: f64,
) -> SVector<f64, NX> {
    x + model.derivative(x, u) * dt_s
}

/// One classical fourth-order Runge-Kutta step with the input held: the plant's truth model.
#[inline]
pub fn rk4_step<const NX: usize, const NU: usize, D: Dynamics<NX, NU>>(
    model: &D,
    x: &SVector<f64, NX>,
    u: &SVector<f64, NU>,
    dt_s: f64,
) -> SVector<f64, NX> {
    let half = 0.5 * dt_s;
    let k1 = model.derivative(x, u);
    let k2 = model.derivative(&(x + k1 * half), u);
    let k3 = model.derivative(&(x + k2 * half), u);
    let k4 = model.derivative(&(x + k3 * dt_s), u);
    x + (k1 + (k2 + k3) * 2.0 + k4) * (dt_s / 6.0)
}

#[cfg(test)]
mod tests;
