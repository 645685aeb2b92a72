//! Helpers shared by the integration tests.

pub mod controller;
pub mod plant;
pub mod process;
pub mod python;
pub mod relay;
pub mod server;
pub mod streams;
pub mod temp;

pub use controller::{RunningController, start_controller};
pub use plant::{RunningPlant, start_plant, start_plant_with_clock, wait_for_state};
pub use process::{Service, free_loopback_address, service_binary};
pub use relay::Relay;
pub use server::Running;
pub use temp::TempDir;

/// Taken by the tests that keep both cores busy for seconds (an attacker flooding the gateway,
/// signed links) and by the real-time runs that must keep up with the wall clock while they
/// read every plant step: on a 2-core machine the first starve the second (an external
/// controller's real-time run read 5,000 steps late), so they take turns. The other tests run
/// beside them as before.
pub static CPU_HEAVY: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());
