//! The commands the vehicle and its controller fall back on: the one sanitiser that every
//! command leaving the controller goes through, and braking. The controller's safety layer and
//! fail-safe check brake with [`braking_command`], and the plant's watchdog brakes with the
//! same law ([`crate::sim::WatchdogAction::Brake`]), so the check's model of a lost link is the
//! plant's own behaviour.

use crate::model::{InputBounds, ModelParams};

/// The braking law's default gain, 1/s: desired acceleration `-v` per second (the safety
/// layer's `brake_gain_per_s` and the plant watchdog's).
pub const DEFAULT_BRAKE_GAIN_PER_S: f64 = 1.0;

/// The one command sanitiser, every command that leaves the controller goes through it:
/// finite and inside the bounds (non-finite components become hover's, then everything is
/// clipped to the box), and a zero is +0: protobuf does not carry the sign of zero, so a -0
/// sent in process would reach the plant as +0 over gRPC and the two logs would differ.
pub fn sanitize_command(params: &ModelParams, bounds: &InputBounds, u: [f64; 3]) -> [f64; 3] {
    let hover = [params.gravity_mps2, 0.0, 0.0];
    let mut out = [0.0; 3];
    for c in 0..3 {
        let v = if u[c].is_finite() { u[c] } else { hover[c] };
        // `-0.0 + 0.0` is `+0.0`; every other value is unchanged.
        out[c] = v.clamp(bounds.min[c], bounds.max[c]) + 0.0;
    }
    out
}

/// A braking command from state `x`: the thrust vector that gives the acceleration
/// `-gain * v` against gravity (`vx' = T cos(phi) sin(theta)`, `vy' = -T sin(phi)`,
/// `vz' = T cos(phi) cos(theta) - g`), clipped to the bounds. Hover for a non-finite state.
pub fn braking_command(params: &ModelParams, bounds: &InputBounds, x: &[f64; 8], gain: f64) -> [f64; 3] {
    let g = params.gravity_mps2;
    let (ax, ay, az) = (-gain * x[3], -gain * x[4], -gain * x[5]);
    let vertical = (g + az).max(0.1 * g);
    let t = (ax * ax + ay * ay + vertical * vertical).sqrt();
    let raw = if t.is_finite() && t > 0.0 {
        [t, (-ay / t).clamp(-1.0, 1.0).asin(), ax.atan2(vertical)]
    } else {
        [g, 0.0, 0.0]
    };
    sanitize_command(params, bounds, raw)
}
#[cfg(test)]
mod tests;
