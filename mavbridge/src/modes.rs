//! Flight modes as the autopilots encode them in `HEARTBEAT.custom_mode` and ask for them in
//! `MAV_CMD_DO_SET_MODE`: PX4's main and sub modes, ArduCopter's mode numbers.

use mavlink::dialects::common::MavAutopilot;

/// A mode the gateway may be asked to set (never on its own).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModeRequest {
    /// PX4's OFFBOARD (main mode 6): attitude setpoints from the gateway.
    Px4Offboard,
    /// ArduCopter's GUIDED_NOGPS (mode 20): attitude targets without position estimate.
    ArduGuidedNoGps,
}

/// `base_mode` flag saying that `custom_mode` is meaningful.
pub const CUSTOM_MODE_ENABLED: f32 = 1.0;
/// PX4 main modes.
pub const PX4_MAIN_POSCTL: u32 = 3;
pub const PX4_MAIN_AUTO: u32 = 4;
pub const PX4_MAIN_OFFBOARD: u32 = 6;
/// PX4 AUTO sub mode LOITER (hold).
pub const PX4_SUB_AUTO_LOITER: u32 = 3;
/// ArduCopter GUIDED_NOGPS.
pub const ARDU_GUIDED_NOGPS: u32 = 20;
/// ArduCopter LOITER.
pub const ARDU_LOITER: u32 = 5;
/// ArduCopter's parameter that says how GUIDED and GUIDED_NOGPS read `SET_ATTITUDE_TARGET`.
pub const ARDU_GUID_OPTIONS: &str = "GUID_OPTIONS";
/// Its bit 3, "SetAttitudeTarget interprets Thrust As Thrust": set, the thrust field is the
/// normalised thrust the gateway sends; clear (the default), a climb rate (0.5 holds height).
pub const ARDU_GUID_THRUST_AS_THRUST: u32 = 1 << 3;

/// Whether ArduCopter with this `GUID_OPTIONS` (a `PARAM_VALUE`'s value: ArduPilot sends
/// integers cast to float) flies `SET_ATTITUDE_TARGET`'s thrust as thrust.
pub fn ardu_thrust_as_thrust(guid_options: f32) -> bool {
    guid_options.is_finite()
        && guid_options >= 0.0
        && guid_options <= u32::MAX as f32
        && (guid_options as u32) & ARDU_GUID_THRUST_AS_THRUST != 0
}

impl ModeRequest {
    /// `MAV_CMD_DO_SET_MODE`'s `(param1, param2, param3)`.
    pub fn params(self) -> (f32, f32, f32) {
        match self {
            Self::Px4Offboard => (CUSTOM_MODE_ENABLED, PX4_MAIN_OFFBOARD as f32, 0.0),
            Self::ArduGuidedNoGps => (CUSTOM_MODE_ENABLED, ARDU_GUIDED_NOGPS as f32, 0.0),
        }
    }

    /// The request of `MAV_CMD_DO_SET_MODE` params, when it is one of these.
    pub fn from_params(param2: f32, param3: f32, autopilot: MavAutopilot) -> Option<Self> {
        match autopilot {
            MavAutopilot::MAV_AUTOPILOT_PX4 if param2 == PX4_MAIN_OFFBOARD as f32 && param3 == 0.0 => {
                Some(Self::Px4Offboard)
            }
            MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA if param2 == ARDU_GUIDED_NOGPS as f32 => {
                Some(Self::ArduGuidedNoGps)
            }
            _ => None,
        }
    }

    /// PX4's `custom_mode` word of a main and sub mode.
    pub fn px4_custom_mode(main: u32, sub: u32) -> u32 {
        (main << 16) | (sub << 24)
    }
}

/// A readable name of a heartbeat's mode.
pub fn mode_name(autopilot: MavAutopilot, custom_mode: u32) -> String {
    match autopilot {
        MavAutopilot::MAV_AUTOPILOT_PX4 => {
            let main = (custom_mode >> 16) & 0xff;
            let sub = (custom_mode >> 24) & 0xff;
            let name = match (main, sub) {
                (1, _) => "MANUAL",
                (2, _) => "ALTCTL",
                (3, _) => "POSCTL",
                (4, 2) => "AUTO_TAKEOFF",
                (4, 3) => "AUTO_LOITER",
                (4, 4) => "AUTO_MISSION",
                (4, 5) => "AUTO_RTL",
                (4, 6) => "AUTO_LAND",
                (4, _) => "AUTO",
                (5, _) => "ACRO",
                (6, _) => "OFFBOARD",
                (7, _) => "STABILIZED",
                _ => return format!("PX4 main {main} sub {sub}"),
            };
            name.to_string()
        }
        MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA => match custom_mode {
            0 => "STABILIZE".into(),
            2 => "ALT_HOLD".into(),
            3 => "AUTO".into(),
            4 => "GUIDED".into(),
            5 => "LOITER".into(),
            6 => "RTL".into(),
            9 => "LAND".into(),
            16 => "POSHOLD".into(),
            17 => "BRAKE".into(),
            20 => "GUIDED_NOGPS".into(),
            m => format!("ArduCopter mode {m}"),
        },
        other => format!("{other:?} mode {custom_mode}"),
    }
}

/// Whether a heartbeat's mode is the one `request` asks for.
pub fn is_mode(request: ModeRequest, autopilot: MavAutopilot, custom_mode: u32) -> bool {
    match (request, autopilot) {
        (ModeRequest::Px4Offboard, MavAutopilot::MAV_AUTOPILOT_PX4) => {
            (custom_mode >> 16) & 0xff == PX4_MAIN_OFFBOARD
        }
        (ModeRequest::ArduGuidedNoGps, MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA) => {
            custom_mode == ARDU_GUIDED_NOGPS
        }
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn px4_and_ardupilot_modes_encode_and_name() {
        let offboard = ModeRequest::px4_custom_mode(PX4_MAIN_OFFBOARD, 0);
        assert_eq!(offboard, 6 << 16);
        assert_eq!(mode_name(MavAutopilot::MAV_AUTOPILOT_PX4, offboard), "OFFBOARD");
        let hold = ModeRequest::px4_custom_mode(PX4_MAIN_AUTO, PX4_SUB_AUTO_LOITER);
        assert_eq!(mode_name(MavAutopilot::MAV_AUTOPILOT_PX4, hold), "AUTO_LOITER");
        assert!(is_mode(ModeRequest::Px4Offboard, MavAutopilot::MAV_AUTOPILOT_PX4, offboard));
        assert!(!is_mode(ModeRequest::Px4Offboard, MavAutopilot::MAV_AUTOPILOT_PX4, hold));
        assert_eq!(mode_name(MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA, 20), "GUIDED_NOGPS");
        let (_, p2, p3) = ModeRequest::Px4Offboard.params();
        assert_eq!(
            ModeRequest::from_params(p2, p3, MavAutopilot::MAV_AUTOPILOT_PX4),
            Some(ModeRequest::Px4Offboard)
        );
        let (_, p2, p3) = ModeRequest::ArduGuidedNoGps.params();
        assert_eq!(ModeRequest::from_params(p2, p3, MavAutopilot::MAV_AUTOPILOT_PX4), None);
    }

    #[test]
    fn only_guid_options_with_bit_3_flies_thrust_as_thrust() {
        for thrust in [8.0, 9.0, 15.0, 8.0 + 1024.0] {
            assert!(ardu_thrust_as_thrust(thrust), "{thrust}");
        }
        for climb_rate in [0.0, 1.0, 4.0, 7.0, 16.0, -8.0, f32::NAN, f32::INFINITY, 1e20] {
            assert!(!ardu_thrust_as_thrust(climb_rate), "{climb_rate}");
        }
    }
}
