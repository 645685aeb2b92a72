//! Integration test of netem's UDP mode (`netem --udp-listen --udp-forward`, the binary): the
//! MAVLink link between the simulated vehicle (`mavsim`, playing PX4) and the gateway runs
//! through it, and the controller flies paper-2 in real time over that link under the paper's
//! Gamma(12, 0.015) delay on the datagrams to the vehicle (set at run time through
//! `NetemControl.SetProfile`, each datagram on its own delay):
//! - the run reaches the goal without a collision (the gateway's samples and the simulator's
//!   own truth);
//! - the delays of the datagrams netem delivered, from their stamps (`StartTrace`/`StopTrace`),
//!   pass a Kolmogorov–Smirnov test against the Gamma;
//! - the gateway's own TIMESYNC round trips (`--record-link`) see the injected delay;
//! - a datagram from another sender than the vehicle is refused and counted.
//!
//! Every wait is bounded; no wall-clock duration is asserted.

use std::net::SocketAddr;
use std::time::Duration;

use delay::{Distribution, Ordering};
use gateway::mavsim::{Mavsim, MavsimConfig};
use gateway::{GatewayConfig, Link};
use hilbench_proto::pb;
use hilbench_proto::pb::netem_control_client::NetemControlClient;
use hilbench_tests::{Service, TempDir, free_loopback_address, server};
use mav::Scenario;
use tonic::transport::Channel;

/// Generous bound for anything that must happen "soon" on a loaded machine.
const PATIENCE: Duration = Duration::from_secs(60);

/// The paper's delay (docs/spec.md): Gamma(12, 0.015), mean 0.18 s.
const SHAPE: f64 = 12.0;
const SCALE_S: f64 = 0.015;

/// A loopback UDP port that was free a moment ago (netem binds it).
fn free_udp_port() -> u16 {
    let s = std::net::UdpSocket::bind("127.0.0.1:0").expect("a loopback UDP port");
    s.local_addr().expect("bound").port()
}

/// Connects to netem's NetemControl, retrying while the process starts.
async fn netem_control(addr: &str) -> NetemControlClient<Channel> {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        match NetemControlClient::connect(format!("http://{addr}")).await {
            Ok(c) => return c,
            Err(e) => assert!(tokio::time::Instant::now() < deadline, "netem never served {addr}: {e}"),
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// The `netem` binary forwarding datagrams from a free loopback port (returned) to `forward`,
/// without delay, and a client of its NetemControl.
async fn start_udp_netem(forward: &str) -> (Service, NetemControlClient<Channel>, String) {
    let control_addr = free_loopback_address();
    let udp_listen = format!("127.0.0.1:{}", free_udp_port());
    let args = [
        "--listen",
        &control_addr,
        "--udp-listen",
        &udp_listen,
        "--udp-forward",
        forward,
        "--profile",
        "none",
    ];
    let netem = Service::start("netem", &args);
    let control = netem_control(&control_addr).await;
    (netem, control, udp_listen)
}

async fn stats(control: &mut NetemControlClient<Channel>) -> pb::NetemStats {
    control.get_stats(pb::GetStatsRequest {}).await.expect("stats").into_inner()
}

/// The round trips (s) of a `--record-link` trace file, and how many were lost.
fn recorded_round_trips(path: &std::path::Path) -> (Vec<f64>, usize) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let entries = delay::parse_trace(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let (lost, rtts): (Vec<f64>, Vec<f64>) = entries.into_iter().partition(|d| delay::is_lost(*d));
    (rtts, lost.len())
}

fn median(xs: &[f64]) -> f64 {
    let mut v = xs.to_vec();
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Critical value of the one-sample KS test at level 0.001 (asymptotic).
fn ks_critical(n: usize) -> f64 {
    1.949 / (n as f64).sqrt()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn paper_2_over_netems_udp_link_to_mavsim_reaches_the_goal_and_the_datagrams_and_timesync_see_the_gamma_delay()
 {
    let _turn = hilbench_tests::CPU_HEAVY.lock().await;
    let scenario = Scenario::paper_2();
    let dir = TempDir::new("netem-udp");
    let link_file = dir.join("link.csv");

    // The gateway listens for MAVLink; netem forwards the vehicle's datagrams to it.
    let link = Link::open_signed("udpin:127.0.0.1:0", 255, 191, None).expect("a loopback UDP port");
    let gateway_port = link.local_addr.expect("bound").port();
    let mut config = GatewayConfig::new(format!("udpin:127.0.0.1:{gateway_port}"), scenario.clone());
    config.record_link = Some(link_file.clone());
    let gateway = server::start("gateway", move |listener, shutdown| {
        gateway::serve_with_link(listener, config, link, shutdown)
    })
    .await;

    let (_netem, mut control, udp_listen) = start_udp_netem(&format!("127.0.0.1:{gateway_port}")).await;

    let vehicle = Mavsim::start(&MavsimConfig {
        mavlink: format!("udpout:{udp_listen}"),
        scenario: scenario.clone(),
        autopilot: Default::default(),
        signing_key: None,
    })
    .expect("mavsim starts");

    // Armed and in OFFBOARD through netem (no delay yet).
    crate::gateway::arm_and_offboard(gateway.addr).await;
    let s = stats(&mut control).await;
    let udp = s.udp.clone().expect("UDP stats");
    assert!(!udp.client_address.is_empty() && udp.plant_side == "listen", "{udp:?}");
    assert_eq!(udp.listen_address, udp_listen);

    // A stranger's datagram on the listen port: refused and counted, never forwarded.
    let stranger = std::net::UdpSocket::bind("127.0.0.1:0").expect("a UDP port");
    stranger.send_to(b"not the vehicle", &udp_listen).expect("sent");

    // The paper's delay on the datagrams to the vehicle, each on its own (datagrams reorder).
    let mut gamma =
        delay::DirectionProfile::with_delay(Distribution::Gamma { shape: SHAPE, scale_s: SCALE_S }, 42);
    gamma.ordering = Ordering::Independent;
    control
        .set_profile(pb::SetProfileRequest {
            direction: pb::Direction::ControllerToPlant as i32,
            profile: Some(pb::DirectionProfile::from(&gamma)),
            preset: String::new(),
        })
        .await
        .expect("profile set at run time");
    control.start_trace(pb::StartTraceRequest {}).await.expect("trace started");

    // The controller reaches the gateway through a gRPC netem without delay: every delay of
    // this run is the UDP link's.
    let netem_config = netem::Config::new(gateway.addr.to_string())
        .with_preset("none", 42)
        .map(|c| netem::Config { time_mode: mav::TimeModeChoice::Fixed(mav::TimeMode::RealTime), ..c })
        .expect("netem config");
    let grpc_netem =
        server::start("netem", move |listener, shutdown| netem::serve(listener, netem_config, shutdown))
            .await;
    let run = crate::gateway::fly_in_real_time(&scenario, gateway.addr, grpc_netem.addr, true).await;
    let s = &run.summary;
    assert!(s.reached && !s.collided && s.min_clearance_m >= 0.0, "{s:?}");
    {
        let a = vehicle.autopilot();
        assert!(!a.sim().collided(), "{:?}", a.sim().collisions());
        assert_eq!(a.mode(), mavbridge::SimMode::Offboard);
    }

    // The delays of the datagrams delivered to the vehicle, from netem's stamps: the Gamma.
    let trace = control.stop_trace(pb::StopTraceRequest {}).await.expect("the trace").into_inner();
    let to_vehicle: Vec<f64> = trace
        .records
        .iter()
        .filter(|r| r.direction == pb::Direction::ControllerToPlant as i32 && !r.dropped)
        .map(|r| r.injected_delay_s)
        .collect();
    assert!(to_vehicle.len() > 500, "{} datagrams to the vehicle", to_vehicle.len());
    let mut sorted = to_vehicle.clone();
    sorted.sort_by(f64::total_cmp);
    let gamma_law = linkfit::Model::Gamma { shape: SHAPE, scale_s: SCALE_S };
    let d = linkfit::fit::ks_distance(&sorted, |x| gamma_law.cdf(x));
    assert!(d < ks_critical(sorted.len()), "KS D = {d} over {} datagrams", sorted.len());
    let to_gateway = trace
        .records
        .iter()
        .filter(|r| r.direction == pb::Direction::PlantToController as i32 && !r.dropped)
        .count();
    assert!(to_gateway > 500, "{to_gateway} datagrams from the vehicle");

    let s = stats(&mut control).await;
    let udp = s.udp.expect("UDP stats");
    assert_eq!(udp.refused_foreign_client, 1, "{udp:?}");
    assert_eq!((udp.refused_foreign_forward, udp.refused_no_client, udp.send_errors), (0, 0, 0), "{udp:?}");
    let c2p = s.controller_to_plant.expect("controller-to-plant stats");
    assert_eq!(c2p.dropped, 0, "{c2p:?}");
    eprintln!(
        "to the vehicle: {} datagrams, KS D {d:.4} (critical {:.4}), delay p50 {:.4} s p99 {:.4} s, release error p99 {:.1} us max {:.1} us",
        sorted.len(),
        ks_critical(sorted.len()),
        c2p.delay_p50_s,
        c2p.delay_p99_s,
        c2p.release_error_p99_s * 1e6,
        c2p.release_error_max_s * 1e6,
    );

    // The gateway's TIMESYNC round trips: the request waits out the delay to the vehicle, the
    // answer comes straight back, so they are the Gamma (median 0.175 s), not loopback's.
    grpc_netem.stop().await.expect("the gRPC netem stops cleanly");
    gateway.stop().await.expect("gateway stops cleanly");
    vehicle.stop();
    let (rtts, lost) = recorded_round_trips(&link_file);
    // Those of the arming, before the delay was set, are loopback's (a millisecond or two; the
    // Gamma puts one in 10^7 below 20 ms).
    let rtts: Vec<f64> = rtts.into_iter().filter(|r| *r > 0.02).collect();
    assert!(rtts.len() > 50, "{} round trips, {lost} lost", rtts.len());
    let gamma_median = SHAPE * SCALE_S * (1.0 - 1.0 / (9.0 * SHAPE)).powi(3);
    let m = median(&rtts);
    eprintln!(
        "TIMESYNC: {} round trips ({lost} lost), median {m:.4} s, the Gamma's {gamma_median:.4} s",
        rtts.len()
    );
    assert!(
        (m - gamma_median).abs() < 0.15 * gamma_median,
        "median round trip {m} s, the Gamma's {gamma_median} s"
    );
}

/// The refusal rules end to end on the binary: the first sender is the client, answers go
/// back to it only, and a datagram from anyone else is refused and counted.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn netems_udp_proxy_learns_its_first_sender_answers_only_it_and_refuses_a_second_sender() {
    let far = std::net::UdpSocket::bind("127.0.0.1:0").expect("a UDP port");
    let far_addr: SocketAddr = far.local_addr().expect("bound");
    let (_netem, mut control, udp_listen) = start_udp_netem(&far_addr.to_string()).await;

    let client = std::net::UdpSocket::bind("127.0.0.1:0").expect("a UDP port");
    let other = std::net::UdpSocket::bind("127.0.0.1:0").expect("a UDP port");
    for s in [&client, &other, &far] {
        s.set_read_timeout(Some(Duration::from_secs(10))).expect("timeout");
    }
    client.send_to(b"hello", &udp_listen).expect("sent");
    let mut buf = [0u8; 64];
    let (n, netem_side) = far.recv_from(&mut buf).expect("forwarded to the far side");
    assert_eq!(&buf[..n], b"hello");
    other.send_to(b"me too", &udp_listen).expect("sent");
    far.send_to(b"answer", netem_side).expect("sent");
    let (n, from) = client.recv_from(&mut buf).expect("the answer reaches the client");
    assert_eq!((&buf[..n], from.to_string()), (&b"answer"[..], udp_listen.clone()));
    let deadline = tokio::time::Instant::now() + PATIENCE;
    let udp = loop {
        let udp = stats(&mut control).await.udp.expect("UDP stats");
        if udp.refused_foreign_client == 1 {
            break udp;
        }
        assert!(tokio::time::Instant::now() < deadline, "the second sender was never refused: {udp:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert_eq!(udp.client_address, client.local_addr().expect("bound").to_string());
    // Nothing of the second sender's reached the far side.
    far.set_nonblocking(true).expect("non-blocking");
    assert!(far.recv_from(&mut buf).is_err(), "the refused datagram was forwarded");
}
