//! Integration tests: faults.
//! A real-time run on loopback ports (plant, netem and the controller in real time, as
//! `hilbench run` with `time_mode = "real-time"` starts them) in which netem goes away mid-run
//! and comes back on the same port: the plant's watchdog holds hover while no command arrives,
//! the controller reports the lost link and flies on when netem is back, and the run's summary
//! records the fault. Every wait is bounded; the only duration asserted is a lower bound the
//! test itself waited out.

use std::net::SocketAddr;
use std::time::Duration;

use hilbench::grpc::{Endpoints, GrpcSettings, TimeMode, netem_config, run_against};
use hilbench_proto::pb;
use hilbench_proto::pb::plant_client::PlantClient;
use hilbench_tests::{start_plant, wait_for_state};
use mav::Scenario;
use mpc::ControllerMode;
use plant::PlantConfig;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tonic::transport::Channel;

/// Generous bound for anything that must happen "soon" on a loaded machine.
const PATIENCE: Duration = Duration::from_secs(120);

/// How long netem stays away after the plant's watchdog has taken over.
const HOLD: Duration = Duration::from_millis(500);

/// paper-2 without its cylinders: the drift while nobody controls the vehicle cannot hit
/// anything, so the run must reach the goal without a collision.
fn open_field() -> Scenario {
    let mut s = Scenario::by_name("paper-2").expect("built in");
    s.name = "fault-open-field".into();
    s.obstacles.clear();
    s
}

struct Netem {
    stop: oneshot::Sender<()>,
    task: JoinHandle<Result<(), netem::NetemError>>,
}

impl Netem {
    /// Serves netem on `listener` in real time, with `scenario`'s delays, in front of `plant`.
    fn serve(listener: tokio::net::TcpListener, plant: SocketAddr, scenario: &Scenario) -> Self {
        let config = netem_config(&plant.to_string(), scenario, TimeMode::RealTime).expect("netem config");
        let (stop, stopped) = oneshot::channel::<()>();
        let task = tokio::spawn(netem::serve(listener, config, async {
            let _ = stopped.await;
        }));
        Self { stop, task }
    }

    async fn stop(self) {
        let _ = self.stop.send(());
        match tokio::time::timeout(PATIENCE, self.task).await {
            Ok(Ok(r)) => r.expect("netem served cleanly"),
            Ok(Err(e)) => panic!("netem task failed: {e}"),
            Err(_) => panic!("netem did not stop within {PATIENCE:?}"),
        }
    }
}

/// Binds `addr` (retried while the port is in transition after the old listener closed).
async fn bind(addr: SocketAddr) -> tokio::net::TcpListener {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        match tokio::net::TcpListener::bind(addr).await {
            Ok(l) => return l,
            Err(e) if tokio::time::Instant::now() >= deadline => panic!("cannot bind {addr}: {e}"),
            Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
        }
    }
}

/// Polls the plant's state every 20 ms until `pred` holds.
async fn wait_for_plant(
    client: &mut PlantClient<Channel>,
    what: &str,
    pred: impl Fn(&pb::StateSample) -> bool,
) -> pb::StateSample {
    wait_for_state(client, what, PATIENCE, Duration::from_millis(20), pred).await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn netem_going_away_mid_run_is_held_by_the_watchdog_survived_and_recorded() {
    let scenario = open_field();
    let plant = start_plant(PlantConfig::real_time(scenario.clone())).await;
    let listener = bind("127.0.0.1:0".parse().expect("address")).await;
    let netem_addr = listener.local_addr().expect("netem address");
    let netem = Netem::serve(listener, plant.addr, &scenario);

    // The controller is started by the run (in real time, idle until the run's request).
    let endpoints = Endpoints {
        plant: Some(plant.addr.to_string()),
        netem: Some(netem_addr.to_string()),
        controller: None,
        time_mode: TimeMode::RealTime,
        keep_netem_profile: false,
    };
    let run = tokio::spawn({
        let scenario = scenario.clone();
        async move {
            run_against(&scenario, ControllerMode::Nmpc, &GrpcSettings { timeout: PATIENCE * 2 }, &endpoints)
                .await
        }
    });

    // Mid-run: the episode has applied commands (the first sample of a plant reports its
    // initial input), and the vehicle has not reached the goal 5 m away.
    let mut client = match PlantClient::connect(format!("http://{}", plant.addr)).await {
        Ok(c) => c,
        Err(e) => panic!("cannot connect to the plant: {e}"),
    };
    let flying = wait_for_plant(&mut client, "the episode to fly", |s| {
        s.last_command.as_ref().is_some_and(|c| !c.initial && c.command_seq >= 10)
    })
    .await;
    assert!(!flying.watchdog_hover, "commands arrive: {flying:?}");
    netem.stop().await;

    // No command gets through: the plant's watchdog takes over and holds hover.
    let held = wait_for_plant(&mut client, "the watchdog to hold hover", |s| s.watchdog_hover).await;
    let input = held.last_command.as_ref().and_then(|c| c.input.as_ref()).expect("last command");
    assert!(input.thrust_mps2.is_finite());
    tokio::time::sleep(HOLD).await;

    // netem comes back on the same port; the controller finds it and finishes the episode.
    let netem = Netem::serve(bind(netem_addr).await, plant.addr, &scenario);
    let run = match tokio::time::timeout(PATIENCE * 3, run).await {
        Ok(Ok(r)) => r.expect("the run completes after the outage"),
        Ok(Err(e)) => panic!("run task failed: {e}"),
        Err(_) => panic!("the run did not finish"),
    };
    let s = &run.summary;
    assert!(s.reached && !s.collided, "{s:?}");
    let faults = run.faults;
    assert_eq!(faults.link_losses, 1, "one outage: {faults:?}");
    assert!(faults.longest_link_down_s >= HOLD.as_secs_f64(), "{faults:?}");
    assert!(faults.link_down_s >= faults.longest_link_down_s, "{faults:?}");
    // The first cycle after the outage starts from a sample in which the watchdog holds hover.
    assert!(faults.watchdog_cycles >= 1, "{faults:?}");
    let resumed = run.records.iter().position(|r| r.watchdog_hover).expect("a cycle after the outage");
    assert!(resumed > 0 && resumed + 1 < run.records.len(), "cycles before and after the outage");
    assert!(s.time_to_goal_s.is_some_and(|t| t > mav::ns_to_s(held.time_ns)), "{s:?}");

    netem.stop().await;
    plant.stop().await.expect("plant stops cleanly");
}
