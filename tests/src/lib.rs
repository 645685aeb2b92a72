//! Helpers shared by the integration tests.

pub mod plant;

pub use plant::{RunningPlant, start_plant, start_plant_with_clock};
