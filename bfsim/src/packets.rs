//! The SITL's UDP packets as bytes (docs/betaflight.md, "Ports and packets"): the state the
//! simulator sends (`fdm_packet`, UDP 9003) and the motor outputs the firmware answers with
//! (`servo_packet`, UDP 9002). Little endian, the structs' natural x86-64 layout. Pure.

use quad::betaflight::FdmState;

/// Size of an `fdm_packet`: 18 doubles.
pub const FDM_PACKET_LEN: usize = 144;
/// Size of a `servo_packet`: 4 floats.
pub const SERVO_PACKET_LEN: usize = 16;

/// Where the virtual GPS puts the world's origin (the `fdm_packet`'s position is longitude,
/// latitude and altitude with `USE_VIRTUAL_GPS`, which the SITL build defines): PX4's default
/// home (Zurich), deg.
pub const ORIGIN_LAT_DEG: f64 = 47.397742;
pub const ORIGIN_LON_DEG: f64 = 8.545594;
/// Mean Earth radius for the origin's local tangent plane, m.
const EARTH_RADIUS_M: f64 = 6_371_000.0;
/// Sea-level standard pressure, Pa (the virtual barometer reads the standard atmosphere at the
/// body's height above the ground, taken as sea level).
const SEA_LEVEL_PA: f64 = 101_325.0;

/// The barometric pressure of the standard atmosphere at `altitude_m`, Pa.
pub fn pressure_pa(altitude_m: f64) -> f64 {
    SEA_LEVEL_PA * (1.0 - 2.255_77e-5 * altitude_m).powf(5.255_88)
}

/// An ENU position about the origin as the virtual GPS's longitude, latitude (deg) and
/// altitude (m).
pub fn lon_lat_alt(position_enu_m: [f64; 3]) -> [f64; 3] {
    let [e, n, u] = position_enu_m;
    let lat = ORIGIN_LAT_DEG + (n / EARTH_RADIUS_M).to_degrees();
    let lon = ORIGIN_LON_DEG + (e / (EARTH_RADIUS_M * ORIGIN_LAT_DEG.to_radians().cos())).to_degrees();
    [lon, lat, u]
}

/// The `fdm_packet` for one state: timestamp, gyro, accelerometer, attitude as `quad` gives
/// them in the firmware's frames, velocity (ENU) and position (longitude, latitude, altitude)
/// for the virtual GPS, and the pressure at the body's height.
pub fn encode_fdm(state: &FdmState) -> [u8; FDM_PACKET_LEN] {
    let mut fields = [0.0f64; 18];
    fields[0] = state.timestamp_s;
    fields[1..4].copy_from_slice(&state.imu_angular_velocity_rpy);
    fields[4..7].copy_from_slice(&state.imu_linear_acceleration_xyz);
    fields[7..11].copy_from_slice(&state.imu_orientation_quat);
    fields[11..14].copy_from_slice(&state.velocity_enu_mps);
    fields[14..17].copy_from_slice(&lon_lat_alt(state.position_enu_m));
    fields[17] = pressure_pa(state.position_enu_m[2]);
    let mut out = [0u8; FDM_PACKET_LEN];
    for (chunk, v) in out.chunks_exact_mut(8).zip(fields) {
        chunk.copy_from_slice(&v.to_le_bytes());
    }
    out
}

/// A datagram on the motor port that is not a motor packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum BadServoPacket {
    #[error("{0} bytes, not {SERVO_PACKET_LEN}")]
    Length(usize),
    #[error("a motor output is not finite")]
    NonFinite,
}

/// The `motor_speed[4]` of a `servo_packet` (the firmware's order, see
/// `quad::betaflight::motors_from_servo_packet`).
pub fn decode_servo(datagram: &[u8]) -> Result<[f32; 4], BadServoPacket> {
    if datagram.len() != SERVO_PACKET_LEN {
        return Err(BadServoPacket::Length(datagram.len()));
    }
    let mut out = [0f32; 4];
    for (o, chunk) in out.iter_mut().zip(datagram.chunks_exact(4)) {
        *o = f32::from_le_bytes([chunk[0], chunk[1], chunk[2], chunk[3]]);
    }
    if out.iter().any(|v| !v.is_finite()) {
        return Err(BadServoPacket::NonFinite);
    }
    Ok(out)
}

/// A `servo_packet` as the firmware writes it (for fakes of the firmware in tests).
pub fn encode_servo(motor_speed: [f32; 4]) -> [u8; SERVO_PACKET_LEN] {
    let mut out = [0u8; SERVO_PACKET_LEN];
    for (chunk, v) in out.chunks_exact_mut(4).zip(motor_speed) {
        chunk.copy_from_slice(&v.to_le_bytes());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f64_at(bytes: &[u8], index: usize) -> f64 {
        f64::from_le_bytes(bytes[index * 8..index * 8 + 8].try_into().expect("8 bytes"))
    }

    #[test]
    fn the_fdm_packet_has_the_struct_s_offsets() {
        let state = FdmState {
            timestamp_s: 1.5,
            imu_angular_velocity_rpy: [0.1, 0.2, 0.3],
            imu_linear_acceleration_xyz: [0.0, 0.0, -9.80665],
            imu_orientation_quat: [1.0, 0.0, 0.0, 0.0],
            velocity_enu_mps: [1.0, 2.0, 3.0],
            position_enu_m: [0.0, 0.0, 10.0],
            position_ned_m: [0.0, 0.0, -10.0],
        };
        let b = encode_fdm(&state);
        assert_eq!(f64_at(&b, 0), 1.5); // offset 0: timestamp
        assert_eq!(f64_at(&b, 1), 0.1); // offset 8: gyro
        assert_eq!(f64_at(&b, 6), -9.80665); // offset 32 + 16: acc z
        assert_eq!(f64_at(&b, 7), 1.0); // offset 56: quaternion w
        assert_eq!(f64_at(&b, 11), 1.0); // offset 88: velocity
        assert_eq!((f64_at(&b, 14), f64_at(&b, 15)), (ORIGIN_LON_DEG, ORIGIN_LAT_DEG)); // 112
        assert_eq!(f64_at(&b, 16), 10.0);
        let p = f64_at(&b, 17); // offset 136: pressure
        assert!((p - 101_205.0).abs() < 5.0, "{p}");
    }

    #[test]
    fn a_metre_north_and_east_moves_the_virtual_gps_by_a_metre() {
        let [lon, lat, _] = lon_lat_alt([1.0, 1.0, 0.0]);
        let dn = (lat - ORIGIN_LAT_DEG).to_radians() * EARTH_RADIUS_M;
        let de = (lon - ORIGIN_LON_DEG).to_radians() * EARTH_RADIUS_M * ORIGIN_LAT_DEG.to_radians().cos();
        assert!((dn - 1.0).abs() < 1e-6 && (de - 1.0).abs() < 1e-6, "{dn} {de}");
    }

    #[test]
    fn servo_packets_round_trip_and_bad_ones_are_named() {
        let m = [0.1, 0.2, 0.3, 0.4];
        assert_eq!(decode_servo(&encode_servo(m)), Ok(m));
        assert_eq!(decode_servo(&[0; 15]), Err(BadServoPacket::Length(15)));
        assert_eq!(decode_servo(&encode_servo([0.0, f32::NAN, 0.0, 0.0])), Err(BadServoPacket::NonFinite));
    }
}
