//! Whom the gateway believes: one vehicle. The link locks to the first autopilot heartbeat's
//! (system, component, address), or to the system and component given (`--vehicle-sysid`,
//! `--vehicle-compid`), as MAVLink routers and ground stations do; every frame from another
//! address, system or component is dropped and counted here, never decoded into state and never
//! answered. Pure: the shell says where a frame came from ([`Peer`]) and whether the vehicle's
//! heartbeat is lost; nothing here reads a clock or a socket.

use mavlink::dialects::common::{MavAutopilot, MavMessage};
use mavlink::{MavHeader, Message};
use std::collections::BTreeMap;
use std::net::SocketAddr;

/// Where a frame came from: a UDP datagram's sender, or `None` on a serial device (one peer).
pub type Peer = Option<SocketAddr>;

/// The vehicle the link is locked to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Vehicle {
    pub system_id: u8,
    pub component_id: u8,
    pub peer: Peer,
}

impl std::fmt::Display for Vehicle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "system {} component {}", self.system_id, self.component_id)?;
        match self.peer {
            Some(at) => write!(f, " at {at}"),
            None => write!(f, " on the serial device"),
        }
    }
}

/// Which vehicle to lock to (`None`: the first autopilot heard).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct VehicleFilter {
    /// `--vehicle-sysid`.
    pub system_id: Option<u8>,
    /// `--vehicle-compid`.
    pub component_id: Option<u8>,
    /// A vehicle lost for its heartbeat's timeout may be locked to again from a new address.
    /// Only on a signed link (`--mavlink-signing-key`): there the signature says it is the
    /// vehicle; on an unsigned link anyone on the network could take its place during a gap
    /// (a 2 s pause of the autopilot was enough), so the lock stays on its address.
    pub may_move: bool,
}

/// Why a frame was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// No vehicle is locked yet, and the frame is not the heartbeat of one (an autopilot's, of
    /// the ids asked for).
    NoVehicle,
    /// From another address than the vehicle's.
    ForeignAddress,
    /// From the vehicle's address, but of another system or component.
    ForeignSystem,
    /// From the vehicle's address, no frame the dialect decodes (junk, an unknown message).
    Undecodable,
    /// Unsigned while the link requires signatures.
    Unsigned,
    /// A signature that does not match the key.
    BadSignature,
    /// A signature whose timestamp is not newer than the last of its stream (a replay), or a
    /// new stream more than a minute older than the newest timestamp seen.
    Replayed,
}

/// Frames dropped since start, by why; foreign messages also by message name.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Dropped {
    pub no_vehicle: u64,
    pub foreign_address: u64,
    pub foreign_system: u64,
    pub undecodable: u64,
    pub unsigned: u64,
    pub bad_signature: u64,
    pub replayed: u64,
    /// The decoded messages among them, by MAVLink name (`LOCAL_POSITION_NED`, ...).
    pub by_message: BTreeMap<&'static str, u64>,
}

impl Dropped {
    fn count(&mut self, why: Refusal, message: Option<&'static str>) {
        let n = match why {
            Refusal::NoVehicle => &mut self.no_vehicle,
            Refusal::ForeignAddress => &mut self.foreign_address,
            Refusal::ForeignSystem => &mut self.foreign_system,
            Refusal::Undecodable => &mut self.undecodable,
            Refusal::Unsigned => &mut self.unsigned,
            Refusal::BadSignature => &mut self.bad_signature,
            Refusal::Replayed => &mut self.replayed,
        };
        *n += 1;
        if let Some(name) = message {
            *self.by_message.entry(name).or_default() += 1;
        }
    }

    /// Every frame dropped.
    pub fn total(&self) -> u64 {
        self.no_vehicle
            + self.foreign_address
            + self.foreign_system
            + self.undecodable
            + self.unsigned
            + self.bad_signature
            + self.replayed
    }
}

/// A frame the vehicle sent: believed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Admitted {
    /// From the locked vehicle.
    Vehicle,
    /// This heartbeat locked the link to its sender (the first, or the same system and component
    /// from a new address after the vehicle's heartbeat was lost).
    Locked(Vehicle),
}

/// The lock and what it dropped.
#[derive(Debug, Clone, Default)]
pub struct Trust {
    filter: VehicleFilter,
    vehicle: Option<Vehicle>,
    dropped: Dropped,
}

impl Trust {
    pub fn new(filter: VehicleFilter) -> Self {
        Self { filter, vehicle: None, dropped: Dropped::default() }
    }

    /// The vehicle locked to (`None`: no autopilot heartbeat heard yet).
    pub fn vehicle(&self) -> Option<Vehicle> {
        self.vehicle
    }

    pub fn dropped(&self) -> &Dropped {
        &self.dropped
    }

    /// The ids of an autopilot heartbeat that may lock the link.
    fn lockable(&self, header: &MavHeader, msg: &MavMessage) -> Option<(u8, u8)> {
        let MavMessage::HEARTBEAT(h) = msg else { return None };
        let system_id = u8::try_from(header.system_id).ok()?;
        let ids = (system_id, header.component_id);
        let wanted = self.filter.system_id.is_none_or(|s| s == ids.0)
            && self.filter.component_id.is_none_or(|c| c == ids.1);
        (h.autopilot != MavAutopilot::MAV_AUTOPILOT_INVALID && wanted).then_some(ids)
    }

    /// Whether to believe `msg`, which came from `peer` with `header`. `vehicle_lost`: the locked
    /// vehicle's heartbeat timed out, so that a heartbeat of the same system and component from
    /// a new address (an autopilot or a router restarted on another port) locks again. A
    /// refusal is counted.
    pub fn admit(
        &mut self,
        peer: Peer,
        header: &MavHeader,
        msg: &MavMessage,
        vehicle_lost: bool,
    ) -> Result<Admitted, Refusal> {
        let lockable = self.lockable(header, msg);
        let verdict = match self.vehicle {
            None => match lockable {
                Some((system_id, component_id)) => {
                    let v = Vehicle { system_id, component_id, peer };
                    self.vehicle = Some(v);
                    Ok(Admitted::Locked(v))
                }
                None => Err(Refusal::NoVehicle),
            },
            Some(v) => {
                let same_ids =
                    header.system_id == u32::from(v.system_id) && header.component_id == v.component_id;
                match (peer == v.peer, same_ids) {
                    (true, true) => Ok(Admitted::Vehicle),
                    (true, false) => Err(Refusal::ForeignSystem),
                    (false, true) if vehicle_lost && lockable.is_some() && self.filter.may_move => {
                        let moved = Vehicle { peer, ..v };
                        self.vehicle = Some(moved);
                        Ok(Admitted::Locked(moved))
                    }
                    (false, _) => Err(Refusal::ForeignAddress),
                }
            }
        };
        if let Err(why) = verdict {
            self.dropped.count(why, Some(msg.message_name()));
        }
        verdict
    }

    /// A frame from `peer` refused before it was decoded (`why`: junk, or its signature),
    /// counted: as from another address when it is not the vehicle's. Returns what it was
    /// counted as.
    pub fn refuse(&mut self, peer: Peer, why: Refusal) -> Refusal {
        let why = match self.vehicle {
            Some(v) if v.peer != peer => Refusal::ForeignAddress,
            None if why == Refusal::Undecodable => Refusal::NoVehicle,
            _ => why,
        };
        self.dropped.count(why, None);
        why
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::{HEARTBEAT_DATA, LOCAL_POSITION_NED_DATA};

    fn at(port: u16) -> Peer {
        Some(SocketAddr::from(([127, 0, 0, 1], port)))
    }

    fn header(system_id: u32, component_id: u8) -> MavHeader {
        MavHeader { system_id, component_id, sequence: 0 }
    }

    fn heartbeat(autopilot: MavAutopilot) -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA { autopilot, ..Default::default() })
    }

    fn position() -> MavMessage {
        MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA::default())
    }

    #[test]
    fn the_first_autopilot_heartbeat_locks_and_everything_else_is_dropped_and_counted_by_why_and_name() {
        let mut t = Trust::new(VehicleFilter::default());
        let px4 = heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4);
        assert_eq!(t.admit(at(5000), &header(1, 1), &position(), false), Err(Refusal::NoVehicle));
        // A ground station's heartbeat (no autopilot) does not lock.
        let gcs = heartbeat(MavAutopilot::MAV_AUTOPILOT_INVALID);
        assert_eq!(t.admit(at(6000), &header(255, 190), &gcs, false), Err(Refusal::NoVehicle));
        let vehicle = Vehicle { system_id: 1, component_id: 1, peer: at(5000) };
        assert_eq!(t.admit(at(5000), &header(1, 1), &px4, false), Ok(Admitted::Locked(vehicle)));
        assert_eq!(t.vehicle(), Some(vehicle));
        assert_eq!(t.admit(at(5000), &header(1, 1), &position(), false), Ok(Admitted::Vehicle));
        // Same ids from another port; another system from another port; another system and
        // another component from the vehicle's address; heartbeats of other systems.
        assert_eq!(t.admit(at(7000), &header(1, 1), &position(), false), Err(Refusal::ForeignAddress));
        assert_eq!(t.admit(at(7000), &header(77, 1), &position(), false), Err(Refusal::ForeignAddress));
        assert_eq!(t.admit(at(5000), &header(77, 1), &position(), false), Err(Refusal::ForeignSystem));
        assert_eq!(t.admit(at(5000), &header(1, 2), &position(), false), Err(Refusal::ForeignSystem));
        for sysid in 2..=250 {
            assert_eq!(t.admit(at(7000), &header(sysid, 1), &px4, false), Err(Refusal::ForeignAddress));
        }
        assert_eq!(t.vehicle(), Some(vehicle), "nothing moved the lock");
        assert_eq!(t.refuse(at(7000), Refusal::Undecodable), Refusal::ForeignAddress);
        assert_eq!(t.refuse(at(5000), Refusal::Undecodable), Refusal::Undecodable);
        assert_eq!(t.refuse(at(5000), Refusal::BadSignature), Refusal::BadSignature);
        let d = t.dropped();
        assert_eq!(
            (d.no_vehicle, d.foreign_address, d.foreign_system, d.undecodable, d.bad_signature),
            (2, 2 + 249 + 1, 2, 1, 1),
            "{d:?}"
        );
        assert_eq!(d.by_message.get("HEARTBEAT"), Some(&(1 + 249)));
        assert_eq!(d.by_message.get("LOCAL_POSITION_NED"), Some(&5));
        assert_eq!(d.total(), 2 + 252 + 2 + 1 + 1);
    }

    #[test]
    fn given_ids_lock_only_to_that_vehicle() {
        let mut t = Trust::new(VehicleFilter { system_id: Some(42), component_id: Some(1), may_move: false });
        let px4 = heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4);
        assert_eq!(t.admit(at(5000), &header(1, 1), &px4, false), Err(Refusal::NoVehicle));
        assert_eq!(t.admit(at(5000), &header(42, 2), &px4, false), Err(Refusal::NoVehicle));
        assert!(matches!(t.admit(at(5001), &header(42, 1), &px4, false), Ok(Admitted::Locked(_))));
        // A system id beyond a byte (MAVLink 2's 32-bit ids) never locks: setpoints target a byte.
        let mut t = Trust::new(VehicleFilter::default());
        assert_eq!(t.admit(at(5000), &header(300, 1), &px4, false), Err(Refusal::NoVehicle));
    }

    #[test]
    fn an_unsigned_link_never_moves_its_lock_to_a_new_address_even_when_the_vehicle_was_lost() {
        let mut t = Trust::new(VehicleFilter::default());
        let px4 = heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4);
        t.admit(at(5000), &header(1, 1), &px4, false).expect("locks");
        // Someone else with the vehicle's ids during a heartbeat gap: refused.
        assert_eq!(t.admit(at(6000), &header(1, 1), &px4, true), Err(Refusal::ForeignAddress));
        assert_eq!(t.vehicle().map(|v| v.peer), Some(at(5000)), "still locked to the vehicle's address");
        assert_eq!(
            t.admit(at(5000), &header(1, 1), &px4, true),
            Ok(Admitted::Vehicle),
            "the vehicle comes back"
        );
    }

    #[test]
    fn a_lost_vehicle_is_found_again_at_a_new_address_only_on_a_signed_link_with_its_own_ids_and_only_once_lost()
     {
        let mut t = Trust::new(VehicleFilter { may_move: true, ..VehicleFilter::default() });
        let px4 = heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4);
        t.admit(at(5000), &header(1, 1), &px4, false).expect("locks");
        assert_eq!(t.admit(at(6000), &header(1, 1), &px4, false), Err(Refusal::ForeignAddress), "alive");
        assert_eq!(t.admit(at(6000), &header(2, 1), &px4, true), Err(Refusal::ForeignAddress), "other ids");
        assert_eq!(
            t.admit(at(6000), &header(1, 1), &position(), true),
            Err(Refusal::ForeignAddress),
            "only a heartbeat"
        );
        let moved = Vehicle { system_id: 1, component_id: 1, peer: at(6000) };
        assert_eq!(t.admit(at(6000), &header(1, 1), &px4, true), Ok(Admitted::Locked(moved)));
        assert_eq!(t.admit(at(5000), &header(1, 1), &position(), false), Err(Refusal::ForeignAddress));
    }
}
