//! The gateway's core for a Betaflight flight controller over MSP: the counterpart of
//! [`crate::Bridge`] for a vehicle that is flown by sticks, as a companion computer flies it.
//!
//! - **Out, on a steady clock**: `MSP_SET_RAW_RC` every [`MspSettings::rc_period_ns`] (50 Hz)
//!   in `AETR` order with AUX1 the arm switch and AUX2 ANGLE mode (always on); requests
//!   (`MSP_STATUS_EX`, `MSP_ATTITUDE`, and once the firmware's identity, boxes and
//!   `angle_limit`) at low rates with at most [`MspSettings::max_in_flight`] unanswered: the
//!   firmware handles one MSP command per 10 ms and its TCP buffer is 1400 bytes
//!   (docs/betaflight.md, section 4).
//! - **Sticks** ([`StickMap`]): the model's input `[T, phi_d, theta_d]` at the yaw held since
//!   arming becomes NED roll and pitch ([`crate::frame::ned_angles`]), a stick of
//!   `angle / angle_limit` (ANGLE mode: full stick is `angle_limit`, a line once
//!   `hilbench.cli` has straightened the rates curve), and a throttle through the firmware's
//!   own throttle path and a propeller's thrust, the square of its speed ([`ThrottleCurve`]),
//!   pinned by the hover throttle. Every clamp is counted.
//! - **Arming** only when asked ([`MspBridge::request_arm`]): the throttle stays low until the
//!   firmware says it armed (it refuses a switch raised with the throttle up).
//! - **A silent controller** (the MAVLink side's rule, docs/gateway.md): no command for
//!   [`MspSettings::command_timeout_ns`] (500 ms): level attitude at hover throttle, the samples
//!   say `watchdog_hover`; still none after [`MspSettings::disarm_timeout_ns`]: the arm switch
//!   goes low (Betaflight has no position hold in ANGLE mode to fall back on).
//! - **In**: bytes from the one flight controller (the TCP peer, or the serial device) through
//!   [`msp::Decoder`], whose counters are the bad frames dropped; the pose stream
//!   ([`Pose`], MAVLink `ODOMETRY`) for position and velocity, the firmware's `MSP_ATTITUDE`
//!   for the attitude.
//!
//! Time is passed in (the gateway's monotonic clock, ns); nothing here reads a clock or does
//! I/O.

use crate::episode::{Episode, initial_command};
use crate::frame::{self, NedState};
use mav::{AppliedCommand, CommandMeta, Input, PlantSample, Scenario, State};
use mavlink::dialects::common::{MavFrame, ODOMETRY_DATA};
use msp::messages::{Attitude, BoxIds, FcVariant, FcVersion, PidAdvanced, RawRc, Status, Sticks, boxes};
use msp::{Decoder, DecoderSettings, Direction, Frame, Version, command};

/// Stick and switch pulse widths, us.
pub const STICK_MIN_US: u16 = 1000;
pub const STICK_CENTRE_US: u16 = 1500;
pub const STICK_MAX_US: u16 = 2000;
/// A switch on (inside the `1700..=2100` us ranges of `firmware/betaflight/hilbench.cli`).
pub const SWITCH_ON_US: u16 = 1800;
/// A switch off.
pub const SWITCH_OFF_US: u16 = 1000;

/// The arm switch stays low at least this long before it goes high, ns: the firmware arms on
/// the switch's edge and must see it low first (RC frames can be lost), else it latches
/// `ARM_SWITCH`.
pub const SWITCH_LOW_MIN_NS: u64 = 300_000_000;

/// The firmware's RXLOSS trigger: RC frames further apart than this lose the receiver, ns
/// (`RXLOSS_TRIGGER_INTERVAL`, 150 ms of firmware time).
pub const RX_LOSS_NS: u64 = 150_000_000;

/// The calibration that maps the controller's command to sticks, measured on the vehicle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// The throttle that hovers the vehicle in ANGLE mode, us (1000 to 2000 exclusive):
    /// `T = g` maps to it (`--hover-throttle-us`).
    pub hover_throttle_us: f64,
    /// The tilt of a full stick in ANGLE mode, degrees (Betaflight's `angle_limit`, 20 in
    /// `hilbench.cli`). The firmware's own value, read over `MSP_PID_ADVANCED`, replaces it
    /// once heard.
    pub angle_limit_deg: f64,
    /// The throttle below which the firmware reads zero throttle, us (its `min_check`, 1050 by
    /// default): `rc.c` maps `min_check..2000` onto the mixer's whole throttle range.
    pub min_check_us: f64,
    /// The motors' output at zero throttle while armed, a fraction of full output (the
    /// firmware's `motor_idle`, 550 = 5.5 % by default): the mixer maps the throttle onto
    /// `motor_idle..1`.
    pub motor_idle: f64,
}

impl Default for Calibration {
    fn default() -> Self {
        Self { hover_throttle_us: 1500.0, angle_limit_deg: 20.0, min_check_us: 1050.0, motor_idle: 0.055 }
    }
}

/// An invalid setting.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MspError {
    #[error("invalid MSP gateway setting `{0}`: {1}")]
    Setting(&'static str, String),
}

impl Calibration {
    pub fn validate(&self) -> Result<(), MspError> {
        let h = self.hover_throttle_us;
        if !(h.is_finite() && h > f64::from(STICK_MIN_US) && h < f64::from(STICK_MAX_US)) {
            return Err(MspError::Setting(
                "hover_throttle_us",
                format!("must be in (1000, 2000) us, got {h}"),
            ));
        }
        let a = self.angle_limit_deg;
        if !(1.0..=90.0).contains(&a) {
            return Err(MspError::Setting("angle_limit_deg", format!("must be 1 to 90 degrees, got {a}")));
        }
        let m = self.min_check_us;
        if !(m.is_finite() && m >= f64::from(STICK_MIN_US) && m < h) {
            return Err(MspError::Setting(
                "min_check_us",
                format!("must be 1000 us or more and below the hover throttle ({h} us), got {m}"),
            ));
        }
        let i = self.motor_idle;
        if !(i.is_finite() && (0.0..0.5).contains(&i)) {
            return Err(MspError::Setting("motor_idle", format!("must be in [0, 0.5), got {i}")));
        }
        Ok(())
    }
}

/// The controller's mass-normalised thrust `T` and the throttle stick, through what lies between
/// them on a Betaflight quadrotor: `rc.c` maps the stick's `min_check..2000` us onto a throttle
/// `t` in `[0, 1]` (the default throttle curve is a line), the mixer maps `t` onto a motor output
/// `m = idle + (1 - idle) t` (no `thrust_linear`, its default), a motor's speed follows its
/// output, and a propeller's thrust is the square of its speed. So `T = g (m / m_hover)^2`, with
/// `m_hover` the output at the measured hover throttle: one measurement pins the curve, as
/// `hover_thrust` pins the MAVLink side's line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThrottleCurve {
    min_check_us: f64,
    motor_idle: f64,
    hover_output: f64,
    gravity_mps2: f64,
}

impl ThrottleCurve {
    pub fn new(calibration: &Calibration, gravity_mps2: f64) -> Result<Self, MspError> {
        calibration.validate()?;
        if !(gravity_mps2.is_finite() && gravity_mps2 > 0.0) {
            return Err(MspError::Setting(
                "gravity_mps2",
                format!("must be finite and > 0, got {gravity_mps2}"),
            ));
        }
        let mut curve = Self {
            min_check_us: calibration.min_check_us,
            motor_idle: calibration.motor_idle,
            hover_output: 1.0,
            gravity_mps2,
        };
        curve.hover_output = curve.output(calibration.hover_throttle_us);
        Ok(curve)
    }

    /// The motor output that hovers, a fraction of full output (the MAVLink side's
    /// `hover_thrust`).
    pub fn hover_output(&self) -> f64 {
        self.hover_output
    }

    /// The motor output for a throttle stick, a fraction of full output.
    pub fn output(&self, throttle_us: f64) -> f64 {
        let range = f64::from(STICK_MAX_US) - self.min_check_us;
        let t = ((throttle_us - self.min_check_us) / range).clamp(0.0, 1.0);
        self.motor_idle + (1.0 - self.motor_idle) * t
    }

    /// The thrust a throttle stick gives, m/s^2.
    pub fn thrust_mps2(&self, throttle_us: f64) -> f64 {
        self.gravity_mps2 * (self.output(throttle_us) / self.hover_output).powi(2)
    }

    /// The throttle stick for `T`, us, and whether it was clamped: below the idle's thrust (an
    /// armed motor does not stop), above full output, or NaN (zero throttle).
    pub fn throttle_us(&self, thrust_mps2: f64) -> (u16, bool) {
        if thrust_mps2.is_nan() {
            return (STICK_MIN_US, true);
        }
        let output = self.hover_output * (thrust_mps2.max(0.0) / self.gravity_mps2).sqrt();
        let t = (output - self.motor_idle) / (1.0 - self.motor_idle);
        let clamped = !(0.0..=1.0).contains(&t);
        let range = f64::from(STICK_MAX_US) - self.min_check_us;
        let us = if t <= 0.0 { f64::from(STICK_MIN_US) } else { self.min_check_us + t.min(1.0) * range };
        let (us, _) = clamp_us(us);
        (us, clamped)
    }
}

/// Where the samples' roll, pitch and heading come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AttitudeSource {
    /// The firmware's own estimate, `MSP_ATTITUDE` (what it flies), at most 10 times a second
    /// within the MSP budget and one round trip old (10 to 150 ms).
    #[default]
    Firmware,
    /// The pose stream's quaternion (motion capture's attitude), at the stream's rate (bfsim:
    /// 100 Hz) and as fresh as its positions.
    Pose,
}

/// Settings of the MSP bridge, with units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MspSettings {
    pub calibration: Calibration,
    /// `MSP_SET_RAW_RC` period, ns (20 ms: 50 Hz; at most 100 ms, the firmware loses the
    /// receiver after 150 ms).
    pub rc_period_ns: u64,
    /// `MSP_ATTITUDE` request period, ns (100 ms; fewer when replies are slower): with the
    /// RC frames and the status, 64 frames a second, within the firmware's 100.
    pub attitude_period_ns: u64,
    /// `MSP_STATUS_EX` request period, ns (250 ms).
    pub status_period_ns: u64,
    /// Requests sent and not answered at most (1 or 2, never two of one command; RC frames
    /// aside): 1 (two lost a third of the RC frames on the SITL, one a tenth).
    pub max_in_flight: usize,
    /// A request unanswered this long is counted lost, ns (300 ms: the SITL's round trips are
    /// 10 to 150 ms).
    pub reply_timeout_ns: u64,
    /// No command for this long: level hover, ns (`--command-timeout-ms`, 500 ms as the
    /// MAVLink side).
    pub command_timeout_ns: u64,
    /// No command for this long while armed (from the last command, or from the arming the
    /// firmware reported): disarm, ns
    /// (`--disarm-timeout-ms`, 2 s).
    pub disarm_timeout_ns: u64,
    /// No frame from the flight controller for this long: the link is lost, ns (1 s; the
    /// RC replies alone come at 50 Hz).
    pub link_timeout_ns: u64,
    /// No pose for this long: the Plant API stops serving, ns (1 s).
    pub pose_timeout_ns: u64,
    /// A `Reset` whose start is farther than this from the vehicle is refused, m.
    pub start_tolerance_m: f64,
    /// A pose farther than this outside the scenario's box is refused, m.
    pub envelope_margin_m: f64,
    /// A pose faster than this is refused, m/s.
    pub max_speed_mps: f64,
    /// Where the samples' attitude comes from (`--attitude-from`).
    pub attitude_source: AttitudeSource,
}

impl Default for MspSettings {
    fn default() -> Self {
        Self {
            calibration: Calibration::default(),
            rc_period_ns: 20_000_000,
            attitude_period_ns: 100_000_000,
            status_period_ns: 250_000_000,
            max_in_flight: 1,
            reply_timeout_ns: 300_000_000,
            command_timeout_ns: 500_000_000,
            disarm_timeout_ns: 2_000_000_000,
            link_timeout_ns: 1_000_000_000,
            pose_timeout_ns: 1_000_000_000,
            start_tolerance_m: 0.5,
            envelope_margin_m: 100.0,
            max_speed_mps: 50.0,
            attitude_source: AttitudeSource::Firmware,
        }
    }
}

impl MspSettings {
    pub fn validate(&self) -> Result<(), MspError> {
        self.calibration.validate()?;
        let bad = |name, why: String| Err(MspError::Setting(name, why));
        if !(5_000_000..=100_000_000).contains(&self.rc_period_ns) {
            return bad("rc_period_ns", format!("must be 5 to 100 ms, got {} ns", self.rc_period_ns));
        }
        if !(1..=2).contains(&self.max_in_flight) {
            return bad("max_in_flight", format!("must be 1 or 2, got {}", self.max_in_flight));
        }
        for (name, v) in [
            ("attitude_period_ns", self.attitude_period_ns),
            ("status_period_ns", self.status_period_ns),
            ("reply_timeout_ns", self.reply_timeout_ns),
            ("command_timeout_ns", self.command_timeout_ns),
            ("link_timeout_ns", self.link_timeout_ns),
            ("pose_timeout_ns", self.pose_timeout_ns),
        ] {
            if v == 0 {
                return bad(name, "must be > 0".into());
            }
        }
        if self.disarm_timeout_ns <= self.command_timeout_ns {
            return bad(
                "disarm_timeout_ns",
                format!(
                    "must exceed the command timeout ({} ns): hover first, then disarm; got {} ns",
                    self.command_timeout_ns, self.disarm_timeout_ns
                ),
            );
        }
        for (name, v) in [
            ("start_tolerance_m", self.start_tolerance_m),
            ("envelope_margin_m", self.envelope_margin_m),
            ("max_speed_mps", self.max_speed_mps),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(name, format!("must be finite and >= 0, got {v}"));
            }
        }
        Ok(())
    }
}

/// Which stick clamps a command needed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Clamps {
    pub throttle: bool,
    pub roll: bool,
    pub pitch: bool,
}

impl Clamps {
    pub fn any(&self) -> bool {
        self.throttle || self.roll || self.pitch
    }
}

/// A stick for a tilt: `1500 + 500 * angle / limit` us, rounded, clamped to 1000..2000, and
/// whether it was clamped.
pub fn angle_stick_us(angle_rad: f64, limit_rad: f64) -> (u16, bool) {
    let us = f64::from(STICK_CENTRE_US) + 500.0 * angle_rad / limit_rad;
    clamp_us(us)
}

fn clamp_us(us: f64) -> (u16, bool) {
    let (lo, hi) = (f64::from(STICK_MIN_US), f64::from(STICK_MAX_US));
    if us.is_nan() {
        return (STICK_CENTRE_US, true);
    }
    let c = us.clamp(lo, hi);
    (c.round() as u16, c != us)
}

/// The command to sticks: the calibration in force.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StickMap {
    throttle: ThrottleCurve,
    angle_limit_rad: f64,
}

impl StickMap {
    pub fn new(calibration: &Calibration, gravity_mps2: f64) -> Result<Self, MspError> {
        let throttle = ThrottleCurve::new(calibration, gravity_mps2)?;
        Ok(Self { throttle, angle_limit_rad: calibration.angle_limit_deg.to_radians() })
    }

    pub fn angle_limit_rad(&self) -> f64 {
        self.angle_limit_rad
    }

    /// The throttle for `T`, us ([`ThrottleCurve`]).
    pub fn throttle_us(&self, thrust_mps2: f64) -> (u16, bool) {
        self.throttle.throttle_us(thrust_mps2)
    }

    pub fn throttle_curve(&self) -> &ThrottleCurve {
        &self.throttle
    }

    /// The sticks for the model's input at the yaw held, rad. Roll right and pitch nose down
    /// are sticks above centre (Betaflight's axes: its pitch is the NED pitch negated).
    pub fn sticks(&self, input: &Input, yaw_rad: f64) -> (Sticks, Clamps) {
        let (roll, pitch) = frame::ned_angles(input[1], input[2], yaw_rad);
        let (roll_us, roll_c) = angle_stick_us(roll, self.angle_limit_rad);
        let (pitch_us, pitch_c) = angle_stick_us(-pitch, self.angle_limit_rad);
        let (throttle_us, throttle_c) = self.throttle_us(input[0]);
        (
            Sticks { roll_us, pitch_us, throttle_us, yaw_us: STICK_CENTRE_US },
            Clamps { throttle: throttle_c, roll: roll_c, pitch: pitch_c },
        )
    }
}

/// The firmware's attitude as NED Euler angles, rad: roll as is, pitch negated (Betaflight's
/// pitch is positive nose down), yaw the heading.
pub fn ned_attitude(a: &Attitude) -> (f64, f64, f64) {
    let yaw = a.yaw_rad();
    let yaw = if yaw > std::f64::consts::PI { yaw - 2.0 * std::f64::consts::PI } else { yaw };
    (a.roll_rad(), -a.pitch_rad(), yaw)
}

/// A motion-capture pose: MAVLink `ODOMETRY` (#331) as the pose stream carries it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// The vehicle's clock, us.
    pub time_us: u64,
    /// NED, m.
    pub position_m: [f64; 3],
    /// NED, m/s (the message's body FRD velocity rotated by its quaternion).
    pub velocity_mps: [f64; 3],
    /// The attitude as NED roll, pitch and heading, rad (from `q`).
    pub attitude_rad: (f64, f64, f64),
}

/// Why a pose is refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoseRefusal {
    /// `frame_id` is not `MAV_FRAME_LOCAL_NED` or `child_frame_id` not `MAV_FRAME_BODY_FRD`.
    Frame,
    /// A non-finite value, or a quaternion that is not of unit norm (within 1e-2).
    Invalid,
}

/// The quaternion `[w, x, y, z]` (body to world) applied to `v`.
fn rotate(q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    let [w, x, y, z] = q;
    [
        (1.0 - 2.0 * (y * y + z * z)) * v[0] + 2.0 * (x * y - w * z) * v[1] + 2.0 * (x * z + w * y) * v[2],
        2.0 * (x * y + w * z) * v[0] + (1.0 - 2.0 * (x * x + z * z)) * v[1] + 2.0 * (y * z - w * x) * v[2],
        2.0 * (x * z - w * y) * v[0] + 2.0 * (y * z + w * x) * v[1] + (1.0 - 2.0 * (x * x + y * y)) * v[2],
    ]
}

impl Pose {
    /// The pose in an `ODOMETRY` message (frames checked, velocity turned into NED).
    pub fn from_odometry(m: &ODOMETRY_DATA) -> Result<Self, PoseRefusal> {
        if m.frame_id != MavFrame::MAV_FRAME_LOCAL_NED || m.child_frame_id != MavFrame::MAV_FRAME_BODY_FRD {
            return Err(PoseRefusal::Frame);
        }
        let q = m.q.map(f64::from);
        let values = [m.x, m.y, m.z, m.vx, m.vy, m.vz];
        let norm = q.iter().map(|c| c * c).sum::<f64>().sqrt();
        if values.iter().any(|v| !v.is_finite()) || norm.is_nan() || (norm - 1.0).abs() > 1e-2 {
            return Err(PoseRefusal::Invalid);
        }
        let q = q.map(|c| c / norm);
        Ok(Self {
            time_us: m.time_usec,
            position_m: [m.x, m.y, m.z].map(f64::from),
            velocity_mps: rotate(q, [m.vx, m.vy, m.vz].map(f64::from)),
            attitude_rad: frame::euler_from_quaternion(q).ok_or(PoseRefusal::Invalid)?,
        })
    }
}

/// What the bridge counted since start.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MspCounters {
    /// `MSP_SET_RAW_RC` frames sent.
    pub rc_sent: u64,
    /// Their (empty) replies.
    pub rc_acks: u64,
    /// Requests sent (`MSP_STATUS_EX`, `MSP_ATTITUDE`, ...).
    pub requests_sent: u64,
    /// Requests unanswered within [`MspSettings::reply_timeout_ns`].
    pub replies_lost: u64,
    /// Replies to nothing asked (or asked and already given up).
    pub unexpected_replies: u64,
    /// Replies whose payload did not decode.
    pub bad_replies: u64,
    /// Commands whose throttle was clamped to 1000..2000 us (below idle or above full).
    pub throttle_clamped: u64,
    /// Commands whose roll stick was clamped (a tilt beyond `angle_limit`).
    pub roll_clamped: u64,
    pub pitch_clamped: u64,
    /// Times the command timeout made the gateway hold level hover.
    pub watchdog_holds: u64,
    /// Commands replaced by a newer one before any RC frame carried them (two arrived within
    /// one RC period): never flown.
    pub commands_superseded: u64,
    /// Times the disarm timeout lowered the arm switch.
    pub watchdog_disarms: u64,
    /// Times an Arm in progress lowered and raised the switch again because the firmware had
    /// latched `ARM_SWITCH`.
    pub arm_edges_retried: u64,
    /// Times the firmware disarmed while the switch was high (its failsafe, crash or runaway
    /// detection); the switch then goes low until the next Arm.
    pub firmware_disarms: u64,
    /// Poses used; refused for their frames, their values, their age, their place.
    pub poses: u64,
    pub poses_bad_frame: u64,
    pub poses_invalid: u64,
    pub poses_stale: u64,
    pub poses_implausible: u64,
    /// Poses from a second sender (the stream locks to its first).
    pub poses_foreign: u64,
    /// Datagrams on the pose port that are no MAVLink frame of the common dialect.
    pub poses_undecodable: u64,
}

/// What the bridge knows of the vehicle (`VehicleControl.GetStatus`).
#[derive(Debug, Clone, PartialEq)]
pub struct MspStatus {
    pub link_alive: bool,
    /// Since the last frame from the flight controller, ns.
    pub last_frame_age_ns: Option<u64>,
    /// `BTFL 4.6.0` once both are heard.
    pub firmware: Option<String>,
    pub armed: bool,
    pub angle_mode: bool,
    pub arm_requested: bool,
    /// Why the firmware refuses to arm (its `status` names).
    pub arming_disabled: Vec<String>,
    /// The firmware's own failsafe is on (the RC stream was lost).
    pub failsafe: bool,
    pub calibration: Calibration,
    /// `angle_limit` as the firmware reported it (`None`: not heard yet).
    pub firmware_angle_limit_deg: Option<u8>,
    pub counters: MspCounters,
    pub decoder: msp::Counters,
}

/// Why a `Reset` is refused.
pub use crate::bridge::ResetRefusal;

/// The request schedule: what is asked once, then what is asked at a rate.
const ONCE: [u16; 4] = [command::FC_VARIANT, command::FC_VERSION, command::BOXIDS, command::PID_ADVANCED];

/// The MSP gateway's core.
#[derive(Debug)]
pub struct MspBridge {
    settings: MspSettings,
    sticks: StickMap,
    decoder: Decoder,
    episode: Episode,
    // What the firmware said.
    variant: Option<FcVariant>,
    version: Option<FcVersion>,
    boxes: Option<BoxIds>,
    angle_limit_deg: Option<u8>,
    status: Option<Status>,
    attitude: Option<Attitude>,
    last_frame_ns: Option<u64>,
    // The pose stream.
    pose_peer: Option<std::net::SocketAddr>,
    pose: Option<(Pose, u64)>,
    // Requests.
    in_flight: Vec<(u16, u64)>,
    next_rc_ns: u64,
    next_attitude_ns: u64,
    next_status_ns: u64,
    // Commands.
    setpoint: Input,
    yaw_hold_rad: f64,
    arm_requested: bool,
    /// Gateway time the firmware first reported ARM after the last request (`None`: not yet).
    armed_seen_ns: Option<u64>,
    /// Gateway time the arm switch last went low (or the start).
    switch_low_ns: u64,
    command_local_ns: u64,
    watchdog_hover: bool,
    /// When the command not yet carried by an RC frame arrived, gateway clock, ns.
    pending_command_ns: Option<u64>,
    /// From a command's arrival to the first RC frame that carries it, ns.
    command_to_rc: mav::latency::Latency,
    counters: MspCounters,
}

impl MspBridge {
    /// A bridge for `scenario` that has heard nothing yet, started at gateway time `now_ns`.
    pub fn new(
        scenario: Scenario,
        settings: MspSettings,
        now_ns: u64,
        flight_id: u64,
    ) -> Result<Self, MspError> {
        settings.validate()?;
        scenario.validate().map_err(|e| MspError::Setting("scenario", e.to_string()))?;
        let sticks = StickMap::new(&settings.calibration, scenario.model.gravity_mps2)?;
        let decoder = Decoder::new(DecoderSettings::default())
            .map_err(|e| MspError::Setting("decoder", e.to_string()))?;
        Ok(Self {
            settings,
            sticks,
            decoder,
            setpoint: scenario.model.hover_input(),
            episode: Episode::new(scenario, flight_id),
            variant: None,
            version: None,
            boxes: None,
            angle_limit_deg: None,
            status: None,
            attitude: None,
            last_frame_ns: None,
            pose_peer: None,
            pose: None,
            in_flight: Vec::new(),
            next_rc_ns: now_ns,
            next_attitude_ns: now_ns,
            next_status_ns: now_ns,
            yaw_hold_rad: 0.0,
            arm_requested: false,
            armed_seen_ns: None,
            switch_low_ns: now_ns,
            command_local_ns: now_ns,
            watchdog_hover: false,
            pending_command_ns: None,
            command_to_rc: mav::latency::Latency::default(),
            counters: MspCounters::default(),
        })
    }

    pub fn settings(&self) -> &MspSettings {
        &self.settings
    }
    pub fn scenario(&self) -> &Scenario {
        &self.episode.scenario
    }
    pub fn counters(&self) -> MspCounters {
        self.counters
    }
    pub fn decoder_counters(&self) -> msp::Counters {
        *self.decoder.counters()
    }
    pub fn sample(&self) -> Option<&PlantSample> {
        self.episode.sample()
    }
    pub fn stick_map(&self) -> &StickMap {
        &self.sticks
    }
    pub fn setpoint_input(&self) -> Input {
        self.setpoint
    }

    /// `BTFL 4.6.0`, once the firmware said both.
    pub fn firmware(&self) -> Option<String> {
        Some(format!("{} {}", self.variant?.as_str(), self.version?))
    }

    /// A frame from the flight controller within the link timeout.
    pub fn link_alive(&self, now_ns: u64) -> bool {
        self.last_frame_ns.is_some_and(|t| now_ns.saturating_sub(t) < self.settings.link_timeout_ns)
    }

    /// A pose within the pose timeout.
    pub fn pose_alive(&self, now_ns: u64) -> bool {
        self.pose.is_some_and(|(_, t)| now_ns.saturating_sub(t) < self.settings.pose_timeout_ns)
    }

    fn box_on(&self, id: u8) -> bool {
        match (&self.status, &self.boxes) {
            (Some(s), Some(b)) => s.is_on(b, id).unwrap_or(false),
            _ => false,
        }
    }

    /// Armed, by the last `MSP_STATUS_EX`.
    pub fn armed(&self) -> bool {
        self.box_on(boxes::ARM)
    }

    pub fn angle_mode(&self) -> bool {
        self.box_on(boxes::ANGLE)
    }

    pub fn arm_requested(&self) -> bool {
        self.arm_requested
    }

    /// Why the firmware refuses to arm, by the last `MSP_STATUS_EX` (`None`: not heard).
    pub fn arming_disabled(&self) -> Option<Vec<String>> {
        self.status.as_ref().map(|s| s.arming_disabled.names())
    }

    /// Raise the arm switch (only ever on request). The throttle stays low until the firmware
    /// says it armed.
    pub fn request_arm(&mut self, _now_ns: u64) {
        if !self.arm_requested {
            self.armed_seen_ns = None;
            // The yaw to hold: the vehicle's heading now.
            if let Some((_, _, yaw)) = self.attitude_ned() {
                self.yaw_hold_rad = yaw;
            }
        }
        self.arm_requested = true;
    }

    /// Lower the arm switch.
    pub fn request_disarm(&mut self, now_ns: u64) {
        self.lower_switch(now_ns);
    }

    fn lower_switch(&mut self, now_ns: u64) {
        if self.arm_requested {
            self.switch_low_ns = now_ns;
        }
        self.arm_requested = false;
        self.armed_seen_ns = None;
    }

    /// Bytes from the flight controller at `now_ns`.
    pub fn on_bytes(&mut self, bytes: &[u8], now_ns: u64) {
        let frames: Vec<Frame> = self.decoder.feed(bytes).collect();
        for f in frames {
            self.on_frame(&f, now_ns);
        }
    }

    fn on_frame(&mut self, f: &Frame, now_ns: u64) {
        if f.direction == Direction::ToFc {
            // Our own requests echoed, or another client's: not the flight controller's.
            self.counters.unexpected_replies += 1;
            return;
        }
        self.last_frame_ns = Some(now_ns);
        if f.command == command::SET_RAW_RC {
            self.counters.rc_acks += 1;
            return;
        }
        let Some(i) = self.in_flight.iter().position(|(c, _)| *c == f.command) else {
            self.counters.unexpected_replies += 1;
            return;
        };
        self.in_flight.remove(i);
        if f.direction == Direction::Error {
            // Counted by the decoder (error_replies); nothing learnt.
            return;
        }
        let p = &f.payload;
        let ok = match f.command {
            command::FC_VARIANT => FcVariant::decode(p).map(|v| self.variant = Some(v)).is_ok(),
            command::FC_VERSION => FcVersion::decode(p).map(|v| self.version = Some(v)).is_ok(),
            command::BOXIDS => {
                self.boxes = Some(BoxIds::decode(p));
                true
            }
            command::PID_ADVANCED => match PidAdvanced::decode(p) {
                Ok(a) => self.on_angle_limit(a.angle_limit_deg),
                Err(_) => false,
            },
            command::STATUS_EX => match Status::decode(p, true) {
                Ok(s) => {
                    let was_armed = self.armed();
                    self.status = Some(s);
                    if self.arm_requested && self.armed() && self.armed_seen_ns.is_none() {
                        self.armed_seen_ns = Some(now_ns);
                    }
                    // Asked to arm, the switch up, and the firmware latched ARM_SWITCH (the switch
                    // rose while something else refused, a lost RC frame's RXLOSS often): the
                    // switch goes low for SWITCH_LOW_MIN_NS and up again, within the same request.
                    let latched = self.status.as_ref().is_some_and(|s| {
                        s.arming_disabled.contains(msp::messages::ArmingDisabled::ARM_SWITCH)
                    });
                    let high = now_ns.saturating_sub(self.switch_low_ns) >= SWITCH_LOW_MIN_NS;
                    if self.arm_requested && !self.armed() && latched && high {
                        self.switch_low_ns = now_ns;
                        self.counters.arm_edges_retried += 1;
                    }
                    if was_armed && !self.armed() && self.arm_requested {
                        // The firmware disarmed on its own (failsafe, crash or runaway
                        // detection): the switch goes low, and only a new Arm raises it.
                        self.lower_switch(now_ns);
                        self.counters.firmware_disarms += 1;
                    }
                    true
                }
                Err(_) => false,
            },
            command::ATTITUDE => match Attitude::decode(p) {
                Ok(a) => {
                    if !self.arm_requested {
                        self.yaw_hold_rad = ned_attitude(&a).2;
                    }
                    self.attitude = Some(a);
                    true
                }
                Err(_) => false,
            },
            _ => true,
        };
        if !ok {
            self.counters.bad_replies += 1;
        }
    }

    /// The firmware's `angle_limit` replaces the configured one (it is what full stick does).
    fn on_angle_limit(&mut self, deg: u8) -> bool {
        let mut calibration = self.settings.calibration;
        calibration.angle_limit_deg = f64::from(deg);
        match StickMap::new(&calibration, self.episode.scenario.model.gravity_mps2) {
            Ok(map) => {
                self.sticks = map;
                self.settings.calibration = calibration;
                self.angle_limit_deg = Some(deg);
                true
            }
            Err(_) => false,
        }
    }

    /// The attitude the samples carry, NED, rad: the firmware's (`MSP_ATTITUDE`) or the pose's
    /// ([`AttitudeSource`]); `None` while not heard.
    fn attitude_ned(&self) -> Option<(f64, f64, f64)> {
        match self.settings.attitude_source {
            AttitudeSource::Firmware => self.attitude.as_ref().map(ned_attitude),
            AttitudeSource::Pose => self.pose.map(|(p, _)| p.attitude_rad),
        }
    }

    /// The vehicle's state now (`None`: no pose or no attitude yet).
    fn state(&self) -> Option<(State, u64)> {
        let (pose, _) = self.pose?;
        let (roll_rad, pitch_rad, yaw_rad) = self.attitude_ned()?;
        let ned = NedState {
            position_m: pose.position_m,
            velocity_mps: pose.velocity_mps,
            roll_rad,
            pitch_rad,
            yaw_rad,
        };
        Some((frame::model_state(&ned), pose.time_us.saturating_mul(1_000)))
    }

    /// A pose from `peer` at `now_ns`: a new sample once an attitude was heard (the pose's own,
    /// with [`AttitudeSource::Pose`]). The stream
    /// locks to its first sender.
    pub fn on_pose(
        &mut self,
        peer: std::net::SocketAddr,
        m: &ODOMETRY_DATA,
        now_ns: u64,
    ) -> Result<Option<PlantSample>, PoseRefusal> {
        if *self.pose_peer.get_or_insert(peer) != peer {
            self.counters.poses_foreign += 1;
            return Ok(None);
        }
        let pose = match Pose::from_odometry(m) {
            Ok(p) => p,
            Err(why) => {
                match why {
                    PoseRefusal::Frame => self.counters.poses_bad_frame += 1,
                    PoseRefusal::Invalid => self.counters.poses_invalid += 1,
                }
                return Err(why);
            }
        };
        if self.pose.is_some_and(|(old, _)| pose.time_us < old.time_us) {
            self.counters.poses_stale += 1;
            return Ok(None);
        }
        if !self.plausible(&pose) {
            self.counters.poses_implausible += 1;
            return Ok(None);
        }
        self.counters.poses += 1;
        self.pose = Some((pose, now_ns));
        let Some((state, vehicle_ns)) = self.state() else { return Ok(None) };
        Ok(self.episode.produce(vehicle_ns, state, self.watchdog_hover))
    }

    fn plausible(&self, p: &Pose) -> bool {
        let s = &self.episode.scenario;
        let margin = self.settings.envelope_margin_m;
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        let mut include = |point: [f64; 3], r: f64| {
            for i in 0..3 {
                lo[i] = lo[i].min(point[i] - r);
                hi[i] = hi[i].max(point[i] + r);
            }
        };
        include([s.start[0], s.start[1], s.start[2]], 0.0);
        include(s.goal_m, 0.0);
        for c in &s.obstacles {
            include([c.x_m, c.y_m, 0.0], c.radius_m);
            include([c.x_m, c.y_m, c.height_m.min(1e6)], c.radius_m);
        }
        let at = [p.position_m[0], -p.position_m[1], -p.position_m[2]];
        let inside = (0..3).all(|i| at[i] >= lo[i] - margin && at[i] <= hi[i] + margin);
        let speed = p.velocity_mps.iter().map(|v| v * v).sum::<f64>().sqrt();
        inside && speed <= self.settings.max_speed_mps
    }

    /// A datagram on the pose port that held no MAVLink frame.
    pub fn count_bad_pose_datagram(&mut self) {
        self.counters.poses_undecodable += 1;
    }

    /// The controller's command at `now_ns`: saturated to the scenario's bounds, flown from
    /// the next RC frame on.
    pub fn apply(&mut self, input: Input, meta: CommandMeta, now_ns: u64) -> AppliedCommand {
        let (saturated_input, saturated) = self.episode.scenario.bounds.saturate(&input);
        self.setpoint = saturated_input;
        self.watchdog_hover = false;
        self.command_local_ns = now_ns;
        if self.pending_command_ns.replace(now_ns).is_some() {
            self.counters.commands_superseded += 1;
        }
        let (_, clamps) = self.sticks.sticks(&saturated_input, self.yaw_hold_rad);
        let vehicle_ns = self.vehicle_ns(now_ns);
        self.episode.last_command = AppliedCommand {
            input: saturated_input,
            meta,
            applied_time_ns: self.episode.plant_ns(vehicle_ns),
            saturated: saturated || clamps.any(),
            initial: false,
        };
        self.episode.last_command
    }

    /// The vehicle's clock at `now_ns`, ns: the last pose's stamp plus the gateway time since.
    fn vehicle_ns(&self, now_ns: u64) -> u64 {
        self.pose.map_or(0, |(p, heard)| p.time_us.saturating_mul(1_000) + now_ns.saturating_sub(heard))
    }

    /// The RC frame now: disarmed (or not yet armed) the sticks centred and the throttle low;
    /// armed the setpoint's sticks, each clamp counted.
    fn rc(&mut self, now_ns: u64) -> RawRc {
        let high = self.arm_requested && now_ns.saturating_sub(self.switch_low_ns) >= SWITCH_LOW_MIN_NS;
        let arm = if high { SWITCH_ON_US } else { SWITCH_OFF_US };
        let sticks = if self.arm_requested && self.armed() {
            let (sticks, clamps) = self.sticks.sticks(&self.setpoint, self.yaw_hold_rad);
            self.counters.throttle_clamped += u64::from(clamps.throttle);
            self.counters.roll_clamped += u64::from(clamps.roll);
            self.counters.pitch_clamped += u64::from(clamps.pitch);
            if let Some(arrived) = self.pending_command_ns.take() {
                self.command_to_rc.record(now_ns.saturating_sub(arrived));
            }
            sticks
        } else {
            // Disarmed, the sticks are not the command's: it is flown by no frame.
            self.pending_command_ns = None;
            Sticks {
                roll_us: STICK_CENTRE_US,
                pitch_us: STICK_CENTRE_US,
                throttle_us: STICK_MIN_US,
                yaw_us: STICK_CENTRE_US,
            }
        };
        // Four sticks and two switches: never more than MAX_RC_CHANNELS.
        RawRc::aetr(sticks, &[arm, SWITCH_ON_US]).unwrap_or_else(|_| unreachable!("6 channels"))
    }

    fn watchdog(&mut self, now_ns: u64) {
        let silent_ns = now_ns.saturating_sub(self.command_local_ns);
        if !self.watchdog_hover && silent_ns >= self.settings.command_timeout_ns {
            self.watchdog_hover = true;
            self.counters.watchdog_holds += 1;
            self.setpoint = self.episode.scenario.model.hover_input();
        }
        // Counted from the last command or from the arming the firmware reported, whichever
        // is later: while `Arm` still waits for the firmware, its own timeout decides.
        if let Some(armed_ns) = self.armed_seen_ns.filter(|_| self.arm_requested)
            && now_ns.saturating_sub(self.command_local_ns.max(armed_ns)) >= self.settings.disarm_timeout_ns
        {
            self.lower_switch(now_ns);
            self.counters.watchdog_disarms += 1;
        }
    }

    /// What is due at `now_ns`, encoded into `out` (MSP v1 frames).
    pub fn poll(&mut self, now_ns: u64, out: &mut Vec<u8>) {
        self.watchdog(now_ns);
        if now_ns >= self.next_rc_ns {
            // A steady clock: the next frame one period after this one was due, unless late by
            // more than a period (then from now).
            self.next_rc_ns = if now_ns - self.next_rc_ns < self.settings.rc_period_ns {
                self.next_rc_ns + self.settings.rc_period_ns
            } else {
                now_ns + self.settings.rc_period_ns
            };
            let rc = self.rc(now_ns);
            if rc.to_frame(Version::V1).encode(out).is_ok() {
                self.counters.rc_sent += 1;
            }
        }
        let timeout = self.settings.reply_timeout_ns;
        let before = self.in_flight.len();
        self.in_flight.retain(|(_, sent)| now_ns.saturating_sub(*sent) < timeout);
        self.counters.replies_lost += (before - self.in_flight.len()) as u64;
        while self.in_flight.len() < self.settings.max_in_flight {
            let Some(c) = self.next_request(now_ns) else { break };
            if msp::request(Version::V1, c, out).is_ok() {
                self.in_flight.push((c, now_ns));
                self.counters.requests_sent += 1;
            }
        }
    }

    /// The next request due, its schedule advanced.
    fn next_request(&mut self, now_ns: u64) -> Option<u16> {
        let known = [
            self.variant.is_some(),
            self.version.is_some(),
            self.boxes.is_some(),
            self.angle_limit_deg.is_some(),
        ];
        let asked = |c: u16, f: &[(u16, u64)]| f.iter().any(|(x, _)| *x == c);
        if let Some(c) =
            ONCE.iter().zip(known).find(|(c, k)| !k && !asked(**c, &self.in_flight)).map(|(c, _)| *c)
        {
            return Some(c);
        }
        if now_ns >= self.next_status_ns && !asked(command::STATUS_EX, &self.in_flight) {
            self.next_status_ns = now_ns + self.settings.status_period_ns;
            return Some(command::STATUS_EX);
        }
        if now_ns >= self.next_attitude_ns && !asked(command::ATTITUDE, &self.in_flight) {
            self.next_attitude_ns = now_ns + self.settings.attitude_period_ns;
            return Some(command::ATTITUDE);
        }
        None
    }

    /// When to call [`MspBridge::poll`] again, ns.
    pub fn next_due_ns(&self) -> u64 {
        let mut due = self.next_rc_ns;
        if self.in_flight.len() < self.settings.max_in_flight {
            due = due.min(self.next_status_ns).min(self.next_attitude_ns);
        }
        if let Some(oldest) = self.in_flight.iter().map(|(_, t)| *t).min() {
            due = due.min(oldest + self.settings.reply_timeout_ns);
        }
        if !self.watchdog_hover {
            due = due.min(self.command_local_ns + self.settings.command_timeout_ns);
        }
        if let Some(armed_ns) = self.armed_seen_ns.filter(|_| self.arm_requested) {
            due = due.min(self.command_local_ns.max(armed_ns) + self.settings.disarm_timeout_ns);
        }
        due
    }

    /// A new episode in `scenario` from where the vehicle is (refused if it is not within the
    /// start tolerance of the requested start).
    pub fn reset(
        &mut self,
        scenario: Scenario,
        start: Option<State>,
        now_ns: u64,
        flight_id: u64,
    ) -> Result<PlantSample, ResetRefusal> {
        scenario.validate().map_err(|e| ResetRefusal::Scenario(e.to_string()))?;
        let sticks = StickMap::new(&self.settings.calibration, scenario.model.gravity_mps2)
            .map_err(|e| ResetRefusal::Scenario(e.to_string()))?;
        let Some((state, vehicle_ns)) = self.state() else { return Err(ResetRefusal::NoState) };
        let requested = start.unwrap_or_else(|| scenario.start_state());
        let requested_m = [requested[0], requested[1], requested[2]];
        let vehicle_m = [state[0], state[1], state[2]];
        let distance_m =
            requested_m.iter().zip(&vehicle_m).map(|(r, v)| (r - v) * (r - v)).sum::<f64>().sqrt();
        if distance_m > self.settings.start_tolerance_m {
            return Err(ResetRefusal::FarFromVehicle {
                requested_m,
                vehicle_m,
                distance_m,
                tolerance_m: self.settings.start_tolerance_m,
            });
        }
        self.sticks = sticks;
        self.setpoint = scenario.model.hover_input();
        self.command_local_ns = now_ns;
        self.watchdog_hover = false;
        self.pending_command_ns = None;
        let mut sample = self.episode.restart(scenario, flight_id, vehicle_ns, state);
        sample.last_command = initial_command(&self.episode.scenario);
        Ok(sample)
    }

    /// From each command's arrival to the first RC frame that carried it (the gateway's hop of
    /// the command's path to the motors).
    pub fn command_to_rc(&self) -> &mav::latency::Latency {
        &self.command_to_rc
    }

    pub fn status(&self, now_ns: u64) -> MspStatus {
        MspStatus {
            link_alive: self.link_alive(now_ns),
            last_frame_age_ns: self.last_frame_ns.map(|t| now_ns.saturating_sub(t)),
            firmware: self.firmware(),
            armed: self.armed(),
            angle_mode: self.angle_mode(),
            arm_requested: self.arm_requested,
            arming_disabled: self.arming_disabled().unwrap_or_default(),
            failsafe: self.box_on(boxes::FAILSAFE),
            calibration: self.settings.calibration,
            firmware_angle_limit_deg: self.angle_limit_deg,
            counters: self.counters,
            decoder: *self.decoder.counters(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use msp::messages::{ArmingDisabled, FlightModes, StatusExtra};
    use proptest::prelude::*;

    const G: f64 = 9.81;

    fn map() -> StickMap {
        StickMap::new(&Calibration { hover_throttle_us: 1400.0, ..Calibration::default() }, G).expect("valid")
    }

    fn bridge() -> MspBridge {
        MspBridge::new(Scenario::paper_2(), MspSettings::default(), 0, 1).expect("valid")
    }

    /// The frames a poll wrote.
    fn frames(bytes: &[u8]) -> Vec<Frame> {
        let mut d = Decoder::new(DecoderSettings::default()).expect("valid");
        d.feed(bytes).collect()
    }

    fn reply(command: u16, payload: Vec<u8>) -> Vec<u8> {
        let f = Frame { direction: Direction::FromFc, ..Frame::request(Version::V1, command, payload) };
        f.to_bytes().expect("encodes")
    }

    /// A status with ARM (bit 0) and ANGLE (bit 1) as given, boxes as the SITL lists them.
    fn status(armed: bool, angle: bool, flags: u32) -> Vec<u8> {
        Status {
            cycle_time_us: 125,
            i2c_errors: 0,
            sensors: 1,
            flight_modes: FlightModes(vec![u8::from(armed) | u8::from(angle) << 1, 0, 0, 0]),
            pid_profile: 0,
            system_load_pct: 10,
            extra: StatusExtra::StatusEx { pid_profile_count: 4, rate_profile: 0 },
            arming_disable_flag_count: 29,
            arming_disabled: ArmingDisabled(flags),
            config_state: 0,
            cpu_temp_c: 0,
            rate_profile_count: 4,
        }
        .encode()
    }

    /// Answers every request in flight as the SITL would.
    fn answer_all(b: &mut MspBridge, sent: &[u8], armed: bool, now: u64) {
        for f in frames(sent) {
            let payload = match f.command {
                command::FC_VARIANT => b"BTFL".to_vec(),
                command::FC_VERSION => vec![4, 6, 0],
                command::BOXIDS => vec![0, 1, 2, 6, 27],
                command::PID_ADVANCED => {
                    let mut p = vec![0; 45];
                    p[17] = 20;
                    p
                }
                command::STATUS_EX => status(armed, true, 0),
                command::ATTITUDE => Attitude { roll_decideg: 0, pitch_decideg: 0, yaw_deg: 0 }.encode(),
                command::SET_RAW_RC => vec![],
                _ => continue,
            };
            b.on_bytes(&reply(f.command, payload), now);
        }
    }

    fn rc_of(bytes: &[u8]) -> Vec<Vec<u16>> {
        frames(bytes)
            .iter()
            .filter(|f| f.command == command::SET_RAW_RC)
            .map(|f| RawRc::decode(&f.payload).expect("rc").channels().to_vec())
            .collect()
    }

    #[test]
    fn hover_thrust_is_the_hover_throttle_level_is_centred_and_full_stick_is_the_angle_limit() {
        let m = map();
        let (s, c) = m.sticks(&Input::new(G, 0.0, 0.0), 0.0);
        assert_eq!((s.roll_us, s.pitch_us, s.throttle_us, s.yaw_us), (1500, 1500, 1400, 1500));
        assert!(!c.any());
        let limit = 20f64.to_radians();
        // Roll right: stick right. Model theta > 0 (towards +x, north, at yaw 0) is nose down:
        // pitch stick forward.
        let (s, c) = m.sticks(&Input::new(G, limit, 0.0), 0.0);
        assert_eq!(s.roll_us, 2000);
        assert!(!c.roll);
        let (s, _) = m.sticks(&Input::new(G, 0.0, limit / 2.0), 0.0);
        assert_eq!(s.pitch_us, 1750);
        let (s, c) = m.sticks(&Input::new(100.0, -2.0 * limit, 0.0), 0.0);
        assert_eq!((s.roll_us, s.throttle_us), (1000, 2000));
        assert!(c.roll && c.throttle && !c.pitch);
        // No thrust is below what idling motors give: zero throttle, counted as a clamp.
        assert_eq!(m.throttle_us(0.0), (1000, true));
        assert_eq!(m.throttle_us(-1.0), (1000, true));
        assert_eq!(m.throttle_us(f64::NAN), (1000, true));
    }

    #[test]
    fn the_throttle_curve_is_the_square_of_the_motor_output_through_min_check_and_idle() {
        let c = Calibration { hover_throttle_us: 1576.0, ..Calibration::default() };
        let curve = ThrottleCurve::new(&c, G).expect("valid");
        // rc.c: min_check..2000 onto [0, 1]; the mixer: [0, 1] onto idle..1.
        assert_eq!(curve.output(1050.0), 0.055);
        assert_eq!(curve.output(1000.0), 0.055);
        assert_eq!(curve.output(2000.0), 1.0);
        let hover = 0.055 + 0.945 * (526.0 / 950.0);
        assert!((curve.hover_output() - hover).abs() < 1e-12);
        // The hover throttle gives g; full throttle (1 / hover)^2 g; idle (0.055 / hover)^2 g.
        assert!((curve.thrust_mps2(1576.0) - G).abs() < 1e-12);
        assert!((curve.thrust_mps2(2000.0) - G / (hover * hover)).abs() < 1e-9);
        assert!((curve.thrust_mps2(1050.0) - G * (0.055 / hover).powi(2)).abs() < 1e-12);
        // Its inverse to the microsecond, unclamped inside the range.
        for us in [1051u16, 1200, 1576, 1800, 1999] {
            let (back, clamped) = curve.throttle_us(curve.thrust_mps2(f64::from(us)));
            assert_eq!((back, clamped), (us, false), "{us} us");
        }
        // Twice the hover thrust needs sqrt(2) times the hover output, not twice the throttle.
        let (us, _) = curve.throttle_us(2.0 * G);
        let t = (std::f64::consts::SQRT_2 * hover - 0.055) / 0.945;
        assert_eq!(us, (1050.0 + 950.0 * t).round() as u16);
        assert_eq!(curve.throttle_us(100.0), (2000, true));
    }

    #[test]
    fn a_calibration_out_of_range_is_refused_naming_its_field() {
        let bad = Calibration { hover_throttle_us: 2000.0, ..Calibration::default() };
        assert!(matches!(bad.validate(), Err(MspError::Setting("hover_throttle_us", _))));
        let bad = Calibration { angle_limit_deg: f64::NAN, ..Calibration::default() };
        assert!(matches!(bad.validate(), Err(MspError::Setting("angle_limit_deg", _))));
        let bad = Calibration { min_check_us: 1600.0, ..Calibration::default() };
        assert!(matches!(bad.validate(), Err(MspError::Setting("min_check_us", _))));
        let bad = Calibration { motor_idle: f64::INFINITY, ..Calibration::default() };
        assert!(matches!(bad.validate(), Err(MspError::Setting("motor_idle", _))));
        let s = MspSettings { disarm_timeout_ns: 100_000_000, ..MspSettings::default() };
        assert!(matches!(s.validate(), Err(MspError::Setting("disarm_timeout_ns", _))));
        let s = MspSettings { rc_period_ns: 200_000_000, ..MspSettings::default() };
        assert!(matches!(s.validate(), Err(MspError::Setting("rc_period_ns", _))));
    }

    /// An armed bridge after 30 ms of polls answered.
    fn armed_bridge() -> MspBridge {
        let mut b = bridge();
        let mut out = Vec::new();
        b.poll(0, &mut out);
        answer_all(&mut b, &out, true, 0);
        b.request_arm(0);
        for ms in 1..30u64 {
            out.clear();
            b.poll(ms * 1_000_000, &mut out);
            answer_all(&mut b, &out, true, ms * 1_000_000);
        }
        b
    }

    #[test]
    fn the_hold_from_a_command_to_its_rc_frame_is_measured_and_a_superseded_command_counted() {
        let mut b = armed_bridge();
        assert!(b.armed());
        // 1 ms polls from 30 ms on; the RC frames' times, and commands at chosen times.
        let commands_ms = [41u64, 83, 85];
        let mut rc_ms = Vec::new();
        let mut out = Vec::new();
        for ms in 30..140u64 {
            let now = ms * 1_000_000;
            if commands_ms.contains(&ms) {
                b.apply(Input::new(G, 0.05, 0.0), CommandMeta::default(), now);
            }
            out.clear();
            b.poll(now, &mut out);
            if !rc_of(&out).is_empty() {
                rc_ms.push(ms);
            }
            answer_all(&mut b, &out, true, now);
        }
        let first_after = |t: u64| rc_ms.iter().copied().find(|&r| r >= t).expect("an RC frame after");
        // 83 and 85 ms fall in one RC period (frames 20 ms apart): the first is never flown.
        assert_eq!(first_after(83), first_after(85), "RC frames at {rc_ms:?}");
        assert_eq!(b.counters().commands_superseded, 1);
        let hold = b.command_to_rc();
        assert_eq!(hold.count(), 2, "one per RC frame that carried a new command");
        let holds_ns = [first_after(41) - 41, first_after(85) - 85].map(|ms| ms * 1_000_000);
        assert_eq!(hold.min_ns(), Some(holds_ns[0].min(holds_ns[1])));
        assert_eq!(hold.max_ns(), Some(holds_ns[0].max(holds_ns[1])));
        assert!(holds_ns.iter().all(|&h| h < 20_000_000), "within one RC period: {holds_ns:?}");
    }

    #[test]
    fn rc_goes_at_a_steady_50_hz_and_requests_one_at_a_time() {
        let mut b = bridge();
        let mut rc = 0;
        let mut most_in_flight = 0;
        // 2 s in 1 ms ticks, a reply to each request 40 ms later.
        let mut waiting: Vec<(u64, Vec<u8>)> = Vec::new();
        for ms in 0..2_000u64 {
            let now = ms * 1_000_000;
            let mut out = Vec::new();
            b.poll(now, &mut out);
            rc += rc_of(&out).len();
            waiting.push((now + 40_000_000, out));
            most_in_flight = most_in_flight.max(b.in_flight.len());
            let (due, later): (Vec<_>, Vec<_>) = waiting.into_iter().partition(|(t, _)| *t <= now);
            waiting = later;
            for (_, sent) in due {
                answer_all(&mut b, &sent, false, now);
            }
        }
        assert_eq!(rc, 100, "50 Hz for 2 s");
        assert_eq!(most_in_flight, 1);
        assert_eq!(b.firmware().as_deref(), Some("BTFL 4.6.0"));
        assert_eq!(b.status(2_000_000_000).firmware_angle_limit_deg, Some(20));
        let c = b.counters();
        assert_eq!(c.replies_lost, 0);
        assert!(c.requests_sent >= 4 + 7, "{c:?}");
        assert_eq!(c.rc_acks, 100 - 2, "the last two are still travelling");
    }

    #[test]
    fn it_never_arms_unasked_keeps_the_throttle_low_until_armed_and_the_watchdog_hovers_then_disarms() {
        let mut b = bridge();
        let mut out = Vec::new();
        // 1 s unasked: the switch stays low.
        for ms in (0..1_000u64).step_by(10) {
            out.clear();
            b.poll(ms * 1_000_000, &mut out);
            answer_all(&mut b, &out, false, ms * 1_000_000);
            for ch in rc_of(&out) {
                assert_eq!((ch[2], ch[4], ch[5]), (1000, 1000, 1800), "throttle low, not armed, ANGLE on");
            }
        }
        assert_eq!(b.counters().watchdog_disarms, 0);
        b.request_arm(1_000_000_000);
        out.clear();
        b.poll(1_010_000_000, &mut out);
        let ch = rc_of(&out).pop().expect("an RC frame");
        assert_eq!((ch[2], ch[4]), (1000, 1800), "switch up, throttle low before the firmware armed");
        answer_all(&mut b, &out, true, 1_010_000_000);
        // The firmware arms; the controller commands a climb.
        let mut t = 1_010_000_000;
        let mut throttles = Vec::new();
        let mut aux1 = Vec::new();
        while t < 5_000_000_000 {
            if t < 1_500_000_000 {
                b.apply(Input::new(11.0, 0.0, 0.0), CommandMeta::default(), t);
            }
            out.clear();
            b.poll(t, &mut out);
            let armed = b.arm_requested();
            answer_all(&mut b, &out, armed, t);
            for ch in rc_of(&out) {
                throttles.push((t, ch[2]));
                aux1.push((t, ch[4]));
            }
            t += 10_000_000;
        }
        let at = |when: u64, v: &[(u64, u16)]| v.iter().rev().find(|(t, _)| *t <= when).map(|(_, x)| *x);
        let climb = map_default().throttle_us(11.0).0;
        let hover = map_default().throttle_us(G).0;
        assert_eq!(at(1_400_000_000, &throttles), Some(climb));
        // Silent from 1.49 s: hover at +500 ms, disarm at +2 s (the firmware armed before).
        assert_eq!(at(2_100_000_000, &throttles), Some(hover));
        assert_eq!(at(3_400_000_000, &aux1), Some(1800));
        assert_eq!(at(3_600_000_000, &aux1), Some(1000));
        let c = b.counters();
        assert_eq!((c.watchdog_holds, c.watchdog_disarms), (2, 1), "{c:?}");
    }

    #[test]
    fn the_disarm_timeout_waits_for_the_firmware_to_arm_so_a_slow_arming_is_not_cut_short() {
        let mut b = bridge();
        b.request_arm(0);
        let mut out = Vec::new();
        for ms in (0..5_000u64).step_by(10) {
            out.clear();
            b.poll(ms * 1_000_000, &mut out);
            // The firmware still refuses (boot grace, calibration): not armed for 5 s.
            answer_all(&mut b, &out, false, ms * 1_000_000);
        }
        assert!(b.arm_requested(), "the Arm call decides, not the watchdog");
        assert_eq!(b.counters().watchdog_disarms, 0);
        b.request_disarm(5_000_000_000);
        assert!(!b.arm_requested());
    }

    #[test]
    fn an_arm_right_after_a_disarm_raises_the_switch_only_after_the_firmware_saw_it_low() {
        let mut b = bridge();
        let mut out = Vec::new();
        b.request_arm(1_000_000_000);
        b.request_disarm(1_000_000_000);
        b.request_arm(1_001_000_000);
        let mut aux1 = Vec::new();
        for ms in (1_010..1_500u64).step_by(10) {
            out.clear();
            b.poll(ms * 1_000_000, &mut out);
            aux1.extend(rc_of(&out).iter().map(|ch| (ms, ch[4])));
        }
        assert!(aux1.iter().filter(|(ms, _)| *ms < 1_300).all(|(_, a)| *a == SWITCH_OFF_US), "{aux1:?}");
        assert!(aux1.iter().filter(|(ms, _)| *ms >= 1_300).all(|(_, a)| *a == SWITCH_ON_US), "{aux1:?}");
    }

    fn map_default() -> StickMap {
        StickMap::new(&Calibration::default(), G).expect("valid")
    }

    #[test]
    fn bad_frames_are_dropped_and_counted_and_replies_to_nothing_asked_too() {
        let mut b = bridge();
        let mut bytes = reply(command::ATTITUDE, vec![0; 6]);
        let n = bytes.len();
        bytes[n - 1] ^= 0xff;
        b.on_bytes(&bytes, 0);
        b.on_bytes(&reply(command::ATTITUDE, vec![0; 6]), 0);
        assert_eq!(b.decoder_counters().dropped.bad_checksum, 1);
        assert_eq!(b.counters().unexpected_replies, 1);
        assert!(b.attitude.is_none(), "an unasked reply teaches nothing");
    }

    fn odometry(t_us: u64, xyz: [f32; 3], v_body: [f32; 3], q: [f32; 4]) -> ODOMETRY_DATA {
        ODOMETRY_DATA {
            time_usec: t_us,
            x: xyz[0],
            y: xyz[1],
            z: xyz[2],
            q,
            vx: v_body[0],
            vy: v_body[1],
            vz: v_body[2],
            frame_id: MavFrame::MAV_FRAME_LOCAL_NED,
            child_frame_id: MavFrame::MAV_FRAME_BODY_FRD,
            ..Default::default()
        }
    }

    #[test]
    fn with_the_pose_as_attitude_source_the_samples_tilt_with_the_quaternion_without_msp_attitude() {
        let settings = MspSettings { attitude_source: AttitudeSource::Pose, ..MspSettings::default() };
        let mut b = MspBridge::new(Scenario::paper_2(), settings, 0, 1).expect("valid");
        let peer: std::net::SocketAddr = "127.0.0.1:5000".parse().expect("addr");
        let start = Scenario::paper_2().start;
        let ned = [start[0] as f32, -start[1] as f32, -start[2] as f32];
        // Roll 6 deg right side down (about body x), heading north.
        let (roll, yaw) = (6f64.to_radians(), 0.0);
        let q = frame::quaternion_from_euler(roll, 0.0, yaw).map(|c| c as f32);
        let s = b.on_pose(peer, &odometry(1_000, ned, [0.0; 3], q), 0).expect("valid").expect("a sample");
        let (phi, theta) = frame::model_angles(roll, 0.0, yaw);
        assert!((s.state[6] - phi).abs() < 1e-6 && (s.state[7] - theta).abs() < 1e-6, "{:?}", s.state);
        assert!(phi.abs() > 0.1, "the tilt shows in the model's angles");
        // The firmware's attitude, when it comes, does not replace the pose's.
        b.in_flight.push((command::ATTITUDE, 0));
        b.on_bytes(
            &reply(command::ATTITUDE, Attitude { roll_decideg: -200, pitch_decideg: 0, yaw_deg: 0 }.encode()),
            0,
        );
        let s = b.on_pose(peer, &odometry(2_000, ned, [0.0; 3], q), 1).expect("valid").expect("a sample");
        assert!((s.state[6] - phi).abs() < 1e-6);
    }

    #[test]
    fn poses_give_position_and_ned_velocity_the_firmware_the_attitude() {
        let mut b = bridge();
        let peer: std::net::SocketAddr = "127.0.0.1:5000".parse().expect("addr");
        let start = Scenario::paper_2().start;
        let ned = [start[0] as f32, -start[1] as f32, -start[2] as f32];
        // Heading east (yaw 90 deg): body forward 1 m/s is east.
        let h = std::f32::consts::FRAC_PI_4;
        let q = [h.cos(), 0.0, 0.0, h.sin()];
        assert_eq!(
            b.on_pose(peer, &odometry(1_000, ned, [1.0, 0.0, 0.0], q), 0),
            Ok(None),
            "no attitude yet"
        );
        b.in_flight.push((command::ATTITUDE, 0));
        b.on_bytes(
            &reply(
                command::ATTITUDE,
                Attitude { roll_decideg: 50, pitch_decideg: -30, yaw_deg: 90 }.encode(),
            ),
            0,
        );
        let s =
            b.on_pose(peer, &odometry(2_000, ned, [1.0, 0.0, 0.0], q), 1).expect("valid").expect("a sample");
        assert!((s.state[0] - start[0]).abs() < 1e-5 && (s.state[2] - start[2]).abs() < 1e-5);
        // East is the model's -y.
        assert!((s.state[4] + 1.0).abs() < 1e-6 && s.state[3].abs() < 1e-6, "{:?}", s.state);
        // Roll 5 deg, nose up 3 deg (firmware pitch -3), heading east: the thrust axis tilts
        // towards... both angles small and finite.
        let (phi, theta) = frame::model_angles(5f64.to_radians(), 3f64.to_radians(), 90f64.to_radians());
        assert!((s.state[6] - phi).abs() < 1e-9 && (s.state[7] - theta).abs() < 1e-9);
        let mut wrong = odometry(3_000, ned, [0.0; 3], q);
        wrong.frame_id = MavFrame::MAV_FRAME_LOCAL_ENU;
        assert_eq!(b.on_pose(peer, &wrong, 2), Err(PoseRefusal::Frame));
        assert_eq!(
            b.on_pose(peer, &odometry(3_000, ned, [0.0; 3], [0.5; 4].map(|c| c * 1.1)), 2),
            Err(PoseRefusal::Invalid)
        );
        assert_eq!(b.on_pose(peer, &odometry(1_500, ned, [0.0; 3], q), 2), Ok(None));
        let other: std::net::SocketAddr = "127.0.0.1:5001".parse().expect("addr");
        assert_eq!(b.on_pose(other, &odometry(9_000, ned, [0.0; 3], q), 2), Ok(None));
        let c = b.counters();
        assert_eq!(
            (c.poses, c.poses_bad_frame, c.poses_invalid, c.poses_stale, c.poses_foreign),
            (2, 1, 1, 1, 1)
        );
        // A reset from where the vehicle is.
        let first = b.reset(Scenario::paper_2(), None, 3, 7).expect("at the start");
        assert_eq!((first.time_ns, first.flight_id, first.seq), (0, 7, 0));
    }

    proptest! {
        #[test]
        fn sticks_are_monotone_in_angle_and_thrust_and_always_in_range(
            a in -1.0f64..1.0, b in -1.0f64..1.0, t1 in -5.0f64..40.0, t2 in -5.0f64..40.0,
        ) {
            let m = map();
            let (lo, hi) = (a.min(b), a.max(b));
            let limit = m.angle_limit_rad();
            let (s_lo, c_lo) = angle_stick_us(lo, limit);
            let (s_hi, _) = angle_stick_us(hi, limit);
            prop_assert!(s_lo <= s_hi);
            prop_assert!((1000..=2000).contains(&s_lo) && (1000..=2000).contains(&s_hi));
            if (lo.abs() - limit).abs() > 1e-9 {
                prop_assert_eq!(c_lo, lo.abs() > limit);
            }
            let (tl, th) = (t1.min(t2), t1.max(t2));
            let (u_lo, _) = m.throttle_us(tl);
            let (u_hi, c_hi) = m.throttle_us(th);
            prop_assert!(u_lo <= u_hi && (1000..=2000).contains(&u_hi));
            // Clamped below the idling motors' thrust and above full output.
            let curve = m.throttle_curve();
            prop_assert_eq!(c_hi, th < curve.thrust_mps2(1000.0) || th > curve.thrust_mps2(2000.0));
        }

        #[test]
        fn every_clamp_is_counted_once_per_rc_frame(phi in -1.0f64..1.0, theta in -1.0f64..1.0, t in 0.0f64..30.0) {
            let mut b = armed_bridge();
            let mut out = Vec::new();
            let before = b.counters();
            let input = Input::new(t, phi, theta);
            let (sat, _) = b.scenario().bounds.saturate(&input);
            let (_, clamps) = b.stick_map().sticks(&sat, b.yaw_hold_rad);
            b.apply(input, CommandMeta::default(), 30_000_000);
            out.clear();
            b.poll(40_000_000, &mut out);
            let frames = rc_of(&out).len() as u64;
            prop_assert_eq!(frames, 1);
            let after = b.counters();
            prop_assert_eq!(after.throttle_clamped - before.throttle_clamped, u64::from(clamps.throttle));
            prop_assert_eq!(after.roll_clamped - before.roll_clamped, u64::from(clamps.roll));
            prop_assert_eq!(after.pitch_clamped - before.pitch_clamped, u64::from(clamps.pitch));
        }
    }
}
