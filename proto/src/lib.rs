//! `hilbench-proto` is the only crate that sees wire types. It compiles the `hilbench.v1`
//! contracts (plant, netem, controller) once, exposes the generated code as [`pb`] and the
//! descriptor set for server reflection, and owns [`convert`]: the one place where incoming
//! messages are validated (NaN, infinities, wrong lengths, missing fields, ranges) and turned
//! into core types, and core types are turned into messages.

/// Generated protobuf messages, clients and servers of `hilbench.v1`.
pub mod pb {
    #![allow(clippy::all, clippy::pedantic, missing_docs)]
    tonic::include_proto!("hilbench.v1");
}

pub mod convert;

/// Encoded `FileDescriptorSet` of every hilbench proto, for `tonic-reflection`.
pub const FILE_DESCRIPTOR_SET: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/hilbench_descriptor.bin"));
