//! The rigid body's continuous dynamics as a `mav::Dynamics` (17 states, 4 inputs), so the
//! workspace's one `rk4_step` integrates it, and the state as named fields.
//!
//! Left out, deliberately: rotor gyroscopic torque and the reaction torque of a motor's
//! acceleration (both small beside `k_m w^2` for light propellers), blade flapping and induced
//! drag, ground effect, wind.

use mav::Dynamics;
use nalgebra::{Quaternion, SVector, UnitQuaternion, Vector3};

use crate::motors::MOTORS;
use crate::params::{ParamError, QuadParams};

/// Length of the state vector: position (3), velocity (3), attitude quaternion `w, x, y, z`
/// (4), body rates (3), motor speeds (4).
pub const STATE_LEN: usize = 17;

/// Offsets into the state vector.
pub mod idx {
    pub const POSITION: usize = 0;
    pub const VELOCITY: usize = 3;
    pub const ATTITUDE: usize = 6;
    pub const RATES: usize = 10;
    pub const MOTORS: usize = 13;
}

/// The state as a vector (layout in [`idx`]).
pub type StateVector = SVector<f64, STATE_LEN>;
/// Commanded motor speeds, rad/s, motors 1 to 4.
pub type MotorSpeeds = SVector<f64, 4>;

/// The rigid body's state, in the frames of the crate's documentation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuadState {
    /// Centre of mass in the world (ENU), m.
    pub position_m: Vector3<f64>,
    /// Velocity in the world (ENU), m/s.
    pub velocity_mps: Vector3<f64>,
    /// Body (FLU) to world (ENU).
    pub attitude: UnitQuaternion<f64>,
    /// Angular velocity in body axes (FLU), rad/s.
    pub angular_velocity_rad_s: Vector3<f64>,
    /// Speed of motors 1 to 4 (Betaflight's order), rad/s, >= 0.
    pub motor_speed_rad_s: [f64; 4],
}

impl QuadState {
    /// At rest on the ground at `(x, y)`, level, nose east, motors stopped.
    pub fn resting_at(x_m: f64, y_m: f64) -> Self {
        Self {
            position_m: Vector3::new(x_m, y_m, 0.0),
            velocity_mps: Vector3::zeros(),
            attitude: UnitQuaternion::identity(),
            angular_velocity_rad_s: Vector3::zeros(),
            motor_speed_rad_s: [0.0; 4],
        }
    }

    /// Hovering at `position_m`, level, nose east, every motor at the hover speed.
    pub fn hovering_at(params: &QuadParams, position_m: Vector3<f64>) -> Self {
        Self {
            position_m,
            motor_speed_rad_s: [params.hover_motor_speed_rad_s(); 4],
            ..Self::resting_at(0.0, 0.0)
        }
    }

    pub fn to_vector(&self) -> StateVector {
        let q = self.attitude.quaternion();
        let mut x = StateVector::zeros();
        x.fixed_rows_mut::<3>(idx::POSITION).copy_from(&self.position_m);
        x.fixed_rows_mut::<3>(idx::VELOCITY).copy_from(&self.velocity_mps);
        x[idx::ATTITUDE] = q.w;
        x[idx::ATTITUDE + 1] = q.i;
        x[idx::ATTITUDE + 2] = q.j;
        x[idx::ATTITUDE + 3] = q.k;
        x.fixed_rows_mut::<3>(idx::RATES).copy_from(&self.angular_velocity_rad_s);
        for (i, w) in self.motor_speed_rad_s.iter().enumerate() {
            x[idx::MOTORS + i] = *w;
        }
        x
    }

    /// The state of a vector; the quaternion is normalised (RK4 does not keep its norm).
    pub fn from_vector(x: &StateVector) -> Self {
        let a = idx::ATTITUDE;
        Self {
            position_m: x.fixed_rows::<3>(idx::POSITION).into_owned(),
            velocity_mps: x.fixed_rows::<3>(idx::VELOCITY).into_owned(),
            attitude: UnitQuaternion::new_normalize(Quaternion::new(x[a], x[a + 1], x[a + 2], x[a + 3])),
            angular_velocity_rad_s: x.fixed_rows::<3>(idx::RATES).into_owned(),
            motor_speed_rad_s: std::array::from_fn(|i| x[idx::MOTORS + i]),
        }
    }

    /// True when every number is finite.
    pub fn is_finite(&self) -> bool {
        self.to_vector().iter().all(|v| v.is_finite())
    }
}

/// The quadrotor's dynamics with its parameters, checked once; the constants the derivative
/// needs are computed here, not per call.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuadModel {
    params: QuadParams,
    /// Motor positions in the body's x-y plane (FLU), m.
    motor_xy_m: [[f64; 2]; 4],
    /// +1 or -1: each motor's reaction torque about body +z.
    yaw_sign: [f64; 4],
    inverse_mass_per_kg: f64,
}

impl QuadModel {
    pub fn new(params: QuadParams) -> Result<Self, ParamError> {
        params.validate()?;
        let a = params.arm_length_m;
        Ok(Self {
            params,
            motor_xy_m: MOTORS.map(|m| [a * m.direction_flu[0], a * m.direction_flu[1]]),
            yaw_sign: MOTORS.map(|m| m.spin.yaw_torque_sign()),
            inverse_mass_per_kg: 1.0 / params.mass_kg,
        })
    }

    pub fn params(&self) -> &QuadParams {
        &self.params
    }

    /// Commanded motor speed for sanitised normalised commands (linear map).
    pub fn commanded_speeds(&self, commands: &[f64; 4]) -> MotorSpeeds {
        MotorSpeeds::from(commands.map(|c| c * self.params.max_motor_speed_rad_s))
    }

    /// Total thrust along body +z, N, and the torque on the body (FLU), N m, of motors at
    /// `speeds` rad/s.
    pub fn thrust_and_torque(&self, speeds: &[f64; 4]) -> (f64, Vector3<f64>) {
        let p = &self.params;
        let mut thrust = 0.0;
        let mut torque = Vector3::zeros();
        for ((w, [x, y]), yaw_sign) in speeds.iter().zip(self.motor_xy_m).zip(self.yaw_sign) {
            let w2 = w * w;
            let f = p.thrust_coefficient_n_per_rad2_s2 * w2;
            thrust += f;
            // r x (0, 0, f) = (y f, -x f, 0).
            torque.x += y * f;
            torque.y -= x * f;
            torque.z += yaw_sign * p.torque_coefficient_n_m_per_rad2_s2 * w2;
        }
        (thrust, torque)
    }

    /// The specific force in body axes (FLU), m/s^2, of a body flying freely in `x`: thrust and
    /// drag over mass (gravity is not felt by an accelerometer).
    pub fn specific_force_body(&self, x: &QuadState) -> Vector3<f64> {
        let (thrust, _) = self.thrust_and_torque(&x.motor_speed_rad_s);
        let drag_world = -self.params.drag_coefficient_n_s_per_m * x.velocity_mps;
        (Vector3::new(0.0, 0.0, thrust) + x.attitude.inverse_transform_vector(&drag_world))
            * self.inverse_mass_per_kg
    }

    /// World z of the net force over mass in `x`, m/s^2: whether a body on the ground lifts.
    pub fn vertical_acceleration(&self, x: &StateVector) -> f64 {
        let a = idx::ATTITUDE;
        let (qx, qy) = (x[a + 1], x[a + 2]);
        let speeds: [f64; 4] = std::array::from_fn(|i| x[idx::MOTORS + i]);
        let (thrust, _) = self.thrust_and_torque(&speeds);
        // World z of body z, as in the derivative.
        let up = 1.0 - 2.0 * (qx * qx + qy * qy);
        (thrust * up - self.params.drag_coefficient_n_s_per_m * x[idx::VELOCITY + 2])
            * self.inverse_mass_per_kg
            - self.params.gravity_mps2
    }
}

impl Dynamics<STATE_LEN, 4> for QuadModel {
    /// `u`: commanded motor speeds, rad/s. The quaternion is used as it is (not normalised),
    /// its derivative `q' = q (0, w) / 2` keeps the norm to first order and the simulation
    /// normalises after every step.
    #[inline]
    fn derivative(&self, x: &StateVector, u: &MotorSpeeds) -> StateVector {
        let p = &self.params;
        let a = idx::ATTITUDE;
        let (qw, qx, qy, qz) = (x[a], x[a + 1], x[a + 2], x[a + 3]);
        let r = idx::RATES;
        let (wx, wy, wz) = (x[r], x[r + 1], x[r + 2]);
        let speeds: [f64; 4] = std::array::from_fn(|i| x[idx::MOTORS + i]);
        let (thrust, torque) = self.thrust_and_torque(&speeds);

        // Body z in the world: the third column of the rotation matrix of q.
        let thrust_per_kg = thrust * self.inverse_mass_per_kg;
        let drag_per_kg = p.drag_coefficient_n_s_per_m * self.inverse_mass_per_kg;
        let v = idx::VELOCITY;
        let acc = [
            thrust_per_kg * 2.0 * (qx * qz + qw * qy) - drag_per_kg * x[v],
            thrust_per_kg * 2.0 * (qy * qz - qw * qx) - drag_per_kg * x[v + 1],
            thrust_per_kg * (1.0 - 2.0 * (qx * qx + qy * qy)) - p.gravity_mps2 - drag_per_kg * x[v + 2],
        ];

        // Euler's equations with principal inertia: I w' = tau - w x (I w) - c w.
        let [ixx, iyy, izz] = p.inertia_kg_m2;
        let c = p.rotational_drag_n_m_s_per_rad;
        let rate_dot = [
            (torque.x - (izz - iyy) * wy * wz - c * wx) / ixx,
            (torque.y - (ixx - izz) * wz * wx - c * wy) / iyy,
            (torque.z - (iyy - ixx) * wx * wy - c * wz) / izz,
        ];

        let mut dx = StateVector::zeros();
        dx[idx::POSITION] = x[v];
        dx[idx::POSITION + 1] = x[v + 1];
        dx[idx::POSITION + 2] = x[v + 2];
        dx[v] = acc[0];
        dx[v + 1] = acc[1];
        dx[v + 2] = acc[2];
        dx[a] = -0.5 * (qx * wx + qy * wy + qz * wz);
        dx[a + 1] = 0.5 * (qw * wx + qy * wz - qz * wy);
        dx[a + 2] = 0.5 * (qw * wy + qz * wx - qx * wz);
        dx[a + 3] = 0.5 * (qw * wz + qx * wy - qy * wx);
        dx[r] = rate_dot[0];
        dx[r + 1] = rate_dot[1];
        dx[r + 2] = rate_dot[2];
        for i in 0..4 {
            dx[idx::MOTORS + i] = (u[i] - speeds[i]) / p.motor_time_constant_s;
        }
        dx
    }
}
