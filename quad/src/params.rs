//! The quadrotor's physical parameters as validated data, and what follows from them (hover
//! command, thrust-to-weight ratio).

/// A parameter that is not finite or not physically meaningful, named.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParamError {
    #[error("invalid quad parameter `{field}`: {reason}")]
    Invalid { field: &'static str, reason: &'static str },
}

/// Physical parameters of the quadrotor. SI units, named in each field.
///
/// `Default` is a 450 mm class quadrotor (an F450-style frame: 450 mm motor-to-motor
/// diagonal, 2212 920 KV motors, 10x4.5 inch props, 3S battery), numbers of the order the
/// parts' public data sheets and thrust tables give:
/// - mass about 1 kg (frame ~0.28 kg, four motors ~0.22 kg, four ESCs ~0.1 kg, 3S 2200 mAh
///   battery ~0.19 kg, flight controller, receiver and wiring ~0.2 kg);
/// - about 7.4 N (750 g) of thrust per motor at full speed, thrust-to-weight about 3;
/// - inertia from the motors and ESCs as point masses of ~0.1 kg at the arms' ends plus the
///   hub and battery (`Izz ~ 4 m a^2`, `Ixx = Iyy ~ Izz / 2`);
/// - hover at about 58 % of full motor speed (`hover_command()`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuadParams {
    /// Mass, kg.
    pub mass_kg: f64,
    /// Distance from the centre of mass to each motor's axis, m (half the motor-to-motor
    /// diagonal; the motors sit at +-45 degrees from the nose).
    pub arm_length_m: f64,
    /// Principal moments of inertia about body x, y, z (FLU), kg m^2. The body axes are
    /// taken as principal: the products of inertia of a symmetric X frame vanish.
    pub inertia_kg_m2: [f64; 3],
    /// Thrust of one motor per squared motor speed, N/(rad/s)^2: `F = k_f w^2`.
    pub thrust_coefficient_n_per_rad2_s2: f64,
    /// Reaction (drag) torque of one motor per squared motor speed, N m/(rad/s)^2:
    /// `Q = k_m w^2`, acting on the body against the propeller's spin. About 1-2 % of the
    /// thrust coefficient (in metres) for 5-10 inch propellers.
    pub torque_coefficient_n_m_per_rad2_s2: f64,
    /// Time constant of a motor's first-order response to its commanded speed, s.
    pub motor_time_constant_s: f64,
    /// Motor speed at a command of 1, rad/s (a command maps linearly to speed).
    pub max_motor_speed_rad_s: f64,
    /// Linear drag on the velocity through the air (no wind), the same on every axis,
    /// N s/m: `F = -c v`.
    pub drag_coefficient_n_s_per_m: f64,
    /// Linear rotational drag on the body rates, N m s/rad: `tau = -c w`.
    pub rotational_drag_n_m_s_per_rad: f64,
    /// Gravitational acceleration, m/s^2 (standard gravity by default, the value Betaflight's
    /// SITL uses for 1 g).
    pub gravity_mps2: f64,
}

impl Default for QuadParams {
    fn default() -> Self {
        Self {
            mass_kg: 1.0,
            arm_length_m: 0.225,
            inertia_kg_m2: [0.011, 0.011, 0.021],
            thrust_coefficient_n_per_rad2_s2: 1.0e-5,
            // k_m / k_f = 0.016 m.
            torque_coefficient_n_m_per_rad2_s2: 1.6e-7,
            // Tens of milliseconds for a 10-inch propeller on a 2212 motor.
            motor_time_constant_s: 0.04,
            // ~8200 rpm: 920 KV at 11.1 V, loaded to about 80 % of the no-load speed.
            max_motor_speed_rad_s: 860.0,
            drag_coefficient_n_s_per_m: 0.25,
            // A rate decays with I / c ~ 10 s: small beside the motors' authority.
            rotational_drag_n_m_s_per_rad: 1.0e-3,
            gravity_mps2: 9.80665,
        }
    }
}

impl QuadParams {
    /// Checks that every parameter is finite and physically meaningful; names the first bad one.
    pub fn validate(&self) -> Result<(), ParamError> {
        let invalid = |field, reason| Err(ParamError::Invalid { field, reason });
        let positive: [(&'static str, f64); 6] = [
            ("mass_kg", self.mass_kg),
            ("arm_length_m", self.arm_length_m),
            ("thrust_coefficient_n_per_rad2_s2", self.thrust_coefficient_n_per_rad2_s2),
            ("motor_time_constant_s", self.motor_time_constant_s),
            ("max_motor_speed_rad_s", self.max_motor_speed_rad_s),
            ("gravity_mps2", self.gravity_mps2),
        ];
        for (field, value) in positive {
            if !value.is_finite() || value <= 0.0 {
                return invalid(field, "must be finite and > 0");
            }
        }
        let non_negative: [(&'static str, f64); 3] = [
            ("torque_coefficient_n_m_per_rad2_s2", self.torque_coefficient_n_m_per_rad2_s2),
            ("drag_coefficient_n_s_per_m", self.drag_coefficient_n_s_per_m),
            ("rotational_drag_n_m_s_per_rad", self.rotational_drag_n_m_s_per_rad),
        ];
        for (field, value) in non_negative {
            if !value.is_finite() || value < 0.0 {
                return invalid(field, "must be finite and >= 0");
            }
        }
        let [ixx, iyy, izz] = self.inertia_kg_m2;
        if [ixx, iyy, izz].iter().any(|i| !i.is_finite() || *i <= 0.0) {
            return invalid("inertia_kg_m2", "every moment must be finite and > 0");
        }
        // Principal moments of a real body: each at most the sum of the other two.
        if ixx > iyy + izz || iyy > ixx + izz || izz > ixx + iyy {
            return invalid("inertia_kg_m2", "must satisfy the triangle inequality of a rigid body");
        }
        Ok(())
    }

    /// Weight, N.
    pub fn weight_n(&self) -> f64 {
        self.mass_kg * self.gravity_mps2
    }

    /// Total thrust of the four motors at full speed, N.
    pub fn max_thrust_n(&self) -> f64 {
        4.0 * self.thrust_coefficient_n_per_rad2_s2 * self.max_motor_speed_rad_s * self.max_motor_speed_rad_s
    }

    /// Thrust-to-weight ratio at full speed.
    pub fn thrust_to_weight(&self) -> f64 {
        self.max_thrust_n() / self.weight_n()
    }

    /// The motor speed at which the four motors together carry the weight, rad/s.
    pub fn hover_motor_speed_rad_s(&self) -> f64 {
        (self.weight_n() / (4.0 * self.thrust_coefficient_n_per_rad2_s2)).sqrt()
    }

    /// The normalised command (the same on every motor) that hovers: `1 / sqrt(thrust-to-weight)`
    /// with the linear command-to-speed map. Above 1 the vehicle cannot hover.
    pub fn hover_command(&self) -> f64 {
        self.hover_motor_speed_rad_s() / self.max_motor_speed_rad_s
    }
}
