//! The body's pose as a motion-capture system publishes it (docs/betaflight.md, "The pose
//! stream"): MAVLink 2 `ODOMETRY` (#331, common dialect), as mavros' `mocap`/`odometry`
//! plugins and motion_capture_tracking bridges send it. Pure: the shell owns the socket.
//!
//! - `time_usec`: plant time, us.
//! - `frame_id` `MAV_FRAME_LOCAL_NED`, `child_frame_id` `MAV_FRAME_BODY_FRD`.
//! - `x, y, z`: position, NED, m (north, east, down from the bench's origin on the ground).
//! - `q`: body FRD to NED, `[w, x, y, z]`, `w >= 0`.
//! - `vx, vy, vz`: velocity in the child frame (body FRD), m/s, as ODOMETRY specifies.
//! - `rollspeed, pitchspeed, yawspeed`: body rates, FRD, rad/s.
//! - `pose_covariance`, `velocity_covariance`: NaN (unknown, the spec's marker).
//! - extensions: `reset_counter` 0, `estimator_type` `MAV_ESTIMATOR_TYPE_MOCAP`, `quality` 100.
//!
//! The bench's world frame (x, y, z up, the ground at z = 0; `mavbridge::frame`) is NED with
//! y and z negated, so the gateway turns this stream into the model's state with
//! `mavbridge::frame` exactly as it does PX4's `LOCAL_POSITION_NED`: x = north, y = west.
//! `quad` integrates in ENU; [`bench_to_enu`] and [`enu_to_bench`] convert.
//!
//! The `mavlink` crate encodes the message; the workspace builds it without
//! `mav2-message-extensions`, so [`encode_odometry`] appends the three extension bytes to its
//! payload and frames it (MAVLink 2 header, trailing zeros truncated, CRC with the message's
//! CRC_EXTRA) itself.

use mavlink::MessageData;
use mavlink::dialects::common::{MavEstimatorType, MavFrame, ODOMETRY_DATA};
use nalgebra::Vector3;
use quad::QuadSample;
use quad::frames::{attitude_frd_ned, enu_to_ned, flu_to_frd};

/// The stream's MAVLink system id (the vehicle's: 1).
pub const SYSTEM_ID: u8 = 1;
/// The stream's component id: `MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY` (197), the external pose
/// source's.
pub const COMPONENT_ID: u8 = 197;
/// `ODOMETRY`'s id.
pub const ODOMETRY_ID: u32 = 331;
/// `quality`: 100, the best (a motion-capture system sees the body exactly here).
pub const QUALITY: i8 = 100;

/// A point of the bench's world (x, y, z up: x north, y west) in `quad`'s ENU world.
pub fn bench_to_enu(p: [f64; 3]) -> Vector3<f64> {
    Vector3::new(-p[1], p[0], p[2])
}

/// A point of `quad`'s ENU world in the bench's world (x north, y west, z up).
pub fn enu_to_bench(p: &Vector3<f64>) -> [f64; 3] {
    [p.y, -p.x, p.z]
}

/// The `ODOMETRY` message of one sample (extensions apart: [`encode_odometry`]).
pub fn odometry(sample: &QuadSample) -> ODOMETRY_DATA {
    let s = &sample.state;
    let p = enu_to_ned(&s.position_m);
    let q = attitude_frd_ned(&s.attitude);
    let q = if q.w < 0.0 { -q.into_inner() } else { q.into_inner() };
    let v = flu_to_frd(&s.attitude.inverse_transform_vector(&s.velocity_mps));
    let w = flu_to_frd(&s.angular_velocity_rad_s);
    let f = |x: f64| (x + 0.0) as f32;
    ODOMETRY_DATA {
        time_usec: sample.time_ns / 1_000,
        x: f(p.x),
        y: f(p.y),
        z: f(p.z),
        q: [f(q.w), f(q.i), f(q.j), f(q.k)],
        vx: f(v.x),
        vy: f(v.y),
        vz: f(v.z),
        rollspeed: f(w.x),
        pitchspeed: f(w.y),
        yawspeed: f(w.z),
        pose_covariance: [f32::NAN; 21],
        velocity_covariance: [f32::NAN; 21],
        frame_id: MavFrame::MAV_FRAME_LOCAL_NED,
        child_frame_id: MavFrame::MAV_FRAME_BODY_FRD,
    }
}

/// Length of ODOMETRY's payload without its extensions, bytes.
const BASE_LEN: usize = ODOMETRY_DATA::ENCODED_LEN;
/// The extensions: `reset_counter` (u8), `estimator_type` (u8), `quality` (i8).
const EXTENSIONS_LEN: usize = 3;

/// One MAVLink 2 frame of `ODOMETRY` for `sample`, with sequence number `sequence`, written to
/// `out` (cleared first).
pub fn encode_odometry(sample: &QuadSample, sequence: u8, out: &mut Vec<u8>) {
    let mut payload = [0u8; BASE_LEN + EXTENSIONS_LEN];
    let n = odometry(sample).ser(mavlink::MavlinkVersion::V2, &mut payload[..BASE_LEN]);
    debug_assert!(n <= BASE_LEN);
    payload[BASE_LEN] = 0; // reset_counter
    payload[BASE_LEN + 1] = MavEstimatorType::MAV_ESTIMATOR_TYPE_MOCAP as u8;
    payload[BASE_LEN + 2] = QUALITY.to_le_bytes()[0];
    // MAVLink 2 drops the payload's trailing zeros (keeping at least one byte).
    let len = payload.iter().rposition(|b| *b != 0).map_or(1, |i| i + 1);
    out.clear();
    let id = ODOMETRY_ID.to_le_bytes();
    out.extend_from_slice(&[0xFD, len as u8, 0, 0, sequence, SYSTEM_ID, COMPONENT_ID, id[0], id[1], id[2]]);
    out.extend_from_slice(&payload[..len]);
    let crc = mavlink::calculate_crc(&out[1..], ODOMETRY_DATA::EXTRA_CRC);
    out.extend_from_slice(&crc.to_le_bytes());
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::MavMessage;
    use nalgebra::UnitQuaternion;
    use quad::{Contact, ImuReading, QuadState};

    fn sample(state: QuadState) -> QuadSample {
        QuadSample {
            time_ns: 1_234_567_000,
            state,
            imu: ImuReading {
                specific_force_body_mps2: Vector3::zeros(),
                angular_velocity_body_rad_s: Vector3::zeros(),
            },
            contact: Contact::default(),
        }
    }

    #[test]
    fn the_bench_s_world_is_ned_with_y_and_z_negated() {
        // 1 m north, 2 m west, 3 m up.
        let enu = bench_to_enu([1.0, 2.0, 3.0]);
        assert_eq!(enu, Vector3::new(-2.0, 1.0, 3.0));
        assert_eq!(enu_to_ned(&enu), Vector3::new(1.0, -2.0, -3.0));
        assert_eq!(enu_to_bench(&enu), [1.0, 2.0, 3.0]);
    }

    #[test]
    fn a_body_flying_north_nose_north_reports_forward_velocity_and_yaw_zero() {
        let mut s = QuadState::resting_at(0.0, 0.0);
        s.position_m = bench_to_enu([1.0, 2.0, 3.0]);
        // Nose north: a quarter turn left from quad's nose east.
        s.attitude = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
        s.velocity_mps = Vector3::new(0.0, 2.0, 0.5); // north 2, up 0.5
        s.angular_velocity_rad_s = Vector3::new(0.0, 0.0, 0.3); // yawing left
        let o = odometry(&sample(s));
        assert_eq!((o.x, o.y, o.z), (1.0, -2.0, -3.0));
        let [w, x, y, z] = o.q;
        assert!((w - 1.0).abs() < 1e-6 && x.abs() < 1e-6 && y.abs() < 1e-6 && z.abs() < 1e-6, "{:?}", o.q);
        assert!((o.vx - 2.0).abs() < 1e-6 && o.vy.abs() < 1e-6 && (o.vz + 0.5).abs() < 1e-6);
        assert!((o.yawspeed + 0.3).abs() < 1e-6, "left is negative about FRD's z (down)");
        assert_eq!(o.time_usec, 1_234_567);
        assert!(o.pose_covariance[0].is_nan() && o.velocity_covariance[0].is_nan());
    }

    #[test]
    fn the_frame_parses_with_the_mavlink_crate_and_carries_the_extensions() {
        let mut s = QuadState::resting_at(0.0, 0.0);
        s.position_m = bench_to_enu([1.0, 2.0, 3.0]);
        let mut out = Vec::new();
        encode_odometry(&sample(s), 9, &mut out);
        assert_eq!(out[1] as usize, BASE_LEN + EXTENSIONS_LEN, "quality is non-zero: nothing truncated");
        let mut r = mavlink::MavlinkReader::new(&out[..]);
        let (h, m) = r.read_message::<MavMessage>(mavlink::MavlinkVersion::V2).expect("parses, CRC good");
        assert_eq!((h.system_id, h.component_id, h.sequence), (u32::from(SYSTEM_ID), COMPONENT_ID, 9));
        let MavMessage::ODOMETRY(o) = m else { panic!("{m:?}") };
        assert_eq!((o.x, o.y, o.z), (1.0, -2.0, -3.0));
        assert_eq!(o.frame_id, MavFrame::MAV_FRAME_LOCAL_NED);
        assert_eq!(o.child_frame_id, MavFrame::MAV_FRAME_BODY_FRD);
        assert_eq!(out[10 + BASE_LEN + 1], MavEstimatorType::MAV_ESTIMATOR_TYPE_MOCAP as u8);
    }
}
