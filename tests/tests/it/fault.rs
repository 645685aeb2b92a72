//! Integration tests: faults during real-time runs on loopback ports (plant, netem and the
//! controller in real time, as `hilbench run` with `time_mode = "real-time"` starts them), each
//! checking what the run's summary says of it:
//! - netem stopped and restarted on its port: held by the plant's watchdog, survived, recorded;
//! - netem frozen (SIGSTOP) for less than the controller's RPC timeout: an outage all the same,
//!   with its whole duration;
//! - the plant killed and restarted: the run fails with a plant reset, and keeps its flight
//!   before it;
//! - the controller killed: `hilbench run` writes what flew and the error, and exits 1
//!   (hilbench/tests/faults.rs).
//!
//! Every wait is bounded; the only durations asserted are lower bounds the test itself waited
//! out.

use std::net::SocketAddr;
use std::time::Duration;

use hilbench::drive::grpc::{GrpcRun, GrpcSettings, run_against};
use hilbench::drive::services::{Endpoints, netem_config};
use hilbench::run::RunFailure;
use hilbench_proto::pb;
use hilbench_proto::pb::plant_client::PlantClient;
use hilbench_tests::{Service, TempDir, free_loopback_address, start_plant, wait_for_state};
use mav::Scenario;
use mav::TimeMode;
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

/// Starts a real-time NMPC run of `scenario` against `endpoints` on a task of its own.
fn start_run(scenario: &Scenario, endpoints: Endpoints) -> JoinHandle<Result<GrpcRun, RunFailure<GrpcRun>>> {
    let scenario = scenario.clone();
    let settings = GrpcSettings { timeout: PATIENCE * 2, ..GrpcSettings::default() };
    tokio::spawn(async move { run_against(&scenario, ControllerMode::Nmpc, &settings, &endpoints).await })
}

/// What the run started by [`start_run`] returned (panics if it does not finish in time).
async fn finished(
    run: JoinHandle<Result<GrpcRun, RunFailure<GrpcRun>>>,
) -> Result<GrpcRun, RunFailure<GrpcRun>> {
    match tokio::time::timeout(PATIENCE * 3, run).await {
        Ok(Ok(r)) => r,
        Ok(Err(e)) => panic!("run task failed: {e}"),
        Err(_) => panic!("the run did not finish"),
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
        live: None,
        tls: Default::default(),
        start_from_vehicle: false,
    };
    let run = start_run(&scenario, endpoints);

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
    let run = finished(run).await.expect("the run completes after the outage");
    let s = &run.summary;
    assert!(s.reached && !s.collided, "{s:?}");
    let faults = run.faults;
    assert_eq!(faults.link_losses, 1, "one outage: {faults:?}");
    assert!(faults.longest_link_down_s >= HOLD.as_secs_f64(), "{faults:?}");
    assert!(faults.link_down_s >= faults.longest_link_down_s, "{faults:?}");
    // The first cycle after the outage starts from a sample in which the watchdog holds hover,
    // and the plant counted the time it held it (at least what the test waited).
    assert!(faults.watchdog_cycles >= 1, "{faults:?}");
    assert!(faults.watchdog_hover_s >= HOLD.as_secs_f64(), "{faults:?}");
    assert_eq!(faults.plant_resets, 0, "{faults:?}");
    let resumed = run.records.iter().position(|r| r.watchdog_hover).expect("a cycle after the outage");
    assert!(resumed > 0 && resumed + 1 < run.records.len(), "cycles before and after the outage");
    assert!(s.time_to_goal_s.is_some_and(|t| t > mav::ns_to_s(held.time_ns)), "{s:?}");

    netem.stop().await;
    plant.stop().await.expect("plant stops cleanly");
}

/// Waits until `addr` serves the Plant API and the episode has applied `commands` commands.
async fn wait_until_flying(addr: &str, commands: u64) -> pb::StateSample {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    let mut client = loop {
        match PlantClient::connect(format!("http://{addr}")).await {
            Ok(c) => break c,
            Err(e) if tokio::time::Instant::now() >= deadline => panic!("cannot connect to {addr}: {e}"),
            Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
        }
    };
    wait_for_plant(&mut client, "the episode to fly", |s| {
        s.last_command.as_ref().is_some_and(|c| !c.initial && c.command_seq >= commands)
    })
    .await
}

/// How long netem stays frozen: less than the controller's 5 s RPC timeout, so no call fails.
const FREEZE: Duration = Duration::from_secs(3);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn netem_frozen_for_3_s_is_an_outage_of_at_least_3_s_during_which_the_plant_held_hover() {
    let scenario = open_field();
    let plant = start_plant(PlantConfig::real_time(scenario.clone())).await;
    let netem_addr = free_loopback_address();
    let plant_addr = plant.addr.to_string();
    let netem = Service::start(
        "netem",
        &["--listen", &netem_addr, "--plant", &plant_addr, "--time-mode", "real-time"],
    );
    let endpoints = Endpoints {
        plant: Some(plant_addr.clone()),
        netem: Some(netem_addr),
        controller: None,
        time_mode: TimeMode::RealTime,
        keep_netem_profile: false,
        live: None,
        tls: Default::default(),
        start_from_vehicle: false,
    };
    let run = start_run(&scenario, endpoints);
    wait_until_flying(&plant_addr, 10).await;
    netem.signal("STOP");
    tokio::time::sleep(FREEZE).await;
    netem.signal("CONT");

    let run = finished(run).await.expect("the run completes after the freeze");
    let s = &run.summary;
    assert!(s.reached && !s.collided, "{s:?}");
    let faults = run.faults;
    // No call failed (the freeze is shorter than the RPC timeout), yet it is an outage: no cycle
    // completed from before the freeze to after it.
    assert_eq!(faults.link_losses, 1, "{faults:?}");
    assert!(faults.longest_link_down_s >= FREEZE.as_secs_f64(), "{faults:?}");
    // The plant's watchdog took over 500 ms after the last command and held hover until the
    // first command after the freeze.
    assert!(faults.watchdog_hover_s >= FREEZE.as_secs_f64() - 1.0, "{faults:?}");
    plant.stop().await.expect("plant stops cleanly");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_plant_killed_and_restarted_mid_run_fails_the_run_with_a_plant_reset_keeping_the_flight_before() {
    let scenario = open_field();
    let plant_addr = free_loopback_address();
    let plant_args = ["--listen", plant_addr.as_str(), "--time-mode", "real-time"];
    let plant = Service::start("plant", &plant_args);
    // netem and the controller are started by the run.
    let endpoints = Endpoints {
        plant: Some(plant_addr.clone()),
        netem: None,
        controller: None,
        time_mode: TimeMode::RealTime,
        keep_netem_profile: false,
        live: None,
        tls: Default::default(),
        start_from_vehicle: false,
    };
    let run = start_run(&scenario, endpoints);
    let flying = wait_until_flying(&plant_addr, 10).await;
    plant.signal("KILL");
    drop(plant);
    let _restarted = Service::start("plant", &plant_args);

    let failure = finished(run).await.expect_err("a run whose plant restarted must fail");
    let error = format!("{failure}");
    assert!(error.contains("the plant was reset or restarted"), "{error}");
    let partial = failure.partial.expect("the flight before the restart is kept");
    assert_eq!(partial.summary.end_reason, mpc::RunEnd::Error);
    assert!(partial.records.len() >= 10, "{} cycles", partial.records.len());
    assert_eq!(partial.faults.plant_resets, 1, "{:?}", partial.faults);
    // The reset is placed at the last sample of the first flight: after the test saw it fly, and
    // at or after its last cycle.
    let last_cycle_s = partial.records.last().map_or(0.0, |r| mav::ns_to_s(r.sample_time_ns));
    assert!(partial.faults.plant_reset_time_s >= last_cycle_s, "{:?}", partial.faults);
    assert!(last_cycle_s > 0.0 && flying.time_ns > 0);
    // Every record is of the first flight: its plant time never goes back.
    assert!(partial.records.windows(2).all(|w| w[0].sample_time_ns <= w[1].sample_time_ns));
}

/// A `hilbench` child process with its output captured.
fn hilbench(args: &[&str], env: &[(&str, &str)]) -> std::process::Child {
    std::process::Command::new(hilbench_tests::service_binary("hilbench"))
        .args(args)
        .envs(env.iter().copied())
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("hilbench starts")
}

/// Waits for `child` to exit (panics past `PATIENCE`: a hang is the failure these tests catch);
/// returns its exit code and stderr.
async fn exited(mut child: std::process::Child) -> (Option<i32>, String) {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        if let Some(status) = child.try_wait().expect("wait") {
            let mut stderr = String::new();
            if let Some(mut e) = child.stderr.take() {
                let _ = std::io::Read::read_to_string(&mut e, &mut stderr);
            }
            return (status.code(), stderr);
        }
        if tokio::time::Instant::now() >= deadline {
            let _ = child.kill();
            let mut stderr = String::new();
            if let Some(mut e) = child.stderr.take() {
                let _ = std::io::Read::read_to_string(&mut e, &mut stderr);
            }
            panic!("the process did not exit within {PATIENCE:?}; its stderr:\n{stderr}");
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

fn scenario_file(name: &str) -> String {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios").join(name).display().to_string()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_controller_killed_mid_run_is_said_to_have_gone_away_keeping_the_cycles_so_far_and_hilbench_exits_1()
 {
    let (plant, netem, controller) =
        (free_loopback_address(), free_loopback_address(), free_loopback_address());
    let _plant = Service::start("plant", &["--listen", &plant, "--time-mode", "real-time"]);
    let _netem =
        Service::start("netem", &["--listen", &netem, "--plant", &plant, "--time-mode", "real-time"]);
    let controller_process = Service::start(
        "controller",
        &["--listen", &controller, "--plant", &netem, "--time-mode", "real-time", "--no-autostart"],
    );
    let out = TempDir::new("controller-killed");
    let out_arg = out.display().to_string();
    let file = scenario_file("paper-2.toml");
    let run = hilbench(
        &[
            "run",
            &file,
            "--mode",
            "nmpc",
            "--time-mode",
            "real-time",
            "--plant",
            &plant,
            "--netem",
            &netem,
            "--controller",
            &controller,
            "--no-plots",
            "--quiet",
            "--out",
            &out_arg,
        ],
        &[],
    );
    wait_until_flying(&plant, 20).await;
    controller_process.signal("KILL");
    let (code, stderr) = exited(run).await;
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains(&format!("the controller at {controller} went away during the run")), "{stderr}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary.json"))
            .expect("JSON");
    assert!(summary["error"].as_str().is_some_and(|e| e.contains("paper-2")), "{summary:#}");
    let run = &summary["runs"][0];
    assert_eq!(run["end_reason"], "error", "{summary:#}");
    assert!(run["error"].is_string(), "{summary:#}");
    let cycles = run["cycles"].as_u64().expect("cycles");
    assert!(cycles >= 10, "{cycles} cycles");
    let csv = std::fs::read_to_string(out.join("paper-2-nmpc.csv")).expect("the per-cycle log");
    assert_eq!(csv.lines().count() as u64, cycles + 1, "a header and a row per cycle");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_panic_in_any_task_of_a_run_ends_it_with_exit_1_and_a_message_naming_it() {
    let file = scenario_file("paper-2.toml");
    for point in ["plant-command", "netem-command", "controller-cycle", "hilbench-run"] {
        let out = TempDir::new(&format!("panic-{point}"));
        let out_arg = out.display().to_string();
        let run = hilbench(
            &["run", &file, "--mode", "nmpc", "--no-plots", "--quiet", "--out", &out_arg],
            &[(hilbench_svc::INJECT_PANIC_VAR, point)],
        );
        let (code, stderr) = exited(run).await;
        assert_eq!(code, Some(1), "{point}: {stderr}");
        assert!(stderr.contains(&format!("injected panic at {point}")), "{point}: {stderr}");
        assert!(out.join("summary.json").is_file(), "{point}: no summary.json");
    }
    // A service binary whose task panics exits 1 (its clients see the link drop).
    let plant = start_plant(PlantConfig::lockstep(Scenario::paper_2())).await;
    let controller = std::process::Command::new(hilbench_tests::service_binary("controller"))
        .args([
            "--listen",
            &free_loopback_address(),
            "--plant",
            &plant.addr.to_string(),
            "--time-mode",
            "lockstep",
        ])
        .env(hilbench_svc::INJECT_PANIC_VAR, "controller-cycle")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("the controller starts");
    let (code, stderr) = exited(controller).await;
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("injected panic at controller-cycle"), "{stderr}");
    plant.stop().await.expect("plant stops cleanly");
}

/// A `hilbench run` of paper-2 (NMPC) against services started by the test, in `time_mode`,
/// writing into `out`.
fn run_against_services(
    plant: &str,
    netem: &str,
    controller: &str,
    time_mode: &str,
    out: &std::path::Path,
) -> std::process::Child {
    let file = scenario_file("paper-2.toml");
    let out_arg = out.display().to_string();
    hilbench(
        &[
            "run",
            &file,
            "--mode",
            "nmpc",
            "--time-mode",
            time_mode,
            "--plant",
            plant,
            "--netem",
            netem,
            "--controller",
            controller,
            "--no-plots",
            "--quiet",
            "--out",
            &out_arg,
        ],
        &[],
    )
}

/// The services of one run, each a process of its own, in `time_mode`.
fn services(time_mode: &str) -> ((String, String, String), (Service, Service, Service)) {
    let (plant, netem, controller) =
        (free_loopback_address(), free_loopback_address(), free_loopback_address());
    let p = Service::start("plant", &["--listen", &plant, "--time-mode", time_mode]);
    let n = Service::start("netem", &["--listen", &netem, "--plant", &plant, "--time-mode", time_mode]);
    let c = Service::start(
        "controller",
        &["--listen", &controller, "--plant", &netem, "--time-mode", time_mode, "--no-autostart"],
    );
    ((plant, netem, controller), (p, n, c))
}

/// summary.json of `out`: its first run's cycles (at least 10 flew) and error.
fn partial_run_of(out: &std::path::Path) -> (u64, String) {
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary.json"))
            .expect("JSON");
    let run = &summary["runs"][0];
    let cycles = run["cycles"].as_u64().unwrap_or_else(|| panic!("no run kept: {summary:#}"));
    assert!(cycles >= 10, "{cycles} cycles: {summary:#}");
    (cycles, run["error"].as_str().unwrap_or_default().to_string())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_frozen_controller_ends_a_lockstep_run_naming_it_frozen_and_keeping_the_flight_so_far() {
    let ((plant, netem, controller), (_p, _n, controller_process)) = services("lockstep");
    let out = TempDir::new("controller-frozen");
    let run = run_against_services(&plant, &netem, &controller, "lockstep", &out);
    wait_until_flying(&plant, 20).await;
    // A paused VM, a deadlock: the process stays, its socket open, and answers nothing.
    controller_process.signal("STOP");
    let (code, stderr) = exited(run).await;
    controller_process.signal("CONT");
    assert_eq!(code, Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!("the controller at {controller} did not answer"))
            && stderr.contains("frozen"),
        "{stderr}"
    );
    let (_, error) = partial_run_of(&out);
    assert!(error.contains("frozen"), "{error}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_netem_killed_mid_run_ends_it_naming_netem_not_after_the_stall_timeout() {
    let ((plant, netem, controller), (_p, netem_process, _c)) = services("real-time");
    let out = TempDir::new("netem-killed");
    let run = run_against_services(&plant, &netem, &controller, "real-time", &out);
    wait_until_flying(&plant, 20).await;
    netem_process.signal("KILL");
    let (code, stderr) = exited(run).await;
    assert_eq!(code, Some(1), "{stderr}");
    // Named by the driver's own probe, not the 30 s stall check's "no control cycle".
    assert!(stderr.contains(&format!("the netem at {netem} has not answered for")), "{stderr}");
    assert!(!stderr.contains("no control cycle"), "{stderr}");
    partial_run_of(&out);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ctrl_c_mid_run_writes_the_flight_so_far_as_interrupted_and_exits_130() {
    let ((plant, netem, controller), _services) = services("real-time");
    let out = TempDir::new("ctrl-c-mid-run");
    let run = run_against_services(&plant, &netem, &controller, "real-time", &out);
    wait_until_flying(&plant, 20).await;
    let pid = run.id().to_string();
    let signalled = std::process::Command::new("kill").args(["-INT", &pid]).status().expect("kill runs");
    assert!(signalled.success());
    let (code, stderr) = exited(run).await;
    assert_eq!(code, Some(130), "{stderr}");
    let (_, error) = partial_run_of(&out);
    assert!(error.contains("interrupted (Ctrl-C)"), "{error}");
}
