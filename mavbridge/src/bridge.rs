//! The gateway's core: what the vehicle said (heartbeat, mode, battery, state, clock), the
//! Plant API's samples made of it, the setpoint stream made of the controller's commands, and
//! the failsafe decisions. Time is passed in (the gateway's monotonic clock, ns); nothing here
//! reads a clock or does I/O: the service shell feeds it messages and sends what it returns.

use crate::frame;
use crate::messages::{self, Attitude};
use crate::modes::{self, ModeRequest};
use crate::thrust::{ThrustError, ThrustMap};
use crate::timesync::TimeSync;
use crate::trust::{Admitted, Dropped, Peer, Refusal, Trust, Vehicle, VehicleFilter};
use mav::{AppliedCommand, CommandMeta, Contacts, Input, PlantSample, Scenario, State};
use mavlink::MavHeader;
use mavlink::dialects::common::{
    COMMAND_LONG_DATA, HEARTBEAT_DATA, LOCAL_POSITION_NED_DATA, MavAutopilot, MavCmd, MavMessage,
    MavModeFlag, MavResult, MavState, MavType, PARAM_REQUEST_READ_DATA, TIMESYNC_DATA,
};

/// A state message stamped this much earlier than the last one of its kind means the vehicle
/// rebooted, ms. Reordered or duplicated UDP datagrams go back by milliseconds (a few state
/// periods); a reboot goes back by the whole uptime. One second separates the two with room on
/// both sides; a vehicle that reboots less than a second after its last message is not seen to
/// reboot (its next messages are stale until its clock passes the old one, under a second).
/// The same margin serves a clock that comes back *ahead* after a silence but counted this much
/// less than the gateway's clock did meanwhile (see [`shows_reboot`]).
pub const REBOOT_CLOCK_JUMP_MS: u32 = 1_000;

/// State messages that must follow a stamp showing a reboot, on the restarted clock (within
/// [`REBOOT_CLOCK_JUMP_MS`] of it), before the reboot is believed: one stray or forged stamp is
/// not a reboot. At the vehicle's state rates (50 Hz and more, two kinds) this takes tens of
/// milliseconds; a message on the old clock meanwhile refuses the stamp
/// ([`Counters::reboot_stamps_refused`]).
pub const REBOOT_CONFIRMATIONS: u32 = 3;

/// Whether a state message stamped `after_ms` on the vehicle's boot clock, arriving `silence_ns`
/// of gateway time after the last one of its kind (stamped `before_ms`), shows that the vehicle
/// rebooted in between. Either its clock went back by more than [`REBOOT_CLOCK_JUMP_MS`], or it
/// went ahead but both
/// - counted more than [`REBOOT_CLOCK_JUMP_MS`] less than the silence lasted: a clock that kept
///   running counts what the gateway's did, give or take the network's jitter (milliseconds);
/// - and reads no more than the silence (give or take the same margin, for the network's
///   jitter): a clock restarted at 0 during the silence cannot have counted more. This keeps a
///   link that held messages back and delivers them late (stamps a little ahead of the last
///   after a long wait) from looking like a reboot: that clock still reads the vehicle's whole
///   uptime. A vehicle rebooted less than a second after its last message, or silent for less
///   than a second, is not seen this way (it is the case above).
pub fn shows_reboot(before_ms: u32, after_ms: u32, silence_ns: u64) -> bool {
    if before_ms.saturating_sub(after_ms) > REBOOT_CLOCK_JUMP_MS {
        return true;
    }
    let silence_ms = silence_ns / 1_000_000;
    let counted_ms = u64::from(after_ms.saturating_sub(before_ms));
    after_ms >= before_ms
        && silence_ms.saturating_sub(counted_ms) > u64::from(REBOOT_CLOCK_JUMP_MS)
        && u64::from(after_ms) <= silence_ms + u64::from(REBOOT_CLOCK_JUMP_MS)
}

/// Settings of the bridge, with units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BridgeSettings {
    /// Normalised thrust that hovers (`--hover-thrust`): `T = g` maps to it.
    pub hover_thrust: f64,
    /// The last setpoint is resent at least this often, ns (PX4 leaves offboard below 2 Hz).
    pub setpoint_period_ns: u64,
    /// No command for this long, ns: hold level attitude at hover thrust (`--command-timeout-ms`).
    pub command_timeout_ns: u64,
    /// No vehicle heartbeat for this long, ns: the link is lost.
    pub heartbeat_timeout_ns: u64,
    /// The gateway's own heartbeat period, ns.
    pub heartbeat_period_ns: u64,
    /// `TIMESYNC` request period, ns.
    pub timesync_period_ns: u64,
    /// A `Reset` whose start is farther than this from the vehicle is refused, m.
    pub start_tolerance_m: f64,
    /// Which vehicle the link locks to (`--vehicle-sysid`, `--vehicle-compid`; default: the
    /// first autopilot heard).
    pub vehicle: VehicleFilter,
    /// A `LOCAL_POSITION_NED` farther than this outside the scenario's box (its start, goal and
    /// obstacles) is refused, m (`--envelope-margin-m`).
    pub envelope_margin_m: f64,
    /// A `LOCAL_POSITION_NED` faster than this is refused, m/s (`--max-speed-mps`).
    pub max_speed_mps: f64,
}

impl Default for BridgeSettings {
    fn default() -> Self {
        Self {
            hover_thrust: 0.5,
            setpoint_period_ns: 20_000_000,
            command_timeout_ns: 500_000_000,
            heartbeat_timeout_ns: 2_000_000_000,
            heartbeat_period_ns: 1_000_000_000,
            timesync_period_ns: 500_000_000,
            start_tolerance_m: 0.5,
            vehicle: VehicleFilter::default(),
            envelope_margin_m: 100.0,
            max_speed_mps: 50.0,
        }
    }
}

/// An invalid setting or scenario.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BridgeError {
    #[error("invalid gateway setting `{0}`: {1}")]
    Setting(&'static str, String),
    #[error(transparent)]
    Thrust(#[from] ThrustError),
}

impl BridgeSettings {
    pub fn validate(&self) -> Result<(), BridgeError> {
        ThrustMap::new(self.hover_thrust, 9.81)?;
        let positive = [
            ("setpoint_period_ns", self.setpoint_period_ns),
            ("command_timeout_ns", self.command_timeout_ns),
            ("heartbeat_timeout_ns", self.heartbeat_timeout_ns),
            ("heartbeat_period_ns", self.heartbeat_period_ns),
            ("timesync_period_ns", self.timesync_period_ns),
        ];
        for (name, v) in positive {
            if v == 0 {
                return Err(BridgeError::Setting(name, "must be > 0".into()));
            }
        }
        // PX4 leaves offboard when setpoints come slower than 2 Hz; the floor is 20 Hz.
        if self.setpoint_period_ns > 50_000_000 {
            return Err(BridgeError::Setting(
                "setpoint_period_ns",
                format!("must be at most 50 ms (20 Hz), got {} ns", self.setpoint_period_ns),
            ));
        }
        if !(self.start_tolerance_m.is_finite() && self.start_tolerance_m >= 0.0) {
            return Err(BridgeError::Setting(
                "start_tolerance_m",
                format!("must be >= 0 m, got {}", self.start_tolerance_m),
            ));
        }
        if !(self.envelope_margin_m.is_finite() && self.envelope_margin_m > 0.0) {
            return Err(BridgeError::Setting(
                "envelope_margin_m",
                format!("must be > 0 m, got {}", self.envelope_margin_m),
            ));
        }
        if !(self.max_speed_mps.is_finite() && self.max_speed_mps > 0.0) {
            return Err(BridgeError::Setting(
                "max_speed_mps",
                format!("must be > 0 m/s, got {}", self.max_speed_mps),
            ));
        }
        Ok(())
    }
}

/// Why a `Reset` is refused (`FAILED_PRECONDITION`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ResetRefusal {
    #[error("the vehicle has reported no state yet (LOCAL_POSITION_NED and ATTITUDE)")]
    NoState,
    #[error(
        "the requested start {requested_m:?} is {distance_m:.3} m from the vehicle at {vehicle_m:?} (tolerance {tolerance_m} m): a gateway never teleports a vehicle; fly it there first, or reset with the vehicle's position as initial_state"
    )]
    FarFromVehicle { requested_m: [f64; 3], vehicle_m: [f64; 3], distance_m: f64, tolerance_m: f64 },
    #[error("{0}")]
    Scenario(String),
}

/// What the gateway knows of the vehicle (`VehicleControl.GetStatus`).
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleStatus {
    /// Since the last vehicle heartbeat, ns (`None`: never heard).
    pub heartbeat_age_ns: Option<u64>,
    pub link_alive: bool,
    pub autopilot: MavAutopilot,
    pub armed: bool,
    pub custom_mode: u32,
    pub mode: String,
    /// Armed and in the mode that flies setpoints, by the last heartbeat
    /// ([`Bridge::flies_setpoints`]).
    pub flies_setpoints: bool,
    /// `SYS_STATUS.voltage_battery`, V (`None`: unknown).
    pub battery_voltage_v: Option<f64>,
    /// `SYS_STATUS.battery_remaining`, percent (`None`: unknown).
    pub battery_remaining_pct: Option<f64>,
    /// `vehicle - gateway` clock offset, ns, and whether `TIMESYNC` measured it.
    pub clock_offset_ns: Option<(i64, bool)>,
    pub counters: Counters,
    /// The vehicle the link is locked to (`None`: no autopilot heartbeat yet).
    pub vehicle: Option<Vehicle>,
    /// Frames not believed: from another address or system, undecodable, unsigned, ...
    pub dropped: Dropped,
}

/// What the bridge counted since start: every fault and best-effort decision.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Counters {
    /// `SET_ATTITUDE_TARGET`s sent; none is sent before the vehicle's attitude is heard.
    pub setpoints_sent: u64,
    /// Commands whose thrust fell outside `[0, 1]` after calibration and was clamped.
    pub thrust_clamped: u64,
    /// Times the command timeout made the gateway hold level hover.
    pub watchdog_holds: u64,
    /// State messages older than the newest sample (out of order), not used.
    pub stale_messages: u64,
    /// State messages with non-finite values, not used.
    pub bad_messages: u64,
    /// Times the vehicle's boot clock showed a reboot ([`shows_reboot`]: it went back by more
    /// than [`REBOOT_CLOCK_JUMP_MS`], or restarted during a silence).
    pub reboots: u64,
    /// `LOCAL_POSITION_NED`s far outside the scenario's envelope or faster than the speed
    /// bound, not used.
    pub implausible_states: u64,
    /// `TIMESYNC` answers not taken: not to an outstanding request of ours, or going back.
    pub timesync_refused: u64,
    /// Stamps that showed a reboot which the next messages did not confirm
    /// ([`REBOOT_CONFIRMATIONS`]).
    pub reboot_stamps_refused: u64,
}

/// A reboot of the vehicle, seen in its boot clock (`time_boot_ms`): gone back, or restarted
/// during a silence ([`shows_reboot`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Reboot {
    /// The newest stamp of the messages of that kind before the reboot, ms.
    pub before_ms: u32,
    /// The stamp of the message that showed the reboot, ms.
    pub after_ms: u32,
    /// Gateway time between the two messages' arrivals, ns.
    pub silence_ns: u64,
}

impl std::fmt::Display for Reboot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (before_s, after_s) = (f64::from(self.before_ms) / 1e3, f64::from(self.after_ms) / 1e3);
        if self.after_ms < self.before_ms {
            write!(
                f,
                "the autopilot rebooted (its boot clock went back from {before_s:.3} s to {after_s:.3} s)"
            )?;
        } else {
            write!(
                f,
                "the autopilot rebooted (its boot clock reads {after_s:.3} s after a silence of {:.3} s; it read {before_s:.3} s before: it restarted during the silence)",
                mav::ns_to_s(self.silence_ns)
            )?;
        }
        write!(f, ": plant time is no longer continuous; call Reset to start a new episode")
    }
}

/// What one incoming message produced.
#[derive(Debug, Default)]
pub struct Event {
    /// A new state sample.
    pub sample: Option<PlantSample>,
    /// A `COMMAND_ACK`: the command and its result.
    pub ack: Option<(MavCmd, MavResult)>,
    /// A `PARAM_VALUE`: the parameter's name and value.
    pub param: Option<(String, f32)>,
    /// A message to send back (an answer to the vehicle's `TIMESYNC` request).
    pub reply: Option<MavMessage>,
    /// This message answered our `TIMESYNC` request sent at gateway time `.0` (its `ts1`),
    /// ns, with round trip `.1`, ns (what `gateway --record-link` records).
    pub timesync_answer: Option<(u64, u64)>,
    /// This message confirmed that the vehicle rebooted (once per reboot).
    pub reboot: Option<Reboot>,
    /// This heartbeat locked the link to its sender: where to send from now on.
    pub locked: Option<Vehicle>,
    /// The message was not believed (counted in [`VehicleStatus::dropped`]).
    pub dropped: Option<Refusal>,
}

/// A stamp that showed a reboot, waiting for [`REBOOT_CONFIRMATIONS`] more.
#[derive(Debug, Clone)]
struct PendingReboot {
    reboot: Reboot,
    /// Gateway time of the stamp, ns.
    heard_ns: u64,
    confirmations: u32,
    /// The newest state of each kind on the restarted clock, with the gateway time it arrived,
    /// ns: kept so that the confirmed reboot starts with both kinds, and a `Reset` right after it
    /// finds a state (else it would wait for the next message of the kind that did not confirm).
    position: Option<(LOCAL_POSITION_NED_DATA, u64)>,
    attitude: Option<(Attitude, u64)>,
}

/// What a state message's stamp means ([`Bridge::is_new_stamp`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stamp {
    /// Newer than the last of its kind: used.
    New,
    /// On the clock of a reboot not confirmed yet: kept in the pending reboot, not used.
    Held,
    /// Older than the last of its kind, or refused: not used.
    Old,
}

#[derive(Debug, Clone)]
struct Heard {
    local_ns: u64,
    autopilot: MavAutopilot,
    armed: bool,
    custom_mode: u32,
}

/// The gateway's core.
#[derive(Debug, Clone)]
pub struct Bridge {
    settings: BridgeSettings,
    scenario: Scenario,
    thrust: ThrustMap,
    /// The vehicle's (system, component), from its heartbeat.
    target: (u8, u8),
    /// Whom to believe.
    trust: Trust,
    /// A stamp that showed a reboot, not confirmed yet.
    pending_reboot: Option<PendingReboot>,
    heard: Option<Heard>,
    battery_voltage_v: Option<f64>,
    battery_remaining_pct: Option<f64>,
    timesync: TimeSync,
    position: Option<LOCAL_POSITION_NED_DATA>,
    attitude: Option<Attitude>,
    /// Gateway time the stored position and attitude arrived, ns (a silence is measured from it).
    position_heard_ns: u64,
    attitude_heard_ns: u64,
    /// The yaw the setpoints hold: the vehicle's at arming (its current one while disarmed).
    yaw_hold_rad: f64,
    /// Vehicle time of plant time 0 (the last reset, or the first state heard), ns.
    epoch_vehicle_ns: Option<u64>,
    next_seq: u64,
    current: Option<PlantSample>,
    last_command: AppliedCommand,
    /// Gateway time of the last command (or of the start or the last reset).
    command_local_ns: u64,
    watchdog_hover: bool,
    watchdog_hover_ns: u64,
    contacts: Contacts,
    path_length_m: f64,
    flight_id: u64,
    /// The vehicle rebooted since the last reset: no samples until the next one.
    rebooted: Option<Reboot>,
    /// The input streamed as setpoints.
    setpoint: Input,
    next_setpoint_ns: u64,
    next_heartbeat_ns: u64,
    next_timesync_ns: u64,
    counters: Counters,
}

fn hover(scenario: &Scenario) -> Input {
    scenario.model.hover_input()
}

fn initial_command(scenario: &Scenario) -> AppliedCommand {
    AppliedCommand {
        input: hover(scenario),
        meta: CommandMeta::default(),
        applied_time_ns: 0,
        saturated: false,
        initial: true,
    }
}

impl Bridge {
    /// A bridge for `scenario` that has heard nothing yet, started at gateway time `now_ns`.
    pub fn new(
        scenario: Scenario,
        settings: BridgeSettings,
        now_ns: u64,
        flight_id: u64,
    ) -> Result<Self, BridgeError> {
        settings.validate()?;
        scenario.validate().map_err(|e| BridgeError::Setting("scenario", e.to_string()))?;
        let thrust = ThrustMap::new(settings.hover_thrust, scenario.model.gravity_mps2)?;
        Ok(Self {
            settings,
            thrust,
            target: (1, 1),
            trust: Trust::new(settings.vehicle),
            pending_reboot: None,
            heard: None,
            battery_voltage_v: None,
            battery_remaining_pct: None,
            timesync: TimeSync::default(),
            position: None,
            attitude: None,
            position_heard_ns: now_ns,
            attitude_heard_ns: now_ns,
            yaw_hold_rad: 0.0,
            epoch_vehicle_ns: None,
            next_seq: 0,
            current: None,
            last_command: initial_command(&scenario),
            command_local_ns: now_ns,
            watchdog_hover: false,
            watchdog_hover_ns: 0,
            contacts: Contacts::new(scenario.obstacles.clone(), scenario.ground_z_m),
            path_length_m: 0.0,
            flight_id,
            rebooted: None,
            setpoint: hover(&scenario),
            next_setpoint_ns: now_ns,
            next_heartbeat_ns: now_ns,
            next_timesync_ns: now_ns,
            counters: Counters::default(),
            scenario,
        })
    }

    pub fn scenario(&self) -> &Scenario {
        &self.scenario
    }
    pub fn settings(&self) -> &BridgeSettings {
        &self.settings
    }
    pub fn counters(&self) -> Counters {
        self.counters
    }
    /// The newest sample (`None` before the vehicle's first state).
    pub fn sample(&self) -> Option<&PlantSample> {
        self.current.as_ref()
    }
    /// The input the setpoints carry now.
    pub fn setpoint_input(&self) -> Input {
        self.setpoint
    }
    pub fn yaw_hold_rad(&self) -> f64 {
        self.yaw_hold_rad
    }

    /// The vehicle rebooted since the last reset (`Some`): its samples are refused until the
    /// next [`Bridge::reset`], since plant time is no longer continuous.
    pub fn awaiting_reset(&self) -> Option<Reboot> {
        self.rebooted
    }

    /// The vehicle's heartbeat is fresh.
    pub fn link_alive(&self, now_ns: u64) -> bool {
        self.heard
            .as_ref()
            .is_some_and(|h| now_ns.saturating_sub(h.local_ns) < self.settings.heartbeat_timeout_ns)
    }

    /// Plant time (ns since the epoch) of a vehicle time.
    fn plant_ns(&self, vehicle_ns: u64) -> u64 {
        vehicle_ns.saturating_sub(self.epoch_vehicle_ns.unwrap_or(vehicle_ns))
    }

    /// An incoming message from `peer`, at gateway time `now_ns`: believed only from the
    /// vehicle the link is locked to ([`Trust`]); anything else is counted and changes nothing.
    pub fn on_message(&mut self, peer: Peer, header: &MavHeader, msg: &MavMessage, now_ns: u64) -> Event {
        let mut event = Event::default();
        let lost = !self.link_alive(now_ns);
        match self.trust.admit(peer, header, msg, lost) {
            Err(why) => {
                event.dropped = Some(why);
                return event;
            }
            Ok(Admitted::Locked(vehicle)) => {
                self.target = (vehicle.system_id, vehicle.component_id);
                event.locked = Some(vehicle);
            }
            Ok(Admitted::Vehicle) => {}
        }
        match msg {
            MavMessage::HEARTBEAT(h) if h.autopilot != MavAutopilot::MAV_AUTOPILOT_INVALID => {
                let armed = h.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
                let was_armed = self.heard.as_ref().is_some_and(|p| p.armed);
                if armed && !was_armed {
                    // The yaw the setpoints hold from now on.
                    if let Some(a) = &self.attitude {
                        self.yaw_hold_rad = a.yaw_rad;
                    }
                }
                self.heard = Some(Heard {
                    local_ns: now_ns,
                    autopilot: h.autopilot,
                    armed,
                    custom_mode: h.custom_mode,
                });
            }
            MavMessage::SYS_STATUS(s) => {
                self.battery_voltage_v =
                    (s.voltage_battery != u16::MAX).then(|| f64::from(s.voltage_battery) / 1000.0);
                self.battery_remaining_pct =
                    (s.battery_remaining >= 0).then(|| f64::from(s.battery_remaining));
            }
            MavMessage::TIMESYNC(t) => {
                if t.tc1 == 0 {
                    // The vehicle asks: answer with our clock.
                    event.reply =
                        Some(MavMessage::TIMESYNC(TIMESYNC_DATA { tc1: now_ns as i64, ts1: t.ts1 }));
                } else {
                    match self.timesync.on_answer(t.tc1, t.ts1, now_ns) {
                        Some(rtt) => event.timesync_answer = Some((t.ts1 as u64, rtt)),
                        None => self.counters.timesync_refused += 1,
                    }
                }
            }
            MavMessage::COMMAND_ACK(a) => event.ack = Some((a.command, a.result)),
            MavMessage::PARAM_VALUE(p) => match p.param_id.to_str() {
                Ok(name) => event.param = Some((name.to_owned(), p.param_value)),
                Err(_) => self.counters.bad_messages += 1,
            },
            MavMessage::ATTITUDE(a) => match Attitude::from_euler(a) {
                Some(att) => self.on_attitude(att, now_ns, &mut event),
                None => self.counters.bad_messages += 1,
            },
            MavMessage::ATTITUDE_QUATERNION(a) => match Attitude::from_quaternion(a) {
                Some(att) => self.on_attitude(att, now_ns, &mut event),
                None => self.counters.bad_messages += 1,
            },
            MavMessage::LOCAL_POSITION_NED(p) => {
                let t = p.time_boot_ms;
                if [p.x, p.y, p.z, p.vx, p.vy, p.vz].iter().any(|v| !v.is_finite()) {
                    self.counters.bad_messages += 1;
                    return event;
                }
                if !self.plausible(p) {
                    self.counters.implausible_states += 1;
                    return event;
                }
                let old_ms = self.position.as_ref().map(|old| old.time_boot_ms);
                match self.is_new_stamp(old_ms, self.position_heard_ns, t, now_ns, &mut event) {
                    Stamp::New => {
                        self.position = Some(p.clone());
                        self.position_heard_ns = now_ns;
                        event.sample = self.produce(u64::from(t) * 1_000_000, now_ns);
                    }
                    Stamp::Held => {
                        if let Some(pending) = &mut self.pending_reboot {
                            pending.position = Some((p.clone(), now_ns));
                        }
                    }
                    Stamp::Old => {}
                }
            }
            _ => {}
        }
        event
    }

    fn on_attitude(&mut self, att: Attitude, now_ns: u64, event: &mut Event) {
        let old_ms = self.attitude.as_ref().map(|old| old.time_boot_ms);
        match self.is_new_stamp(old_ms, self.attitude_heard_ns, att.time_boot_ms, now_ns, event) {
            Stamp::New => {}
            Stamp::Held => {
                if let Some(pending) = &mut self.pending_reboot {
                    pending.attitude = Some((att, now_ns));
                }
                return;
            }
            Stamp::Old => return,
        }
        if !self.heard.as_ref().is_some_and(|h| h.armed) {
            self.yaw_hold_rad = att.yaw_rad;
        }
        self.attitude = Some(att);
        self.attitude_heard_ns = now_ns;
        event.sample = self.produce(u64::from(att.time_boot_ms) * 1_000_000, now_ns);
    }

    /// Whether a `LOCAL_POSITION_NED` is inside the scenario's envelope: its position within
    /// [`BridgeSettings::envelope_margin_m`] of the box around the scenario's start, goal and
    /// obstacles (the model's frame), its speed at most [`BridgeSettings::max_speed_mps`].
    fn plausible(&self, p: &LOCAL_POSITION_NED_DATA) -> bool {
        let s = &self.scenario;
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
        // The model's frame: z up, y = -east.
        let at = [f64::from(p.x), -f64::from(p.y), -f64::from(p.z)];
        let inside = (0..3).all(|i| at[i] >= lo[i] - margin && at[i] <= hi[i] + margin);
        let speed = [p.vx, p.vy, p.vz].iter().map(|v| f64::from(*v).powi(2)).sum::<f64>().sqrt();
        inside && speed <= self.settings.max_speed_mps
    }

    /// A state message of one kind stamped `t_ms`, after the last of its kind stamped `old_ms`
    /// and heard at `heard_ns`: whether it is newer (else it is counted stale). A stamp that
    /// shows a reboot ([`shows_reboot`]) is held as a candidate and the message not used; the
    /// next [`REBOOT_CONFIRMATIONS`] state messages on the restarted clock confirm it (the
    /// reboot is then recorded in `event` and the confirming message starts afresh, with the
    /// held messages of the other kind), and one on any other clock refuses it (counted).
    fn is_new_stamp(
        &mut self,
        old_ms: Option<u32>,
        heard_ns: u64,
        t_ms: u32,
        now_ns: u64,
        event: &mut Event,
    ) -> Stamp {
        if let Some(pending) = &mut self.pending_reboot {
            let elapsed_ms = now_ns.saturating_sub(pending.heard_ns) / 1_000_000;
            let expected_ms = u64::from(pending.reboot.after_ms) + elapsed_ms;
            if u64::from(t_ms).abs_diff(expected_ms) <= u64::from(REBOOT_CLOCK_JUMP_MS) {
                pending.confirmations += 1;
                if pending.confirmations < REBOOT_CONFIRMATIONS {
                    return Stamp::Held;
                }
                if let Some(pending) = self.pending_reboot.take() {
                    event.reboot = Some(self.on_reboot(pending, now_ns));
                }
                return Stamp::New;
            }
            self.pending_reboot = None;
            self.counters.reboot_stamps_refused += 1;
        }
        let Some(old_ms) = old_ms else { return Stamp::New };
        let silence_ns = now_ns.saturating_sub(heard_ns);
        if shows_reboot(old_ms, t_ms, silence_ns) {
            self.pending_reboot = Some(PendingReboot {
                reboot: Reboot { before_ms: old_ms, after_ms: t_ms, silence_ns },
                heard_ns: now_ns,
                confirmations: 0,
                position: None,
                attitude: None,
            });
            return Stamp::Held;
        }
        if old_ms > t_ms {
            self.counters.stale_messages += 1;
            return Stamp::Old;
        }
        Stamp::New
    }

    /// The vehicle's boot clock went from `before_ms` to `after_ms` in a way that shows a reboot
    /// ([`shows_reboot`]), `silence_ns` apart, and the next messages confirmed it. What was
    /// measured on its old clock is forgotten (the clock offset, the last state and its stamps,
    /// which become the messages held on the new clock, the plant-time epoch, the last
    /// command's stamps), as is its armed state (a rebooted autopilot is disarmed; the next
    /// heartbeat says so, and an arming after it takes the yaw to hold again). The setpoint goes
    /// back to level hover, and no sample is made until the next [`Bridge::reset`]. Nothing is
    /// sent to the vehicle.
    fn on_reboot(&mut self, pending: PendingReboot, now_ns: u64) -> Reboot {
        let reboot = pending.reboot;
        self.counters.reboots += 1;
        self.rebooted = Some(reboot);
        self.timesync.restart(now_ns);
        (self.position, self.position_heard_ns) = match pending.position {
            Some((p, heard_ns)) => (Some(p), heard_ns),
            None => (None, now_ns),
        };
        (self.attitude, self.attitude_heard_ns) = match pending.attitude {
            Some((a, heard_ns)) => (Some(a), heard_ns),
            None => (None, now_ns),
        };
        self.epoch_vehicle_ns = None;
        self.current = None;
        self.last_command = initial_command(&self.scenario);
        if let Some(h) = &mut self.heard {
            h.armed = false;
        }
        self.setpoint = hover(&self.scenario);
        self.watchdog_hover = true;
        reboot
    }

    /// A new sample at vehicle time `vehicle_ns`, once both a position and an attitude exist.
    fn produce(&mut self, vehicle_ns: u64, now_ns: u64) -> Option<PlantSample> {
        self.timesync.on_arrival(vehicle_ns, now_ns);
        if self.rebooted.is_some() {
            return None;
        }
        let (p, a) = (self.position.as_ref()?, self.attitude.as_ref()?);
        let ned = messages::ned_of(p, a)?;
        let state = frame::model_state(&ned);
        let epoch = *self.epoch_vehicle_ns.get_or_insert(vehicle_ns);
        let time_ns = vehicle_ns.saturating_sub(epoch);
        if let Some(prev) = &self.current {
            if time_ns < prev.time_ns {
                self.counters.stale_messages += 1;
                return None;
            }
            let dt_s = mav::ns_to_s(time_ns - prev.time_ns);
            self.path_length_m += 0.5 * (speed(&prev.state) + speed(&state)) * dt_s;
            if self.watchdog_hover && prev.watchdog_hover {
                self.watchdog_hover_ns += time_ns - prev.time_ns;
            }
        }
        self.contacts.observe(time_ns, &state);
        Some(self.emit(time_ns, state))
    }

    fn emit(&mut self, time_ns: u64, state: State) -> PlantSample {
        let sample = PlantSample {
            seq: self.next_seq,
            time_ns,
            state,
            last_command: self.last_command,
            watchdog_hover: self.watchdog_hover,
            collided: self.contacts.collided(),
            min_clearance_m: self.contacts.min_clearance_m(),
            path_length_m: self.path_length_m,
            collisions: self.contacts.collisions().to_vec(),
            watchdog_hover_ns: self.watchdog_hover_ns,
            flight_id: self.flight_id,
        };
        self.next_seq += 1;
        self.current = Some(sample.clone());
        sample
    }

    /// A command from the controller at gateway time `now_ns`: saturated at the scenario's
    /// limits, stamped with the vehicle's clock, and sent at once. Returns what was applied and
    /// the setpoint to send (none before the vehicle's attitude is known: its yaw is what the
    /// setpoints hold, and the first poll after it sends the setpoint).
    pub fn apply(
        &mut self,
        input: Input,
        meta: CommandMeta,
        now_ns: u64,
    ) -> (AppliedCommand, Option<MavMessage>) {
        let (saturated_input, saturated) = self.scenario.bounds.saturate(&input);
        let vehicle_ns = self.timesync.vehicle_ns(now_ns).unwrap_or(0);
        self.setpoint = saturated_input;
        self.watchdog_hover = false;
        self.command_local_ns = now_ns;
        let msg = self.attitude.is_some().then(|| self.setpoint_message(now_ns));
        let (_, clamped) = self.thrust.normalise(saturated_input[0]);
        self.last_command = AppliedCommand {
            input: saturated_input,
            meta,
            applied_time_ns: self.plant_ns(vehicle_ns),
            saturated: saturated || clamped,
            initial: false,
        };
        (self.last_command, msg)
    }

    fn setpoint_message(&mut self, now_ns: u64) -> MavMessage {
        let vehicle_ns = self.timesync.vehicle_ns(now_ns).unwrap_or(0);
        let (data, clamped) =
            messages::setpoint(&self.setpoint, self.yaw_hold_rad, &self.thrust, vehicle_ns, self.target);
        self.counters.setpoints_sent += 1;
        self.counters.thrust_clamped += u64::from(clamped);
        self.next_setpoint_ns = now_ns + self.settings.setpoint_period_ns;
        MavMessage::SET_ATTITUDE_TARGET(data)
    }

    /// What is due at gateway time `now_ns` (the command timeout's hover, the setpoint resent,
    /// the gateway's heartbeat, a `TIMESYNC` request), appended to `out`.
    ///
    /// No setpoint goes out (or is counted) before the vehicle's attitude is known: before it
    /// there is no vehicle to hold the yaw of, and on a `udpin` link no address to send to, so
    /// `setpoints_sent` counts only setpoints a vehicle could have heard (what a client waits
    /// for before asking for OFFBOARD).
    pub fn poll(&mut self, now_ns: u64, out: &mut Vec<MavMessage>) {
        let vehicle_known = self.attitude.is_some();
        if !self.watchdog_hover
            && now_ns.saturating_sub(self.command_local_ns) >= self.settings.command_timeout_ns
        {
            // Mirrors PX4's offboard-loss failsafe: level attitude at hover thrust, at once.
            self.watchdog_hover = true;
            self.counters.watchdog_holds += 1;
            self.setpoint = hover(&self.scenario);
            if vehicle_known {
                out.push(self.setpoint_message(now_ns));
            }
        } else if vehicle_known && now_ns >= self.next_setpoint_ns {
            out.push(self.setpoint_message(now_ns));
        }
        if now_ns >= self.next_heartbeat_ns {
            self.next_heartbeat_ns = now_ns + self.settings.heartbeat_period_ns;
            out.push(MavMessage::HEARTBEAT(HEARTBEAT_DATA {
                custom_mode: 0,
                mavtype: MavType::MAV_TYPE_ONBOARD_CONTROLLER,
                autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
                base_mode: MavModeFlag::empty(),
                system_status: MavState::MAV_STATE_ACTIVE,
                mavlink_version: 3,
            }));
        }
        if now_ns >= self.next_timesync_ns {
            self.next_timesync_ns = now_ns + self.settings.timesync_period_ns;
            let (tc1, ts1) = self.timesync.request(now_ns);
            out.push(MavMessage::TIMESYNC(TIMESYNC_DATA { tc1, ts1 }));
        }
    }

    /// The earliest gateway time at which [`Bridge::poll`] has something to do.
    pub fn next_due_ns(&self) -> u64 {
        let watchdog = if self.watchdog_hover {
            u64::MAX
        } else {
            self.command_local_ns + self.settings.command_timeout_ns
        };
        let setpoint = if self.attitude.is_some() { self.next_setpoint_ns } else { u64::MAX };
        setpoint.min(self.next_heartbeat_ns).min(self.next_timesync_ns).min(watchdog)
    }

    /// A `Reset`: the scenario (obstacles, goal) changes, plant time restarts at the vehicle's
    /// newest state, a new flight begins, and the setpoint goes back to level hover; the
    /// vehicle is not moved. After a reboot, this is what serves samples again (on the new
    /// clock). Refused when the requested start (or the scenario's) is farther
    /// from the vehicle than the tolerance.
    pub fn reset(
        &mut self,
        scenario: Scenario,
        start: Option<State>,
        now_ns: u64,
        flight_id: u64,
    ) -> Result<PlantSample, ResetRefusal> {
        scenario.validate().map_err(|e| ResetRefusal::Scenario(e.to_string()))?;
        let thrust = ThrustMap::new(self.settings.hover_thrust, scenario.model.gravity_mps2)
            .map_err(|e| ResetRefusal::Scenario(e.to_string()))?;
        let (p, a) = match (&self.position, &self.attitude) {
            (Some(p), Some(a)) => (p, a),
            _ => return Err(ResetRefusal::NoState),
        };
        let state = frame::model_state(&messages::ned_of(p, a).ok_or(ResetRefusal::NoState)?);
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
        let vehicle_ns = u64::from(p.time_boot_ms.max(a.time_boot_ms)) * 1_000_000;
        self.thrust = thrust;
        self.contacts = Contacts::new(scenario.obstacles.clone(), scenario.ground_z_m);
        self.last_command = initial_command(&scenario);
        self.setpoint = hover(&scenario);
        self.scenario = scenario;
        self.epoch_vehicle_ns = Some(vehicle_ns);
        self.next_seq = 0;
        self.command_local_ns = now_ns;
        self.watchdog_hover = false;
        self.watchdog_hover_ns = 0;
        self.path_length_m = 0.0;
        self.flight_id = flight_id;
        self.rebooted = None;
        self.contacts.observe(0, &state);
        Ok(self.emit(0, state))
    }

    /// `COMMAND_LONG` for a command to the vehicle.
    pub fn command_long(&self, command: MavCmd, params: [f32; 7]) -> MavMessage {
        let [param1, param2, param3, param4, param5, param6, param7] = params;
        MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            param1,
            param2,
            param3,
            param4,
            param5,
            param6,
            param7,
            command,
            target_system: self.target.0,
            target_component: self.target.1,
            confirmation: 0,
        })
    }

    /// `COMMAND_LONG` arming (`true`) or disarming the vehicle.
    pub fn arm_message(&self, arm: bool) -> MavMessage {
        self.command_long(
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            [f32::from(u8::from(arm)), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        )
    }

    /// `PARAM_REQUEST_READ` of the vehicle's parameter `name`.
    pub fn param_request(&self, name: &str) -> MavMessage {
        MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
            param_index: -1,
            target_system: self.target.0,
            target_component: self.target.1,
            param_id: name.into(),
        })
    }

    /// A frame from `peer` refused before it was decoded (junk, or its signature), counted;
    /// returns what it was counted as ([`Trust::refuse`]).
    pub fn refuse(&mut self, peer: Peer, why: Refusal) -> Refusal {
        self.trust.refuse(peer, why)
    }

    /// The frames not believed so far.
    pub fn dropped(&self) -> &Dropped {
        self.trust.dropped()
    }

    /// The vehicle the link is locked to (`None`: no autopilot heartbeat heard yet).
    pub fn vehicle(&self) -> Option<Vehicle> {
        self.trust.vehicle()
    }

    /// The autopilot of the last heartbeat (`None`: none heard).
    pub fn autopilot(&self) -> Option<MavAutopilot> {
        self.heard.as_ref().map(|h| h.autopilot)
    }

    /// Whether the vehicle flies the setpoints, by its last heartbeat: armed, in PX4's OFFBOARD
    /// or ArduCopter's GUIDED_NOGPS. Otherwise they are sent, and the vehicle ignores them.
    pub fn flies_setpoints(&self) -> bool {
        self.heard.as_ref().is_some_and(|h| {
            h.armed
                && [ModeRequest::Px4Offboard, ModeRequest::ArduGuidedNoGps]
                    .into_iter()
                    .any(|m| modes::is_mode(m, h.autopilot, h.custom_mode))
        })
    }

    /// `COMMAND_LONG` asking for `mode`.
    pub fn mode_message(&self, mode: ModeRequest) -> MavMessage {
        let (p1, p2, p3) = mode.params();
        self.command_long(MavCmd::MAV_CMD_DO_SET_MODE, [p1, p2, p3, 0.0, 0.0, 0.0, 0.0])
    }

    pub fn status(&self, now_ns: u64) -> VehicleStatus {
        let (autopilot, armed, custom_mode) = self
            .heard
            .as_ref()
            .map(|h| (h.autopilot, h.armed, h.custom_mode))
            .unwrap_or((MavAutopilot::MAV_AUTOPILOT_INVALID, false, 0));
        VehicleStatus {
            heartbeat_age_ns: self.heard.as_ref().map(|h| now_ns.saturating_sub(h.local_ns)),
            link_alive: self.link_alive(now_ns),
            autopilot,
            armed,
            custom_mode,
            mode: if self.heard.is_some() {
                modes::mode_name(autopilot, custom_mode)
            } else {
                "unknown".into()
            },
            flies_setpoints: self.flies_setpoints(),
            battery_voltage_v: self.battery_voltage_v,
            battery_remaining_pct: self.battery_remaining_pct,
            clock_offset_ns: self.timesync.offset_ns(),
            counters: self.counters,
            vehicle: self.trust.vehicle(),
            dropped: self.trust.dropped().clone(),
        }
    }
}

fn speed(x: &State) -> f64 {
    (x[3] * x[3] + x[4] * x[4] + x[5] * x[5]).sqrt()
}
