//! `mavbridge`: the pure core of the vehicle gateway and of its MAVLink vehicle simulator
//! (ARCHITECTURE.md). No tokio, no tonic, no sockets, no clock: time is passed in.
//!
//! - [`frame`]: the model's frame (z up, no yaw) and MAVLink's (NED, FRD), both ways.
//! - [`thrust`]: the model's `T` and the autopilot's normalised thrust.
//! - [`timesync`]: the vehicle's clock from `TIMESYNC`.
//! - [`messages`]: MAVLink messages to and from model values (both sides use it).
//! - [`modes`]: PX4 and ArduPilot modes.
//! - [`bridge`]: the gateway's core (samples, setpoints, the command timeout, resets, the
//!   vehicle's reboots).
//! - [`betaflight`]: the gateway's core for a Betaflight flight controller over MSP (sticks
//!   at 50 Hz, requests paced, the same command timeout, poses from motion capture).
//! - [`episode`]: plant time, samples, contacts and path length of one episode on a vehicle.
//! - [`trust`]: whom the gateway believes (the vehicle lock) and what it dropped.
//! - [`signing`]: MAVLink 2 message signing, both ways.
//! - [`autopilot`]: the simulator's autopilot around `mav::PlantSim`.

pub mod autopilot;
pub mod betaflight;
pub mod bridge;
pub mod episode;
pub mod frame;
pub mod messages;
pub mod modes;
pub mod signing;
pub mod thrust;
pub mod timesync;
pub mod trust;

pub use autopilot::{AutopilotError, AutopilotSettings, Firmware, SimAutopilot, SimMode};
pub use bridge::{
    Bridge, BridgeError, BridgeSettings, Counters, Event, REBOOT_CLOCK_JUMP_MS, REBOOT_CONFIRMATIONS, Reboot,
    ResetRefusal, VehicleStatus, shows_reboot,
};
pub use mavlink;
pub use modes::ModeRequest;
pub use signing::{KeyError, Signer, SigningKey, Verifier};
pub use thrust::ThrustMap;
pub use trust::{Dropped, Peer, Refusal, Vehicle, VehicleFilter};
