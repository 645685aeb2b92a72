//! Integration tests: closed_loop.
//! The whole bench over gRPC (lockstep plant, netem with the scenario's delays, controller, all
//! on loopback ports, as `hilbench reproduce` runs it) against the in-process closed loop of
//! `mpc`, which is the contract of `docs/spec.md`'s paper mode: same states, commands, weights and
//! solver iterations at every cycle, compared by f64 bits. And the multi-stage controller's
//! paper-mode results in process.

use std::time::Duration;

use controller::ControllerConfig;
use hilbench::drive::grpc::{GrpcRun, GrpcSettings, run_against, run_over_grpc};
use hilbench::drive::services::Endpoints;
use hilbench::run::DelaySource;
use hilbench_tests::{Service, free_loopback_address, start_controller, start_plant};
use mav::Scenario;
use mpc::{ClosedLoopSettings, ControllerMode, run_closed_loop};
use plant::PlantConfig;

/// Run settings that wait up to `secs` for an episode (a loaded machine's runs are slow).
fn patient(secs: u64) -> GrpcSettings {
    GrpcSettings { timeout: Duration::from_secs(secs), ..GrpcSettings::default() }
}

fn bits_of(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

async fn assert_grpc_run_is_bit_identical_to_in_process(name: &str, mode: ControllerMode) {
    let scenario = Scenario::by_name(name).expect("built-in scenario");
    let run = run_over_grpc(&scenario, mode, &patient(300)).await.expect("gRPC run");
    assert_bit_identical(&scenario, mode, &run);
}

/// `run` against `mpc::run_closed_loop` of the same scenario and mode, bit for bit.
fn assert_bit_identical(scenario: &Scenario, mode: ControllerMode, run: &GrpcRun) {
    // With the predicted trajectories, which the telemetry streams to its subscribers.
    let settings = ClosedLoopSettings { record_predictions: true, ..ClosedLoopSettings::paper(mode) };
    let (expected, records) = run_closed_loop(scenario, &settings).expect("in-process closed loop");
    let what = format!("{} with {}", scenario.name, mode.name());
    assert!(!records.is_empty(), "{what}: the in-process run has no cycles");
    for (k, (got, trace)) in run.records.iter().zip(&records).enumerate() {
        // The whole record, bit for bit (Debug prints -0.0 and every digit), predicted
        // trajectories and their weights included, but for the solve time (a wall-clock
        // measurement).
        let comparable = |r: &mpc::CycleRecord| {
            let mut r = r.clone();
            r.solve.solve_ms = 0.0;
            format!("{r:?}")
        };
        assert_eq!(comparable(got), comparable(&trace.record), "{what}: cycle {k} differs");
        if k > 0 {
            // The delay the controller measured from plant stamps is the one drawn for the
            // previous cycle.
            assert_eq!(
                got.known_delay_s.map(f64::to_bits),
                Some(records[k - 1].delay_s.to_bits()),
                "{what}: delay measured at cycle {k}"
            );
        }
    }
    // Compared after the cycles, so that a divergence names its first cycle.
    assert_eq!(run.records.len(), records.len(), "{what}: number of cycles");
    let got = &run.summary;
    assert_eq!(got.reached, expected.reached, "{what}: reached");
    assert_eq!(got.collided, expected.collided, "{what}: collided");
    assert_eq!(got.end_reason, expected.end_reason, "{what}: end reason");
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
    // With the safety layer, as the paper reproduction flies, and without it: PANOC's plans
    // alone, the paper's controller.
    let with_layer = ClosedLoopSettings::paper(ControllerMode::Multistage);
    let mut panoc_alone = with_layer.clone();
    panoc_alone.episode.safety = None;
    for (scenario_name, settings) in
        Scenario::BUILT_IN.iter().flat_map(|n| [(n, &with_layer), (n, &panoc_alone)])
    {
        let scenario = Scenario::by_name(scenario_name).expect("built-in scenario");
        let layer = if settings.episode.safety.is_some() { "on" } else { "off" };
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
    netem_config.time_mode = mav::TimeModeChoice::Fixed(mav::TimeMode::Lockstep);
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
    let run =
        run_against(&scenario, mode, &patient(300), &endpoints).await.expect("run against given services");
    assert_bit_identical(&scenario, mode, &run);
    // A second run against the same services gives the same trajectory again.
    let again = run_against(&scenario, mode, &patient(300), &endpoints).await.expect("second run");
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scenario_file_flies_over_separately_started_binaries_bit_identically_to_in_process() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/slalom-4.toml");
    let scenario =
        hilbench::scenario_file::ScenarioFile::load(&path).expect("a valid scenario file").scenario;
    assert!(Scenario::by_name(&scenario.name).is_err(), "the file's scenario must not be built in");
    let (plant, netem, controller) =
        (free_loopback_address(), free_loopback_address(), free_loopback_address());
    // Started as a user would by hand: the plant and the controller know nothing of the file
    // (the plant loads its default scenario, the controller idles); the scenario reaches both
    // over the wire (SetScenario, then the controller's Reset).
    let _plant = Service::start("plant", &["--listen", &plant, "--time-mode", "lockstep"]);
    let _netem =
        Service::start("netem", &["--listen", &netem, "--upstream", &plant, "--time-mode", "lockstep"]);
    let _controller = Service::start(
        "controller",
        &["--listen", &controller, "--plant", &netem, "--time-mode", "lockstep", "--no-autostart"],
    );
    let endpoints = Endpoints {
        plant: Some(plant),
        netem: Some(netem),
        controller: Some(controller),
        ..Endpoints::default()
    };
    let mode = ControllerMode::Multistage;
    let run = run_against(&scenario, mode, &patient(300), &endpoints)
        .await
        .expect("a run against separately started services");
    assert_bit_identical(&scenario, mode, &run);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_per_cycle_csv_of_a_grpc_run_is_byte_identical_to_the_in_process_one_but_for_solve_times() {
    // paper-1 with the multi-stage controller sends a pitch of -0 in its first cycle: the sign
    // of zero does not cross protobuf, so the sanitiser makes every zero +0 on both paths.
    let scenario = Scenario::by_name("paper-1").expect("built-in scenario");
    let mode = ControllerMode::Multistage;
    let run = run_over_grpc(&scenario, mode, &patient(300)).await.expect("gRPC run");
    let (_, traces) = run_closed_loop(&scenario, &ClosedLoopSettings::paper(mode)).expect("in-process run");
    let csv = |records: &[mpc::CycleRecord]| {
        let mut rows = hilbench::run::rows_of(records);
        rows.iter_mut().for_each(|r| r.solve_ms = 0.0);
        hilbench::output::cycle_log::to_csv(&rows)
    };
    let in_process: Vec<_> = traces.into_iter().map(|t| t.record).collect();
    let (grpc, local) = (csv(&run.records), csv(&in_process));
    assert!(!local.contains(",-0,"), "a -0 cell in the in-process log");
    for (k, (a, b)) in grpc.lines().zip(local.lines()).enumerate() {
        assert_eq!(a, b, "line {k} of the per-cycle CSV differs");
    }
    assert_eq!(grpc, local);
}

fn scenario_file(name: &str) -> Scenario {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios").join(name);
    hilbench::scenario_file::ScenarioFile::load(&path).unwrap_or_else(|e| panic!("{e}")).scenario
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_recorded_delay_trace_file_flies_over_grpc_bit_identically_to_in_process() {
    // scenarios/wifi-trace.toml names wifi-trace.csv: the loader reads it into the scenario,
    // which then travels whole; netem replays it on commands, the in-process loop on its line.
    let scenario = scenario_file("wifi-trace.toml");
    let mode = ControllerMode::Nmpc;
    let run = run_over_grpc(&scenario, mode, &patient(300)).await.expect("gRPC run");
    assert_bit_identical(&scenario, mode, &run);
    // What netem stamped on cycle k's command is line k of the file, to the nanosecond.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/wifi-trace.csv");
    let trace = delay::parse_trace(&std::fs::read_to_string(path).expect("the trace")).expect("a trace");
    for (k, r) in run.records.iter().enumerate() {
        let ns = r.injected_delay_s.map(|d| (d * 1e9).round() as u64);
        assert_eq!(ns, Some((trace[k] * 1e9).round() as u64), "cycle {k}: injected delay");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_run_that_outlasts_its_delay_trace_stops_with_an_error_naming_the_file_and_the_cycle() {
    let mut scenario = scenario_file("wifi-trace.toml");
    scenario.delays = Some(delay::DelaysTable::trace("short.csv", vec![0.1, 0.2, 0.05], false));
    let mode = ControllerMode::Nmpc;
    let in_process = run_closed_loop(&scenario, &ClosedLoopSettings::paper(mode)).map(|_| ());
    let message = in_process.expect_err("the in-process run must stop").to_string();
    assert!(message.contains("short.csv") && message.contains("cycle 3"), "{message}");
    let over_grpc = run_over_grpc(&scenario, mode, &patient(120)).await;
    let message = format!("{:#}", over_grpc.map(|_| ()).expect_err("the gRPC run must stop"));
    // netem refuses the command that has no delay (message 3 of the line: cycle 3's command).
    assert!(message.contains("short.csv") && message.contains("message 3 has none"), "{message}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_regime_process_with_delayed_samples_flies_over_grpc_with_both_directions_in_force() {
    // scenarios/bursty-lte.toml: a two-state regime with loss on commands, a constant delay on
    // samples (which the in-process loop refuses to model).
    let scenario = scenario_file("bursty-lte.toml");
    let mode = ControllerMode::Multistage;
    let refused = run_closed_loop(&scenario, &ClosedLoopSettings::paper(mode)).map(|_| ());
    assert!(format!("{refused:?}").contains("delays.to_controller"), "{refused:?}");
    let run = run_over_grpc(&scenario, mode, &patient(300)).await.expect("gRPC run");
    assert!(run.summary.cycles > 20, "{} cycles", run.summary.cycles);
    // The same network without the samples' delay: cycle 0's command draws the same delay
    // (same seed, same send time), so cycle 1's sample is read exactly 10 ms earlier with it.
    let mut undelayed = scenario.clone();
    if let Some(t) = undelayed.delays.as_mut() {
        t.to_controller = Some(Box::new(delay::DelaysTable::none()));
    }
    let reference =
        run_over_grpc(&undelayed, mode, &patient(300)).await.expect("gRPC run without the samples' delay");
    assert_eq!(
        run.records[1].sample_time_ns + 10_000_000,
        reference.records[1].sample_time_ns,
        "cycle 1's sample is 10 ms stale"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_netem_profile_set_by_the_user_is_kept_when_asked_or_when_the_file_has_no_delays() {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("keep-netem-profile");
    std::fs::create_dir_all(&dir).expect("a temporary directory");
    let profile = dir.join("lte.toml");
    std::fs::write(&profile, "kind = \"lognormal\"\nmean_s = 0.08\nstd_s = 0.03\n")
        .expect("write the profile");
    let (plant, netem, controller) =
        (free_loopback_address(), free_loopback_address(), free_loopback_address());
    let _plant = Service::start("plant", &["--listen", &plant, "--time-mode", "lockstep"]);
    let profile_arg = profile.display().to_string();
    let _netem =
        Service::start("netem", &["--listen", &netem, "--plant", &plant, "--profile-file", &profile_arg]);
    let _controller = Service::start(
        "controller",
        &["--listen", &controller, "--plant", &netem, "--time-mode", "lockstep", "--no-autostart"],
    );
    let endpoints = |keep_netem_profile| Endpoints {
        plant: Some(plant.clone()),
        netem: Some(netem.clone()),
        controller: Some(controller.clone()),
        keep_netem_profile,
        ..Endpoints::default()
    };
    let lognormal = Some(delay::DelaysTable {
        kind: Some("lognormal".into()),
        mean_s: Some(0.08),
        std_s: Some(0.03),
        ..delay::DelaysTable::default()
    });
    let settings = patient(300);
    let mode = ControllerMode::Nmpc;
    // slalom-4 says Gamma(8, 0.02); kept, netem's lognormal is in force, and said so.
    let slalom = scenario_file("slalom-4.toml");
    let kept =
        run_against(&slalom, mode, &settings, &endpoints(true)).await.expect("a run keeping the profile");
    assert_eq!((kept.delay_profile.source, &kept.delay_profile.delays), (DelaySource::Netem, &lognormal));
    // A scenario that does not describe its network leaves it alone without being asked.
    let mut undescribed = slalom.clone();
    undescribed.delays = None;
    let run = run_against(&undescribed, mode, &settings, &endpoints(false)).await.expect("a run");
    assert_eq!((run.delay_profile.source, &run.delay_profile.delays), (DelaySource::Netem, &lognormal));
    // Otherwise the scenario's network replaces it.
    let run = run_against(&slalom, mode, &settings, &endpoints(false)).await.expect("a run");
    assert_eq!(run.delay_profile.source, DelaySource::Scenario);
    assert_eq!(run.delay_profile.delays, slalom.delays);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plant_and_controller_binaries_take_a_scenario_file_as_their_scenario() {
    use hilbench_proto::pb;
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/bursty-lte.toml");
    let file = file.display().to_string();
    let expected = scenario_file("bursty-lte.toml");
    let (plant, controller) = (free_loopback_address(), free_loopback_address());
    let _plant =
        Service::start("plant", &["--listen", &plant, "--time-mode", "lockstep", "--scenario", &file]);
    let _controller = Service::start(
        "controller",
        &["--listen", &controller, "--plant", &plant, "--no-autostart", "--scenario", &file],
    );
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    let mut client = pb::plant_client::PlantClient::new(
        hilbench::drive::services::connect(&plant, deadline).await.expect("plant"),
    );
    let described = client.describe(pb::DescribeRequest {}).await.expect("Describe").into_inner();
    let definition = described.definition.as_ref().expect("the scenario in force");
    assert_eq!(Scenario::try_from(definition).expect("a valid scenario"), expected);
    let mut client = pb::controller_client::ControllerClient::new(
        hilbench::drive::services::connect(&controller, deadline).await.expect("controller"),
    );
    let status = client.get_status(pb::GetStatusRequest {}).await.expect("GetStatus").into_inner();
    assert_eq!(status.scenario, expected.name);
    let definition = status.definition.as_ref().expect("the controller's scenario");
    assert_eq!(Scenario::try_from(definition).expect("a valid scenario"), expected);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_run_ends_at_its_first_collision_over_grpc_as_in_process() {
    // paper-2 launched at 12 m/s at a cylinder it cannot stop in front of.
    let mut scenario = Scenario::paper_2();
    scenario.name = "launched".into();
    scenario.start = [3.5, 0.0, 1.0, 0.0, 12.0, 0.0, 0.0, 0.0];
    scenario.max_duration_s = 2.0;
    let mode = ControllerMode::Nmpc;
    let settings = patient(120);
    let run = run_over_grpc(&scenario, mode, &settings).await.expect("gRPC run");
    assert!(run.summary.collided, "the launched vehicle must collide");
    assert_eq!(run.summary.end_reason, mpc::RunEnd::Collided);
    assert_bit_identical(&scenario, mode, &run);
    scenario.continue_after_collision = true;
    let went_on = run_over_grpc(&scenario, mode, &settings).await.expect("gRPC run");
    assert_eq!(went_on.summary.end_reason, mpc::RunEnd::TimeLimit);
    assert!(went_on.summary.cycles > run.summary.cycles);
    assert_bit_identical(&scenario, mode, &went_on);
}
