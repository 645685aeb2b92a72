//! How a run is flown: the [`Driver`] (in process, over the bench's gRPC services, or an
//! external controller's process against them) and what each driver needs. A driver flies one
//! [`crate::run::Job`] and hands back its summary and facts; `crate::fly` runs the jobs.
//!
//! The drivers know nothing of the outputs: the live Foxglove view is a
//! [`crate::run::CycleSink`] handed in with the endpoints, so that no output module is
//! imported here.

pub mod external;
pub mod grpc;
pub mod in_process;
pub mod services;

use mav::TimeMode;

/// How the runs reach a plant.
#[derive(Debug, Clone)]
pub enum Driver {
    /// `mpc::run_closed_loop`, no services.
    InProcess,
    /// Plant, netem and controller over gRPC; what the endpoints do not name is started here.
    Services(services::Endpoints),
    /// An external controller's process (the job's `Controller::External`) against a plant
    /// and netem started here, judged from the plant's truth.
    External(external::ExternalDriver),
}

impl Driver {
    /// The `transport` value of `summary.json`.
    pub fn name(&self) -> &'static str {
        match self {
            Driver::InProcess => "in-process",
            Driver::Services(_) => "grpc",
            Driver::External(_) => "external",
        }
    }

    /// One phrase for the printed header.
    pub fn describe(&self) -> &'static str {
        match self {
            Driver::InProcess => "in process",
            Driver::Services(e) if e.is_local() => "over gRPC (plant, netem, controller on loopback)",
            Driver::Services(_) => "over gRPC (given services)",
            Driver::External(_) => "over gRPC (an external controller; plant and netem on loopback)",
        }
    }

    /// How plant time moves in its runs.
    pub fn time_mode(&self) -> TimeMode {
        match self {
            Driver::Services(e) => e.time_mode,
            Driver::External(c) => c.time_mode,
            Driver::InProcess => TimeMode::Lockstep,
        }
    }
}
