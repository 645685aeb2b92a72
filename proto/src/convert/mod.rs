//! Wire <-> core conversion. Everything that comes in is validated here, once, for every
//! service: `TryFrom<pb::X>` (or a `*_from_pb` function) returns a [`FieldError`] naming the
//! offending field, which services turn into `INVALID_ARGUMENT` via `From<FieldError> for
//! tonic::Status`. Outgoing conversions (`From<&core> for pb::X`) cannot fail.

#[cfg(feature = "controller")]
pub mod controller;
#[cfg(feature = "netem")]
pub mod netem;
#[cfg(feature = "plant")]
pub mod plant;
#[cfg(feature = "plant")]
pub mod scenario;
#[cfg(feature = "vehicle")]
pub mod vehicle;

use crate::pb;

/// A field of an incoming message that failed validation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid field `{field}`: {reason}")]
pub struct FieldError {
    /// Dotted path of the field, e.g. `command.input.thrust_mps2` or `initial_state.x[3]`.
    pub field: String,
    /// What is wrong with it.
    pub reason: String,
}

impl FieldError {
    pub fn new(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self { field: field.into(), reason: reason.into() }
    }

    /// The same error for a field nested inside `parent`.
    pub fn within(self, parent: &str) -> Self {
        Self { field: format!("{parent}.{}", self.field), reason: self.reason }
    }
}

impl From<FieldError> for tonic::Status {
    fn from(e: FieldError) -> Self {
        tonic::Status::invalid_argument(e.to_string())
    }
}

/// Largest mass-normalised thrust a command may ask for, m/s^2 (about 100 g); the plant then
/// saturates it to the scenario's limit.
pub const MAX_THRUST_MPS2: f64 = 1000.0;

/// A control input every plant accepts (what the plant checks, and netem before it holds a
/// command): finite, thrust in `[0, MAX_THRUST_MPS2]`, roll and pitch in `(-pi/2, pi/2)` rad.
/// `field` is the path of the `ControlInput`; the result is `[thrust, roll, pitch]`.
pub fn check_input(field: &str, u: &pb::ControlInput) -> Result<[f64; 3], FieldError> {
    let range = |f: &str, v: f64, range: &str| {
        FieldError::new(f, format!("must be in {range}, got {}", delay::Number(v)))
    };
    let thrust_field = format!("{field}.thrust_mps2");
    let thrust = finite(&thrust_field, u.thrust_mps2)?;
    if !(0.0..=MAX_THRUST_MPS2).contains(&thrust) {
        return Err(range(&thrust_field, thrust, &format!("[0, {MAX_THRUST_MPS2}] m/s^2")));
    }
    let mut angles = [0.0; 2];
    for (out, (name, v)) in angles.iter_mut().zip([("roll_rad", u.roll_rad), ("pitch_rad", u.pitch_rad)]) {
        let f = format!("{field}.{name}");
        *out = finite(&f, v)?;
        if out.abs() >= std::f64::consts::FRAC_PI_2 {
            return Err(range(&f, v, "(-pi/2, pi/2) rad"));
        }
    }
    Ok([thrust, angles[0], angles[1]])
}

/// A finite number, or an error naming `field`.
pub fn finite(field: &str, v: f64) -> Result<f64, FieldError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(FieldError::new(field, format!("must be finite, got {}", delay::Number(v))))
    }
}

/// Exactly `N` finite numbers, or an error naming `field` (and the index of a bad element).
pub fn finite_array<const N: usize>(field: &str, v: &[f64]) -> Result<[f64; N], FieldError> {
    if v.len() != N {
        return Err(FieldError::new(field, format!("must hold exactly {N} values, got {}", v.len())));
    }
    let mut out = [0.0; N];
    for (i, (o, x)) in out.iter_mut().zip(v).enumerate() {
        *o = finite(&format!("{field}[{i}]"), *x)?;
    }
    Ok(out)
}

/// A required sub-message, or an error naming `field` as missing.
pub fn required<'a, T>(field: &str, v: &'a Option<T>) -> Result<&'a T, FieldError> {
    v.as_ref().ok_or_else(|| FieldError::new(field, "is required"))
}

impl From<mav::TimeMode> for pb::TimeMode {
    fn from(mode: mav::TimeMode) -> Self {
        match mode {
            mav::TimeMode::Lockstep => pb::TimeMode::Lockstep,
            mav::TimeMode::RealTime => pb::TimeMode::RealTime,
        }
    }
}

/// The time mode a plant's `PlantDescription.time_mode` says it runs in: lockstep only when it
/// says so; any other value (unspecified, or a mode of a newer contract) is a plant on its own
/// clock, real time.
pub fn time_mode_of_plant(time_mode: i32) -> mav::TimeMode {
    if time_mode == pb::TimeMode::Lockstep as i32 { mav::TimeMode::Lockstep } else { mav::TimeMode::RealTime }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arrays_are_checked_for_length_and_finiteness() {
        assert_eq!(finite_array::<3>("u", &[1.0, 2.0, 3.0]), Ok([1.0, 2.0, 3.0]));
        assert_eq!(finite_array::<3>("u", &[1.0, 2.0]).map_err(|e| e.field), Err("u".to_string()));
        assert_eq!(
            finite_array::<3>("u", &[1.0, f64::NAN, 3.0]).map_err(|e| e.field),
            Err("u[1]".to_string())
        );
        let status: tonic::Status = FieldError::new("x", "bad").within("req").into();
        assert_eq!(status.code(), tonic::Code::InvalidArgument);
        assert!(status.message().contains("req.x"));
    }
}
