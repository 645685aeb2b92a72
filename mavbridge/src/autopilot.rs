//! The simulator's autopilot: the MAV model of `mav` (its `PlantSim`, RK4 at 1 kHz) behind
//! the autopilot's side of the MAVLink subset the gateway speaks, as PX4 plays it: heartbeats
//! with the armed state and the custom mode, `ATTITUDE` and `LOCAL_POSITION_NED`, answers to
//! `TIMESYNC`, `COMMAND_LONG` for arming and modes answered with `COMMAND_ACK`, and
//! `SET_ATTITUDE_TARGET` through the same frame and thrust conversions as the gateway's.
//!
//! What it does as PX4 does: OFFBOARD is refused unless setpoints are streaming (one within
//! the loss timeout), and when the stream stops in OFFBOARD it fails safe to a hold
//! (AUTO_LOITER; here level attitude at hover thrust). As ArduCopter does
//! ([`Firmware::ArduCopter`]): GUIDED_NOGPS (mode 20) is accepted without a stream; when the
//! stream stops the vehicle levels and holds its height in that mode (`GUID_TIMEOUT`); the
//! setpoints' thrust is thrust only with `GUID_OPTIONS` bit 3, otherwise a climb rate (0.5
//! holds the height, 1 climbs at 2.5 m/s, 0 sinks at 1.5 m/s, `WPNAV_SPEED_UP`/`_DN`'s
//! defaults); `PARAM_REQUEST_READ` of `GUID_OPTIONS` is answered. What it simplifies: disarmed,
//! the vehicle rests (the model is not integrated: it stands on the ground or a stand); armed in
//! POSCTL (LOITER) or a hold, it flies level at hover thrust. Time is the vehicle's boot clock,
//! passed in.

use crate::messages;
use crate::modes::{self, ModeRequest};
use crate::thrust::{ThrustError, ThrustMap};
use mav::{CommandMeta, PlantSim, Scenario, SimSettings};
use mavlink::dialects::common::{
    COMMAND_ACK_DATA, HEARTBEAT_DATA, MavAutopilot, MavCmd, MavMessage, MavModeFlag, MavParamType, MavResult,
    MavState, MavSysStatusSensor, MavType, PARAM_VALUE_DATA, SYS_STATUS_DATA, TIMESYNC_DATA,
};

/// Whose side of MAVLink the simulator plays.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Firmware {
    #[default]
    Px4,
    /// ArduCopter with this `GUID_OPTIONS` (its default is 0: thrust read as a climb rate).
    /// [`AutopilotSettings::offboard_loss_ns`] plays `GUID_TIMEOUT` (ArduCopter's default is
    /// 3 s; `mavsim` sets it).
    ArduCopter { guid_options: u32 },
}

impl Firmware {
    fn autopilot(self) -> MavAutopilot {
        match self {
            Self::Px4 => MavAutopilot::MAV_AUTOPILOT_PX4,
            Self::ArduCopter { .. } => MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        }
    }
}

/// ArduCopter's climb and descent rates at full and zero climb-rate "thrust", m/s
/// (`WPNAV_SPEED_UP` and `WPNAV_SPEED_DN`'s defaults).
const ARDU_CLIMB_MPS: f64 = 2.5;
const ARDU_DESCENT_MPS: f64 = 1.5;
/// The gain from a climb-rate error to mass-normalised thrust, 1/s.
const ARDU_CLIMB_GAIN_PER_S: f64 = 2.0;

/// Settings of the simulated autopilot, with units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AutopilotSettings {
    /// Normalised thrust that hovers (the vehicle's; the gateway's `--hover-thrust` must match).
    pub hover_thrust: f64,
    /// Setpoints older than this end OFFBOARD (failsafe to hold), and refuse entering it, ns.
    pub offboard_loss_ns: u64,
    /// `ATTITUDE` and `LOCAL_POSITION_NED` period, ns.
    pub state_period_ns: u64,
    /// `HEARTBEAT` and `SYS_STATUS` period, ns.
    pub heartbeat_period_ns: u64,
    /// The vehicle's heading, rad (the model has no yaw; the frames carry it).
    pub yaw_rad: f64,
    pub firmware: Firmware,
}

impl Default for AutopilotSettings {
    fn default() -> Self {
        Self {
            hover_thrust: 0.5,
            offboard_loss_ns: 500_000_000,
            state_period_ns: 10_000_000,
            heartbeat_period_ns: 1_000_000_000,
            yaw_rad: 0.0,
            firmware: Firmware::Px4,
        }
    }
}

/// The flight modes the simulator plays.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimMode {
    /// PX4's POSCTL, ArduCopter's LOITER.
    Posctl,
    /// PX4's OFFBOARD, ArduCopter's GUIDED_NOGPS.
    Offboard,
    /// PX4's AUTO_LOITER, where the offboard failsafe goes (ArduCopter stays in GUIDED_NOGPS).
    Hold,
}

impl SimMode {
    fn custom_mode(self, firmware: Firmware) -> u32 {
        match (firmware, self) {
            (Firmware::Px4, Self::Posctl) => ModeRequest::px4_custom_mode(modes::PX4_MAIN_POSCTL, 0),
            (Firmware::Px4, Self::Offboard) => ModeRequest::px4_custom_mode(modes::PX4_MAIN_OFFBOARD, 0),
            (Firmware::Px4, Self::Hold) => {
                ModeRequest::px4_custom_mode(modes::PX4_MAIN_AUTO, modes::PX4_SUB_AUTO_LOITER)
            }
            (Firmware::ArduCopter { .. }, Self::Offboard) => modes::ARDU_GUIDED_NOGPS,
            (Firmware::ArduCopter { .. }, Self::Posctl | Self::Hold) => modes::ARDU_LOITER,
        }
    }
}

/// What the simulated autopilot counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AutopilotCounters {
    pub setpoints: u64,
    /// Setpoints that could not fly (attitude or thrust ignored, not a rotation).
    pub refused_setpoints: u64,
    /// OFFBOARD left because the setpoint stream stopped (ArduCopter: levelled in GUIDED_NOGPS).
    pub offboard_failsafes: u64,
}

/// Why a simulated autopilot cannot start.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AutopilotError {
    #[error(transparent)]
    Thrust(#[from] ThrustError),
    #[error(transparent)]
    Sim(#[from] mav::SimError),
    #[error("invalid simulator setting `{0}`: must be > 0")]
    Setting(&'static str),
}

#[derive(Debug, Clone)]
pub struct SimAutopilot {
    sim: PlantSim,
    thrust: ThrustMap,
    settings: AutopilotSettings,
    armed: bool,
    mode: SimMode,
    /// Vehicle time minus simulation time, ns (grows while disarmed: the model rests).
    offset_ns: u64,
    last_setpoint_ns: Option<u64>,
    setpoint: Option<mav::Input>,
    /// ArduCopter, thrust read as a climb rate: the last setpoint's, m/s up.
    climb_mps: Option<f64>,
    /// ArduCopter: levelled in GUIDED_NOGPS since the setpoints stopped.
    levelled: bool,
    next_state_ns: u64,
    next_heartbeat_ns: u64,
    counters: AutopilotCounters,
}

impl SimAutopilot {
    /// The vehicle at `scenario`'s start, disarmed in POSCTL, booted at vehicle time 0.
    pub fn new(scenario: &Scenario, settings: AutopilotSettings) -> Result<Self, ThrustError> {
        let thrust = ThrustMap::new(settings.hover_thrust, scenario.model.gravity_mps2)?;
        // No watchdog in the model: the autopilot's failsafe is the one that acts.
        let sim =
            PlantSim::new(scenario, SimSettings::default()).map_err(|_| ThrustError::Gravity(f64::NAN))?;
        Ok(Self {
            sim,
            thrust,
            settings,
            armed: false,
            mode: SimMode::Posctl,
            offset_ns: 0,
            last_setpoint_ns: None,
            setpoint: None,
            climb_mps: None,
            levelled: false,
            next_state_ns: 0,
            next_heartbeat_ns: 0,
            counters: AutopilotCounters::default(),
        })
    }

    pub fn sim(&self) -> &PlantSim {
        &self.sim
    }
    pub fn armed(&self) -> bool {
        self.armed
    }
    pub fn mode(&self) -> SimMode {
        self.mode
    }
    pub fn counters(&self) -> AutopilotCounters {
        self.counters
    }

    /// Integrates the model to vehicle time `now_ns` (nothing moves while disarmed).
    fn advance(&mut self, now_ns: u64) {
        if self.armed {
            self.sim.advance_to(now_ns.saturating_sub(self.offset_ns), |_| {});
        } else {
            self.offset_ns = now_ns.saturating_sub(self.sim.time_ns());
        }
    }

    /// Flies `input` from now on.
    fn fly(&mut self, input: mav::Input) {
        // The model saturates at the scenario's limits, as the plant does.
        let _ = self.sim.apply(input, CommandMeta::default());
    }

    fn hover(&mut self) {
        self.fly(self.sim.model().params.hover_input());
    }

    /// The setpoint flown now: as sent, or (ArduCopter reading a climb rate) its attitude with
    /// the thrust that closes the climb-rate error.
    fn flown(&self, input: mav::Input) -> mav::Input {
        match self.climb_mps {
            Some(climb_mps) => {
                // Hover, the drag at the target rate (where ArduCopter's vertical speed loop has
                // integral action, the model's drag is known here) and a proportional term, over
                // the tilt (ArduCopter's angle boost: a tilted thrust lifts by its cosines).
                let params = &self.sim.model().params;
                let x = self.sim.state();
                let vertical = params.gravity_mps2
                    + params.drag_z_per_s * climb_mps
                    + ARDU_CLIMB_GAIN_PER_S * (climb_mps - x[5]);
                let thrust = vertical / (x[6].cos() * x[7].cos()).max(0.5);
                mav::Input::new(thrust.max(0.0), input[1], input[2])
            }
            None => input,
        }
    }

    /// ArduCopter in GUIDED_NOGPS without setpoints: level, climb rate 0 (whatever
    /// `GUID_OPTIONS`), until the next setpoint.
    fn level_and_hold_height(&mut self) {
        self.levelled = true;
        self.climb_mps = Some(0.0);
        self.setpoint = Some(self.sim.model().params.hover_input());
    }

    fn fly_setpoint(&mut self, input: mav::Input) {
        self.fly(self.flown(input));
    }

    /// A message from the gateway at vehicle time `now_ns`; answers are appended to `out`.
    pub fn on_message(&mut self, msg: &MavMessage, now_ns: u64, out: &mut Vec<MavMessage>) {
        self.advance(now_ns);
        match msg {
            MavMessage::TIMESYNC(t) if t.tc1 == 0 => {
                out.push(MavMessage::TIMESYNC(TIMESYNC_DATA { tc1: now_ns as i64, ts1: t.ts1 }));
            }
            MavMessage::SET_ATTITUDE_TARGET(d) => match messages::setpoint_input(d, &self.thrust) {
                Ok((input, _yaw)) => {
                    self.counters.setpoints += 1;
                    self.last_setpoint_ns = Some(now_ns);
                    self.setpoint = Some(input);
                    self.levelled = false;
                    self.climb_mps = match self.settings.firmware {
                        Firmware::ArduCopter { guid_options }
                            if !modes::ardu_thrust_as_thrust(guid_options as f32) =>
                        {
                            let rate = (f64::from(d.thrust) - 0.5) * 2.0;
                            Some(rate * if rate > 0.0 { ARDU_CLIMB_MPS } else { ARDU_DESCENT_MPS })
                        }
                        _ => None,
                    };
                    if self.mode == SimMode::Offboard {
                        self.fly_setpoint(input);
                    }
                }
                Err(_) => self.counters.refused_setpoints += 1,
            },
            MavMessage::PARAM_REQUEST_READ(r) => {
                if let Firmware::ArduCopter { guid_options } = self.settings.firmware
                    && r.param_id.to_str() == Ok(modes::ARDU_GUID_OPTIONS)
                {
                    out.push(MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
                        param_value: guid_options as f32,
                        param_count: 1,
                        param_index: 0,
                        param_id: modes::ARDU_GUID_OPTIONS.into(),
                        param_type: MavParamType::MAV_PARAM_TYPE_INT32,
                    }));
                }
            }
            MavMessage::COMMAND_LONG(c) => {
                let result = self.command(c.command, c.param1, c.param2, c.param3, now_ns);
                out.push(MavMessage::COMMAND_ACK(COMMAND_ACK_DATA { command: c.command, result }));
            }
            _ => {}
        }
    }

    fn streaming(&self, now_ns: u64) -> bool {
        self.last_setpoint_ns.is_some_and(|t| now_ns.saturating_sub(t) < self.settings.offboard_loss_ns)
    }

    fn command(&mut self, command: MavCmd, p1: f32, p2: f32, p3: f32, now_ns: u64) -> MavResult {
        match command {
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM if p1 == 1.0 => {
                if !self.armed {
                    self.armed = true;
                    self.offset_ns = now_ns.saturating_sub(self.sim.time_ns());
                    if self.mode != SimMode::Offboard {
                        self.hover();
                    }
                }
                MavResult::MAV_RESULT_ACCEPTED
            }
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM if p1 == 0.0 => {
                self.armed = false;
                MavResult::MAV_RESULT_ACCEPTED
            }
            MavCmd::MAV_CMD_DO_SET_MODE if matches!(self.settings.firmware, Firmware::ArduCopter { .. }) => {
                match ModeRequest::from_params(p2, p3, MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA) {
                    // ArduCopter enters GUIDED_NOGPS without a setpoint stream, level until one comes.
                    Some(ModeRequest::ArduGuidedNoGps) => {
                        self.mode = SimMode::Offboard;
                        if !(self.streaming(now_ns) && self.setpoint.is_some()) {
                            self.level_and_hold_height();
                        }
                        if let Some(input) = self.setpoint {
                            self.fly_setpoint(input);
                        }
                        MavResult::MAV_RESULT_ACCEPTED
                    }
                    _ if p2 as u32 == modes::ARDU_LOITER => {
                        self.mode = SimMode::Posctl;
                        self.hover();
                        MavResult::MAV_RESULT_ACCEPTED
                    }
                    _ => MavResult::MAV_RESULT_UNSUPPORTED,
                }
            }
            MavCmd::MAV_CMD_DO_SET_MODE => {
                let main = p2 as u32;
                match ModeRequest::from_params(p2, p3, MavAutopilot::MAV_AUTOPILOT_PX4) {
                    Some(ModeRequest::Px4Offboard) => match (self.streaming(now_ns), self.setpoint) {
                        (true, Some(input)) => {
                            self.mode = SimMode::Offboard;
                            self.fly(input);
                            MavResult::MAV_RESULT_ACCEPTED
                        }
                        // PX4: "Switching to Offboard requires setpoints".
                        _ => MavResult::MAV_RESULT_DENIED,
                    },
                    _ if main == modes::PX4_MAIN_POSCTL => {
                        self.mode = SimMode::Posctl;
                        self.hover();
                        MavResult::MAV_RESULT_ACCEPTED
                    }
                    _ if main == modes::PX4_MAIN_AUTO && p3 as u32 == modes::PX4_SUB_AUTO_LOITER => {
                        self.mode = SimMode::Hold;
                        self.hover();
                        MavResult::MAV_RESULT_ACCEPTED
                    }
                    _ => MavResult::MAV_RESULT_UNSUPPORTED,
                }
            }
            _ => MavResult::MAV_RESULT_UNSUPPORTED,
        }
    }

    /// Vehicle time `now_ns`: integrates, fails safe when the setpoints stopped in OFFBOARD,
    /// and appends the streams that are due to `out`.
    pub fn poll(&mut self, now_ns: u64, out: &mut Vec<MavMessage>) {
        self.advance(now_ns);
        if self.mode == SimMode::Offboard && !self.streaming(now_ns) {
            match self.settings.firmware {
                Firmware::Px4 => {
                    self.mode = SimMode::Hold;
                    self.counters.offboard_failsafes += 1;
                    self.hover();
                }
                // ArduCopter levels and holds its height (climb rate 0, whatever GUID_OPTIONS).
                Firmware::ArduCopter { .. } if !self.levelled => {
                    self.counters.offboard_failsafes += 1;
                    self.level_and_hold_height();
                }
                Firmware::ArduCopter { .. } => {}
            }
        }
        if self.mode == SimMode::Offboard
            && self.climb_mps.is_some()
            && let Some(input) = self.setpoint
        {
            // The climb-rate loop follows the vertical speed.
            self.fly_setpoint(input);
        }
        if now_ns >= self.next_heartbeat_ns {
            self.next_heartbeat_ns = now_ns + self.settings.heartbeat_period_ns;
            let mut base_mode = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
            if self.armed {
                base_mode |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
            }
            out.push(MavMessage::HEARTBEAT(HEARTBEAT_DATA {
                custom_mode: self.mode.custom_mode(self.settings.firmware),
                mavtype: MavType::MAV_TYPE_QUADROTOR,
                autopilot: self.settings.firmware.autopilot(),
                base_mode,
                system_status: if self.armed {
                    MavState::MAV_STATE_ACTIVE
                } else {
                    MavState::MAV_STATE_STANDBY
                },
                mavlink_version: 3,
            }));
            out.push(MavMessage::SYS_STATUS(SYS_STATUS_DATA {
                onboard_control_sensors_present: MavSysStatusSensor::empty(),
                onboard_control_sensors_enabled: MavSysStatusSensor::empty(),
                onboard_control_sensors_health: MavSysStatusSensor::empty(),
                load: 0,
                voltage_battery: 16_000,
                current_battery: -1,
                drop_rate_comm: 0,
                errors_comm: 0,
                errors_count1: 0,
                errors_count2: 0,
                errors_count3: 0,
                errors_count4: 0,
                battery_remaining: 90,
            }));
        }
        if now_ns >= self.next_state_ns {
            self.next_state_ns = now_ns + self.settings.state_period_ns;
            let (attitude, position) =
                messages::state_messages(self.sim.state(), self.settings.yaw_rad, now_ns);
            out.push(MavMessage::ATTITUDE(attitude));
            out.push(MavMessage::LOCAL_POSITION_NED(position));
        }
    }

    /// The earliest vehicle time at which [`SimAutopilot::poll`] has something to do.
    pub fn next_due_ns(&self) -> u64 {
        let loss = match (self.mode, self.last_setpoint_ns) {
            (SimMode::Offboard, Some(t)) => t + self.settings.offboard_loss_ns,
            _ => u64::MAX,
        };
        self.next_state_ns.min(self.next_heartbeat_ns).min(loss)
    }
}
