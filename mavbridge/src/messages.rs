//! MAVLink messages of the subset the bench speaks, to and from the model's values: the one
//! place where both the gateway and the simulator turn model values into MAVLink fields and
//! back (through [`crate::frame`] and [`crate::thrust`]).

use crate::frame::{self, NedState};
use crate::thrust::ThrustMap;
use mav::{Input, State};
use mavlink::dialects::common::{
    ATTITUDE_DATA, ATTITUDE_QUATERNION_DATA, AttitudeTargetTypemask, LOCAL_POSITION_NED_DATA,
    SET_ATTITUDE_TARGET_DATA,
};

/// The type mask of every setpoint the gateway sends: body rates ignored, attitude and thrust
/// used.
pub fn setpoint_type_mask() -> AttitudeTargetTypemask {
    AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
        | AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
        | AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE
}

/// The vehicle time in MAVLink's `time_boot_ms` (wraps after 49 days, as the field does).
pub fn boot_ms(vehicle_ns: u64) -> u32 {
    (vehicle_ns / 1_000_000) as u32
}

/// `SET_ATTITUDE_TARGET` for the model's input `u` (after saturation) at the held `yaw_rad`;
/// the normalised thrust says whether it was clamped into `[0, 1]`.
pub fn setpoint(
    u: &Input,
    yaw_rad: f64,
    thrust: &ThrustMap,
    vehicle_ns: u64,
    target: (u8, u8),
) -> (SET_ATTITUDE_TARGET_DATA, bool) {
    let q = frame::setpoint_quaternion(u[1], u[2], yaw_rad);
    let (normalised, clamped) = thrust.normalise(u[0]);
    let data = SET_ATTITUDE_TARGET_DATA {
        time_boot_ms: boot_ms(vehicle_ns),
        q: q.map(|v| v as f32),
        body_roll_rate: 0.0,
        body_pitch_rate: 0.0,
        body_yaw_rate: 0.0,
        thrust: normalised as f32,
        target_system: target.0,
        target_component: target.1,
        type_mask: setpoint_type_mask(),
    };
    (data, clamped)
}

/// Why a `SET_ATTITUDE_TARGET` cannot fly the model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SetpointError {
    #[error("type_mask {0:#04x} ignores the attitude or the thrust")]
    Ignored(u8),
    #[error("q {0:?} is not a rotation")]
    Quaternion([f32; 4]),
    #[error("thrust {0} is not finite")]
    Thrust(f32),
}

/// The model's input `[T, phi_d, theta_d]` and the yaw asked for in a `SET_ATTITUDE_TARGET`
/// (the simulator's side).
pub fn setpoint_input(
    d: &SET_ATTITUDE_TARGET_DATA,
    thrust: &ThrustMap,
) -> Result<(Input, f64), SetpointError> {
    let ignored = AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
        | AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE;
    if d.type_mask.intersects(ignored) {
        return Err(SetpointError::Ignored(d.type_mask.bits()));
    }
    if !d.thrust.is_finite() {
        return Err(SetpointError::Thrust(d.thrust));
    }
    let (phi, theta, yaw) =
        frame::setpoint_angles(d.q.map(f64::from)).ok_or(SetpointError::Quaternion(d.q))?;
    Ok((Input::new(thrust.thrust_mps2(f64::from(d.thrust)), phi, theta), yaw))
}

/// `ATTITUDE` and `LOCAL_POSITION_NED` of a vehicle in the model's state `x` at `yaw_rad`
/// (the simulator's side).
pub fn state_messages(x: &State, yaw_rad: f64, vehicle_ns: u64) -> (ATTITUDE_DATA, LOCAL_POSITION_NED_DATA) {
    let n = frame::ned_state(x, yaw_rad);
    let time_boot_ms = boot_ms(vehicle_ns);
    let attitude = ATTITUDE_DATA {
        time_boot_ms,
        roll: n.roll_rad as f32,
        pitch: n.pitch_rad as f32,
        yaw: n.yaw_rad as f32,
        rollspeed: 0.0,
        pitchspeed: 0.0,
        yawspeed: 0.0,
    };
    let [x, y, z] = n.position_m.map(|v| v as f32);
    let [vx, vy, vz] = n.velocity_mps.map(|v| v as f32);
    (attitude, LOCAL_POSITION_NED_DATA { time_boot_ms, x, y, z, vx, vy, vz })
}

/// A vehicle's attitude as the gateway keeps it, from either attitude message.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Attitude {
    pub time_boot_ms: u32,
    pub roll_rad: f64,
    pub pitch_rad: f64,
    pub yaw_rad: f64,
}

impl Attitude {
    pub fn from_euler(a: &ATTITUDE_DATA) -> Option<Self> {
        let v = [a.roll, a.pitch, a.yaw];
        v.iter().all(|x| x.is_finite()).then(|| Self {
            time_boot_ms: a.time_boot_ms,
            roll_rad: f64::from(a.roll),
            pitch_rad: f64::from(a.pitch),
            yaw_rad: f64::from(a.yaw),
        })
    }

    pub fn from_quaternion(a: &ATTITUDE_QUATERNION_DATA) -> Option<Self> {
        let (roll_rad, pitch_rad, yaw_rad) =
            frame::euler_from_quaternion([a.q1, a.q2, a.q3, a.q4].map(f64::from))?;
        Some(Self { time_boot_ms: a.time_boot_ms, roll_rad, pitch_rad, yaw_rad })
    }
}

/// The vehicle's state of a position message and an attitude, or `None` when a value is not
/// finite.
pub fn ned_of(p: &LOCAL_POSITION_NED_DATA, a: &Attitude) -> Option<NedState> {
    let v = [p.x, p.y, p.z, p.vx, p.vy, p.vz];
    v.iter().all(|x| x.is_finite()).then(|| NedState {
        position_m: [p.x, p.y, p.z].map(f64::from),
        velocity_mps: [p.vx, p.vy, p.vz].map(f64::from),
        roll_rad: a.roll_rad,
        pitch_rad: a.pitch_rad,
        yaw_rad: a.yaw_rad,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::MavMessage;
    use mavlink::{MavHeader, MavlinkVersion};

    /// Encodes `msg` as a MAVLink 2 frame and decodes it again.
    fn round_trip(msg: &MavMessage) -> (Vec<u8>, MavMessage) {
        let mut bytes = Vec::new();
        let header = MavHeader { system_id: 1, component_id: 1, sequence: 7 };
        mavlink::write_v2_msg(&mut bytes, header, msg).expect("encodes");
        let mut reader = mavlink::MavlinkReader::new(&bytes[..]);
        let (h, back) = reader.read_message::<MavMessage>(MavlinkVersion::V2).expect("decodes");
        assert_eq!(h, header);
        (bytes, back)
    }

    #[test]
    fn frames_round_trip_bit_for_bit_and_the_values_survive_both_ways() {
        let thrust = ThrustMap::new(0.5, 9.81).expect("valid");
        let x = State::from([1.5, -2.25, 1.0, 0.5, -0.125, 0.25, 0.08, -0.05]);
        let yaw = 0.4;
        let (att, pos) = state_messages(&x, yaw, 12_345_000_000);
        for msg in [MavMessage::ATTITUDE(att.clone()), MavMessage::LOCAL_POSITION_NED(pos.clone())] {
            let (bytes, back) = round_trip(&msg);
            assert_eq!(back, msg);
            let (again, _) = round_trip(&back);
            assert_eq!(again, bytes, "the same frame, bit for bit");
        }
        // Simulator -> wire -> gateway: the model's state within f32's precision.
        let a = Attitude::from_euler(&att).expect("finite");
        let got = frame::model_state(&ned_of(&pos, &a).expect("finite"));
        for i in 0..8 {
            assert!((got[i] - x[i]).abs() < 1e-6 * (1.0 + x[i].abs()), "x[{i}]: {} != {}", got[i], x[i]);
        }
        assert_eq!(pos.time_boot_ms, 12_345);

        // Gateway -> wire -> simulator: the input within f32's precision, yaw held.
        let u = Input::new(11.0, -0.1, 0.15);
        let (sp, clamped) = setpoint(&u, yaw, &thrust, 12_345_678_901, (1, 1));
        assert!(!clamped);
        assert_eq!(sp.type_mask.bits(), 0b111);
        let msg = MavMessage::SET_ATTITUDE_TARGET(sp.clone());
        let (bytes, back) = round_trip(&msg);
        assert_eq!(back, msg);
        assert_eq!(round_trip(&back).0, bytes);
        let (u2, yaw2) = setpoint_input(&sp, &thrust).expect("flyable");
        for i in 0..3 {
            assert!((u2[i] - u[i]).abs() < 1e-5, "u[{i}]: {} != {}", u2[i], u[i]);
        }
        assert!((yaw2 - yaw).abs() < 1e-6);
    }

    #[test]
    fn attitude_quaternion_gives_the_same_attitude_as_euler_attitude() {
        let (roll, pitch, yaw) = (0.12, -0.07, 2.5);
        let [q1, q2, q3, q4] = frame::quaternion_from_euler(roll, pitch, yaw).map(|v| v as f32);
        let q = ATTITUDE_QUATERNION_DATA { time_boot_ms: 5, q1, q2, q3, q4, ..Default::default() };
        let a = Attitude::from_quaternion(&q).expect("a rotation");
        assert_eq!(a.time_boot_ms, 5);
        for (got, want) in [(a.roll_rad, roll), (a.pitch_rad, pitch), (a.yaw_rad, yaw)] {
            assert!((got - want).abs() < 1e-6, "{got} != {want}");
        }
        let zero = ATTITUDE_QUATERNION_DATA::default();
        assert_eq!(Attitude::from_quaternion(&zero), None, "no length: not used");
        let nan = ATTITUDE_DATA { roll: f32::NAN, ..Default::default() };
        assert_eq!(Attitude::from_euler(&nan), None);
    }

    #[test]
    fn setpoints_that_ignore_attitude_or_thrust_or_are_not_rotations_are_refused() {
        let thrust = ThrustMap::new(0.5, 9.81).expect("valid");
        let (mut sp, _) = setpoint(&Input::new(9.81, 0.0, 0.0), 0.0, &thrust, 0, (1, 1));
        assert_eq!(sp.thrust, 0.5);
        sp.type_mask |= AttitudeTargetTypemask::ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE;
        assert!(matches!(setpoint_input(&sp, &thrust), Err(SetpointError::Ignored(_))));
        sp.type_mask = setpoint_type_mask();
        sp.q = [0.0; 4];
        assert!(matches!(setpoint_input(&sp, &thrust), Err(SetpointError::Quaternion(_))));
        sp.q = [1.0, 0.0, 0.0, 0.0];
        sp.thrust = f32::NAN;
        assert!(matches!(setpoint_input(&sp, &thrust), Err(SetpointError::Thrust(_))));
    }
}
