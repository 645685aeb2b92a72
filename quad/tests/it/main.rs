//! The quadrotor against analytic cases and Betaflight's conventions: one integration-test
//! binary, a module per area.

mod betaflight;
mod commands;
mod determinism;
mod fixtures;
mod ground;
mod motion;
mod params;
mod properties;
