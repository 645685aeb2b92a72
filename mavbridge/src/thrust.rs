//! The model's mass-normalised thrust `T` (m/s^2) and the autopilot's normalised thrust in
//! `[0, 1]`: a line through zero fixed by one calibration point, the thrust that hovers.

/// Why a calibration is refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ThrustError {
    #[error("hover thrust must be in (0, 1), got {0}")]
    HoverThrust(f64),
    #[error("gravity must be finite and > 0 m/s^2, got {0}")]
    Gravity(f64),
}

/// `normalised = hover_thrust * T / g`, clamped to `[0, 1]`; `T = g * normalised / hover_thrust`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThrustMap {
    hover_thrust: f64,
    gravity_mps2: f64,
}

impl ThrustMap {
    /// `hover_thrust` in `(0, 1)` is what the vehicle needs to hover (`--hover-thrust`);
    /// `gravity_mps2` the model's `g`.
    pub fn new(hover_thrust: f64, gravity_mps2: f64) -> Result<Self, ThrustError> {
        if !(hover_thrust.is_finite() && hover_thrust > 0.0 && hover_thrust < 1.0) {
            return Err(ThrustError::HoverThrust(hover_thrust));
        }
        if !(gravity_mps2.is_finite() && gravity_mps2 > 0.0) {
            return Err(ThrustError::Gravity(gravity_mps2));
        }
        Ok(Self { hover_thrust, gravity_mps2 })
    }

    pub fn hover_thrust(&self) -> f64 {
        self.hover_thrust
    }

    /// The normalised thrust for `T`, and whether it had to be clamped into `[0, 1]`.
    pub fn normalise(&self, thrust_mps2: f64) -> (f64, bool) {
        let n = self.hover_thrust * thrust_mps2 / self.gravity_mps2;
        let c = n.clamp(0.0, 1.0);
        (c, c != n)
    }

    /// `T` for a normalised thrust (clamped into `[0, 1]` first, as an autopilot does).
    pub fn thrust_mps2(&self, normalised: f64) -> f64 {
        normalised.clamp(0.0, 1.0) * self.gravity_mps2 / self.hover_thrust
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn g_maps_to_the_hover_thrust_and_the_range_is_clamped() {
        let m = ThrustMap::new(0.5, 9.81).expect("valid");
        assert_eq!(m.normalise(9.81), (0.5, false));
        assert_eq!(m.normalise(0.0), (0.0, false));
        assert_eq!(m.normalise(2.0 * 9.81), (1.0, false));
        assert_eq!(m.normalise(30.0), (1.0, true));
        assert_eq!(m.normalise(-1.0), (0.0, true));
        assert_eq!(m.thrust_mps2(0.5), 9.81);
        let m = ThrustMap::new(0.3, 9.81).expect("valid");
        let (n, _) = m.normalise(12.0);
        assert!((m.thrust_mps2(n) - 12.0).abs() < 1e-12);
        assert!(ThrustMap::new(1.0, 9.81).is_err());
        assert!(ThrustMap::new(f64::NAN, 9.81).is_err());
        assert!(ThrustMap::new(0.5, 0.0).is_err());
    }
}
