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
//! And on bare sockets: loss, duplication and reordering (numbered datagrams both ways, what
//! each receiver saw against netem's statistics and trace), and `--udp-plant-side forward`
//! (the vehicle at the forward address: the datagrams to it are the delayed commands).
//!
//! Every wait is bounded; no wall-clock duration is asserted but the injected delays' own.

use std::collections::BTreeMap;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering as AtomicOrdering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

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

/// The gateway flying `scenario` over `link` (opened as `mavlink` says), recording its
/// TIMESYNC round trips in `record_link`.
async fn start_gateway(
    mavlink: String,
    link: Link,
    scenario: &Scenario,
    record_link: &std::path::Path,
) -> server::Running<gateway::GatewayError> {
    let mut config = GatewayConfig::new(mavlink, scenario.clone());
    config.record_link = Some(record_link.to_path_buf());
    server::start("gateway", move |listener, shutdown| {
        gateway::serve_with_link(listener, config, link, shutdown)
    })
    .await
}

/// `mavsim` flying `scenario` as PX4 on `mavlink`, unsigned.
fn start_mavsim(mavlink: String, scenario: &Scenario) -> Mavsim {
    Mavsim::start(&MavsimConfig {
        mavlink,
        scenario: scenario.clone(),
        autopilot: Default::default(),
        signing_key: None,
    })
    .expect("mavsim starts")
}

/// The `netem` binary forwarding datagrams from a free loopback port (returned) to `forward`,
/// without delay, with `extra` flags, and a client of its NetemControl.
async fn start_udp_netem(forward: &str, extra: &[&str]) -> (Service, NetemControlClient<Channel>, String) {
    let control_addr = free_loopback_address();
    let udp_listen = format!("127.0.0.1:{}", free_udp_port());
    let mut args = vec![
        "--listen",
        &control_addr,
        "--udp-listen",
        &udp_listen,
        "--udp-forward",
        forward,
        "--profile",
        "none",
    ];
    args.extend_from_slice(extra);
    let netem = Service::start("netem", &args);
    let control = netem_control(&control_addr).await;
    (netem, control, udp_listen)
}

async fn stats(control: &mut NetemControlClient<Channel>) -> pb::NetemStats {
    control.get_stats(pb::GetStatsRequest {}).await.expect("stats").into_inner()
}

async fn set_profile(
    control: &mut NetemControlClient<Channel>,
    dir: pb::Direction,
    p: &delay::DirectionProfile,
) {
    control
        .set_profile(pb::SetProfileRequest {
            direction: dir as i32,
            profile: Some(pb::DirectionProfile::from(p)),
            preset: String::new(),
        })
        .await
        .expect("profile set at run time");
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
    let gateway = start_gateway(format!("udpin:127.0.0.1:{gateway_port}"), link, &scenario, &link_file).await;

    let (_netem, mut control, udp_listen) = start_udp_netem(&format!("127.0.0.1:{gateway_port}"), &[]).await;

    let vehicle = start_mavsim(format!("udpout:{udp_listen}"), &scenario);

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
    set_profile(&mut control, pb::Direction::ControllerToPlant, &gamma).await;
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
    let (_netem, mut control, udp_listen) = start_udp_netem(&far_addr.to_string(), &[]).await;

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

/// Datagrams a socket received, in arrival order: each one's number and when it came.
type Arrivals = Arc<Mutex<Vec<(u64, Instant)>>>;

/// Reads numbered datagrams (8 bytes, little-endian) on `socket` on a thread of its own until
/// `stop` is set; the sender of the first one is sent on `heard`; with `echo`, each goes back
/// to its sender at once.
fn receive_numbered(
    socket: &UdpSocket,
    stop: Arc<AtomicBool>,
    heard: std::sync::mpsc::Sender<SocketAddr>,
    echo: bool,
) -> (Arrivals, std::thread::JoinHandle<()>) {
    let socket = socket.try_clone().expect("a second handle of the socket");
    socket.set_read_timeout(Some(Duration::from_millis(50))).expect("timeout");
    let arrivals: Arrivals = Arc::default();
    let kept = arrivals.clone();
    let thread = std::thread::spawn(move || {
        let mut buf = [0u8; 64];
        let mut first = true;
        while !stop.load(AtomicOrdering::Relaxed) {
            let Ok((n, from)) = socket.recv_from(&mut buf) else { continue };
            let at = Instant::now();
            assert_eq!(n, 8, "a numbered datagram");
            let k = u64::from_le_bytes(buf[..8].try_into().expect("8 bytes"));
            kept.lock().expect("arrivals").push((k, at));
            if echo {
                socket.send_to(&buf[..8], from).expect("echoed");
            }
            if first {
                let _ = heard.send(from);
                first = false;
            }
        }
    });
    (arrivals, thread)
}

/// Sends datagrams numbered `0..n` to `to` from `socket`, one every `every`; when each left.
fn send_numbered(socket: &UdpSocket, to: SocketAddr, n: u64, every: Duration) -> Vec<Instant> {
    let start = Instant::now();
    (0..n)
        .map(|k| {
            let due = start + every * k as u32;
            std::thread::sleep(due.saturating_duration_since(Instant::now()));
            let at = Instant::now();
            socket.send_to(&k.to_le_bytes(), to).expect("sent");
            at
        })
        .collect()
}

/// `k` within five standard deviations of a Binomial(`n`, `p`)'s mean.
fn within_binomial(k: u64, n: u64, p: f64) -> bool {
    let (mean, sd) = (n as f64 * p, (n as f64 * p * (1.0 - p)).sqrt());
    (k as f64 - mean).abs() <= 5.0 * sd
}

/// One direction's datagrams as a receiver saw them, checked against netem's statistics and
/// trace of that direction: the same losses (datagram for datagram), duplicates arriving
/// twice, and the arrival order netem's release thread sent them in. Returns how many
/// datagrams arrived after one numbered higher (reordered).
fn check_direction(
    what: &str,
    sent: u64,
    arrivals: &[(u64, Instant)],
    stats: &pb::DirectionStats,
    records: &[&pb::TraceRecord],
    profile: &delay::DirectionProfile,
) -> usize {
    let mut seen: BTreeMap<u64, usize> = BTreeMap::new();
    for (k, _) in arrivals {
        *seen.entry(*k).or_default() += 1;
    }
    let lost: Vec<u64> = (0..sent).filter(|k| !seen.contains_key(k)).collect();
    let twice: Vec<u64> = seen.iter().filter(|(_, n)| **n == 2).map(|(k, _)| *k).collect();
    assert!(seen.values().all(|n| *n <= 2), "{what}: a datagram arrived more than twice");
    // netem's counts are what the receiver saw.
    assert_eq!(stats.sent, sent, "{what}: {stats:?}");
    assert_eq!((stats.in_flight, stats.dropped), (0, lost.len() as u64), "{what}: {stats:?}");
    assert_eq!(stats.delivered, arrivals.len() as u64, "{what}: {stats:?}");
    assert_eq!(stats.duplicated, twice.len() as u64, "{what}: {stats:?}");
    // Datagram for datagram: the trace's losses are the ones that never came, its duplicates
    // the ones that came twice.
    let mut dropped: Vec<u64> = records.iter().filter(|r| r.dropped).map(|r| r.payload_seq).collect();
    dropped.sort_unstable();
    assert_eq!(dropped, lost, "{what}: the datagrams netem dropped are those that never arrived");
    assert!(records.iter().filter(|r| r.dropped).all(|r| r.drop_reason == "loss"), "{what}");
    let mut duplicates: Vec<u64> =
        records.iter().filter(|r| r.duplicate && !r.dropped).map(|r| r.payload_seq).collect();
    duplicates.sort_unstable();
    assert_eq!(duplicates, twice, "{what}: the duplicates netem sent are those that arrived twice");
    // The counts are the profile's probabilities' (a duplicate is drawn for a delivered one).
    let delivered_once = sent - lost.len() as u64;
    assert!(
        within_binomial(lost.len() as u64, sent, profile.loss_probability),
        "{what}: {} lost",
        lost.len()
    );
    assert!(
        within_binomial(twice.len() as u64, delivered_once, profile.duplicate_probability),
        "{what}: {} duplicated of {delivered_once}",
        twice.len()
    );
    // The receiver got them in the order the release thread sent them: the j-th arrival of a
    // datagram is its copy sent j-th (actual release = scheduled + release error).
    let mut sent_at: BTreeMap<u64, Vec<i128>> = BTreeMap::new();
    for r in records.iter().filter(|r| !r.dropped) {
        sent_at
            .entry(r.payload_seq)
            .or_default()
            .push(r.release_time_ns as i128 + r.release_error_ns as i128);
    }
    sent_at.values_mut().for_each(|v| v.sort_unstable());
    let mut taken: BTreeMap<u64, usize> = BTreeMap::new();
    let order: Vec<i128> = arrivals
        .iter()
        .map(|(k, _)| {
            let j = taken.entry(*k).or_default();
            *j += 1;
            sent_at[k][*j - 1]
        })
        .collect();
    assert!(order.windows(2).all(|w| w[0] <= w[1]), "{what}: datagrams arrived out of netem's sending order");
    arrivals.windows(2).filter(|w| w[1].0 < w[0].0).count()
}

/// Loss and duplication on both directions of the UDP link, and reordering where the profile
/// lets each datagram keep its own delay: each side sends 2,000 numbered datagrams at 1 kHz,
/// and what each receiver saw is what netem's statistics count and its trace records,
/// datagram for datagram (the lost ones never arrive, the duplicated ones arrive twice),
/// in numbers a binomial interval of the profile's probabilities holds.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn netems_udp_link_loses_duplicates_and_reorders_datagrams_as_its_statistics_and_trace_say() {
    const N: u64 = 2000;
    let far = UdpSocket::bind("127.0.0.1:0").expect("a UDP port");
    let far_addr = far.local_addr().expect("bound");
    let (_netem, mut control, udp_listen) = start_udp_netem(&far_addr.to_string(), &[]).await;
    // The client is the plant (`--udp-plant-side listen`): its datagrams are samples,
    // plant_to_controller, each on its own delay (they overtake each other); the far side's
    // are commands, controller_to_plant, FIFO.
    let to_far = delay::DirectionProfile {
        delay: Distribution::Uniform { min_s: 0.005, max_s: 0.025 },
        loss_probability: 0.2,
        duplicate_probability: 0.1,
        ordering: Ordering::Independent,
        seed: 7,
    };
    let to_client = delay::DirectionProfile {
        delay: Distribution::Uniform { min_s: 0.002, max_s: 0.012 },
        loss_probability: 0.1,
        duplicate_probability: 0.2,
        ordering: Ordering::Fifo,
        seed: 8,
    };
    set_profile(&mut control, pb::Direction::PlantToController, &to_far).await;
    set_profile(&mut control, pb::Direction::ControllerToPlant, &to_client).await;
    control.start_trace(pb::StartTraceRequest {}).await.expect("trace started");

    let client = UdpSocket::bind("127.0.0.1:0").expect("a UDP port");
    let stop = Arc::new(AtomicBool::new(false));
    let (heard_tx, heard) = std::sync::mpsc::channel();
    let (at_far, far_reader) = receive_numbered(&far, stop.clone(), heard_tx.clone(), false);
    let (at_client, client_reader) = receive_numbered(&client, stop.clone(), heard_tx, false);
    let listen: SocketAddr = udp_listen.parse().expect("an address");
    let client_sender = {
        let client = client.try_clone().expect("a second handle");
        std::thread::spawn(move || send_numbered(&client, listen, N, Duration::from_millis(1)))
    };
    // The far side answers the address netem forwards from, once it has heard it.
    let netem_side = heard.recv_timeout(PATIENCE).expect("the client's datagrams reach the far side");
    let far_sender = {
        let far = far.try_clone().expect("a second handle");
        std::thread::spawn(move || send_numbered(&far, netem_side, N, Duration::from_millis(1)))
    };
    client_sender.join().expect("the client sent");
    far_sender.join().expect("the far side sent");

    // Until netem holds nothing and the receivers have what it delivered.
    let deadline = tokio::time::Instant::now() + PATIENCE;
    let s = loop {
        let s = stats(&mut control).await;
        let (p2c, c2p) =
            (s.plant_to_controller.clone().expect("stats"), s.controller_to_plant.clone().expect("stats"));
        let arrived = |a: &Arrivals| a.lock().expect("arrivals").len() as u64;
        if p2c.in_flight + c2p.in_flight == 0
            && p2c.sent == N
            && c2p.sent == N
            && arrived(&at_far) == p2c.delivered
            && arrived(&at_client) == c2p.delivered
        {
            break s;
        }
        assert!(tokio::time::Instant::now() < deadline, "the datagrams never all arrived: {s:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    // Nothing late: a quiet moment, then the receivers stop.
    tokio::time::sleep(Duration::from_millis(200)).await;
    stop.store(true, AtomicOrdering::Relaxed);
    far_reader.join().expect("the far side's reader");
    client_reader.join().expect("the client's reader");
    let trace = control.stop_trace(pb::StopTraceRequest {}).await.expect("the trace").into_inner();
    let of = |d: pb::Direction| trace.records.iter().filter(|r| r.direction == d as i32).collect::<Vec<_>>();

    let udp = s.udp.clone().expect("UDP stats");
    assert_eq!(
        (udp.refused_foreign_client, udp.refused_foreign_forward, udp.send_errors),
        (0, 0, 0),
        "{udp:?}"
    );
    let [reordered_to_far, reordered_to_client] = [
        ("to the far side", &at_far, &s.plant_to_controller, pb::Direction::PlantToController, &to_far),
        ("to the client", &at_client, &s.controller_to_plant, pb::Direction::ControllerToPlant, &to_client),
    ]
    .map(|(what, arrivals, stats, dir, profile)| {
        let arrivals = arrivals.lock().expect("arrivals");
        check_direction(what, N, &arrivals, stats.as_ref().expect("stats"), &of(dir), profile)
    });
    // Independent delays of 5-25 ms a millisecond apart overtake each other all the time;
    // FIFO never does.
    eprintln!("reordered arrivals: {reordered_to_far} to the far side, {reordered_to_client} to the client");
    assert!(reordered_to_far > N as usize / 10, "{reordered_to_far} reordered arrivals");
    assert_eq!(reordered_to_client, 0, "FIFO reordered");
}

/// `--udp-plant-side forward`: the vehicle is at the forward address (it listens; the ground
/// side speaks first), so the datagrams to it are the commands (`to_plant`) and those back
/// are the samples (`to_controller`). With a delay on the commands only, the vehicle receives
/// every datagram at least that late, and its answers come straight back; with the default
/// side it would be the other way round.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_the_plant_side_forward_the_datagrams_to_the_forward_address_are_the_delayed_commands() {
    const N: u64 = 40;
    const DELAY: Duration = Duration::from_millis(80);
    let vehicle = UdpSocket::bind("127.0.0.1:0").expect("a UDP port");
    let vehicle_addr = vehicle.local_addr().expect("bound");
    let (_netem, mut control, udp_listen) =
        start_udp_netem(&vehicle_addr.to_string(), &["--udp-plant-side", "forward"]).await;
    let commands =
        delay::DirectionProfile::with_delay(Distribution::Constant { delay_s: DELAY.as_secs_f64() }, 1);
    set_profile(&mut control, pb::Direction::ControllerToPlant, &commands).await;

    // The vehicle answers each datagram at once, to netem's forward socket it came from.
    let stop = Arc::new(AtomicBool::new(false));
    let (heard_tx, _heard) = std::sync::mpsc::channel();
    let (at_vehicle, vehicle_reader) = receive_numbered(&vehicle, stop.clone(), heard_tx.clone(), true);
    let ground = UdpSocket::bind("127.0.0.1:0").expect("a UDP port");
    let (at_ground, ground_reader) = receive_numbered(&ground, stop.clone(), heard_tx, false);
    let listen: SocketAddr = udp_listen.parse().expect("an address");
    let sent_at = send_numbered(&ground, listen, N, Duration::from_millis(20));

    let deadline = Instant::now() + PATIENCE;
    while at_ground.lock().expect("arrivals").len() < N as usize {
        assert!(Instant::now() < deadline, "{} answers of {N}", at_ground.lock().expect("arrivals").len());
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    stop.store(true, AtomicOrdering::Relaxed);
    vehicle_reader.join().expect("the vehicle's reader");
    ground_reader.join().expect("the ground's reader");
    let at_vehicle = at_vehicle.lock().expect("arrivals").clone();
    let at_ground = at_ground.lock().expect("arrivals").clone();
    assert_eq!(at_vehicle.iter().map(|a| a.0).collect::<Vec<_>>(), (0..N).collect::<Vec<_>>());
    assert_eq!(at_ground.iter().map(|a| a.0).collect::<Vec<_>>(), (0..N).collect::<Vec<_>>());
    // Commands: never before the delay (netem stamps its send time after the datagram is in).
    let to_vehicle: Vec<Duration> = at_vehicle.iter().map(|(k, at)| *at - sent_at[*k as usize]).collect();
    let back: Vec<Duration> =
        at_ground.iter().zip(&at_vehicle).map(|((_, at), (_, answered))| *at - *answered).collect();
    let median = |xs: &[Duration]| {
        let mut v = xs.to_vec();
        v.sort_unstable();
        v[v.len() / 2]
    };
    eprintln!(
        "to the vehicle: min {:?} median {:?}; back: median {:?}",
        to_vehicle.iter().min(),
        median(&to_vehicle),
        median(&back)
    );
    assert!(to_vehicle.iter().all(|d| *d >= DELAY), "a command reached the vehicle early: {to_vehicle:?}");
    // Samples: undelayed (loopback and two thread wake-ups; a loaded machine's median is well
    // under the delay).
    assert!(median(&back) < DELAY / 4, "the answers were delayed: {back:?}");

    let s = stats(&mut control).await;
    let udp = s.udp.expect("UDP stats");
    assert_eq!(udp.plant_side, "forward", "{udp:?}");
    assert_eq!(udp.client_address, ground.local_addr().expect("bound").to_string());
    let (c2p, p2c) = (s.controller_to_plant.expect("stats"), s.plant_to_controller.expect("stats"));
    assert_eq!((c2p.sent, c2p.delivered, p2c.sent, p2c.delivered), (N, N, N, N), "{c2p:?} {p2c:?}");
    assert!((c2p.delay_p50_s - DELAY.as_secs_f64()).abs() < 0.005, "{c2p:?}");
    assert!(p2c.delay_p99_s < 0.005, "{p2c:?}");
}

/// `--udp-plant-side forward` on a MAVLink link, as docs/netem.md gives it for a vehicle that
/// listens: `mavsim` waits on its port (`udpin`), the gateway speaks first (`udpout`) to
/// netem, which forwards to the vehicle. The vehicle is armed and switched to OFFBOARD through
/// it, and the gateway's TIMESYNC round trips see the delay put on the datagrams to the vehicle.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_gateway_arms_a_listening_vehicle_through_netem_with_the_plant_side_forward() {
    const DELAY_S: f64 = 0.06;
    let scenario = Scenario::paper_2();
    let dir = TempDir::new("netem-udp-forward");
    let link_file = dir.join("link.csv");
    let vehicle_port = free_udp_port();
    let vehicle = start_mavsim(format!("udpin:127.0.0.1:{vehicle_port}"), &scenario);
    let (_netem, mut control, udp_listen) =
        start_udp_netem(&format!("127.0.0.1:{vehicle_port}"), &["--udp-plant-side", "forward"]).await;
    let commands = delay::DirectionProfile::with_delay(Distribution::Constant { delay_s: DELAY_S }, 1);
    set_profile(&mut control, pb::Direction::ControllerToPlant, &commands).await;

    let link = Link::open_signed(&format!("udpout:{udp_listen}"), 255, 191, None).expect("a UDP link");
    let gateway = start_gateway(format!("udpout:{udp_listen}"), link, &scenario, &link_file).await;
    crate::gateway::arm_and_offboard(gateway.addr).await;
    // A few TIMESYNC round trips (one every 0.5 s).
    tokio::time::sleep(Duration::from_secs(3)).await;
    let s = stats(&mut control).await;
    let udp = s.udp.expect("UDP stats");
    assert_eq!((udp.plant_side.as_str(), udp.refused_no_client), ("forward", 0), "{udp:?}");
    let (c2p, p2c) = (s.controller_to_plant.expect("stats"), s.plant_to_controller.expect("stats"));
    assert!(c2p.delivered > 50 && p2c.delivered > 50, "{c2p:?} {p2c:?}");
    // The way back has no delay: its tail is the machine's scheduling (6.6 ms seen on a loaded
    // 2-core VM), far below the commands' 60 ms.
    assert!((c2p.delay_p50_s - DELAY_S).abs() < 0.005 && p2c.delay_p99_s < 0.02, "{c2p:?} {p2c:?}");
    {
        let a = vehicle.autopilot();
        assert!(a.armed() && a.mode() == mavbridge::SimMode::Offboard);
    }
    gateway.stop().await.expect("gateway stops cleanly");
    vehicle.stop();
    let (rtts, lost) = recorded_round_trips(&link_file);
    let rtts: Vec<f64> = rtts.into_iter().filter(|r| *r > 0.02).collect();
    assert!(rtts.len() >= 3, "{} round trips, {lost} lost", rtts.len());
    let m = median(&rtts);
    assert!((m - DELAY_S).abs() < 0.15 * DELAY_S, "median round trip {m} s, the delay {DELAY_S} s");
}
