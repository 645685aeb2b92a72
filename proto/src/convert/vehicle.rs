//! Conversions of the `VehicleControl` messages: the mode asked for, and the status the
//! gateway's core reports.

use super::FieldError;
use crate::pb;
use mavbridge::{ModeRequest, VehicleStatus};

/// The mode of a `SetModeRequest`.
pub fn mode_request(r: &pb::SetModeRequest) -> Result<ModeRequest, FieldError> {
    match pb::FlightMode::try_from(r.mode) {
        Ok(pb::FlightMode::Px4Offboard) => Ok(ModeRequest::Px4Offboard),
        Ok(pb::FlightMode::ArdupilotGuidedNogps) => Ok(ModeRequest::ArduGuidedNoGps),
        Ok(pb::FlightMode::Unspecified) => Err(FieldError::new(
            "mode",
            "is required: FLIGHT_MODE_PX4_OFFBOARD or FLIGHT_MODE_ARDUPILOT_GUIDED_NOGPS",
        )),
        Err(_) => Err(FieldError::new("mode", format!("unknown flight mode {}", r.mode))),
    }
}

/// The `VehicleStatus` message of the core's status, with the calibration in force.
pub fn vehicle_status(s: &VehicleStatus, hover_thrust: f64) -> pb::VehicleStatus {
    pb::VehicleStatus {
        heartbeat_seen: s.heartbeat_age_ns.is_some(),
        heartbeat_age_ns: s.heartbeat_age_ns.unwrap_or(0),
        link_alive: s.link_alive,
        autopilot: format!("{:?}", s.autopilot),
        armed: s.armed,
        custom_mode: s.custom_mode,
        mode: s.mode.clone(),
        flies_setpoints: s.flies_setpoints,
        battery_voltage_v: s.battery_voltage_v,
        battery_remaining_pct: s.battery_remaining_pct,
        clock_offset_ns: s.clock_offset_ns.map(|(o, _)| o),
        clock_offset_from_timesync: s.clock_offset_ns.is_some_and(|(_, t)| t),
        setpoints_sent: s.counters.setpoints_sent,
        thrust_clamped: s.counters.thrust_clamped,
        watchdog_holds: s.counters.watchdog_holds,
        stale_messages: s.counters.stale_messages,
        bad_messages: s.counters.bad_messages,
        autopilot_reboots: s.counters.reboots,
        vehicle_locked: s.vehicle.is_some(),
        vehicle_system_id: s.vehicle.map_or(0, |v| u32::from(v.system_id)),
        vehicle_component_id: s.vehicle.map_or(0, |v| u32::from(v.component_id)),
        vehicle_address: match s.vehicle {
            Some(v) => v.peer.map_or_else(|| "serial".to_string(), |at| at.to_string()),
            None => String::new(),
        },
        dropped_no_vehicle: s.dropped.no_vehicle,
        dropped_foreign_address: s.dropped.foreign_address,
        dropped_foreign_system: s.dropped.foreign_system,
        dropped_undecodable: s.dropped.undecodable,
        dropped_unsigned: s.dropped.unsigned,
        dropped_bad_signature: s.dropped.bad_signature,
        dropped_replayed: s.dropped.replayed,
        dropped_by_message: s.dropped.by_message.iter().map(|(k, v)| ((*k).to_string(), *v)).collect(),
        implausible_states: s.counters.implausible_states,
        timesync_refused: s.counters.timesync_refused,
        reboot_stamps_refused: s.counters.reboot_stamps_refused,
        // The link's, which the gateway fills in.
        mavlink_signed: false,
        hover_thrust,
        // The transport's counters are the gateway's (`gateway::link`), which fills them in.
        link_losses: 0,
        link_reopens: 0,
        link_error: String::new(),
        link_read_errors: 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_are_named_and_an_unset_or_unknown_mode_is_refused_naming_the_field() {
        let m = |mode| mode_request(&pb::SetModeRequest { mode });
        assert_eq!(m(pb::FlightMode::Px4Offboard as i32), Ok(ModeRequest::Px4Offboard));
        assert_eq!(m(pb::FlightMode::ArdupilotGuidedNogps as i32), Ok(ModeRequest::ArduGuidedNoGps));
        assert_eq!(m(0).map_err(|e| e.field), Err("mode".to_string()));
        assert_eq!(m(99).map_err(|e| e.field), Err("mode".to_string()));
    }
}
