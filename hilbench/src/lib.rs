//! The hilbench CLI's library: paper-mode runs over real gRPC ([`grpc`]), runs of scenarios
//! and their `summary.json` ([`bench`]), scenario files ([`scenario_file`]), per-cycle CSV logs ([`cycle_log`]) and the paper's
//! tables beside the measured values ([`report`]).

pub mod bench;
pub mod cycle_log;
pub mod grpc;
pub mod report;
pub mod scenario_file;
