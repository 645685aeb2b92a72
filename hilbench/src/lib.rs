//! The hilbench CLI's library: paper-mode runs over real gRPC ([`grpc`]), runs of scenarios
//! and their `summary.json` ([`bench`]), scenario files ([`scenario_file`]), an external
//! controller under test ([`external`]), per-cycle CSV logs ([`cycle_log`]), MCAP files and the
//! live Foxglove view ([`foxglove_out`]), sweeps ([`sweep`]), the paper's
//! tables beside the measured values ([`report`]), plots ([`plots`]), progress bars ([`progress`])
//! and `report.md` ([`report_md`]); certificates for mutual TLS ([`certs`]).

pub mod bench;
pub mod certs;
pub mod cycle_log;
pub mod external;
pub mod foxglove_out;
pub mod grpc;
pub mod panics;
pub mod plots;
pub mod progress;
pub mod report;
pub mod report_md;
pub mod sweep;
pub use hilbench_svc::scenario_file;
