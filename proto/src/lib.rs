pub mod pb {
    tonic::include_proto!("hilbench.v1");
}
