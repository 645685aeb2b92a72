//! Integration tests: plant.
//! A real plant server on a loopback port, driven over gRPC, checked against the in-process
//! truth simulation of `mav` (bit for bit in lockstep).

use hilbench_proto::pb;
use hilbench_proto::pb::plant_client::PlantClient;
use hilbench_tests::streams::{assert_exhausted, open_when_a_slot_is_free};
use hilbench_tests::{start_plant, wait_for_state};
use mav::{CommandMeta, Input, PlantSim, Scenario, SimSettings, State};
use plant::PlantConfig;
use std::time::Duration;
use tokio_stream::StreamExt;
use tonic::transport::Channel;
use tonic::{Code, Status, Streaming};

/// Generous bound for anything that must happen "soon" on a loaded machine.
const PATIENCE: Duration = Duration::from_secs(30);

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn state_bits(s: &pb::StateSample) -> Vec<u64> {
    bits(&s.state.as_ref().expect("sample carries a state").x)
}

fn command(input: [f64; 3], seq: u64, based_on: &pb::StateSample) -> pb::Command {
    pb::Command {
        input: Some(pb::ControlInput { thrust_mps2: input[0], roll_rad: input[1], pitch_rad: input[2] }),
        command_seq: seq,
        based_on_sample_seq: based_on.seq,
        based_on_sample_time_ns: based_on.time_ns,
    }
}

fn meta(seq: u64, based_on: &pb::StateSample) -> CommandMeta {
    CommandMeta {
        command_seq: seq,
        based_on_sample_seq: based_on.seq,
        based_on_sample_time_ns: based_on.time_ns,
    }
}

async fn next_sample(stream: &mut Streaming<pb::StateSample>) -> pb::StateSample {
    match tokio::time::timeout(PATIENCE, stream.next()).await {
        Ok(Some(Ok(s))) => s,
        Ok(Some(Err(e))) => panic!("stream failed: {e}"),
        Ok(None) => panic!("stream ended"),
        Err(_) => panic!("no sample within {PATIENCE:?}"),
    }
}

async fn get_state(client: &mut PlantClient<Channel>) -> pb::StateSample {
    client.get_state(pb::GetStateRequest {}).await.expect("GetState").into_inner()
}

/// The call failed with INVALID_ARGUMENT and the message names `field`.
fn assert_invalid(result: Result<impl std::fmt::Debug, Status>, field: &str) {
    match result {
        Ok(v) => panic!("expected INVALID_ARGUMENT naming `{field}`, got {v:?}"),
        Err(s) => {
            assert_eq!(s.code(), Code::InvalidArgument, "{s:?}");
            assert!(
                s.message().contains(&format!("`{field}`")),
                "message {:?} does not name `{field}`",
                s.message()
            );
        }
    }
}

#[tokio::test]
async fn lockstep_over_grpc_is_bit_identical_to_the_in_process_simulation() {
    let scenario = Scenario::paper_2();
    let server = start_plant(PlantConfig::default()).await;
    let mut client = server.client().await;

    // Reset the server to paper-2 (it starts on paper-1) and describe it.
    let reset = client
        .reset(pb::ResetRequest { definition: None, scenario: "paper-2".into(), initial_state: None })
        .await
        .expect("reset")
        .into_inner();
    let description = reset.description.expect("description");
    assert_eq!(description.scenario, "paper-2");
    assert_eq!(description.time_mode, pb::TimeMode::Lockstep as i32);
    assert_eq!(description.obstacles.len(), 3);
    assert_eq!(description.step_ns, 1_000_000);
    let first = reset.sample.expect("sample");
    assert_eq!((first.seq, first.time_ns), (0, 0));
    assert_eq!(state_bits(&first), bits(scenario.start.as_slice()));

    // A subscriber every 10 ms of plant time, reading concurrently.
    let period_ns = 10_000_000;
    let mut stream =
        client.stream_state(pb::StreamStateRequest { period_ns }).await.expect("stream").into_inner();
    assert_eq!(next_sample(&mut stream).await.time_ns, 0);

    // The same commands at the same plant times, in process. The reference records the state
    // at the first step end on or after every multiple of the period, as the stream should.
    let mut sim = PlantSim::new(&scenario, SimSettings::default()).expect("valid");
    let mut expected_stream: Vec<(u64, Vec<u64>)> = Vec::new();
    let mut last_slot = 0u64;
    let mut record = |p: &PlantSim| {
        let slot = p.time_ns() / period_ns;
        if slot > last_slot {
            last_slot = slot;
            expected_stream.push((p.time_ns(), bits(p.state().as_slice())));
        }
    };

    let plan: [([f64; 3], u64); 6] = [
        ([12.0, 0.0, 0.15], 50_000_000),
        ([10.5, -0.1, 0.05], 2_500_000), // off the 1 ms grid
        ([30.0, 0.5, 0.0], 47_500_000),  // saturated at the plant
        ([9.0, 0.05, -0.05], 100_000_000),
        ([9.81, 0.0, 0.0], 1_000_000),
        ([11.0, 0.17, 0.17], 250_000_000), // long enough to run on the blocking pool
    ];
    let mut last = first;
    for (i, (u, duration_ns)) in plan.into_iter().enumerate() {
        let seq = i as u64 + 1;
        sim.apply(Input::from(u), meta(seq, &last)).expect("finite");
        sim.advance(duration_ns, &mut record);
        // Alternate between the one-call Step and ApplyCommand + Advance.
        last = if i % 2 == 0 {
            let r = client
                .step(pb::StepRequest {
                    command: Some(command(u, seq, &last)),
                    duration_ns,
                    ..Default::default()
                })
                .await
                .expect("step");
            r.into_inner().sample.expect("sample")
        } else {
            let applied = client.apply_command(command(u, seq, &last)).await.expect("apply").into_inner();
            let applied = applied.applied.expect("applied");
            assert_eq!(applied.saturated, u[0] > 19.62 || u[1].abs() > std::f64::consts::PI / 18.0);
            let r = client
                .advance(pb::AdvanceRequest { duration_ns, ..Default::default() })
                .await
                .expect("advance");
            r.into_inner().sample.expect("sample")
        };
        assert_eq!(last.time_ns, sim.time_ns());
        assert_eq!(state_bits(&last), bits(sim.state().as_slice()), "after command {seq}");
        let echoed = last.last_command.as_ref().expect("last command");
        assert_eq!(echoed.command_seq, seq);
        assert_eq!(echoed.applied_time_ns, sim.last_command().applied_time_ns);
        assert_eq!(echoed.saturated, sim.last_command().saturated);
        assert!(!echoed.initial);
    }
    let reference = sim.peek();
    assert_eq!(last.path_length_m.to_bits(), reference.path_length_m.to_bits());
    assert_eq!(last.min_clearance_m.to_bits(), reference.min_clearance_m.to_bits());
    assert_eq!(last.collided, reference.collided);
    assert_eq!(last.collisions.len(), reference.collisions.len());
    assert!(last.path_length_m > 0.1, "the vehicle moved: {}", last.path_length_m);

    // GetState reads without moving anything, and returns the same numbered sample.
    let again = get_state(&mut client).await;
    assert_eq!(again, last);

    // The stream saw every period boundary, with the states of the in-process run.
    let total = sim.time_ns();
    let expected_len = expected_stream.len();
    assert_eq!(expected_len as u64, total / period_ns);
    for (time_ns, state) in expected_stream {
        let s = next_sample(&mut stream).await;
        assert_eq!(s.time_ns, time_ns);
        assert_eq!(state_bits(&s), state, "stream sample at {time_ns} ns");
    }
    drop(stream);
    server.stop().await.expect("clean shutdown");
}

#[tokio::test]
async fn bad_input_is_invalid_argument_naming_the_field_while_the_stream_keeps_going() {
    let server = start_plant(PlantConfig::default()).await;
    let mut client = server.client().await;
    let mut stream =
        client.stream_state(pb::StreamStateRequest { period_ns: 0 }).await.expect("stream").into_inner();
    let scenario = Scenario::paper_1();
    let mut sim = PlantSim::new(&scenario, SimSettings::default()).expect("valid");

    let start = next_sample(&mut stream).await;
    let good = command([11.0, 0.02, -0.03], 1, &start);
    client.apply_command(good).await.expect("apply");
    sim.apply(Input::new(11.0, 0.02, -0.03), meta(1, &start)).expect("finite");

    let nan = |t: f64, r: f64, p: f64| command([t, r, p], 99, &start);
    let short_state = pb::MavState { x: vec![0.0; 7] };
    let mut nan_state = pb::MavState { x: vec![0.0; 8] };
    nan_state.x[2] = f64::NAN;
    let mut tilted_state = pb::MavState { x: vec![0.0; 8] };
    tilted_state.x[6] = 2.0;
    let mut underground_state = pb::MavState { x: vec![0.0; 8] };
    underground_state.x[2] = -0.5;

    for round in 0..3u64 {
        // Several kinds of bad input, each rejected with the field named ...
        assert_invalid(client.apply_command(nan(f64::NAN, 0.0, 0.0)).await, "input.thrust_mps2");
        assert_invalid(client.apply_command(nan(9.81, f64::INFINITY, 0.0)).await, "input.roll_rad");
        assert_invalid(client.apply_command(nan(9.81, 0.0, -3.0)).await, "input.pitch_rad");
        assert_invalid(client.apply_command(nan(-1.0, 0.0, 0.0)).await, "input.thrust_mps2");
        assert_invalid(client.apply_command(pb::Command::default()).await, "input");
        assert_invalid(
            client
                .reset(pb::ResetRequest { definition: None, scenario: "paper-9".into(), initial_state: None })
                .await,
            "scenario",
        );
        assert_invalid(
            client
                .reset(pb::ResetRequest {
                    definition: None,
                    scenario: String::new(),
                    initial_state: Some(short_state.clone()),
                })
                .await,
            "initial_state.x",
        );
        assert_invalid(
            client
                .reset(pb::ResetRequest {
                    definition: None,
                    scenario: String::new(),
                    initial_state: Some(nan_state.clone()),
                })
                .await,
            "initial_state.x[2]",
        );
        assert_invalid(
            client
                .reset(pb::ResetRequest {
                    definition: None,
                    scenario: "paper-1".into(),
                    initial_state: Some(tilted_state.clone()),
                })
                .await,
            "initial_state.x[6]",
        );
        // Below the ground (paper-1's is at 0 m): a collision before the first step.
        assert_invalid(
            client
                .reset(pb::ResetRequest {
                    definition: None,
                    scenario: "paper-1".into(),
                    initial_state: Some(underground_state.clone()),
                })
                .await,
            "initial_state.x[2]",
        );
        assert_invalid(
            client.advance(pb::AdvanceRequest { duration_ns: 0, ..Default::default() }).await,
            "duration_ns",
        );
        assert_invalid(
            client.advance(pb::AdvanceRequest { duration_ns: u64::MAX, ..Default::default() }).await,
            "duration_ns",
        );
        assert_invalid(
            client
                .step(pb::StepRequest {
                    command: Some(nan(9.81, f64::NAN, 0.0)),
                    duration_ns: 1_000_000,
                    ..Default::default()
                })
                .await,
            "command.input.roll_rad",
        );

        // ... the state is unchanged (same sample, same number) ...
        let before = get_state(&mut client).await;
        assert_eq!(before.time_ns, sim.time_ns());
        assert_eq!(state_bits(&before), bits(sim.state().as_slice()));
        assert_eq!(before.last_command.as_ref().map(|c| c.command_seq), Some(1));

        // ... and the plant keeps serving: time moves, and the open stream delivers each step.
        let r = client
            .advance(pb::AdvanceRequest { duration_ns: 3_000_000, ..Default::default() })
            .await
            .expect("advance");
        sim.advance(3_000_000, |_| {});
        let after = r.into_inner().sample.expect("sample");
        assert_eq!(after.time_ns, (round + 1) * 3_000_000);
        assert_eq!(state_bits(&after), bits(sim.state().as_slice()));
        let mut times = Vec::new();
        loop {
            let s = next_sample(&mut stream).await;
            times.push(s.time_ns);
            if s.time_ns == after.time_ns {
                assert_eq!(s, after);
                break;
            }
        }
        let t0 = round * 3_000_000;
        assert_eq!(times, vec![t0 + 1_000_000, t0 + 2_000_000, t0 + 3_000_000]);
    }
    drop(stream);
    server.stop().await.expect("clean shutdown");
}

#[tokio::test]
async fn reset_to_a_custom_start_restarts_time_and_numbering() {
    let server = start_plant(PlantConfig::default()).await;
    let mut client = server.client().await;
    client
        .advance(pb::AdvanceRequest { duration_ns: 5_000_000, ..Default::default() })
        .await
        .expect("advance");
    let start = [1.0, 2.0, 3.0, 0.5, -0.5, 0.0, 0.1, -0.1];
    let r = client
        .reset(pb::ResetRequest {
            definition: None,
            scenario: String::new(),
            initial_state: Some(pb::MavState { x: start.to_vec() }),
        })
        .await
        .expect("reset")
        .into_inner();
    let s = r.sample.expect("sample");
    assert_eq!((s.seq, s.time_ns), (0, 0));
    assert_eq!(state_bits(&s), bits(&start));
    assert!(s.last_command.as_ref().is_some_and(|c| c.initial));
    assert_eq!(r.description.map(|d| d.scenario), Some("paper-1".to_string()));
    server.stop().await.expect("clean shutdown");
}

/// Polls GetState every 10 ms until `pred` holds; panics after `PATIENCE`.
async fn poll_until(
    client: &mut PlantClient<Channel>,
    what: &str,
    pred: impl Fn(&pb::StateSample) -> bool,
) -> pb::StateSample {
    wait_for_state(client, what, PATIENCE, Duration::from_millis(10), pred).await
}

#[tokio::test]
async fn real_time_plant_runs_on_its_own_refuses_advance_and_holds_hover_after_the_watchdog() {
    let config =
        PlantConfig { watchdog_timeout_ns: Some(200_000_000), ..PlantConfig::real_time(Scenario::paper_1()) };
    let server = start_plant(config).await;
    let mut client = server.client().await;
    let description = client.describe(pb::DescribeRequest {}).await.expect("describe").into_inner();
    assert_eq!(description.time_mode, pb::TimeMode::RealTime as i32);
    assert_eq!(description.watchdog_timeout_ns, 200_000_000);
    assert_eq!(description.watchdog_action, pb::WatchdogAction::Brake as i32, "brakes by default");
    assert_eq!(hilbench_proto::convert::plant::braking_watchdog_s(&description), Some(0.2));

    // Time moves without being asked, and the stream follows it.
    let mut stream =
        client.stream_state(pb::StreamStateRequest { period_ns: 0 }).await.expect("stream").into_inner();
    let t0 = next_sample(&mut stream).await.time_ns;
    let t1 = next_sample(&mut stream).await.time_ns;
    assert!(t1 > t0, "{t1} > {t0}");

    let err = client
        .advance(pb::AdvanceRequest { duration_ns: 1_000_000, ..Default::default() })
        .await
        .expect_err("refused");
    assert_eq!(err.code(), Code::FailedPrecondition);
    let base = get_state(&mut client).await;
    let err = client
        .step(pb::StepRequest {
            command: Some(command([12.0, 0.0, 0.0], 1, &base)),
            duration_ns: 1_000_000,
            ..Default::default()
        })
        .await
        .expect_err("refused");
    assert_eq!(err.code(), Code::FailedPrecondition);
    // Bad input is still INVALID_ARGUMENT in real time.
    assert_invalid(client.apply_command(command([f64::NAN, 0.0, 0.0], 1, &base)).await, "input.thrust_mps2");

    // A command (climb) applied now, then silence: the watchdog takes over with hover.
    let applied = client
        .step(pb::StepRequest {
            command: Some(command([12.0, 0.0, 0.0], 2, &base)),
            duration_ns: 0,
            ..Default::default()
        })
        .await
        .expect("apply and read")
        .into_inner()
        .sample
        .expect("sample");
    let applied_at = applied.last_command.as_ref().map(|c| c.applied_time_ns).expect("last command");
    assert!(applied_at >= base.time_ns);
    assert!(!applied.watchdog_hover);
    let held = poll_until(&mut client, "watchdog hover", |s| s.watchdog_hover).await;
    assert!(
        held.time_ns >= applied_at + 200_000_000,
        "hover at {} after command at {applied_at}",
        held.time_ns
    );
    assert_eq!(held.last_command.as_ref().map(|c| c.command_seq), Some(2));
    // It climbed while the command held.
    assert!(held.state.as_ref().map(|s| s.x[5]).is_some_and(|vz| vz > 0.0));

    // The next command ends the hover.
    let resumed = client.apply_command(command([9.81, 0.0, 0.0], 3, &held)).await.expect("apply");
    assert!(resumed.into_inner().applied.is_some_and(|a| !a.initial));
    let s = poll_until(&mut client, "hover released", |s| {
        s.last_command.as_ref().is_some_and(|c| c.command_seq == 3)
    })
    .await;
    assert!(!s.watchdog_hover);
    drop(stream);
    server.stop().await.expect("clean shutdown");
}

#[tokio::test]
async fn health_is_serving_and_reflection_lists_the_plant() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::health_client::HealthClient;
    use tonic_reflection::pb::v1::ServerReflectionRequest;
    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;

    let server = start_plant(PlantConfig::default()).await;
    let channel = server.channel().await;
    let mut health = HealthClient::new(channel.clone());
    for service in ["", "hilbench.v1.Plant"] {
        let r = health
            .check(tonic_health::pb::HealthCheckRequest { service: service.into() })
            .await
            .expect("health check")
            .into_inner();
        assert_eq!(r.status, ServingStatus::Serving as i32, "service {service:?}");
    }

    let mut reflection = ServerReflectionClient::new(channel);
    let request = ServerReflectionRequest {
        host: String::new(),
        message_request: Some(MessageRequest::ListServices(String::new())),
    };
    let mut responses = reflection
        .server_reflection_info(tokio_stream::iter([request]))
        .await
        .expect("reflection")
        .into_inner();
    let response = responses.next().await.expect("one response").expect("ok");
    let Some(MessageResponse::ListServicesResponse(list)) = response.message_response else {
        panic!("unexpected reflection response {response:?}");
    };
    let names: Vec<_> = list.service.into_iter().map(|s| s.name).collect();
    assert!(names.contains(&"hilbench.v1.Plant".to_string()), "{names:?}");
    assert!(names.contains(&"grpc.health.v1.Health".to_string()), "{names:?}");
    // Only what the plant serves: not netem's control API nor the controller's.
    assert!(!names.iter().any(|n| n.contains("NetemControl") || n.contains("Controller")), "{names:?}");
    drop(responses);
    server.stop().await.expect("clean shutdown");
}

#[tokio::test]
async fn shutdown_ends_open_streams_and_returns() {
    let server = start_plant(PlantConfig::real_time(Scenario::paper_3())).await;
    let mut client = server.client().await;
    let mut stream =
        client.stream_state(pb::StreamStateRequest { period_ns: 0 }).await.expect("stream").into_inner();
    next_sample(&mut stream).await;
    server.stop().await.expect("clean shutdown");
    // The stream ends (possibly after samples already queued) instead of hanging.
    let drained =
        tokio::time::timeout(PATIENCE, async { while let Some(Ok(_)) = stream.next().await {} }).await;
    assert!(drained.is_ok(), "stream still open after shutdown");
}

#[test]
fn in_process_reference_is_itself_deterministic() {
    // The reference the gRPC tests compare with: two runs, same bits.
    let run = || {
        let mut sim = PlantSim::new(&Scenario::paper_1(), SimSettings::default()).expect("valid");
        sim.reset(State::from([0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0])).expect("finite");
        sim.apply(Input::new(10.0, 0.1, 0.1), CommandMeta::default()).expect("finite");
        sim.advance(123_456_789, |_| {});
        bits(sim.state().as_slice())
    };
    assert_eq!(run(), run());
}

#[tokio::test]
async fn reset_with_a_whole_scenario_flies_it_describe_returns_it_and_a_bad_one_changes_nothing() {
    let server = start_plant(PlantConfig::default()).await;
    let mut client = server.client().await;
    let mut custom = Scenario::paper_2();
    custom.name = "two-cylinders".into();
    custom.obstacles.push(mav::Cylinder { x_m: -1.0, y_m: 6.0, radius_m: 0.3, height_m: 5.0 });
    custom.goal_m = [0.5, 8.0, 1.5];
    let reset = client
        .reset(pb::ResetRequest {
            scenario: String::new(),
            initial_state: None,
            definition: Some((&custom).into()),
        })
        .await
        .expect("a valid scenario is loaded")
        .into_inner();
    let described = reset.description.expect("a description");
    assert_eq!(described.scenario, "two-cylinders");
    assert_eq!(described.obstacles.len(), custom.obstacles.len());
    let in_force = client.describe(pb::DescribeRequest {}).await.expect("describe").into_inner();
    let definition = in_force.definition.as_ref().expect("the scenario in force");
    assert_eq!(Scenario::try_from(definition).expect("valid"), custom);

    // A scenario no solver can mean: refused with its field, and the plant keeps flying the
    // one in force.
    let mut far = pb::Scenario::from(&custom);
    far.obstacles[1].x_m = 1e300;
    assert_invalid(
        client
            .reset(pb::ResetRequest { scenario: String::new(), initial_state: None, definition: Some(far) })
            .await,
        "definition.obstacles[1].x_m",
    );
    let mut mismatched = pb::Scenario::from(&custom);
    mismatched.name = "other".into();
    assert_invalid(
        client
            .reset(pb::ResetRequest {
                scenario: "paper-2".into(),
                initial_state: None,
                definition: Some(mismatched),
            })
            .await,
        "scenario",
    );
    let after = client.describe(pb::DescribeRequest {}).await.expect("describe").into_inner();
    assert_eq!(after, in_force, "a refused reset changes nothing");
    server.stop().await.expect("plant stops cleanly");
}

#[tokio::test]
async fn a_stream_beyond_max_streams_is_resource_exhausted_and_a_dropped_stream_frees_its_slot() {
    let server = start_plant(PlantConfig { max_streams: 2, ..PlantConfig::default() }).await;
    let mut client = server.client().await;
    let request = || pb::StreamStateRequest { period_ns: 0 };
    let first = client.stream_state(request()).await.expect("first stream").into_inner();
    let second = client.stream_state(request()).await.expect("second stream").into_inner();
    assert_exhausted(client.stream_state(request()).await, 2);
    // Unary calls are not streams: they are served as before.
    get_state(&mut client).await;
    drop(first);
    let mut third = open_when_a_slot_is_free("plant StreamState", PATIENCE, || {
        let mut client = client.clone();
        async move { client.stream_state(request()).await }
    })
    .await
    .into_inner();
    assert_eq!(next_sample(&mut third).await.time_ns, 0, "the new stream starts with the current sample");
    drop((second, third));
    server.stop().await.expect("clean shutdown");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_real_time_stream_with_period_0_gives_each_step_once_in_order() {
    // A buffer that cannot fill here, so that a gap or a repeat would be the sampling rule's.
    let config = PlantConfig { stream_buffer: 1 << 20, ..PlantConfig::real_time(Scenario::paper_1()) };
    let server = start_plant(config).await;
    let mut client = server.client().await;
    let step_ns = client.describe(pb::DescribeRequest {}).await.expect("describe").into_inner().step_ns;
    let mut stream =
        client.stream_state(pb::StreamStateRequest { period_ns: 0 }).await.expect("stream").into_inner();
    let first = next_sample(&mut stream).await;
    let mut samples = Vec::new();
    for k in 0..600 {
        samples.push(next_sample(&mut stream).await);
        // Commands arrive between steps and end integration sub-steps there.
        if k % 50 == 0 {
            client.apply_command(command([9.81, 0.0, 0.0], k + 1, &first)).await.expect("apply");
        }
    }
    let times: Vec<u64> = samples.iter().map(|s| s.time_ns).collect();
    assert!(
        times[0] > first.time_ns && times[0] - first.time_ns <= step_ns,
        "{} then {times:?}",
        first.time_ns
    );
    let off_grid: Vec<&u64> = times.iter().filter(|t| !t.is_multiple_of(step_ns)).collect();
    assert!(off_grid.is_empty(), "samples between steps: {off_grid:?}");
    let spacing: Vec<u64> = times.windows(2).map(|w| w[1] - w[0]).filter(|d| *d != step_ns).collect();
    assert!(spacing.is_empty(), "consecutive samples not one step apart: {spacing:?}");
    assert!(samples.windows(2).all(|w| w[1].seq > w[0].seq), "numbered in order");
    drop(stream);
    server.stop().await.expect("clean shutdown");
}
