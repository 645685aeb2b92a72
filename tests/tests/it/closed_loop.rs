//! Integration tests: closed_loop.
//! The whole bench over gRPC (lockstep plant, netem with the scenario's delays, controller, all
//! on loopback ports, as `hilbench reproduce` runs it) against the in-process closed loop of
//! `mpc`, which is the contract of SPEC.md's paper mode: same states, commands, weights and
//! solver iterations at every cycle, compared by f64 bits. And the multi-stage controller's
//! paper-mode results in process.

use std::time::Duration;

use controller::ControllerConfig;
use hilbench::grpc::{Endpoints, GrpcRun, GrpcSettings, run_against, run_over_grpc};
use hilbench_tests::{start_controller, start_plant};
use mav::Scenario;
use mpc::{ClosedLoopSettings, ControllerMode, run_closed_loop};
use plant::PlantConfig;

fn bits<const N: usize>(v: &[f64]) -> Vec<u64> {
    assert_eq!(v.len(), N, "length");
    v.iter().map(|x| x.to_bits()).collect()
}

fn bits_of(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

async fn assert_grpc_run_is_bit_identical_to_in_process(name: &str, mode: ControllerMode) {
    let scenario = Scenario::by_name(name).expect("built-in scenario");
    let run = run_over_grpc(&scenario, mode, &GrpcSettings { timeout: Duration::from_secs(300) })
        .await
        .expect("gRPC run");
    assert_bit_identical(&scenario, mode, &run);
}

/// `run` against `mpc::run_closed_loop` of the same scenario and mode, bit for bit.
fn assert_bit_identical(scenario: &Scenario, mode: ControllerMode, run: &GrpcRun) {
    let (expected, records) =
        run_closed_loop(scenario, &ClosedLoopSettings::paper(mode)).expect("in-process closed loop");
    let what = format!("{} with {}", scenario.name, mode.name());
    assert!(!records.is_empty(), "{what}: the in-process run has no cycles");
    for (k, (t, r)) in run.telemetry.iter().zip(&records).enumerate() {
        assert_eq!(t.cycle, k as u64, "{what}: cycle numbering");
        let sample = t.sample.as_ref().expect("telemetry carries the sample");
        assert_eq!(
            mav::ns_to_s(sample.time_ns).to_bits(),
            r.t_s.to_bits(),
            "{what}: cycle {k} starts at {} s over gRPC, {} s in process",
            mav::ns_to_s(sample.time_ns),
            r.t_s
        );
        let state = sample.state.as_ref().expect("sample has a state");
        assert_eq!(
            bits::<8>(&state.x),
            bits_of(&r.state),
            "{what}: state at cycle {k} differs: {:?} vs {:?}",
            state.x,
            r.state
        );
        let c = t.command.as_ref().expect("telemetry carries the command");
        assert_eq!(
            bits_of(&[c.thrust_mps2, c.roll_rad, c.pitch_rad]),
            bits_of(&r.command),
            "{what}: command at cycle {k} differs"
        );
        assert_eq!(
            bits_of(&t.scenario_weights),
            bits_of(&r.weights_used),
            "{what}: weights at cycle {k} differ: {:?} vs {:?}",
            t.scenario_weights,
            r.weights_used
        );
        let solve = t.solve.as_ref().expect("telemetry carries solve statistics");
        assert_eq!(solve.iterations as usize, r.report.iterations, "{what}: iterations at cycle {k}");
        if k > 0 {
            // The delay the controller measured from plant stamps is the one drawn for the
            // previous cycle.
            assert_eq!(
                t.measured_delay_s.to_bits(),
                records[k - 1].delay_s.to_bits(),
                "{what}: delay measured at cycle {k}"
            );
        }
    }
    // Compared after the cycles, so that a divergence names its first cycle.
    assert_eq!(run.telemetry.len(), records.len(), "{what}: number of cycles");
    let got = &run.summary;
    assert_eq!(got.reached, expected.reached, "{what}: reached");
    assert_eq!(got.collided, expected.collided, "{what}: collided");
    assert_eq!(got.cycles, expected.cycles, "{what}: cycles");
    assert_eq!(got.end_time_s.to_bits(), expected.end_time_s.to_bits(), "{what}: end time");
    assert_eq!(
        got.time_to_goal_s.map(f64::to_bits),
        expected.time_to_goal_s.map(f64::to_bits),
        "{what}: time to goal"
    );
    assert_eq!(got.path_length_m.to_bits(), expected.path_length_m.to_bits(), "{what}: path length");
    assert_eq!(got.min_clearance_m.to_bits(), expected.min_clearance_m.to_bits(), "{what}: clearance");
    assert_eq!(bits_of(&got.final_position_m), bits_of(&expected.final_position_m), "{what}: end position");
    assert_eq!(got.iterations_median.to_bits(), expected.iterations_median.to_bits(), "{what}: iterations");
    assert_eq!(got.fallbacks, expected.fallbacks, "{what}: fallbacks");
    assert_eq!(got.collisions.len(), expected.collisions.len(), "{what}: collision events");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn paper_2_multistage_over_grpc_is_bit_identical_to_the_in_process_closed_loop() {
    assert_grpc_run_is_bit_identical_to_in_process("paper-2", ControllerMode::Multistage).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn paper_3_nmpc_over_grpc_is_bit_identical_to_the_in_process_closed_loop() {
    assert_grpc_run_is_bit_identical_to_in_process("paper-3", ControllerMode::Nmpc).await;
}

#[test]
fn multistage_reaches_the_goal_of_every_paper_scenario_without_touching_a_cylinder() {
    // With the safety layer (issue 5), as the paper reproduction flies, and without it: PANOC's
    // plans alone, the controller of issue 3.
    let with_layer = ClosedLoopSettings::paper(ControllerMode::Multistage);
    let panoc_alone = ClosedLoopSettings { safety: None, ..with_layer.clone() };
    for (scenario_name, settings) in
        Scenario::BUILT_IN.iter().flat_map(|n| [(n, &with_layer), (n, &panoc_alone)])
    {
        let scenario = Scenario::by_name(scenario_name).expect("built-in scenario");
        let layer = if settings.safety.is_some() { "on" } else { "off" };
        let name = format!("{scenario_name} (safety layer {layer})");
        let (s, records) = run_closed_loop(&scenario, settings).expect("closed loop runs");
        assert!(s.reached, "{name}: multi-stage did not reach the goal (ended at {:?})", s.final_position_m);
        assert!(!s.collided, "{name}: collided: {:?}", s.collisions);
        assert!(s.min_clearance_m >= 0.0, "{name}: true min clearance {} m < 0", s.min_clearance_m);
        let goal = scenario.goal_m;
        let p = s.final_position_m;
        let dist = ((p[0] - goal[0]).powi(2) + (p[1] - goal[1]).powi(2) + (p[2] - goal[2]).powi(2)).sqrt();
        assert!(dist < 0.15, "{name}: ended {dist} m from the goal");
        assert_eq!(s.cycles as usize, records.len());
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_run_against_given_services_sets_the_netem_profile_and_is_bit_identical() {
    let scenario = Scenario::by_name("paper-2").expect("built-in scenario");
    let mode = ControllerMode::Multistage;
    let plant = start_plant(PlantConfig::lockstep(scenario.clone())).await;
    // A netem without delays: the run must give it the scenario's profile.
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("bind");
    let netem_addr = listener.local_addr().expect("address");
    let mut netem_config = netem::Config::new(plant.addr.to_string());
    netem_config.time_mode = netem::TimeModeSetting::Lockstep;
    let (stop_netem, netem_stopped) = tokio::sync::oneshot::channel::<()>();
    let netem_task = tokio::spawn(netem::serve(listener, netem_config, async {
        let _ = netem_stopped.await;
    }));
    // A controller that starts flying on its own (as a deployed one would): the run's request
    // restarts it or follows its first episode.
    let ctl = start_controller(ControllerConfig::new(netem_addr.to_string(), scenario.clone(), mode)).await;
    let endpoints = Endpoints {
        plant: Some(plant.addr.to_string()),
        netem: Some(netem_addr.to_string()),
        controller: Some(ctl.addr.to_string()),
        ..Endpoints::default()
    };
    let run = run_against(&scenario, mode, &GrpcSettings { timeout: Duration::from_secs(300) }, &endpoints)
        .await
        .expect("run against given services");
    assert_bit_identical(&scenario, mode, &run);
    // A second run against the same services gives the same trajectory again.
    let again = run_against(&scenario, mode, &GrpcSettings { timeout: Duration::from_secs(300) }, &endpoints)
        .await
        .expect("second run");
    assert_bit_identical(&scenario, mode, &again);

    ctl.stop().await.expect("controller stops cleanly");
    let _ = stop_netem.send(());
    match tokio::time::timeout(Duration::from_secs(30), netem_task).await {
        Ok(Ok(r)) => r.expect("netem served cleanly"),
        Ok(Err(e)) => panic!("netem task failed: {e}"),
        Err(_) => panic!("netem did not stop"),
    }
    plant.stop().await.expect("plant stops cleanly");
}
