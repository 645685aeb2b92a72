//! The hilbench CLI's library: paper-mode runs over real gRPC ([`grpc`]) and the paper's
//! tables beside the measured values ([`report`]).

pub mod grpc;
pub mod report;
