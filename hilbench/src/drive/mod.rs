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
    /// An external controller's process against a plant and netem started here, judged from
    /// the plant's truth; a job's controller mode is not used.
    External(external::ExternalController),
}

/// The controller a run flies, as the outputs name it: the bench's `mode`, or
/// [`external::CONTROLLER_NAME`] for an external controller's command line.
pub fn controller_name(controller_cmd: Option<&str>, mode: mpc::ControllerMode) -> &'static str {
    match controller_cmd {
        Some(_) => external::CONTROLLER_NAME,
        None => mode.name(),
    }
}

impl Driver {
    /// The external controller's command line, if the runs fly one.
    pub fn controller_cmd(&self) -> Option<&str> {
        match self {
            Driver::External(c) => Some(&c.command),
            _ => None,
        }
    }

    /// The controller a job of `mode` flies with this driver, as the outputs name it.
    pub fn controller_name(&self, mode: mpc::ControllerMode) -> &'static str {
        controller_name(self.controller_cmd(), mode)
    }

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
