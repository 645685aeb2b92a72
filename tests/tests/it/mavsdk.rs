//! PX4's own client library against `mavsim`: MAVSDK (the `mavsdk` wheel from PyPI and the
//! `mavsdk_server` it ships, tests/python/mavsdk_mavsim.py) connects to the simulated vehicle,
//! reads its telemetry, arms it, flies OFFBOARD attitude setpoints, leaves OFFBOARD and
//! disarms. So the PX4 imitation is checked by the library PX4 ships for it, not only by the
//! gateway and pymavlink. Every wait is bounded (in the script, 20 s a step, 120 s in all).

use std::net::{TcpListener, UdpSocket};

use gateway::mavsim::{Mavsim, MavsimConfig};
use mav::Scenario;
use mavbridge::{AutopilotSettings, SimMode};

/// A port free on loopback now (bound and released: the script's `mavsdk_server` binds it).
fn free_udp_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0").expect("a loopback UDP port").local_addr().expect("bound").port()
}

fn free_tcp_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").expect("a loopback TCP port").local_addr().expect("bound").port()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn px4s_own_sdk_mavsdk_arms_mavsim_flies_offboard_attitude_and_reads_its_telemetry() {
    let scenario = Scenario::paper_1();
    let (udp, grpc) = (free_udp_port(), free_tcp_port());
    // mavsim as its binary runs by default (udpout to PX4 SITL's offboard port, here an
    // ephemeral one), MAVSDK listening there as a companion computer's does.
    let vehicle = Mavsim::start(&MavsimConfig {
        mavlink: format!("udpout:127.0.0.1:{udp}"),
        scenario: scenario.clone(),
        autopilot: AutopilotSettings::default(),
        signing_key: None,
    })
    .expect("mavsim starts");
    let address = format!("udpin://127.0.0.1:{udp}");
    let out = tokio::task::spawn_blocking(move || {
        hilbench_tests::python::run_script("mavsdk_mavsim.py", &[&address, &grpc.to_string()])
    })
    .await
    .expect("the script's thread");
    let line = out.lines().last().unwrap_or_default();
    let r: serde_json::Value = serde_json::from_str(line).expect("the script's JSON line");
    let f = |k: &str| r[k].as_f64().unwrap_or_else(|| panic!("{k} in {r}"));

    // MAVSDK saw the vehicle as PX4 shows itself: disarmed in POSCTL, OFFBOARD once asked
    // (after a setpoint), HOLD when offboard stopped, disarmed at the end.
    assert_eq!(r["armed_at_start"], serde_json::json!(false), "{r}");
    assert_eq!(r["mode_at_start"], "POSCTL", "{r}");
    assert_eq!(r["mode_offboard"], "OFFBOARD", "{r}");
    assert_eq!(r["mode_after_stop"], "HOLD", "{r}");
    assert_eq!(r["disarmed"], serde_json::json!(true), "{r}");
    // Its telemetry followed its setpoints: roll 5 deg (the model's first-order attitude is
    // there within 2 s), level pitch, a climb at thrust 0.6 over a hover of 0.5, drifting east
    // (NED roll right).
    assert!((f("roll_deg") - 5.0).abs() < 1.0, "{r}");
    assert!(f("pitch_deg").abs() < 1.0, "{r}");
    assert!(f("climbed_m") > 0.2, "{r}");
    assert!(f("east_m") > 0.0, "{r}");

    // The simulator's truth agrees: MAVSDK's setpoints arrived and flew, OFFBOARD was left by
    // the request (HOLD), not by the loss failsafe, and the vehicle is disarmed above its start.
    let a = vehicle.autopilot();
    let counters = a.counters();
    assert!(counters.setpoints >= 20, "MAVSDK repeats the setpoint (20 Hz): {counters:?}");
    assert_eq!(counters.refused_setpoints, 0, "{counters:?}");
    assert_eq!(counters.offboard_failsafes, 0, "{counters:?}");
    assert!(!a.armed(), "disarmed");
    assert_eq!(a.mode(), SimMode::Hold);
    let z = a.sim().state()[2];
    assert!(z > scenario.start[2] + 0.2, "the model climbed: z = {z}, start {:?}", scenario.start);
    drop(a);
    vehicle.stop();
}
