//! Our gRPC services against an independent implementation: Python grpcio, which knows nothing
//! of our .proto files but what the servers' reflection tells it (tests/python/).

use hilbench_tests::python::run_script;
use hilbench_tests::start_plant;
use plant::PlantConfig;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_grpcio_flies_the_plant_from_reflection_alone_and_a_nan_thrust_is_refused_naming_it() {
    let server = start_plant(PlantConfig::default()).await;
    let address = server.addr.to_string();
    let out = tokio::task::spawn_blocking(move || run_script("reflect_plant.py", &[&address, "paper-2"]))
        .await
        .expect("the script's thread");
    let report: serde_json::Value = serde_json::from_str(out.trim()).expect("the script's JSON line");
    let services: Vec<&str> =
        report["services"].as_array().expect("services").iter().filter_map(|s| s.as_str()).collect();
    for expected in ["grpc.reflection.v1.ServerReflection", "grpc.reflection.v1alpha.ServerReflection"] {
        assert!(services.contains(&expected), "{services:?} lacks {expected}");
    }
    // 1 s of hover thrust from paper-2's start at rest barely moves the vehicle.
    let drift_m = report["hover_drift_m"].as_f64().expect("hover_drift_m");
    assert!(drift_m < 0.05, "hovered {drift_m} m off the start");
    let refusal = report["refusal"].as_str().expect("refusal");
    assert!(refusal.contains("thrust_mps2"), "the refusal names the field: {refusal:?}");
    server.stop().await.expect("the plant stops cleanly");
}
