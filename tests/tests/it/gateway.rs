//! Integration tests: the vehicle gateway against `mavsim` (the model playing PX4's side of
//! MAVLink 2 over UDP on loopback), both in process on ephemeral ports:
//! - paper-2 in real time: controller -> netem -> gateway -> MAVLink -> simulated vehicle
//!   reaches the goal without a collision (judged by the gateway's samples and by the
//!   simulator's own truth);
//! - the vehicle going silent: the Plant API answers UNAVAILABLE, health goes NOT_SERVING;
//! - the vehicle rebooting (its clock restarts): UNAVAILABLE and NOT_SERVING until a Reset;
//!   also the `mavsim` binary rebooting from its command line after a silence;
//! - refusals: a Reset far from the vehicle, a mode the vehicle does not know, GUIDED_NOGPS on an
//!   ArduCopter whose `GUID_OPTIONS` would read the thrust as a climb rate (accepted with bit 3);
//! - a serial autopilot (pymavlink behind a pty, the `gateway` binary) unplugged and plugged
//!   back in: UNAVAILABLE and NOT_SERVING without burning CPU, served again, stopped by SIGTERM;
//! - trust: pymavlink as the vehicle and as an attacker on another port (junk, spoofed states,
//!   heartbeats, acks, a reboot stamp, TIMESYNC), with and without MAVLink signing; who may
//!   call VehicleControl (`--allow-client`).
//!
//! Every wait is bounded; no wall-clock duration is asserted (CPU time is, in the serial test).

use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

use gateway::mavsim::{Mavsim, MavsimConfig};
use gateway::{GatewayConfig, GatewayError, Link};
use hilbench::drive::grpc::{GrpcSettings, run_against};
use hilbench::drive::services::{Endpoints, netem_config};
use hilbench_proto::pb;
use hilbench_proto::pb::plant_client::PlantClient;
use hilbench_proto::pb::vehicle_control_client::VehicleControlClient;
use hilbench_tests::server::{self, Running};
use mav::Scenario;
use mav::TimeMode;
use mavbridge::{AutopilotSettings, Firmware};
use mpc::ControllerMode;
use tonic::transport::Channel;
use tonic_health::pb::HealthCheckRequest;
use tonic_health::pb::health_check_response::ServingStatus;
use tonic_health::pb::health_client::HealthClient;

/// Generous bound for anything that must happen "soon" on a loaded machine.
const PATIENCE: Duration = Duration::from_secs(60);

struct Bench {
    gateway: Running<GatewayError>,
    vehicle: Mavsim,
}

/// A gateway for `scenario` listening for MAVLink on an ephemeral loopback UDP port (returned).
async fn start_gateway(scenario: &Scenario) -> (Running<GatewayError>, u16) {
    start_gateway_with(scenario, None, |_| {}).await
}

/// As [`start_gateway`], the link signed with `key`, the configuration changed by `set`.
async fn start_gateway_with(
    scenario: &Scenario,
    key: Option<mavbridge::SigningKey>,
    set: impl FnOnce(&mut GatewayConfig),
) -> (Running<GatewayError>, u16) {
    let link = Link::open_signed("udpin:127.0.0.1:0", 255, 191, key).expect("a loopback UDP port");
    let port = link.local_addr.expect("bound").port();
    let mut config = GatewayConfig::new(format!("udpin:127.0.0.1:{port}"), scenario.clone());
    set(&mut config);
    let gateway = server::start("gateway", move |listener, shutdown| {
        gateway::serve_with_link(listener, config, link, shutdown)
    })
    .await;
    (gateway, port)
}

/// A gateway and a simulated vehicle of `scenario` sending to it.
async fn start(scenario: &Scenario) -> Bench {
    start_with(scenario, AutopilotSettings::default()).await
}

/// As [`start`], the vehicle's autopilot set by `autopilot`.
async fn start_with(scenario: &Scenario, autopilot: AutopilotSettings) -> Bench {
    let (gateway, port) = start_gateway(scenario).await;
    let vehicle = Mavsim::start(&MavsimConfig {
        mavlink: format!("udpout:127.0.0.1:{port}"),
        scenario: scenario.clone(),
        autopilot,
        signing_key: None,
    })
    .expect("mavsim starts");
    Bench { gateway, vehicle }
}

async fn vehicle_control(addr: SocketAddr) -> VehicleControlClient<Channel> {
    VehicleControlClient::connect(format!("http://{addr}")).await.expect("connects")
}

async fn plant(addr: SocketAddr) -> PlantClient<Channel> {
    PlantClient::connect(format!("http://{addr}")).await.expect("connects")
}

/// Polls `GetState` until the vehicle's first state has arrived.
async fn wait_for_state(p: &mut PlantClient<Channel>) {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while let Err(e) = p.get_state(pb::GetStateRequest {}).await {
        assert!(tokio::time::Instant::now() < deadline, "no state from the vehicle: {e}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

async fn health(addr: SocketAddr, service: &str) -> i32 {
    let channel =
        Channel::from_shared(format!("http://{addr}")).expect("uri").connect().await.expect("connects");
    let mut client = HealthClient::new(channel);
    let r = client.check(HealthCheckRequest { service: service.into() }).await.expect("health answers");
    r.into_inner().status
}

/// Polls until `pred` holds of the gateway's status (panics after PATIENCE).
pub(crate) async fn wait_status(
    client: &mut VehicleControlClient<Channel>,
    what: &str,
    pred: impl Fn(&pb::VehicleStatus) -> bool,
) {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        let s = client.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
        if pred(&s) {
            return;
        }
        assert!(tokio::time::Instant::now() < deadline, "timed out waiting for {what}; last status {s:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Arms the simulated vehicle and switches it to OFFBOARD through VehicleControl.
pub(crate) async fn arm_and_offboard(addr: SocketAddr) {
    let mut vc = vehicle_control(addr).await;
    // PX4 takes OFFBOARD only once setpoints stream (a tenth of a second of them here).
    wait_status(&mut vc, "the vehicle's heartbeat and the setpoint stream", |s| {
        s.link_alive && s.setpoints_sent >= 5
    })
    .await;
    vc.arm(pb::ArmRequest {}).await.expect("armed");
    vc.set_mode(pb::SetModeRequest { mode: pb::FlightMode::Px4Offboard as i32 }).await.expect("offboard");
    wait_status(&mut vc, "OFFBOARD, armed", |s| s.armed && s.mode == "OFFBOARD").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn paper_2_in_real_time_through_netem_and_the_gateway_reaches_the_goal_of_the_simulated_vehicle() {
    let scenario = Scenario::paper_2();
    let bench = start(&scenario).await;
    // Nothing armed or switched the vehicle before it was asked.
    {
        let a = bench.vehicle.autopilot();
        assert!(!a.armed() && a.mode() == mavbridge::SimMode::Posctl);
    }
    arm_and_offboard(bench.gateway.addr).await;

    let netem_listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("port");
    let netem_addr = netem_listener.local_addr().expect("address");
    let config =
        netem_config(&bench.gateway.addr.to_string(), &scenario, TimeMode::RealTime).expect("netem config");
    let (stop_netem, netem_stopped) = tokio::sync::oneshot::channel::<()>();
    let netem = tokio::spawn(netem::serve(netem_listener, config, async {
        let _ = netem_stopped.await;
    }));

    let run = fly_in_real_time(&scenario, bench.gateway.addr, netem_addr, false).await;
    let s = &run.summary;
    assert!(s.reached && !s.collided, "{s:?}");
    // The run names what flew it: the gateway and its link (summary.json's `plant`).
    assert!(run.plant.starts_with(gateway::service::IMPLEMENTATION), "{}", run.plant);
    assert!(s.min_clearance_m >= 0.0, "{s:?}");
    // Delays were measured from the gateway's stamps (the last command applied and when, in
    // the vehicle's clock): after the first cycles every cycle knows one, positive and finite.
    assert!(run.records.len() > 20, "{} cycles", run.records.len());
    let first_known = run.records.iter().position(|r| r.known_delay_s.is_some()).expect("a delay known");
    let unknown: Vec<u64> =
        run.records.iter().filter(|r| r.known_delay_s.is_none()).map(|r| r.cycle).collect();
    assert!(first_known <= 10 && unknown.len() == first_known, "cycles without a delay: {unknown:?}");
    let known: Vec<f64> = run.records.iter().filter_map(|r| r.known_delay_s).collect();
    assert!(known.iter().all(|d| d.is_finite() && *d > 0.0 && *d < 1.0), "{known:?}");

    // The simulator's own truth: no collision, at the goal, still in OFFBOARD.
    {
        let a = bench.vehicle.autopilot();
        assert!(!a.sim().collided(), "{:?}", a.sim().collisions());
        let x = a.sim().state();
        let d = ((x[0] - scenario.goal_m[0]).powi(2)
            + (x[1] - scenario.goal_m[1]).powi(2)
            + (x[2] - scenario.goal_m[2]).powi(2))
        .sqrt();
        assert!(d < 0.5, "the vehicle is {d} m from the goal: {x:?}");
        assert_eq!(a.mode(), mavbridge::SimMode::Offboard);
        assert_eq!(a.counters().refused_setpoints, 0);
    }
    let _ = stop_netem.send(());
    let _ = tokio::time::timeout(PATIENCE, netem).await;
    bench.gateway.stop().await.expect("gateway stops cleanly");
    bench.vehicle.stop();
}

/// Flies `scenario` with the standard NMPC in real time, through the netem at `netem` (its
/// profile left alone with `keep_netem_profile`) to the gateway at `gateway`.
pub(crate) async fn fly_in_real_time(
    scenario: &Scenario,
    gateway: SocketAddr,
    netem: SocketAddr,
    keep_netem_profile: bool,
) -> hilbench::drive::grpc::GrpcRun {
    fly_to_the_gateway(scenario, gateway, Some(netem), keep_netem_profile).await.expect("the run completes")
}

/// `run_against` the gateway at `gateway` in real time with the standard NMPC, through the
/// netem at `netem`, else one started as `hilbench run --plant` starts it.
async fn fly_to_the_gateway(
    scenario: &Scenario,
    gateway: SocketAddr,
    netem: Option<SocketAddr>,
    keep_netem_profile: bool,
) -> Result<hilbench::drive::grpc::GrpcRun, String> {
    let endpoints = Endpoints {
        plant: Some(gateway.to_string()),
        netem: netem.map(|a| a.to_string()),
        controller: None,
        time_mode: TimeMode::RealTime,
        keep_netem_profile,
        live: None,
        tls: Default::default(),
        start_from_vehicle: false,
    };
    let settings = GrpcSettings { timeout: Duration::from_secs(240), ..GrpcSettings::default() };
    run_against(scenario, ControllerMode::Nmpc, &settings, &endpoints).await.map_err(|e| format!("{e:#}"))
}

/// The vehicle mistakes a new user met: a vehicle not armed is refused before the run flies,
/// naming what to do; once armed and in OFFBOARD, a scenario whose start is away from the
/// vehicle ends at the gateway's FAILED_PRECONDITION (its Reset refused) at once, not after
/// the stall timeout, and says why.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_run_refuses_a_vehicle_not_flying_setpoints_and_ends_at_once_on_a_start_away_from_the_vehicle() {
    let scenario = Scenario::paper_2();
    let bench = start(&scenario).await;
    let addr = bench.gateway.addr;
    let mut vc = vehicle_control(addr).await;
    wait_status(&mut vc, "the vehicle's heartbeat", |s| s.link_alive).await;
    let status = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
    assert!(!status.flies_setpoints, "{status:?}");
    let refused = fly_to_the_gateway(&scenario, addr, None, false).await.map(|_| ()).expect_err("refused");
    let text = refused;
    assert!(text.contains("disarmed") && text.contains("arm-offboard"), "{text}");
    assert_eq!(bench.vehicle.autopilot().counters().refused_setpoints, 0);

    arm_and_offboard(addr).await;
    let status = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
    assert!(status.flies_setpoints, "{status:?}");
    // paper-1 starts 3.2 m from where the vehicle stands. Ended by the refusal, not by the
    // stall timeout ("no control cycle for 30 s", the failure this catches).
    let far =
        fly_to_the_gateway(&Scenario::paper_1(), addr, None, false).await.map(|_| ()).expect_err("refused");
    let text = far;
    assert!(text.contains("episode ended with an error") && text.contains("teleport"), "{text}");
    bench.gateway.stop().await.expect("gateway stops cleanly");
    bench.vehicle.stop();
}

/// The regression test of an autopilot that reboots under the gateway: its clock restarts,
/// and the gateway used to count every new state as stale and serve the last one, frozen,
/// while the heartbeat said SERVING.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_autopilot_whose_clock_restarts_makes_the_plant_api_unavailable_and_not_serving_until_a_reset() {
    let scenario = Scenario::paper_2();
    let bench = start(&scenario).await;
    let addr = bench.gateway.addr;
    let mut vc = vehicle_control(addr).await;
    let mut p = plant(addr).await;
    wait_for_state(&mut p).await;
    // Let the vehicle's clock pass 2 s, so that restarting it goes back by more than 1 s.
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while p.get_state(pb::GetStateRequest {}).await.expect("served").into_inner().time_ns < 2_000_000_000 {
        assert!(tokio::time::Instant::now() < deadline, "the vehicle's clock never passed 2 s");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    wait_health(addr, "hilbench.v1.Plant", ServingStatus::Serving).await;

    bench.vehicle.reboot().expect("reboots");
    wait_status(&mut vc, "the reboot to be counted", |s| s.autopilot_reboots == 1).await;
    let err = p.get_state(pb::GetStateRequest {}).await.expect_err("UNAVAILABLE");
    assert_eq!(err.code(), tonic::Code::Unavailable, "{err}");
    assert!(err.message().contains("rebooted") && err.message().contains("Reset"), "{err}");
    let cmd = pb::Command {
        input: Some(pb::ControlInput { thrust_mps2: 9.81, roll_rad: 0.0, pitch_rad: 0.0 }),
        ..Default::default()
    };
    assert_eq!(p.apply_command(cmd).await.map_err(|e| e.code()).err(), Some(tonic::Code::Unavailable));
    for service in ["hilbench.v1.Plant", "hilbench.v1.VehicleControl"] {
        wait_health(addr, service, ServingStatus::NotServing).await;
    }
    // The link itself is alive, and the gateway did not arm the rebooted vehicle.
    let status = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
    assert!(status.link_alive && !status.armed, "{status:?}");
    assert!(!bench.vehicle.autopilot().armed());

    // A Reset starts a new episode on the new clock: served again.
    let reset = p.reset(pb::ResetRequest::default()).await.expect("reset after the reboot").into_inner();
    let first = reset.sample.expect("the vehicle's state");
    assert_eq!((first.seq, first.time_ns), (0, 0));
    wait_health(addr, "hilbench.v1.Plant", ServingStatus::Serving).await;
    let s = wait_get_state(&mut p, tonic::Code::Ok).await.expect("served again");
    assert_eq!(s.flight_id, first.flight_id);
    assert!(s.time_ns < 2_000_000_000, "plant time restarted at the reset: {s:?}");
    let status = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
    assert_eq!(status.autopilot_reboots, 1);
    bench.gateway.stop().await.expect("gateway stops cleanly");
    bench.vehicle.stop();
}

/// The `mavsim` binary told to reboot from its command line, silent for 5 s from the reboot as
/// an autopilot booting: its clock comes back ahead of its last stamp (about 5 s against 3 s),
/// never going back, and the gateway still sees the reboot (it counted less than the silence).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mavsim_rebooting_from_its_command_line_silent_longer_than_its_uptime_is_seen_as_a_reboot() {
    let scenario = Scenario::paper_2();
    let (gateway, port) = start_gateway(&scenario).await;
    let mavlink = format!("udpout:127.0.0.1:{port}");
    let args =
        ["--mavlink", &mavlink, "--scenario", "paper-2", "--reboot-after-s", "3", "--reboot-silence-s", "5"];
    let vehicle = hilbench_tests::Service::start("mavsim", &args);
    let addr = gateway.addr;
    let mut vc = vehicle_control(addr).await;
    let mut p = plant(addr).await;
    wait_for_state(&mut p).await;
    wait_status(&mut vc, "the reboot to be counted", |s| s.autopilot_reboots == 1).await;
    // The first state after the silence shows the reboot; the heartbeat may follow it by up to
    // its 1 s period, and until then the call names the lost heartbeat instead.
    let deadline = tokio::time::Instant::now() + PATIENCE;
    let err = loop {
        let err = p.get_state(pb::GetStateRequest {}).await.expect_err("UNAVAILABLE after the reboot");
        assert_eq!(err.code(), tonic::Code::Unavailable, "{err}");
        if err.message().contains("rebooted") {
            break err;
        }
        assert!(tokio::time::Instant::now() < deadline, "the reboot never named: {err}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert!(
        err.message().contains("restarted during the silence") && err.message().contains("Reset"),
        "{err}"
    );
    let reset = p.reset(pb::ResetRequest::default()).await.expect("reset after the reboot").into_inner();
    assert_eq!(reset.sample.map(|s| (s.seq, s.time_ns)), Some((0, 0)));
    wait_get_state(&mut p, tonic::Code::Ok).await.expect("served again");
    drop(vehicle);
    gateway.stop().await.expect("gateway stops cleanly");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_vehicle_makes_the_plant_api_and_new_streams_unavailable_and_health_not_serving_until_it_talks_again_and_open_streams_resume()
 {
    let scenario = Scenario::paper_2();
    let bench = start(&scenario).await;
    let addr = bench.gateway.addr;
    let mut vc = vehicle_control(addr).await;
    wait_status(&mut vc, "the vehicle's heartbeat", |s| s.link_alive && s.heartbeat_seen).await;
    let mut p = plant(addr).await;
    wait_for_state(&mut p).await;
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while health(addr, "hilbench.v1.Plant").await != ServingStatus::Serving as i32 {
        assert!(tokio::time::Instant::now() < deadline, "never SERVING");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // A stream opened before the silence stays open through it.
    let mut open_stream =
        p.stream_state(pb::StreamStateRequest { period_ns: 0 }).await.expect("a stream").into_inner();

    bench.vehicle.set_silent(true);
    wait_status(&mut vc, "the link to be lost", |s| !s.link_alive).await;
    let err = p.get_state(pb::GetStateRequest {}).await.expect_err("UNAVAILABLE");
    assert_eq!(err.code(), tonic::Code::Unavailable, "{err}");
    assert!(err.message().contains("heartbeat"), "{err}");
    let err = p.stream_state(pb::StreamStateRequest { period_ns: 0 }).await.expect_err("UNAVAILABLE");
    assert_eq!(err.code(), tonic::Code::Unavailable, "a new StreamState: {err}");
    let cmd = pb::Command {
        input: Some(pb::ControlInput { thrust_mps2: 9.81, roll_rad: 0.0, pitch_rad: 0.0 }),
        ..Default::default()
    };
    assert_eq!(p.apply_command(cmd).await.map_err(|e| e.code()).err(), Some(tonic::Code::Unavailable));
    let deadline = tokio::time::Instant::now() + PATIENCE;
    for service in ["hilbench.v1.Plant", "hilbench.v1.VehicleControl"] {
        while health(addr, service).await != ServingStatus::NotServing as i32 {
            assert!(tokio::time::Instant::now() < deadline, "{service} never NOT_SERVING");
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
    // The vehicle talks again: served again.
    bench.vehicle.set_silent(false);
    wait_status(&mut vc, "the link to come back", |s| s.link_alive).await;
    let again = p.get_state(pb::GetStateRequest {}).await.expect("served again").into_inner();
    // The stream opened before the silence carries the samples after it.
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        use tokio_stream::StreamExt;
        let next = tokio::time::timeout_at(deadline, open_stream.next()).await;
        let sample = next.expect("a sample after the silence").expect("open").expect("a sample");
        if sample.time_ns >= again.time_ns {
            break;
        }
    }
    bench.gateway.stop().await.expect("gateway stops cleanly");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_reset_far_from_the_vehicle_and_a_mode_the_vehicle_refuses_are_failed_precondition() {
    let scenario = Scenario::paper_2();
    let bench = start(&scenario).await;
    let addr = bench.gateway.addr;
    let mut vc = vehicle_control(addr).await;
    wait_status(&mut vc, "the vehicle's state", |s| s.link_alive).await;
    let mut p = plant(addr).await;
    wait_for_state(&mut p).await;
    // paper-1 starts at the origin; the vehicle stands at paper-2's start, 3.2 m away.
    let far = p
        .reset(pb::ResetRequest { scenario: "paper-1".into(), ..Default::default() })
        .await
        .expect_err("refused");
    assert_eq!(far.code(), tonic::Code::FailedPrecondition, "{far}");
    assert!(far.message().contains("teleport"), "{far}");
    // Nothing changed: the scenario in force is still paper-2.
    let d = p.describe(pb::DescribeRequest {}).await.expect("describe").into_inner();
    assert_eq!(d.scenario, "paper-2");
    assert_eq!(d.time_mode, pb::TimeMode::RealTime as i32);
    // paper-2's own start is where the vehicle is: accepted, with the vehicle's state.
    let ok =
        p.reset(pb::ResetRequest { scenario: "paper-2".into(), ..Default::default() }).await.expect("reset");
    let sample = ok.into_inner().sample.expect("sample");
    assert_eq!((sample.seq, sample.time_ns), (0, 0));

    // A PX4 vehicle does not know ArduPilot's GUIDED_NOGPS: the COMMAND_ACK result is named.
    let refused = vc
        .set_mode(pb::SetModeRequest { mode: pb::FlightMode::ArdupilotGuidedNogps as i32 })
        .await
        .expect_err("refused");
    assert_eq!(refused.code(), tonic::Code::FailedPrecondition, "{refused}");
    assert!(refused.message().contains("MAV_RESULT_UNSUPPORTED"), "{refused}");
    // A mode left unset is the caller's error.
    let unset = vc.set_mode(pb::SetModeRequest { mode: 0 }).await.expect_err("invalid");
    assert_eq!(unset.code(), tonic::Code::InvalidArgument, "{unset}");
    // Advance is a lockstep call.
    let adv = p
        .advance(pb::AdvanceRequest { duration_ns: 1_000_000, ..Default::default() })
        .await
        .expect_err("refused");
    assert_eq!(adv.code(), tonic::Code::FailedPrecondition);
    assert!(!bench.vehicle.autopilot().armed(), "nobody asked to arm");
    // Reflection lists both services (grpcurl needs no .proto files).
    let services = reflected_services(addr).await;
    for expected in ["hilbench.v1.Plant", "hilbench.v1.VehicleControl", "grpc.health.v1.Health"] {
        assert!(services.iter().any(|s| s == expected), "{services:?} lacks {expected}");
    }
    bench.gateway.stop().await.expect("gateway stops cleanly");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn guided_nogps_is_refused_naming_guid_options_when_arducopter_would_read_the_thrust_as_a_climb_rate() {
    let scenario = Scenario::paper_2();
    for (guid_options, thrust_as_thrust) in [(0, false), (8, true)] {
        let firmware = Firmware::ArduCopter { guid_options };
        let bench = start_with(&scenario, AutopilotSettings { firmware, ..Default::default() }).await;
        let mut vc = vehicle_control(bench.gateway.addr).await;
        wait_status(&mut vc, "the ArduCopter's heartbeat", |s| s.link_alive && s.mode == "LOITER").await;
        let asked =
            vc.set_mode(pb::SetModeRequest { mode: pb::FlightMode::ArdupilotGuidedNogps as i32 }).await;
        if thrust_as_thrust {
            asked.expect("GUID_OPTIONS has bit 3: GUIDED_NOGPS is asked for and accepted");
            wait_status(&mut vc, "GUIDED_NOGPS", |s| s.mode == "GUIDED_NOGPS").await;
            assert_eq!(bench.vehicle.autopilot().mode(), mavbridge::SimMode::Offboard);
        } else {
            let refused = asked.expect_err("refused before the mode is asked for");
            assert_eq!(refused.code(), tonic::Code::FailedPrecondition, "{refused}");
            assert!(refused.message().contains("GUID_OPTIONS is 0"), "{refused}");
            assert!(refused.message().contains("climb rate"), "{refused}");
            let status = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
            assert_eq!(status.mode, "LOITER", "the mode is unchanged");
            assert_eq!(bench.vehicle.autopilot().mode(), mavbridge::SimMode::Posctl);
        }
        bench.gateway.stop().await.expect("gateway stops cleanly");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pymavlink_as_the_autopilot_sees_setpoints_at_50_hz_heartbeats_no_unasked_command_and_the_hover_hold_after_silence()
 {
    // The gateway records its link's TIMESYNC round trips (--record-link) meanwhile.
    let record = std::env::temp_dir().join(format!("gateway-record-link-{}.csv", std::process::id()));
    let path = record.clone();
    let (gateway, port) =
        start_gateway_with(&Scenario::paper_2(), None, |c| c.record_link = Some(path)).await;
    let yaw = 0.5;
    let script = tokio::task::spawn_blocking(move || {
        hilbench_tests::python::run_script(
            "autopilot_gateway.py",
            &[&port.to_string(), &yaw.to_string(), "30"],
        )
    });

    let mut vc = vehicle_control(gateway.addr).await;
    wait_status(&mut vc, "pymavlink's heartbeat", |s| s.link_alive && s.autopilot == "MAV_AUTOPILOT_PX4")
        .await;
    let mut p = plant(gateway.addr).await;
    wait_for_state(&mut p).await;
    // A controller commands at 20 Hz for a second, then falls silent.
    for k in 1..=20 {
        let cmd = pb::Command {
            input: Some(pb::ControlInput { thrust_mps2: 12.0, roll_rad: 0.1, pitch_rad: 0.0 }),
            command_seq: k,
            ..Default::default()
        };
        let applied = p.apply_command(cmd).await.expect("applied").into_inner().applied.expect("applied");
        assert!(!applied.saturated && applied.command_seq == k);
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let deadline = tokio::time::Instant::now() + PATIENCE;
    let held = loop {
        let s = p.get_state(pb::GetStateRequest {}).await.expect("state").into_inner();
        if s.watchdog_hover {
            break s;
        }
        assert!(tokio::time::Instant::now() < deadline, "the command timeout never held hover: {s:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert_eq!(
        held.last_command.as_ref().map(|c| c.command_seq),
        Some(20),
        "the last command is still reported"
    );

    let out = script.await.expect("the script's thread");
    let r: serde_json::Value = serde_json::from_str(out.trim()).expect("the script's JSON line");
    let f = |k: &str| r[k].as_f64().unwrap_or_else(|| panic!("{k} in {r}"));
    assert!(f("setpoints_per_second_min") >= 20.0, "PX4 needs >= 2 Hz, the gateway promises >= 20 Hz: {r}");
    assert_eq!(r["type_masks"], serde_json::json!([7]), "body rates ignored, attitude and thrust used: {r}");
    assert_eq!(r["targets"], serde_json::json!([[1, 1]]), "addressed to the vehicle heard: {r}");
    assert!(f("quat_norm_err_max") < 1e-6, "{r}");
    assert!(f("yaw_err_max") < 1e-5, "the yaw held is the vehicle's: {r}");
    assert!(f("thrust_min") >= 0.0 && f("thrust_max") <= 1.0, "{r}");
    // The commanded phase: T = 12 m/s^2 at hover thrust 0.5 is 0.5 * 12 / g.
    assert!(f("commanded") >= 20.0, "{r}");
    let thrust = r["commanded_thrust"].as_array().expect("thrusts");
    assert_eq!(thrust.len(), 1, "{r}");
    assert!((thrust[0].as_f64().expect("thrust") - 0.5 * 12.0 / 9.81).abs() < 1e-6, "{r}");
    assert!(f("commanded_tilt_min") > 0.09, "{r}");
    // Roll 0.1 rad in the model's frame (z up, y = -east) tilts the thrust east by sin 0.1 and
    // not north, at the vehicle's yaw (ARCHITECTURE.md, "The frames").
    let east = 0.1f64.sin();
    assert!((f("commanded_thrust_east_min") - east).abs() < 1e-5, "{r}");
    assert!((f("commanded_thrust_east_max") - east).abs() < 1e-5, "{r}");
    assert!(f("commanded_thrust_north_abs_max") < 1e-5, "{r}");
    // After the controller fell silent: level hover at hover thrust, held, and still streamed.
    assert_eq!(r["after_commanded_all_level_hover"], serde_json::json!(true), "{r}");
    assert!(f("hover_held_s") >= 1.0 && f("after_commanded") >= 20.0, "{r}");
    // The gateway's own heartbeat (an onboard controller) and TIMESYNC requests; no command.
    assert!(f("gateway_heartbeats") >= 2.0, "{r}");
    assert_eq!(r["gateway_heartbeat_types"], serde_json::json!([18]), "MAV_TYPE_ONBOARD_CONTROLLER: {r}");
    assert_eq!(r["unasked"], serde_json::json!([]), "the gateway never arms or switches unasked: {r}");
    assert!(f("timesync_requests") >= 1.0, "{r}");
    let status = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
    assert!(status.clock_offset_from_timesync, "{status:?}");
    assert!(status.watchdog_holds >= 1, "{status:?}");
    gateway.stop().await.expect("gateway stops cleanly");
    // pymavlink answered every TIMESYNC request (10 Hz while recording) over loopback.
    let trace = delay::parse_trace_file(&std::fs::read_to_string(&record).expect("--record-link's file"))
        .expect("a trace file");
    let _ = std::fs::remove_file(&record);
    assert!(trace.delays_s.len() >= 10, "{trace:?}");
    // The requests after the script stopped answering (its last second at most) may be lost.
    let answered_phase = &trace.delays_s[..trace.delays_s.len() - 10];
    assert!(answered_phase.iter().all(|d| !delay::is_lost(*d)), "{trace:?}");
    assert_eq!(trace.provenance.losses, Some(trace.losses() as u64), "{trace:?}");
    assert_eq!(trace.provenance.rate_hz, Some(10.0));
    assert!(trace.provenance.tool.as_deref().is_some_and(|t| t.contains("TIMESYNC")), "{trace:?}");
    assert!(answered_phase.iter().all(|d| *d > 0.0 && *d < 0.5), "{trace:?}");
}

/// The services a server's reflection (v1) lists.
async fn reflected_services(addr: SocketAddr) -> Vec<String> {
    use tokio_stream::StreamExt;
    use tonic_reflection::pb::v1::ServerReflectionRequest;
    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;
    let channel =
        Channel::from_shared(format!("http://{addr}")).expect("uri").connect().await.expect("connects");
    let mut client = ServerReflectionClient::new(channel);
    let request = ServerReflectionRequest {
        host: String::new(),
        message_request: Some(MessageRequest::ListServices(String::new())),
    };
    let mut answers =
        client.server_reflection_info(tokio_stream::once(request)).await.expect("reflection").into_inner();
    let answer = answers.next().await.expect("an answer").expect("ok");
    match answer.message_response {
        Some(MessageResponse::ListServicesResponse(list)) => {
            list.service.into_iter().map(|s| s.name).collect()
        }
        other => panic!("not a service list: {other:?}"),
    }
}

/// pymavlink playing a serial autopilot behind a pty (`tests/python/autopilot_serial.py`),
/// driven by lines on its stdin; its JSON events arrive on a channel.
struct SerialAutopilot {
    child: std::process::Child,
    events: std::sync::mpsc::Receiver<serde_json::Value>,
    /// The symbolic link the gateway opens: the pty behind it changes when replugged.
    link: std::path::PathBuf,
}

impl SerialAutopilot {
    fn start(dir: &std::path::Path) -> Self {
        use std::io::BufRead;
        let link = dir.join("autopilot");
        let script = hilbench_tests::python::scripts_dir().join("autopilot_serial.py");
        let mut child = std::process::Command::new(hilbench_tests::python::python())
            .arg(script)
            .arg(&link)
            .arg(PATIENCE.as_secs().to_string())
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .spawn()
            .expect("autopilot_serial.py starts");
        let stdout = child.stdout.take().expect("piped");
        let (tx, events) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in std::io::BufReader::new(stdout).lines().map_while(Result::ok) {
                let event = serde_json::from_str(&line).unwrap_or_else(|e| panic!("{line:?}: {e}"));
                if tx.send(event).is_err() {
                    return;
                }
            }
        });
        Self { child, events, link }
    }

    /// Waits (at most PATIENCE) for the event named `name`; panics on another one, but for
    /// `heard` (the gateway's heartbeat heard on a device), which may come at any time.
    fn expect(&self, name: &str) -> serde_json::Value {
        loop {
            let event =
                self.events.recv_timeout(PATIENCE).unwrap_or_else(|e| panic!("no {name:?} event: {e}"));
            if event["event"] == "heard" && name != "heard" {
                continue;
            }
            assert_eq!(event["event"], name, "{event}");
            return event;
        }
    }

    fn tell(&mut self, command: &str) {
        use std::io::Write;
        let stdin = self.child.stdin.as_mut().expect("piped");
        writeln!(stdin, "{command}").and_then(|()| stdin.flush()).expect("the script reads its stdin");
    }
}

impl Drop for SerialAutopilot {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Polls `GetState` until it answers `code` (`Ok` as `Code::Ok`); panics after PATIENCE.
async fn wait_get_state(
    p: &mut PlantClient<Channel>,
    code: tonic::Code,
) -> Result<pb::StateSample, tonic::Status> {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        let r = p.get_state(pb::GetStateRequest {}).await.map(tonic::Response::into_inner);
        if r.as_ref().map_or_else(tonic::Status::code, |_| tonic::Code::Ok) == code {
            return r;
        }
        assert!(tokio::time::Instant::now() < deadline, "GetState never answered {code:?}: last {r:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Polls the health of `service` until it is `status`; panics after PATIENCE.
async fn wait_health(addr: SocketAddr, service: &str, status: ServingStatus) {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while health(addr, service).await != status as i32 {
        assert!(tokio::time::Instant::now() < deadline, "{service} never {status:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// The regression test of a serial autopilot unplugged under the gateway (its reads then fail
/// at once, for ever; the gateway used to spin a core on them and never stop). The real
/// `gateway` binary on a pty, pymavlink on the other end.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unplugged_serial_autopilot_makes_the_gateway_unavailable_without_spinning_and_is_served_again_when_plugged_back()
 {
    // Removed on drop, also when an assertion below fails (dropped after the processes).
    let dir = hilbench_tests::TempDir::new("gateway-serial");
    let mut autopilot = SerialAutopilot::start(dir.path());
    autopilot.expect("plugged");

    let addr = hilbench_tests::free_loopback_address();
    let log = dir.path().join("gateway.log");
    let mavlink = format!("serial:{}:921600", autopilot.link.display());
    let mut gateway = hilbench_tests::Service::start_logged(
        "gateway",
        &["--listen", &addr, "--mavlink", &mavlink, "--scenario", "paper-2"],
        &log,
    );
    let addr: SocketAddr = addr.parse().expect("an address");
    let deadline = tokio::time::Instant::now() + PATIENCE;
    let mut p = loop {
        match PlantClient::connect(format!("http://{addr}")).await {
            Ok(p) => break p,
            Err(e) => assert!(tokio::time::Instant::now() < deadline, "the gateway never listened: {e}"),
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    };

    // Served over the serial line: the state, and a command that leaves as SET_ATTITUDE_TARGET.
    let sample = wait_get_state(&mut p, tonic::Code::Ok).await.expect("a state");
    let x = sample.state.as_ref().map(|s| s.x.clone()).unwrap_or_default();
    assert!(
        x.first().is_some_and(|x0| (x0 - 3.2).abs() < 1e-6),
        "paper-2's start, as the autopilot reports it: {x:?}"
    );
    wait_health(addr, "hilbench.v1.Plant", ServingStatus::Serving).await;
    let commanded = {
        let command = pb::Command {
            input: Some(pb::ControlInput { thrust_mps2: 12.0, roll_rad: 0.1, pitch_rad: 0.0 }),
            command_seq: 1,
            ..Default::default()
        };
        // Within the command timeout, until pymavlink has seen it (bounded by `expect`).
        let commanding = {
            let mut p = p.clone();
            tokio::spawn(async move {
                loop {
                    p.apply_command(command).await.expect("applied");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                }
            })
        };
        let event = tokio::task::block_in_place(|| autopilot.expect("commanded"));
        commanding.abort();
        event
    };
    assert!((commanded["thrust"].as_f64().expect("thrust") - 0.5 * 12.0 / 9.81).abs() < 1e-6, "{commanded}");
    assert_eq!(commanded["type_mask"], 7, "{commanded}");
    assert_eq!(commanded["target"], serde_json::json!([1, 1]), "{commanded}");

    // Unplugged: the pty's master closes under the gateway.
    autopilot.tell("unplug");
    tokio::task::block_in_place(|| autopilot.expect("unplugged"));
    // The heartbeat is lost (2 s), as it would be over UDP.
    let lost = wait_get_state(&mut p, tonic::Code::Unavailable).await.expect_err("UNAVAILABLE");
    assert!(lost.message().contains("heartbeat") && lost.message().contains("lost"), "{lost}");
    wait_health(addr, "hilbench.v1.Plant", ServingStatus::NotServing).await;
    wait_health(addr, "hilbench.v1.VehicleControl", ServingStatus::NotServing).await;
    // ... and the gateway waits on it rather than spinning: a spin is a whole core (100 %), an
    // idle gateway a few per cent. CPU time, not wall-clock time, is what is bounded.
    let (cpu_before, wall) = (gateway.cpu_time(), std::time::Instant::now());
    tokio::time::sleep(Duration::from_secs(3)).await;
    let (cpu, wall) = (gateway.cpu_time() - cpu_before, wall.elapsed());
    assert!(
        cpu.as_secs_f64() < 0.3 * wall.as_secs_f64(),
        "the gateway used {cpu:?} of CPU in {wall:?} with its serial device unplugged"
    );
    let mut vc = vehicle_control(addr).await;
    let status = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
    assert!(!status.link_alive && status.link_losses == 1 && status.link_reopens == 0, "{status:?}");
    assert!(status.link_error.contains("lost"), "{status:?}");

    // Plugged back in (a new pty behind the same path, as a USB autopilot re-enumerates): the
    // gateway opens it again and serves again.
    autopilot.tell("plug");
    tokio::task::block_in_place(|| autopilot.expect("plugged"));
    tokio::task::block_in_place(|| autopilot.expect("heard"));
    wait_get_state(&mut p, tonic::Code::Ok).await.expect("served again");
    wait_health(addr, "hilbench.v1.Plant", ServingStatus::Serving).await;
    let status = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
    assert!(status.link_alive && status.link_losses == 1 && status.link_reopens == 1, "{status:?}");
    assert!(status.link_error.is_empty(), "{status:?}");

    // SIGTERM stops it cleanly, and the log said why the link was lost once, not per retry.
    gateway.signal("TERM");
    let deadline = std::time::Instant::now() + PATIENCE;
    let exit = loop {
        if let Some(exit) = gateway.0.try_wait().expect("the gateway's status") {
            break exit;
        }
        assert!(std::time::Instant::now() < deadline, "the gateway ignored SIGTERM");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let log = std::fs::read_to_string(&log).expect("the gateway's log");
    assert!(exit.success(), "{exit}:\n{log}");
    // (The link's own warning; the heartbeat warning quotes the link's state once more.)
    assert_eq!(log.matches("; closed, opening it again").count(), 1, "{log}");
    assert_eq!(log.matches("open again").count(), 1, "{log}");
    autopilot.tell("quit");
}

/// The serial test's temporary directory is removed when the test fails (it was left behind).
#[test]
fn a_gateway_tests_temporary_directory_is_removed_when_the_test_panics() {
    let path = std::sync::Mutex::new(None);
    let failed = std::panic::catch_unwind(|| {
        let dir = hilbench_tests::TempDir::new("gateway-temp-guard");
        std::fs::write(dir.path().join("gateway.log"), "a log").expect("written");
        *path.lock().unwrap_or_else(std::sync::PoisonError::into_inner) = Some(dir.path().to_owned());
        panic!("a failing test");
    });
    assert!(failed.is_err());
    let path = path.into_inner().unwrap_or_else(std::sync::PoisonError::into_inner).expect("made");
    assert!(!path.exists(), "{} left behind", path.display());
}

/// `vehiclectl ARGS` against the gateway at `addr`: exit success, stdout, stderr.
async fn vehiclectl(addr: SocketAddr, args: &[&str]) -> (bool, String, String) {
    let mut command = std::process::Command::new(hilbench_tests::service_binary("vehiclectl"));
    command.args(["--gateway", &addr.to_string(), "--wait-s", "10"]).args(args);
    let out = tokio::task::spawn_blocking(move || command.output().expect("vehiclectl runs"))
        .await
        .expect("joined");
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    (out.status.success(), text(&out.stdout), text(&out.stderr))
}

/// The shell's side of VehicleControl: the `vehiclectl` binary arms the simulated PX4 and
/// switches it to OFFBOARD, reads the status back, and a mode the vehicle refuses fails the
/// command (non-zero exit) naming the `COMMAND_ACK` result.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn vehiclectl_arms_and_switches_to_offboard_reads_the_status_as_json_and_fails_naming_a_refusal() {
    let scenario = Scenario::paper_2();
    let bench = start(&scenario).await;
    let addr = bench.gateway.addr;
    let (ok, out, err) = vehiclectl(addr, &["arm-offboard"]).await;
    assert!(ok, "{out}{err}");
    assert!(
        out.contains("arm: MAV_RESULT_ACCEPTED") && out.contains("offboard: MAV_RESULT_ACCEPTED"),
        "{out}"
    );
    // The status follows the vehicle's heartbeat (1 Hz): read it until it shows the change.
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        let (ok, out, err) = vehiclectl(addr, &["status"]).await;
        assert!(ok, "{out}{err}");
        let status: serde_json::Value = serde_json::from_str(&out).unwrap_or_else(|e| panic!("{e}: {out}"));
        // Every field by its name in vehicle.proto, numbers as numbers, defaults included.
        assert_eq!(status["autopilot"], "MAV_AUTOPILOT_PX4", "{out}");
        assert!(status["setpoints_sent"].is_u64() && status["dropped_replayed"] == 0, "{out}");
        assert!(status["hover_thrust"].as_f64().is_some_and(|t| t > 0.0 && t < 1.0), "{out}");
        assert!(status["dropped_by_message"].is_object(), "{out}");
        if status["armed"] == true && status["mode"] == "OFFBOARD" {
            break;
        }
        assert!(tokio::time::Instant::now() < deadline, "never armed in OFFBOARD: {out}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // The simulated PX4 has no GUIDED_NOGPS.
    let (ok, out, err) = vehiclectl(addr, &["guided-nogps"]).await;
    assert!(!ok, "{out}{err}");
    assert!(err.contains("FailedPrecondition") && err.contains("MAV_RESULT_"), "{err}");
    {
        let a = bench.vehicle.autopilot();
        assert!(a.armed() && a.mode() == mavbridge::SimMode::Offboard);
    }
    bench.gateway.stop().await.expect("gateway stops cleanly");
}

/// The model's x of a state sample.
fn x0(s: &pb::StateSample) -> f64 {
    s.state.as_ref().expect("a state").x[0]
}

/// Runs `attacker_gateway.py` against the gateway on `port` while the test watches the
/// gateway: every state served is the vehicle's; the status never says armed, OFFBOARD or
/// rebooted; `Arm` during the attack is not answered by a forged ack; a `Reset` at the spoofed
/// position is refused. Returns the script's report and the last status.
async fn watch_an_attack(
    addr: SocketAddr,
    script_args: Vec<String>,
) -> (serde_json::Value, pb::VehicleStatus) {
    let script = tokio::task::spawn_blocking(move || {
        let args: Vec<&str> = script_args.iter().map(String::as_str).collect();
        hilbench_tests::python::run_script("attacker_gateway.py", &args)
    });
    let mut vc = vehicle_control(addr).await;
    wait_status(&mut vc, "the vehicle locked", |s| s.link_alive && s.vehicle_locked).await;
    let mut p = plant(addr).await;
    wait_for_state(&mut p).await;
    let home = x0(&p.get_state(pb::GetStateRequest {}).await.expect("state").into_inner());
    let mut arm: Option<tokio::task::JoinHandle<Result<_, tonic::Status>>> = None;
    let mut reset_refused = false;
    let mut states = 0;
    while !script.is_finished() {
        let status = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
        assert!(!status.armed && status.mode == "POSCTL", "{status:?}");
        assert_eq!((status.vehicle_system_id, status.vehicle_component_id), (1, 1), "{status:?}");
        assert_eq!(status.autopilot_reboots, 0, "{status:?}");
        if let Ok(s) = p.get_state(pb::GetStateRequest {}).await {
            let s = s.into_inner();
            assert!((x0(&s) - home).abs() < 1e-3, "served a state that is not the vehicle's: {s:?}");
            states += 1;
        }
        let attacked = status.dropped_foreign_address > 100;
        if attacked && arm.is_none() {
            let mut vc = vc.clone();
            arm = Some(tokio::spawn(async move { vc.arm(pb::ArmRequest {}).await }));
        }
        if attacked && !reset_refused {
            let mut far = Scenario::paper_2().start;
            far[0] += 40.0;
            let refused = p
                .reset(pb::ResetRequest {
                    initial_state: Some(pb::MavState { x: far.to_vec() }),
                    ..Default::default()
                })
                .await
                .expect_err("the vehicle is 40 m away from the spoofed position");
            assert_eq!(refused.code(), tonic::Code::FailedPrecondition, "{refused:?}");
            reset_refused = true;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let out = script.await.expect("the script's thread");
    let report: serde_json::Value = serde_json::from_str(out.trim()).expect("the script's JSON line");
    assert!(states > 50, "the gateway served states throughout: {states}");
    let arm = arm.expect("the attack was seen").await.expect("the Arm call's task");
    assert_eq!(
        arm.expect_err("no ack from the vehicle: the forged one is not believed").code(),
        tonic::Code::DeadlineExceeded
    );
    assert!(reset_refused);
    let status = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
    (report, status)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_attacker_on_another_port_gets_nothing_changes_nothing_and_is_counted_while_the_setpoints_stay_on_the_vehicle()
 {
    let _turn = hilbench_tests::CPU_HEAVY.lock().await;
    let (gateway, port) = start_gateway(&Scenario::paper_2()).await;
    let args = [port.to_string(), "10".into(), "2".into(), "8".into()].to_vec();
    let (r, status) = watch_an_attack(gateway.addr, args).await;
    let f = |k: &str| r[k].as_f64().unwrap_or_else(|| panic!("{k} in {r}"));
    assert_eq!(f("attacker_received"), 0.0, "nothing is sent to another address: {r}");
    assert!(f("attack_rounds") >= 100.0, "{r}");
    assert!(f("setpoints_per_second_min_during_attack") >= 20.0, "the setpoints stay on the vehicle: {r}");
    assert_eq!(r["targets"], serde_json::json!([[1, 1]]), "{r}");
    assert!(
        r["commands"].as_array().expect("commands").contains(&serde_json::json!(400)),
        "Arm reached it: {r}"
    );
    assert_eq!(status.vehicle_address, format!("127.0.0.1:{}", r["vehicle_port"]), "{status:?}");
    let rounds = f("attack_rounds") as u64;
    // Per round: junk, 2 x (position, attitude), a heartbeat, an ack, a reboot stamp, TIMESYNC.
    assert!(status.dropped_foreign_address >= 8 * rounds, "{status:?}");
    for name in ["LOCAL_POSITION_NED", "ATTITUDE", "HEARTBEAT", "COMMAND_ACK", "TIMESYNC"] {
        assert!(
            status.dropped_by_message.get(name).copied().unwrap_or(0) >= rounds - 1,
            "{name}: {status:?}"
        );
    }
    assert_eq!((status.dropped_foreign_system, status.implausible_states), (0, 0), "{status:?}");
    assert!(status.clock_offset_from_timesync, "{status:?}");
    gateway.stop().await.expect("gateway stops cleanly");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_signed_link_locks_to_the_vehicle_with_the_key_though_another_key_and_unsigned_frames_came_first() {
    let _turn = hilbench_tests::CPU_HEAVY.lock().await;
    let key = [0x5au8; 32];
    let (gateway, port) =
        start_gateway_with(&Scenario::paper_2(), Some(mavbridge::SigningKey::new(key)), |_| {}).await;
    let hex: String = key.iter().map(|b| format!("{b:02x}")).collect();
    let args = [port.to_string(), "8".into(), "0".into(), "7".into(), hex].to_vec();
    let (r, status) = watch_an_attack(gateway.addr, args).await;
    let f = |k: &str| r[k].as_f64().unwrap_or_else(|| panic!("{k} in {r}"));
    assert!(status.mavlink_signed, "{status:?}");
    assert_eq!(status.vehicle_address, format!("127.0.0.1:{}", r["vehicle_port"]), "{status:?}");
    assert_eq!(f("attacker_received"), 0.0, "{r}");
    // The vehicle's pymavlink delivers only frames signed with the key: the gateway's.
    assert!(f("setpoints_per_second_min_during_attack") >= 20.0, "{r}");
    assert!(
        status.dropped_bad_signature > 0 && status.dropped_unsigned > 0,
        "refused before the lock: {status:?}"
    );
    assert!(status.dropped_foreign_address > 0, "{status:?}");
    gateway.stop().await.expect("gateway stops cleanly");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_capture_of_signed_frames_from_before_a_gateway_restart_is_refused_as_replayed_and_never_locks_the_link()
 {
    use mavbridge::mavlink::dialects::common::{HEARTBEAT_DATA, MavAutopilot, MavMessage};
    let key = mavbridge::SigningKey::new([0x3cu8; 32]);
    // The vehicle's signed heartbeats, as an eavesdropper captured them in the seconds before
    // the gateway restarted (the vehicle was talking to the gateway that is now gone).
    let tap = std::net::UdpSocket::bind("127.0.0.1:0").expect("the eavesdropper");
    tap.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
    let heard_by_tap =
        Link::open_signed(&format!("udpout:{}", tap.local_addr().expect("bound")), 1, 1, Some(key.clone()))
            .expect("opens");
    let heartbeat = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        ..Default::default()
    });
    let mut captured = Vec::new();
    for _ in 0..5 {
        heard_by_tap.send(&heartbeat).expect("sent");
        let mut buf = [0u8; 512];
        let n = tap.recv(&mut buf).expect("captured");
        captured.push(buf[..n].to_vec());
    }
    // The gateway restarts with the same key; the replayer speaks before the vehicle does.
    tokio::time::sleep(Duration::from_millis(5)).await;
    let (gateway, port) = start_gateway_with(&Scenario::paper_2(), Some(key.clone()), |_| {}).await;
    let replayer = std::net::UdpSocket::bind("127.0.0.1:0").expect("the replayer");
    for frame in captured.iter().cycle().take(50) {
        replayer.send_to(frame, ("127.0.0.1", port)).expect("replayed");
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    let mut vc = vehicle_control(gateway.addr).await;
    wait_status(&mut vc, "the replays counted", |s| s.dropped_replayed >= 50).await;
    let status = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
    assert!(!status.vehicle_locked && status.vehicle_address.is_empty(), "locked to a replay: {status:?}");
    assert_eq!((status.dropped_bad_signature, status.dropped_unsigned), (0, 0), "{status:?}");
    // The vehicle's next heartbeats are signed after the restart: the link locks to it.
    let vehicle = Link::open_signed(&format!("udpout:127.0.0.1:{port}"), 1, 1, Some(key)).expect("opens");
    let deadline = tokio::time::Instant::now() + PATIENCE;
    let status = loop {
        vehicle.send(&heartbeat).expect("sent");
        let s = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
        if s.vehicle_locked {
            break s;
        }
        assert!(tokio::time::Instant::now() < deadline, "never locked to the vehicle: {s:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    let replayer_address = replayer.local_addr().expect("bound").to_string();
    assert!(!status.vehicle_address.is_empty() && status.vehicle_address != replayer_address, "{status:?}");
    gateway.stop().await.expect("gateway stops cleanly");
}

#[tokio::test]
async fn allow_client_limits_vehicle_control_to_the_named_certificates_and_the_refusal_names_the_certificate()
{
    use hilbench_svc::tls::TlsFiles;
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("gateway-allow-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    hilbench::commands::certs::write_dir(&dir, &[], hilbench::commands::certs::DEFAULT_DAYS)
        .expect("certificates");
    let tls = TlsFiles { ca: None, ..TlsFiles::in_dir(&dir, "gateway") }.load().expect("the gateway's TLS");
    let (gateway, _) = start_gateway_with(&Scenario::paper_2(), None, |c| {
        c.tls = tls;
        c.allow_clients = vec!["hilbench".into()];
    })
    .await;
    let client = |name: &str| {
        TlsFiles { ca: Some(dir.join("ca.pem")), client_ca: None, ..TlsFiles::in_dir(&dir, name) }
            .load()
            .expect("the client's TLS")
    };
    let connect = |tls: hilbench_svc::tls::Tls| async move {
        let channel =
            tls.endpoint(&gateway.addr.to_string()).expect("endpoint").connect().await.expect("connects");
        VehicleControlClient::new(channel)
    };
    let mut allowed = connect(client("hilbench")).await;
    allowed.get_status(pb::GetVehicleStatusRequest {}).await.expect("hilbench may");
    // The plant's certificate is from the same CA, and still may not fly.
    let mut plant_client = connect(client("plant")).await;
    let refused = plant_client.arm(pb::ArmRequest {}).await.expect_err("the plant may not arm");
    assert_eq!(refused.code(), tonic::Code::PermissionDenied, "{refused:?}");
    assert!(
        refused.message().contains("\"plant\"") && refused.message().contains("--allow-client"),
        "{refused:?}"
    );
    let refused = plant_client.get_status(pb::GetVehicleStatusRequest {}).await.expect_err("nor read");
    assert_eq!(refused.code(), tonic::Code::PermissionDenied);
    // The Plant API is not VehicleControl: the plant's certificate still reads states.
    let mut p = PlantClient::new(
        client("plant")
            .endpoint(&gateway.addr.to_string())
            .expect("endpoint")
            .connect()
            .await
            .expect("connects"),
    );
    p.describe(pb::DescribeRequest {}).await.expect("Describe is served");
    gateway.stop().await.expect("gateway stops cleanly");
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mavsim_signing_with_the_gateways_key_is_served_and_with_another_key_is_never_locked_to_and_a_run_names_the_signing()
 {
    let _turn = hilbench_tests::CPU_HEAVY.lock().await;
    let scenario = Scenario::paper_2();
    let key = mavbridge::SigningKey::new([0x21; 32]);
    for (vehicle_key, served) in [(key.clone(), true), (mavbridge::SigningKey::new([0x22; 32]), false)] {
        let (gateway, port) = start_gateway_with(&scenario, Some(key.clone()), |_| {}).await;
        let vehicle = Mavsim::start(&MavsimConfig {
            mavlink: format!("udpout:127.0.0.1:{port}"),
            scenario: scenario.clone(),
            autopilot: AutopilotSettings::default(),
            signing_key: Some(vehicle_key),
        })
        .expect("mavsim starts");
        let mut vc = vehicle_control(gateway.addr).await;
        if served {
            let mut p = plant(gateway.addr).await;
            wait_for_state(&mut p).await;
            // Its TIMESYNC answers are signed too.
            wait_status(&mut vc, "the clock offset from TIMESYNC", |s| s.clock_offset_from_timesync).await;
            let s = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
            assert!(s.mavlink_signed && s.vehicle_locked && s.dropped_bad_signature == 0, "{s:?}");
        } else {
            wait_status(&mut vc, "mavsim's frames refused", |s| s.dropped_bad_signature > 100).await;
            let s = vc.get_status(pb::GetVehicleStatusRequest {}).await.expect("status").into_inner();
            assert!(!s.vehicle_locked && !s.link_alive, "{s:?}");
            // A run says why: the signing, not a lost link.
            let text = fly_to_the_gateway(&scenario, gateway.addr, None, false)
                .await
                .map(|_| ())
                .expect_err("no run without the vehicle");
            assert!(text.contains("badly signed") && text.contains("--mavlink-signing-key"), "{text}");
        }
        vehicle.stop();
        gateway.stop().await.expect("gateway stops cleanly");
    }
}

/// Your own controller on a vehicle (`hilbench run --plant GATEWAY --controller-cmd CMD`): the
/// Python PD controller of examples/python-controller flies the simulated vehicle through
/// netem and the gateway to the goal of open-field, judged from the gateway's samples, and the
/// run names the gateway as its plant. The vehicle is then at the goal: a second run from the
/// file's start is refused (a gateway never moves its vehicle to a start), and one with
/// `--start-from-vehicle` starts where the vehicle is and flies.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_users_controller_flies_the_vehicle_behind_the_gateway_and_the_next_run_starts_from_where_it_left_it()
 {
    use hilbench::drive::external::{ExternalDriver, ExternalSettings, run_external};
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let scenario =
        hilbench::scenario_file::ScenarioFile::load(&repo.join("examples/python-controller/open-field.toml"))
            .expect("open-field.toml")
            .scenario;
    let command = format!(
        "'{}' '{}'",
        hilbench_tests::python::python().display(),
        repo.join("examples/python-controller/controller.py").display()
    );
    let bench = start(&scenario).await;
    let addr = bench.gateway.addr;
    arm_and_offboard(addr).await;
    let controller = |start_from_vehicle| ExternalDriver {
        time_mode: TimeMode::RealTime,
        settings: ExternalSettings::default(),
        plant: Some(addr.to_string()),
        start_from_vehicle,
    };
    let first =
        run_external(&scenario, &command, &controller(false)).await.map_err(|f| format!("{:#}", f.error));
    let first = first.expect("the user's controller flies the vehicle");
    assert!(first.summary.reached && !first.summary.collided, "{:?}", first.summary);
    assert!(first.plant.starts_with(gateway::service::IMPLEMENTATION), "{}", first.plant);
    {
        let autopilot = bench.vehicle.autopilot();
        let x = autopilot.sim().state();
        let d = ((x[0] - scenario.goal_m[0]).powi(2) + (x[1] - scenario.goal_m[1]).powi(2)).sqrt();
        assert!(d < 0.5, "the simulator's vehicle is {d} m from the goal: {x:?}");
    }

    let refused =
        run_external(&scenario, &command, &controller(false)).await.map(|_| ()).expect_err("refused");
    let text = format!("{:#}", refused.error);
    assert!(text.contains("teleport"), "{text}");

    let second =
        run_external(&scenario, &command, &controller(true)).await.map_err(|f| format!("{:#}", f.error));
    let second = second.expect("a run from where the vehicle is");
    assert!(second.summary.reached && !second.summary.collided, "{:?}", second.summary);
    let moved =
        (0..3).map(|i| (second.final_sample.state[i] - first.final_sample.state[i]).powi(2)).sum::<f64>();
    assert!(
        moved.sqrt() < 0.5,
        "the second run started away from the vehicle: {:?}",
        second.final_sample.state
    );
    bench.gateway.stop().await.expect("gateway stops cleanly");
    bench.vehicle.stop();
}

/// The vehicle lost mid-run (mavsim stopped: its firmware gone): the gateway still answers
/// Describe, so the run's probe of the plant asks GetState, which the gateway refuses naming
/// the lost link; the run ends with that error after the service timeout (10 s), not after the
/// 30 s stall timeout with "no control cycle" (what it did before).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_vehicle_lost_mid_run_ends_the_run_naming_the_lost_vehicle_link_not_the_stall_timeout() {
    let scenario = Scenario::paper_2();
    let bench = start(&scenario).await;
    let addr = bench.gateway.addr;
    arm_and_offboard(addr).await;
    let scenario_in_run = scenario.clone();
    let run = tokio::spawn(async move { fly_to_the_gateway(&scenario_in_run, addr, None, false).await });
    // Fly a little, then the vehicle goes.
    let mut p = plant(addr).await;
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        let s = p.get_state(pb::GetStateRequest {}).await.expect("state").into_inner();
        let x = &s.state.as_ref().expect("a state").x;
        let moved = (0..3).map(|i| (x[i] - scenario.start[i]).powi(2)).sum::<f64>().sqrt();
        if moved > 0.1 {
            break;
        }
        assert!(tokio::time::Instant::now() < deadline, "the vehicle never moved: {s:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    bench.vehicle.stop();
    let ended = tokio::time::timeout(PATIENCE, run).await.expect("the run ends").expect("the run's task");
    let text = ended.map(|r| format!("{:?}", r.summary)).expect_err("a run without its vehicle fails");
    assert!(text.contains("has not answered") && text.contains("GetState"), "{text}");
    assert!(!text.contains("no control cycle for"), "{text}");
    bench.gateway.stop().await.expect("gateway stops cleanly");
}
