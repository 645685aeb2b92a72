//! Compiles the .proto files with `protox` (a pure-Rust protobuf compiler), so that building
//! needs no system `protoc`, and writes the descriptor set used by gRPC server reflection.

use prost::Message;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let files = [
        "proto/hilbench/v1/delay.proto",
        "proto/hilbench/v1/plant.proto",
        "proto/hilbench/v1/netem.proto",
        "proto/hilbench/v1/controller.proto",
        "proto/hilbench/v1/vehicle.proto",
    ];
    for f in files {
        println!("cargo:rerun-if-changed={f}");
    }
    let descriptors = protox::compile(files, ["proto"])?;
    let out_dir = PathBuf::from(std::env::var("OUT_DIR")?);
    std::fs::write(out_dir.join("hilbench_descriptor.bin"), descriptors.encode_to_vec())?;
    tonic_prost_build::configure().build_server(true).build_client(true).compile_fds(descriptors)?;
    Ok(())
}
