//! Integration tests: controller.
//! A real controller service against a real plant on loopback ports: it flies the paper's
//! scenario to the goal in lockstep, refuses bad requests naming the field while its loop goes
//! on, and survives the plant going away. Every wait is bounded; no wall-clock durations are
//! asserted.

use std::time::Duration;

use controller::ControllerConfig;
use hilbench_proto::pb;
use hilbench_proto::pb::controller_client::ControllerClient;
use hilbench_tests::streams::{assert_exhausted, open_when_a_slot_is_free};
use hilbench_tests::{Relay, RunningController, RunningPlant, start_controller, start_plant};
use mav::Scenario;
use mpc::ControllerMode;
use plant::PlantConfig;
use tonic::Code;
use tonic::transport::Channel;

/// Generous bound for anything that must happen "soon" on a loaded machine.
const PATIENCE: Duration = Duration::from_secs(60);

async fn status(client: &mut ControllerClient<Channel>) -> pb::ControllerStatus {
    client.get_status(pb::GetStatusRequest {}).await.expect("GetStatus").into_inner()
}

/// Polls the status until `pred` holds; panics with `what` and the last status after PATIENCE.
async fn wait_for(
    client: &mut ControllerClient<Channel>,
    what: &str,
    pred: impl Fn(&pb::ControllerStatus) -> bool,
) -> pb::ControllerStatus {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        let s = status(client).await;
        if pred(&s) {
            return s;
        }
        if tokio::time::Instant::now() >= deadline {
            panic!("timed out waiting for {what}; last status: {s:?}");
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nmpc_reaches_the_goal_of_paper_3_against_a_lockstep_plant() {
    let scenario = Scenario::by_name("paper-3").expect("built-in");
    let plant = start_plant(PlantConfig::lockstep(scenario.clone())).await;
    let mut config = ControllerConfig::new(plant.addr.to_string(), scenario.clone(), ControllerMode::Nmpc);
    config.time_mode = mav::TimeModeChoice::Fixed(mav::TimeMode::Lockstep);
    let ctl = start_controller(config).await;
    let mut client = ctl.client().await;

    let s = wait_for(&mut client, "the episode to finish", |s| s.episode_finished).await;
    assert_eq!(s.episode, 1);
    assert_eq!(s.episodes_finished, 1);
    assert_eq!(s.finish_reason(), pb::FinishReason::Reached, "status: {s:?}");
    assert!(s.reached);
    assert!(s.cycles > 0);
    assert_eq!(s.scenario, "paper-3");
    assert_eq!(s.mode, "nmpc");

    // The plant agrees: it is within the goal tolerance, collision-free.
    let sample = plant.client().await.get_state(pb::GetStateRequest {}).await.expect("GetState").into_inner();
    let x = sample.state.expect("state").x;
    let g = scenario.goal_m;
    let dist = ((x[0] - g[0]).powi(2) + (x[1] - g[1]).powi(2) + (x[2] - g[2]).powi(2)).sqrt();
    let speed = (x[3] * x[3] + x[4] * x[4] + x[5] * x[5]).sqrt();
    assert!(dist < 0.15 && speed < 0.2, "plant ends at {x:?}, {dist} m from the goal at {speed} m/s");
    assert!(!sample.collided, "collided: {:?}", sample.collisions);
    // One command per cycle reached the plant.
    let last = sample.last_command.expect("a command was applied");
    assert_eq!(last.command_seq, s.cycles);

    // The loop idles after the episode: the cycle count stays put, and a new SetScenario
    // starts a second episode.
    client
        .set_scenario(pb::SetScenarioRequest {
            definition: None,
            scenario: "paper-3".into(),
            mode: "nmpc".into(),
        })
        .await
        .expect("SetScenario");
    let s2 = wait_for(&mut client, "the second episode to finish", |s| s.episodes_finished >= 2).await;
    assert_eq!(s2.episode, 2);
    assert_eq!(s2.finish_reason(), pb::FinishReason::Reached);
    // Lockstep is deterministic: the second run is the first one again.
    assert_eq!(s2.cycles, s.cycles);

    ctl.stop().await.expect("controller stops cleanly");
    plant.stop().await.expect("plant stops cleanly");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_goal_and_scenario_are_invalid_argument_naming_the_field_and_the_loop_goes_on() {
    let scenario = Scenario::by_name("paper-1").expect("built-in");
    // Real time: the loop runs on its own until stopped.
    let plant = start_plant(PlantConfig::real_time(scenario.clone())).await;
    let config = ControllerConfig::new(plant.addr.to_string(), scenario.clone(), ControllerMode::Nmpc);
    let ctl = start_controller(config).await;
    let mut client = ctl.client().await;
    let before = wait_for(&mut client, "the loop to cycle", |s| s.cycles >= 2).await;

    let bad_goals: [(Vec<f64>, &str); 5] = [
        (vec![1.0, f64::NAN, 1.0], "goal_m[1]"),
        (vec![1.0, 2.0], "goal_m"),
        (vec![1.0, 2.0, 1e12], "goal_m[2]"),
        (vec![1.0, 2.0, -0.5], "goal_m[2]"),          // below the ground
        (vec![0.3, 6.0, 1.0], "inside obstacles[0]"), // inside paper-1's cylinder
    ];
    for (goal_m, field) in bad_goals {
        let err = client.set_goal(pb::SetGoalRequest { goal_m: goal_m.clone() }).await.expect_err("refused");
        assert_eq!(err.code(), Code::InvalidArgument, "goal {goal_m:?}: {err:?}");
        assert!(
            err.message().contains(field),
            "goal {goal_m:?}: message {:?} names no {field}",
            err.message()
        );
    }
    let bad_scenarios =
        [("paper-7", "nmpc", "scenario"), ("", "nmpc", "scenario"), ("paper-2", "fast", "mode")];
    for (name, mode, field) in bad_scenarios {
        let err = client
            .set_scenario(pb::SetScenarioRequest {
                definition: None,
                scenario: name.into(),
                mode: mode.into(),
            })
            .await
            .expect_err("refused");
        assert_eq!(err.code(), Code::InvalidArgument, "{name}/{mode}: {err:?}");
        assert!(err.message().contains(field), "{name}/{mode}: message {:?} names no {field}", err.message());
    }
    // A whole scenario no solver can mean (a cylinder at 1e300 m once hung the solver).
    let mut far = pb::Scenario::from(&Scenario::paper_2());
    far.name = "far".into();
    far.obstacles[0].x_m = 1e300;
    let err = client
        .set_scenario(pb::SetScenarioRequest {
            scenario: String::new(),
            mode: String::new(),
            definition: Some(far),
        })
        .await
        .expect_err("refused");
    assert_eq!(err.code(), Code::InvalidArgument, "{err:?}");
    assert!(err.message().contains("`definition.obstacles[0].x_m`"), "{:?}", err.message());

    // Nothing changed, and the loop keeps cycling.
    let after =
        wait_for(&mut client, "more cycles after the bad requests", |s| s.cycles > before.cycles + 2).await;
    assert_eq!(after.scenario, "paper-1");
    assert_eq!(after.mode, "nmpc");
    assert_eq!(after.goal_m, scenario.goal_m.to_vec());
    assert_eq!(after.episode, 1);
    assert!(after.plant_connected);
    // The status carries the whole scenario flown.
    let flown = after.definition.as_ref().expect("the scenario of the episode");
    assert_eq!(Scenario::try_from(flown).expect("valid"), scenario);

    // A good goal is taken.
    client.set_goal(pb::SetGoalRequest { goal_m: vec![1.0, 2.0, 1.5] }).await.expect("SetGoal");
    wait_for(&mut client, "the new goal", |s| s.goal_m == vec![1.0, 2.0, 1.5]).await;

    ctl.stop().await.expect("controller stops cleanly");
    plant.stop().await.expect("plant stops cleanly");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_plant_that_restarts_ends_the_episode_as_a_plant_reset_and_the_controller_flies_the_next() {
    let scenario = Scenario::by_name("paper-1").expect("built-in");
    let plant = start_plant(PlantConfig::real_time(scenario.clone())).await;
    let addr = plant.addr;
    let mut config = ControllerConfig::new(addr.to_string(), scenario.clone(), ControllerMode::Nmpc);
    config.backoff_min = Duration::from_millis(20);
    config.backoff_max = Duration::from_millis(200);
    let ctl = start_controller(config).await;
    let mut client = ctl.client().await;
    let first = wait_for(&mut client, "the loop to cycle", |s| s.plant_connected && s.cycles >= 2).await;
    assert_eq!(first.reconnects, 0);

    plant.stop().await.expect("plant stops cleanly");
    let lost = wait_for(&mut client, "the lost link to be reported", |s| !s.plant_connected).await;
    assert!(lost.reconnects > 0, "{lost:?}");
    assert!(!lost.last_error.is_empty(), "the error is reported: {lost:?}");

    // A new plant comes back on the same address: another flight, back at the start. The
    // controller finds it, sees the flight change, and ends the episode rather than flying the
    // old episode's plan on a vehicle it no longer describes.
    let listener = rebind(addr).await;
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(plant::serve(listener, PlantConfig::real_time(scenario.clone()), async {
        let _ = stopped.await;
    }));
    let ended = wait_for(&mut client, "the episode to end at the plant reset", |s| s.episode_finished).await;
    assert_eq!((ended.finish_reason(), ended.plant_resets), (pb::FinishReason::Error, 1), "{ended:?}");
    assert!(ended.last_error.contains("the plant was reset or restarted"), "{ended:?}");
    assert!(ended.plant_reset_time_s > 0.0, "{ended:?}");
    assert_eq!(ended.episode, 1);
    // A goal starts the next episode, on the new plant.
    client.set_goal(pb::SetGoalRequest { goal_m: scenario.goal_m.to_vec() }).await.expect("SetGoal");
    let resumed = wait_for(&mut client, "the next episode to cycle", |s| {
        s.episode == 2 && s.plant_connected && s.cycles > 2
    })
    .await;
    assert!(resumed.reconnects > 0);
    assert_eq!(resumed.plant_resets, 0, "counted per episode: {resumed:?}");

    ctl.stop().await.expect("controller stops cleanly");
    let _ = stop.send(());
    match tokio::time::timeout(PATIENCE, task).await {
        Ok(Ok(r)) => r.expect("second plant served cleanly"),
        Ok(Err(e)) => panic!("second plant task failed: {e}"),
        Err(_) => panic!("second plant did not stop"),
    }
}

/// A real-time paper-1 plant, a relay in front of it, and an NMPC controller flying through
/// the relay with `rpc_timeout`, once it has cycled twice.
async fn fly_through_a_relay(
    rpc_timeout: Duration,
) -> (RunningPlant, Relay, RunningController, ControllerClient<Channel>, pb::ControllerStatus) {
    let scenario = Scenario::by_name("paper-1").expect("built-in");
    let plant = start_plant(PlantConfig::real_time(scenario.clone())).await;
    let relay = Relay::start(plant.addr).await;
    let mut config = ControllerConfig::new(relay.addr.to_string(), scenario, ControllerMode::Nmpc);
    config.backoff_min = Duration::from_millis(20);
    config.backoff_max = Duration::from_millis(200);
    config.rpc_timeout = rpc_timeout;
    let ctl = start_controller(config).await;
    let mut client = ctl.client().await;
    let first = wait_for(&mut client, "the loop to cycle", |s| s.plant_connected && s.cycles >= 2).await;
    (plant, relay, ctl, client, first)
}

/// A link that goes silent without closing (a frozen gateway): every call hangs. The controller
/// gives up on the call after `rpc_timeout`, reports the loss, retries, and flies on once the
/// link answers again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn controller_reports_a_link_that_stops_answering_and_flies_on_when_it_answers_again() {
    // Long enough that a loaded machine's ordinary calls never reach it.
    let (plant, relay, ctl, mut client, first) = fly_through_a_relay(Duration::from_secs(2)).await;

    relay.freeze();
    let lost = wait_for(&mut client, "the silent link to be reported", |s| !s.plant_connected).await;
    assert!(lost.link_losses > first.link_losses, "{lost:?}");
    assert!(lost.last_error.contains("no answer"), "the timeout is reported: {lost:?}");
    // Retries go on while the link is silent, each timing out in its turn (`Describe` never
    // answers, so the status never says connected) and all one outage.
    let retried =
        wait_for(&mut client, "retries of the silent link", |s| s.reconnects >= lost.reconnects + 2).await;
    assert!(!retried.plant_connected, "{retried:?}");
    assert_eq!(retried.link_losses, lost.link_losses, "one outage, however many retries");

    relay.thaw();
    let back = wait_for(&mut client, "the link to come back", |s| s.plant_connected).await;
    let resumed = wait_for(&mut client, "cycles after the link came back", |s| {
        s.plant_connected && s.cycles > back.cycles + 2
    })
    .await;
    assert_eq!(resumed.episode, 1, "the episode survives the outage");
    assert!(resumed.link_down_s > 0.0, "{resumed:?}");
    assert!(relay.accepted() >= 2, "the controller connected again");
    ctl.stop().await.expect("controller stops cleanly");
    drop(relay); // its frozen connection to the plant would hold the plant's graceful shutdown
    plant.stop().await.expect("plant stops cleanly");
}

/// A stop does not wait for a call that hangs on a silent link (here for an hour).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn controller_stops_while_a_call_hangs_on_a_silent_link() {
    let (plant, relay, ctl, mut client, _) = fly_through_a_relay(Duration::from_secs(3600)).await;
    relay.freeze();
    // Real time cycles every 50 ms: by now the loop waits on a call that will not answer.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let hung = status(&mut client).await;
    assert!(hung.plant_connected, "no failure is visible before the timeout: {hung:?}");
    ctl.stop().await.expect("controller stops cleanly, without waiting for the call");
    drop(relay); // its frozen connection to the plant would hold the plant's graceful shutdown
    plant.stop().await.expect("plant stops cleanly");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn telemetry_streams_beyond_max_streams_are_resource_exhausted_and_a_dropped_one_frees_its_slot() {
    let scenario = Scenario::by_name("paper-1").expect("built-in");
    let plant = start_plant(PlantConfig::lockstep(scenario.clone())).await;
    let mut config = ControllerConfig::new(plant.addr.to_string(), scenario, ControllerMode::Nmpc);
    config.autostart = false;
    config.max_streams = 1;
    let ctl = start_controller(config).await;
    let mut client = ctl.client().await;
    let first = client.stream_telemetry(pb::StreamTelemetryRequest {}).await.expect("a telemetry stream");
    assert_exhausted(client.stream_telemetry(pb::StreamTelemetryRequest {}).await, 1);
    status(&mut client).await; // unary calls are served as before
    drop(first);
    let again = open_when_a_slot_is_free("controller StreamTelemetry", PATIENCE, || {
        let mut client = client.clone();
        async move { client.stream_telemetry(pb::StreamTelemetryRequest {}).await }
    })
    .await;
    drop(again);
    ctl.stop().await.expect("controller stops cleanly");
    plant.stop().await.expect("plant stops cleanly");
}

/// Binds `addr` again (the old listener is closed; retried while the port is in transition).
async fn rebind(addr: std::net::SocketAddr) -> tokio::net::TcpListener {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        match tokio::net::TcpListener::bind(addr).await {
            Ok(l) => return l,
            Err(e) if tokio::time::Instant::now() >= deadline => panic!("cannot bind {addr} again: {e}"),
            Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
        }
    }
}
