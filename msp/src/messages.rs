//! Betaflight's messages that a companion computer needs, typed, with units.
//!
//! Layouts as Betaflight 4.6.0 writes them (`src/main/msp/msp.c`, API 1.47), little endian.
//! Decoding checks that a payload holds every field it reads and names the first missing one;
//! bytes beyond the fields known are ignored (newer firmware appends fields at the end).

use crate::frame::{Direction, EncodeError, Frame, Version};

/// Command numbers (`msp_protocol.h`).
pub mod command {
    pub const API_VERSION: u16 = 1;
    pub const FC_VARIANT: u16 = 2;
    pub const FC_VERSION: u16 = 3;
    pub const MODE_RANGES: u16 = 34;
    pub const PID_ADVANCED: u16 = 94;
    pub const STATUS: u16 = 101;
    pub const RAW_IMU: u16 = 102;
    pub const MOTOR: u16 = 104;
    pub const RC: u16 = 105;
    pub const ATTITUDE: u16 = 108;
    pub const ANALOG: u16 = 110;
    pub const BOXNAMES: u16 = 116;
    pub const BOXIDS: u16 = 119;
    pub const STATUS_EX: u16 = 150;
    pub const SET_RAW_RC: u16 = 200;
}

/// A payload that does not hold what its command says.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    #[error("{message}: payload of {len} bytes ends before `{field}` (needs {needed})")]
    Short { message: &'static str, field: &'static str, needed: usize, len: usize },
    #[error("{message}: `{field}` {reason}")]
    Invalid { message: &'static str, field: &'static str, reason: String },
    #[error("expected a reply to command {expected}, got command {got}")]
    WrongCommand { expected: u16, got: u16 },
    #[error("the flight controller refused command {0} (an error reply)")]
    Refused(u16),
    #[error("command {0} is a request, not a reply")]
    NotAReply(u16),
}

/// Reads fields in order, naming the one that is missing.
struct Reader<'a> {
    message: &'static str,
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn new(message: &'static str, bytes: &'a [u8]) -> Self {
        Self { message, bytes, at: 0 }
    }

    fn take(&mut self, field: &'static str, n: usize) -> Result<&'a [u8], DecodeError> {
        let end = self.at + n;
        let out = self.bytes.get(self.at..end).ok_or(DecodeError::Short {
            message: self.message,
            field,
            needed: end,
            len: self.bytes.len(),
        })?;
        self.at = end;
        Ok(out)
    }

    fn u8(&mut self, field: &'static str) -> Result<u8, DecodeError> {
        Ok(self.take(field, 1)?[0])
    }

    fn u16(&mut self, field: &'static str) -> Result<u16, DecodeError> {
        let b = self.take(field, 2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }

    fn i16(&mut self, field: &'static str) -> Result<i16, DecodeError> {
        let b = self.take(field, 2)?;
        Ok(i16::from_le_bytes([b[0], b[1]]))
    }

    fn u32(&mut self, field: &'static str) -> Result<u32, DecodeError> {
        let b = self.take(field, 4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
}

/// A reply's payload once its frame was checked against the command asked.
pub fn reply_payload(frame: &Frame, expected: u16) -> Result<&[u8], DecodeError> {
    if frame.command != expected {
        return Err(DecodeError::WrongCommand { expected, got: frame.command });
    }
    match frame.direction {
        Direction::FromFc => Ok(&frame.payload),
        Direction::Error => Err(DecodeError::Refused(frame.command)),
        Direction::ToFc => Err(DecodeError::NotAReply(frame.command)),
    }
}

/// A request without payload (every query below), encoded.
pub fn request(version: Version, command: u16, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    crate::frame::encode(version, Direction::ToFc, 0, command, &[], out)
}

/// `MSP_API_VERSION`: the MSP protocol and API version (Betaflight 4.6.0: 0, 1.47).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ApiVersion {
    pub protocol: u8,
    pub major: u8,
    pub minor: u8,
}

impl ApiVersion {
    pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new("MSP_API_VERSION", payload);
        Ok(Self { protocol: r.u8("protocol")?, major: r.u8("api_major")?, minor: r.u8("api_minor")? })
    }

    pub fn encode(&self) -> Vec<u8> {
        vec![self.protocol, self.major, self.minor]
    }
}

/// `MSP_FC_VARIANT`: four ASCII letters (`BTFL` for Betaflight, `INAV`, ...).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FcVariant(pub [u8; 4]);

impl FcVariant {
    pub const BETAFLIGHT: Self = Self(*b"BTFL");

    pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new("MSP_FC_VARIANT", payload);
        let b = r.take("identifier", 4)?;
        Ok(Self([b[0], b[1], b[2], b[3]]))
    }

    pub fn as_str(&self) -> &str {
        std::str::from_utf8(&self.0).unwrap_or("????")
    }
}

/// `MSP_FC_VERSION`: the firmware's version.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FcVersion {
    pub major: u8,
    pub minor: u8,
    pub patch: u8,
}

impl FcVersion {
    pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new("MSP_FC_VERSION", payload);
        Ok(Self { major: r.u8("major")?, minor: r.u8("minor")?, patch: r.u8("patch")? })
    }

    pub fn encode(&self) -> Vec<u8> {
        vec![self.major, self.minor, self.patch]
    }
}

impl std::fmt::Display for FcVersion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}.{}.{}", self.major, self.minor, self.patch)
    }
}

/// Why arming is refused: Betaflight's `armingDisableFlags_e` (`fc/runtime_config.h`), bit i
/// named by [`ArmingDisabled::NAMES`]`[i]` as the CLI's `status` prints it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ArmingDisabled(pub u32);

impl ArmingDisabled {
    /// The names of bits 0 to 28 (Betaflight 4.6.0's `armingDisableFlagNames`).
    pub const NAMES: [&'static str; 29] = [
        "NOGYRO",
        "FAILSAFE",
        "RXLOSS",
        "NOT_DISARMED",
        "BOXFAILSAFE",
        "RUNAWAY",
        "CRASH",
        "THROTTLE",
        "ANGLE",
        "BOOTGRACE",
        "NOPREARM",
        "LOAD",
        "CALIB",
        "CLI",
        "CMS",
        "BST",
        "MSP",
        "PARALYZE",
        "GPS",
        "RESCUE_SW",
        "DSHOT_TELEM",
        "REBOOT_REQD",
        "DSHOT_BBANG",
        "NO_ACC_CAL",
        "MOTOR_PROTO",
        "FLIP_SWITCH",
        "ALT_HOLD_SW",
        "POS_HOLD_SW",
        "ARM_SWITCH",
    ];
    /// No receiver signal (`RXLOSS`).
    pub const RX_LOSS: u32 = 1 << 2;
    /// Throttle not low when the arm switch went on (`THROTTLE`).
    pub const THROTTLE: u32 = 1 << 7;
    /// Tilted beyond `small_angle` (`ANGLE`).
    pub const ANGLE: u32 = 1 << 8;
    /// The first seconds after boot (`BOOTGRACE`).
    pub const BOOT_GRACE: u32 = 1 << 9;
    /// Gyro calibration running (`CALIB`).
    pub const CALIBRATING: u32 = 1 << 12;
    /// The CLI is open on a port (`CLI`).
    pub const CLI: u32 = 1 << 13;
    /// The arm switch was on while something else refused arming: it must go off and on again
    /// (`ARM_SWITCH`).
    pub const ARM_SWITCH: u32 = 1 << 28;

    /// Nothing refuses arming.
    pub fn none(&self) -> bool {
        self.0 == 0
    }

    pub fn contains(&self, bits: u32) -> bool {
        self.0 & bits == bits
    }

    /// The names of the bits set, lowest first (`UNKNOWN_<bit>` beyond the table).
    pub fn names(&self) -> Vec<String> {
        (0..32)
            .filter(|i| self.0 >> i & 1 == 1)
            .map(|i| Self::NAMES.get(i).map_or_else(|| format!("UNKNOWN_{i}"), |n| (*n).to_string()))
            .collect()
    }
}

/// Flight mode flags: bit i is the i-th box of [`BoxIds`] (the *active* boxes in the order the
/// firmware lists them, `packFlightModeFlags`), not a permanent box id. Up to 32 + 15 * 8 bits.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FlightModes(pub Vec<u8>);

impl FlightModes {
    /// Whether the box at `index` of [`BoxIds`] is on.
    pub fn is_set(&self, index: usize) -> bool {
        self.0.get(index / 8).is_some_and(|b| b >> (index % 8) & 1 == 1)
    }
}

/// `MSP_STATUS` and `MSP_STATUS_EX` (the same fields but two, see [`StatusExtra`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Status {
    /// The PID loop's period, us.
    pub cycle_time_us: u16,
    pub i2c_errors: u16,
    /// Sensors present: bit 0 acc, 1 baro, 2 mag, 3 GPS, 4 rangefinder, 5 gyro, 6 optical flow.
    pub sensors: u16,
    pub flight_modes: FlightModes,
    pub pid_profile: u8,
    /// Average system load, percent (0-100).
    pub system_load_pct: u16,
    pub extra: StatusExtra,
    /// The number of arming-disable flags this firmware knows (29 in 4.6.0).
    pub arming_disable_flag_count: u8,
    pub arming_disabled: ArmingDisabled,
    /// Bit 0: a reboot is needed for a setting to take effect.
    pub config_state: u8,
    /// The MCU's temperature, degrees Celsius (0 where unmeasured, as in SITL).
    pub cpu_temp_c: u16,
    pub rate_profile_count: u8,
}

/// The two fields in which `MSP_STATUS` and `MSP_STATUS_EX` differ.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StatusExtra {
    /// `MSP_STATUS`: the gyro's cycle time, us (Betaflight sends 0).
    Status { gyro_cycle_time_us: u16 },
    /// `MSP_STATUS_EX`.
    StatusEx { pid_profile_count: u8, rate_profile: u8 },
}

impl Status {
    /// Decodes `MSP_STATUS` (`extended == false`) or `MSP_STATUS_EX`.
    pub fn decode(payload: &[u8], extended: bool) -> Result<Self, DecodeError> {
        let mut r = Reader::new(if extended { "MSP_STATUS_EX" } else { "MSP_STATUS" }, payload);
        let cycle_time_us = r.u16("cycle_time_us")?;
        let i2c_errors = r.u16("i2c_errors")?;
        let sensors = r.u16("sensors")?;
        let mut modes = r.take("flight_modes", 4)?.to_vec();
        let pid_profile = r.u8("pid_profile")?;
        let system_load_pct = r.u16("system_load_pct")?;
        let extra = if extended {
            StatusExtra::StatusEx {
                pid_profile_count: r.u8("pid_profile_count")?,
                rate_profile: r.u8("rate_profile")?,
            }
        } else {
            StatusExtra::Status { gyro_cycle_time_us: r.u16("gyro_cycle_time_us")? }
        };
        let more = r.u8("flight_mode_extra_bytes")?;
        if more > 15 {
            return Err(DecodeError::Invalid {
                message: r.message,
                field: "flight_mode_extra_bytes",
                reason: format!("is {more}, at most 15"),
            });
        }
        modes.extend_from_slice(r.take("flight_modes_extra", usize::from(more))?);
        Ok(Self {
            cycle_time_us,
            i2c_errors,
            sensors,
            flight_modes: FlightModes(modes),
            pid_profile,
            system_load_pct,
            extra,
            arming_disable_flag_count: r.u8("arming_disable_flag_count")?,
            arming_disabled: ArmingDisabled(r.u32("arming_disable_flags")?),
            config_state: r.u8("config_state")?,
            cpu_temp_c: r.u16("cpu_temp_c")?,
            rate_profile_count: r.u8("rate_profile_count")?,
        })
    }

    /// The payload as Betaflight writes it (for tests and simulators).
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(32);
        out.extend_from_slice(&self.cycle_time_us.to_le_bytes());
        out.extend_from_slice(&self.i2c_errors.to_le_bytes());
        out.extend_from_slice(&self.sensors.to_le_bytes());
        let mut modes = self.flight_modes.0.clone();
        modes.resize(modes.len().max(4), 0);
        out.extend_from_slice(&modes[..4]);
        out.push(self.pid_profile);
        out.extend_from_slice(&self.system_load_pct.to_le_bytes());
        match self.extra {
            StatusExtra::Status { gyro_cycle_time_us } => {
                out.extend_from_slice(&gyro_cycle_time_us.to_le_bytes())
            }
            StatusExtra::StatusEx { pid_profile_count, rate_profile } => {
                out.extend_from_slice(&[pid_profile_count, rate_profile])
            }
        }
        let extra = &modes[4..modes.len().min(4 + 15)];
        out.push(extra.len() as u8);
        out.extend_from_slice(extra);
        out.push(self.arming_disable_flag_count);
        out.extend_from_slice(&self.arming_disabled.0.to_le_bytes());
        out.push(self.config_state);
        out.extend_from_slice(&self.cpu_temp_c.to_le_bytes());
        out.push(self.rate_profile_count);
        out
    }

    /// Whether the box `permanent_id` is on, by the firmware's list of active boxes
    /// (`None`: that box is not active on this firmware).
    pub fn is_on(&self, boxes: &BoxIds, permanent_id: u8) -> Option<bool> {
        boxes.index_of(permanent_id).map(|i| self.flight_modes.is_set(i))
    }
}

/// Permanent box ids (`msp_box.c`): the modes an AUX range can switch.
pub mod boxes {
    pub const ARM: u8 = 0;
    pub const ANGLE: u8 = 1;
    pub const HORIZON: u8 = 2;
    pub const FAILSAFE: u8 = 27;
    pub const AIRMODE: u8 = 28;
}

/// `MSP_BOXIDS`: the permanent ids of the active boxes, in the order of the flight mode bits.
/// Paged by 32 boxes (request payload: the page number, one byte; none: page 0).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct BoxIds(pub Vec<u8>);

impl BoxIds {
    pub fn decode(payload: &[u8]) -> Self {
        Self(payload.to_vec())
    }

    /// The flight-mode bit of box `permanent_id`.
    pub fn index_of(&self, permanent_id: u8) -> Option<usize> {
        self.0.iter().position(|&id| id == permanent_id)
    }
}

/// `MSP_BOXNAMES`: the active boxes' names, each followed by `;`, in [`BoxIds`]'s order.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct BoxNames(pub Vec<String>);

impl BoxNames {
    pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
        let text = std::str::from_utf8(payload).map_err(|e| DecodeError::Invalid {
            message: "MSP_BOXNAMES",
            field: "names",
            reason: format!("is not UTF-8 ({e})"),
        })?;
        Ok(Self(text.split_terminator(';').map(str::to_string).collect()))
    }
}

/// One slot of `MSP_MODE_RANGES`: box `permanent_id` is on while AUX channel `aux_index`
/// (0 is AUX1, the fifth channel) is within `[start_us, end_us]`. A slot whose range is empty
/// (`start_us == end_us`, 900 us by default) is unused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModeRange {
    pub permanent_id: u8,
    pub aux_index: u8,
    pub start_us: u16,
    pub end_us: u16,
}

impl ModeRange {
    /// Decodes every slot (four bytes each: id, channel, start and end steps of 25 us from
    /// 900 us).
    pub fn decode_all(payload: &[u8]) -> Result<Vec<Self>, DecodeError> {
        if !payload.len().is_multiple_of(4) {
            return Err(DecodeError::Invalid {
                message: "MSP_MODE_RANGES",
                field: "ranges",
                reason: format!("is {} bytes, not a multiple of 4", payload.len()),
            });
        }
        let step = |s: u8| 900 + 25 * u16::from(s);
        Ok(payload
            .chunks_exact(4)
            .map(|c| Self { permanent_id: c[0], aux_index: c[1], start_us: step(c[2]), end_us: step(c[3]) })
            .collect())
    }

    pub fn is_used(&self) -> bool {
        self.start_us < self.end_us
    }
}

/// `MSP_PID_ADVANCED`, the one field a companion computer needs of it: the current PID
/// profile's `angle_limit`, the tilt of a full stick in ANGLE mode, whole degrees (byte 17 in
/// Betaflight 4.6.0's layout).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PidAdvanced {
    /// `angle_limit`, degrees.
    pub angle_limit_deg: u8,
}

impl PidAdvanced {
    /// Byte offset of `angle_limit` in the payload.
    pub const ANGLE_LIMIT_AT: usize = 17;

    pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new("MSP_PID_ADVANCED", payload);
        r.take("fields_before_angle_limit", Self::ANGLE_LIMIT_AT)?;
        Ok(Self { angle_limit_deg: r.u8("angle_limit")? })
    }
}

/// `MSP_ATTITUDE`: the attitude estimate in Betaflight's axes: roll right positive, pitch
/// positive **nose down** (the NED pitch negated: measured on the SITL, whose state packets
/// carry a body FRD to NED quaternion; `gateway/tests/betaflight_sitl.rs` checks it), yaw as a
/// heading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attitude {
    /// Roll, tenths of a degree.
    pub roll_decideg: i16,
    /// Pitch, tenths of a degree.
    pub pitch_decideg: i16,
    /// Yaw (heading), whole degrees, 0 to 359.
    pub yaw_deg: i16,
}

impl Attitude {
    pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new("MSP_ATTITUDE", payload);
        Ok(Self { roll_decideg: r.i16("roll")?, pitch_decideg: r.i16("pitch")?, yaw_deg: r.i16("yaw")? })
    }

    pub fn encode(&self) -> Vec<u8> {
        [self.roll_decideg, self.pitch_decideg, self.yaw_deg].iter().flat_map(|v| v.to_le_bytes()).collect()
    }

    pub fn roll_rad(&self) -> f64 {
        f64::from(self.roll_decideg).to_radians() / 10.0
    }

    pub fn pitch_rad(&self) -> f64 {
        f64::from(self.pitch_decideg).to_radians() / 10.0
    }

    pub fn yaw_rad(&self) -> f64 {
        f64::from(self.yaw_deg).to_radians()
    }
}

/// At most this many channels in `MSP_SET_RAW_RC` (`MAX_SUPPORTED_RC_CHANNEL_COUNT`); more is
/// an error reply.
pub const MAX_RC_CHANNELS: usize = 18;

/// `MSP_SET_RAW_RC`: RC channels as a receiver delivers them, us, in the receiver's order,
/// which Betaflight maps with `rcmap` (default `AETR1234`: roll, pitch, throttle, yaw, then
/// AUX1, AUX2, ...). The firmware answers with an empty reply.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawRc {
    channels: Vec<u16>,
}

/// Sticks and switches, us (1000 to 2000; 1500 centred).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sticks {
    pub roll_us: u16,
    pub pitch_us: u16,
    pub throttle_us: u16,
    pub yaw_us: u16,
}

impl RawRc {
    /// Channels in `AETR1234` order (the firmware's default map): the sticks, then `aux_us`
    /// (AUX1 first). At most [`MAX_RC_CHANNELS`] channels in all.
    pub fn aetr(sticks: Sticks, aux_us: &[u16]) -> Result<Self, DecodeError> {
        let mut channels = vec![sticks.roll_us, sticks.pitch_us, sticks.throttle_us, sticks.yaw_us];
        channels.extend_from_slice(aux_us);
        Self::from_channels(channels)
    }

    /// Channels as they go on the wire.
    pub fn from_channels(channels: Vec<u16>) -> Result<Self, DecodeError> {
        if channels.len() > MAX_RC_CHANNELS {
            return Err(DecodeError::Invalid {
                message: "MSP_SET_RAW_RC",
                field: "channels",
                reason: format!("are {}, at most {MAX_RC_CHANNELS}", channels.len()),
            });
        }
        Ok(Self { channels })
    }

    pub fn channels(&self) -> &[u16] {
        &self.channels
    }

    pub fn encode(&self) -> Vec<u8> {
        self.channels.iter().flat_map(|c| c.to_le_bytes()).collect()
    }

    /// The request frame.
    pub fn to_frame(&self, version: Version) -> Frame {
        Frame::request(version, command::SET_RAW_RC, self.encode())
    }

    pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
        if !payload.len().is_multiple_of(2) {
            return Err(DecodeError::Invalid {
                message: "MSP_SET_RAW_RC",
                field: "channels",
                reason: format!("are {} bytes, not whole u16s", payload.len()),
            });
        }
        Self::from_channels(payload.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect())
    }
}

/// `MSP_RC`: the channels as the firmware uses them (`rcData`), us, in *function* order:
/// roll, pitch, yaw, throttle (`AERT`), then AUX1, ... (after `rcmap`, so not the order of
/// [`RawRc`]). As many channels as the receiver has (18 for the MSP receiver).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rc(pub Vec<u16>);

impl Rc {
    pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
        if !payload.len().is_multiple_of(2) {
            return Err(DecodeError::Invalid {
                message: "MSP_RC",
                field: "channels",
                reason: format!("are {} bytes, not whole u16s", payload.len()),
            });
        }
        Ok(Self(payload.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect()))
    }

    pub fn encode(&self) -> Vec<u8> {
        self.0.iter().flat_map(|c| c.to_le_bytes()).collect()
    }

    /// The sticks (`None`: fewer than four channels).
    pub fn sticks(&self) -> Option<Sticks> {
        match self.0[..] {
            [roll_us, pitch_us, yaw_us, throttle_us, ..] => {
                Some(Sticks { roll_us, pitch_us, throttle_us, yaw_us })
            }
            _ => None,
        }
    }

    /// AUX channel `index` (0 is AUX1).
    pub fn aux_us(&self, index: usize) -> Option<u16> {
        self.0.get(4 + index).copied()
    }
}

/// `MSP_MOTOR`: eight motor outputs in the firmware's motor order (0 for motors absent or
/// disabled). With PWM (as in SITL) in us, 1000 stopped to 2000 full; with DShot the DShot
/// value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Motor(pub [u16; 8]);

impl Motor {
    pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
        const FIELDS: [&str; 8] =
            ["motor1", "motor2", "motor3", "motor4", "motor5", "motor6", "motor7", "motor8"];
        let mut r = Reader::new("MSP_MOTOR", payload);
        let mut m = [0; 8];
        for (v, field) in m.iter_mut().zip(FIELDS) {
            *v = r.u16(field)?;
        }
        Ok(Self(m))
    }

    pub fn encode(&self) -> Vec<u8> {
        self.0.iter().flat_map(|v| v.to_le_bytes()).collect()
    }
}

/// `MSP_RAW_IMU`: the sensors' readings in the body frame (x forward, y right, z down, as the
/// firmware aligns them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RawImu {
    /// Accelerometer, raw units (the sensor's `acc_1G` per g: 256 for SITL's virtual sensor).
    pub acc: [i16; 3],
    /// Gyro, degrees per second.
    pub gyro_dps: [i16; 3],
    /// Magnetometer, raw units.
    pub mag: [i16; 3],
}

impl RawImu {
    pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new("MSP_RAW_IMU", payload);
        Ok(Self {
            acc: [r.i16("acc_x")?, r.i16("acc_y")?, r.i16("acc_z")?],
            gyro_dps: [r.i16("gyro_x")?, r.i16("gyro_y")?, r.i16("gyro_z")?],
            mag: [r.i16("mag_x")?, r.i16("mag_y")?, r.i16("mag_z")?],
        })
    }

    pub fn encode(&self) -> Vec<u8> {
        self.acc.iter().chain(&self.gyro_dps).chain(&self.mag).flat_map(|v| v.to_le_bytes()).collect()
    }
}

/// `MSP_ANALOG`: battery and RSSI.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Analog {
    /// Battery voltage, tenths of a volt (legacy, saturates at 25.5 V).
    pub vbat_decivolt: u8,
    /// Charge drawn, mAh.
    pub drawn_mah: u16,
    /// RSSI, 0 to 1023.
    pub rssi: u16,
    /// Current, hundredths of an ampere.
    pub current_centiamp: i16,
    /// Battery voltage, hundredths of a volt.
    pub voltage_centivolt: u16,
}

impl Analog {
    pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new("MSP_ANALOG", payload);
        Ok(Self {
            vbat_decivolt: r.u8("vbat")?,
            drawn_mah: r.u16("mah_drawn")?,
            rssi: r.u16("rssi")?,
            current_centiamp: r.i16("amperage")?,
            voltage_centivolt: r.u16("voltage")?,
        })
    }

    pub fn encode(&self) -> Vec<u8> {
        let mut out = vec![self.vbat_decivolt];
        out.extend_from_slice(&self.drawn_mah.to_le_bytes());
        out.extend_from_slice(&self.rssi.to_le_bytes());
        out.extend_from_slice(&self.current_centiamp.to_le_bytes());
        out.extend_from_slice(&self.voltage_centivolt.to_le_bytes());
        out
    }

    pub fn voltage_v(&self) -> f64 {
        f64::from(self.voltage_centivolt) / 100.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `MSP_STATUS_EX` as Betaflight 4.6.0 SITL answered it (`tests/sitl.rs`), configured by
    /// `firmware/betaflight/hilbench.cli`, with AUX2 high (ANGLE on: flight-mode bit 1 of 20
    /// active boxes, so no extra mode byte), disarmed, no state packets: the PID loop at
    /// 2,088 us, acc, baro and gyro present, 29 arming flags, ANGLE, BOOTGRACE and CALIB set.
    const STATUS_EX_SITL: [u8; 25] = [
        0x28, 0x08, 0x00, 0x00, 0x23, 0x00, 0x02, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x04, 0x00, 0x00, 0x1d,
        0x00, 0x13, 0x00, 0x00, 0x00, 0x00, 0x00, 0x04,
    ];

    #[test]
    fn status_ex_layout_matches_the_firmware() {
        let s = Status::decode(&STATUS_EX_SITL, true).expect("decodes");
        assert_eq!(s.cycle_time_us, 2088);
        assert_eq!(s.sensors, 0b10_0011, "acc, baro, gyro");
        assert!(!s.flight_modes.is_set(0) && s.flight_modes.is_set(1) && !s.flight_modes.is_set(2));
        assert_eq!(s.flight_modes.0.len(), 4);
        assert_eq!(s.extra, StatusExtra::StatusEx { pid_profile_count: 4, rate_profile: 0 });
        assert_eq!(s.arming_disable_flag_count, 29);
        assert_eq!(s.arming_disabled.names(), vec!["ANGLE", "BOOTGRACE", "CALIB"]);
        assert_eq!(s.rate_profile_count, 4);
        assert_eq!(s.encode(), STATUS_EX_SITL.to_vec(), "re-encodes byte for byte");
        let boxes = BoxIds(vec![0, 1, 2, 6, 27]);
        assert_eq!(s.is_on(&boxes, boxes::ARM), Some(false));
        assert_eq!(s.is_on(&boxes, boxes::ANGLE), Some(true));
        assert_eq!(s.is_on(&boxes, boxes::FAILSAFE), Some(false));
        assert_eq!(s.is_on(&boxes, boxes::AIRMODE), None);
        // A 5th mode byte (more than 32 active boxes) is read from the extra bytes.
        let mut more = s.clone();
        more.flight_modes = FlightModes(vec![0, 0, 0, 0, 0b10]);
        let back = Status::decode(&more.encode(), true).expect("decodes");
        assert!(back.flight_modes.is_set(33));
        assert_eq!(back, more);
    }

    #[test]
    fn status_differs_from_status_ex_in_two_bytes_and_a_short_payload_names_its_field() {
        let mut plain = STATUS_EX_SITL.to_vec();
        // MSP_STATUS: a u16 gyro cycle time (0) where STATUS_EX has the two profile bytes.
        plain[13] = 0;
        plain[14] = 0;
        let s = Status::decode(&plain, false).expect("decodes");
        assert_eq!(s.extra, StatusExtra::Status { gyro_cycle_time_us: 0 });
        assert_eq!(s.encode(), plain);
        let err = Status::decode(&STATUS_EX_SITL[..20], true).expect_err("short");
        assert_eq!(
            err,
            DecodeError::Short {
                message: "MSP_STATUS_EX",
                field: "arming_disable_flags",
                needed: 21,
                len: 20
            }
        );
        assert!(err.to_string().contains("arming_disable_flags"), "{err}");
    }

    #[test]
    fn arming_flags_are_named_as_the_cli_names_them() {
        let f =
            ArmingDisabled(ArmingDisabled::RX_LOSS | ArmingDisabled::ANGLE | ArmingDisabled::CLI | 1 << 30);
        assert_eq!(f.names(), vec!["RXLOSS", "ANGLE", "CLI", "UNKNOWN_30"]);
        assert!(f.contains(ArmingDisabled::ANGLE));
        assert!(!f.contains(ArmingDisabled::ARM_SWITCH));
        assert_eq!(ArmingDisabled::NAMES[28], "ARM_SWITCH");
    }

    #[test]
    fn attitude_is_decidegrees_and_degrees() {
        // roll -12.5 deg, pitch 3.0 deg, heading 270 deg.
        let a = Attitude::decode(&[0x83, 0xff, 0x1e, 0x00, 0x0e, 0x01]).expect("decodes");
        assert_eq!(a, Attitude { roll_decideg: -125, pitch_decideg: 30, yaw_deg: 270 });
        assert!((a.roll_rad() - (-12.5f64).to_radians()).abs() < 1e-12);
        assert!((a.yaw_rad() - 270f64.to_radians()).abs() < 1e-12);
        assert_eq!(a.encode(), vec![0x83, 0xff, 0x1e, 0x00, 0x0e, 0x01]);
        assert!(matches!(Attitude::decode(&[0; 5]), Err(DecodeError::Short { field: "yaw", .. })));
    }

    #[test]
    fn raw_rc_goes_out_in_aetr_order_and_rc_comes_back_in_aert_order() {
        let sticks = Sticks { roll_us: 1400, pitch_us: 1600, throttle_us: 1100, yaw_us: 1550 };
        let raw = RawRc::aetr(sticks, &[1800, 1900]).expect("six channels");
        assert_eq!(raw.channels(), &[1400, 1600, 1100, 1550, 1800, 1900]);
        assert_eq!(raw.encode()[..4], [0x78, 0x05, 0x40, 0x06]);
        assert_eq!(RawRc::decode(&raw.encode()), Ok(raw.clone()));
        // What MSP_RC reports after the default map: roll, pitch, yaw, throttle.
        let rc = Rc(vec![1400, 1600, 1550, 1100, 1800, 1900]);
        assert_eq!(rc.sticks(), Some(sticks));
        assert_eq!(rc.aux_us(1), Some(1900));
        assert_eq!(Rc::decode(&rc.encode()), Ok(rc));
        assert!(RawRc::from_channels(vec![1500; 19]).is_err());
        assert!(Rc::decode(&[0; 3]).is_err());
    }

    #[test]
    fn fixed_layouts_round_trip_and_name_what_is_missing() {
        let imu = RawImu { acc: [1, -2, 256], gyro_dps: [-300, 0, 7], mag: [0, 0, 0] };
        assert_eq!(RawImu::decode(&imu.encode()), Ok(imu));
        assert_eq!(imu.encode().len(), 18);
        let analog = Analog {
            vbat_decivolt: 168,
            drawn_mah: 350,
            rssi: 1023,
            current_centiamp: -12,
            voltage_centivolt: 1680,
        };
        assert_eq!(analog.encode().len(), 9);
        assert_eq!(Analog::decode(&analog.encode()), Ok(analog));
        let motor = Motor([1000, 1055, 1100, 2000, 0, 0, 0, 0]);
        assert_eq!(motor.encode().len(), 16);
        assert_eq!(Motor::decode(&motor.encode()), Ok(motor));
        assert!(matches!(Motor::decode(&[0; 15]), Err(DecodeError::Short { field: "motor8", .. })));
        assert_eq!(ApiVersion::decode(&[0, 1, 47]), Ok(ApiVersion { protocol: 0, major: 1, minor: 47 }));
        assert_eq!(FcVersion::decode(&[4, 6, 0]).map(|v| v.to_string()), Ok("4.6.0".to_string()));
        assert_eq!(FcVariant::decode(b"BTFL"), Ok(FcVariant::BETAFLIGHT));
        assert!(matches!(FcVariant::decode(b"BTF"), Err(DecodeError::Short { field: "identifier", .. })));
        // Bytes after the known fields (a newer firmware's) are ignored.
        assert!(FcVersion::decode(&[4, 6, 0, 9]).is_ok());
    }

    #[test]
    fn pid_advanced_gives_the_angle_limit_at_byte_17() {
        let mut payload = vec![0u8; 45];
        payload[PidAdvanced::ANGLE_LIMIT_AT] = 20;
        assert_eq!(PidAdvanced::decode(&payload), Ok(PidAdvanced { angle_limit_deg: 20 }));
        assert!(matches!(
            PidAdvanced::decode(&payload[..17]),
            Err(DecodeError::Short { field: "angle_limit", .. })
        ));
    }

    #[test]
    fn boxes_and_mode_ranges() {
        let names = BoxNames::decode(b"ARM;ANGLE;HORIZON;").expect("utf-8");
        assert_eq!(names.0, vec!["ARM", "ANGLE", "HORIZON"]);
        let ids = BoxIds::decode(&[0, 1, 2]);
        assert_eq!(ids.index_of(boxes::HORIZON), Some(2));
        // ARM on AUX1 and ANGLE on AUX2 from 1700 to 2100 us, then an unused slot.
        let ranges = ModeRange::decode_all(&[0, 0, 32, 48, 1, 1, 32, 48, 0, 0, 0, 0]).expect("decodes");
        assert_eq!(ranges[0], ModeRange { permanent_id: 0, aux_index: 0, start_us: 1700, end_us: 2100 });
        assert_eq!(ranges[1].permanent_id, boxes::ANGLE);
        assert!(!ranges[2].is_used());
        assert!(ModeRange::decode_all(&[0; 5]).is_err());
    }

    #[test]
    fn a_reply_is_checked_against_the_command_asked_and_an_error_reply_is_a_refusal() {
        let ok = Frame { direction: Direction::FromFc, ..Frame::request(Version::V1, 1, vec![0, 1, 47]) };
        assert_eq!(reply_payload(&ok, 1), Ok(&[0u8, 1, 47][..]));
        assert_eq!(reply_payload(&ok, 2), Err(DecodeError::WrongCommand { expected: 2, got: 1 }));
        let refused = Frame { direction: Direction::Error, ..ok.clone() };
        assert_eq!(reply_payload(&refused, 1), Err(DecodeError::Refused(1)));
        let request = Frame::request(Version::V1, 1, vec![]);
        assert_eq!(reply_payload(&request, 1), Err(DecodeError::NotAReply(1)));
    }
}
