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
