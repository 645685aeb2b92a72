//! The gateway's overhead on loopback at 50 Hz (BENCHMARKS.md):
//! - command: from just before a Plant API `ApplyCommand` call to the `SET_ATTITUDE_TARGET`
//!   carrying it arriving at the vehicle's UDP socket;
//! - state: from a `LOCAL_POSITION_NED` leaving the vehicle's UDP socket to the Plant API
//!   sample made of it arriving on a `StreamState` stream.
//!
//! Both include the loopback sockets and the gRPC client's side (an upper bound on the
//! gateway's own share). The "vehicle" is a plain UDP socket with the `mavlink` crate's
//! encoder, nothing of the gateway's. Run: `cargo bench -p gateway --bench overhead [TICKS]`.

use gateway::{GatewayConfig, Link};
use hilbench_proto::pb;
use hilbench_proto::pb::plant_client::PlantClient;
use mavbridge::mavlink::dialects::common::{
    ATTITUDE_DATA, HEARTBEAT_DATA, LOCAL_POSITION_NED_DATA, MavAutopilot, MavMessage, MavModeFlag, MavState,
    MavType,
};
use mavbridge::mavlink::{self, MavHeader, MavlinkVersion};
use std::net::UdpSocket;
use std::sync::mpsc;
use std::time::{Duration, Instant};
use tokio_stream::StreamExt;

fn encode(msg: &MavMessage, seq: u8) -> Vec<u8> {
    let mut bytes = Vec::new();
    let header = MavHeader { system_id: 1, component_id: 1, sequence: seq };
    mavlink::write_v2_msg(&mut bytes, header, msg).expect("encodes");
    bytes
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn report(what: &str, mut ms: Vec<f64>) {
    ms.sort_by(f64::total_cmp);
    println!(
        "{what}: n = {}, median {:.3} ms, p99 {:.3} ms, max {:.3} ms",
        ms.len(),
        percentile(&ms, 0.5),
        percentile(&ms, 0.99),
        ms[ms.len() - 1]
    );
}

/// The command path without gRPC: the core's `apply` (saturation, frames, thrust, stamps,
/// encoding) and the link's send, to a datagram received on loopback.
fn core_share_ms(ticks: usize) -> Vec<f64> {
    let probe = UdpSocket::bind("127.0.0.1:0").expect("probe socket");
    let out =
        Link::open(&format!("udpout:{}", probe.local_addr().expect("address")), 255, 191).expect("link");
    let mut bridge =
        mavbridge::Bridge::new(mav::Scenario::paper_2(), mavbridge::BridgeSettings::default(), 0, 1)
            .expect("valid");
    let header = MavHeader { system_id: 1, component_id: 1, sequence: 0 };
    bridge.on_message(
        &header,
        &MavMessage::ATTITUDE(ATTITUDE_DATA { time_boot_ms: 1, ..Default::default() }),
        0,
    );
    let mut buf = [0u8; 512];
    let mut ms = Vec::with_capacity(ticks);
    for k in 0..ticks {
        let input = mav::Input::new(5.0 + k as f64 * 0.001, 0.01, -0.01);
        let start = Instant::now();
        let (_, msg) = bridge.apply(input, mav::CommandMeta::default(), k as u64 * 20_000_000);
        out.send(&msg.expect("attitude known")).expect("sent");
        probe.recv(&mut buf).expect("received");
        ms.push(start.elapsed().as_secs_f64() * 1e3);
        std::thread::sleep(Duration::from_millis(20));
    }
    ms
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let ticks: usize = std::env::args().skip(1).find_map(|a| a.parse().ok()).unwrap_or(1000);
    let scenario = mav::Scenario::paper_2();
    let link = Link::open("udpin:127.0.0.1:0", 255, 191).expect("a loopback UDP port");
    let gateway_udp = link.local_addr.expect("bound");
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("port");
    let addr = listener.local_addr().expect("address");
    let config = GatewayConfig::new(format!("udpin:{gateway_udp}"), scenario);
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(gateway::serve_with_link(listener, config, link, async {
        let _ = stopped.await;
    }));

    let vehicle = UdpSocket::bind("127.0.0.1:0").expect("vehicle socket");
    vehicle.connect(gateway_udp).expect("connect");
    let heartbeat = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 6 << 16,
        mavtype: MavType::MAV_TYPE_QUADROTOR,
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        base_mode: MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED,
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    });
    let attitude = MavMessage::ATTITUDE(ATTITUDE_DATA { time_boot_ms: 1, ..Default::default() });
    vehicle.send(&encode(&heartbeat, 0)).expect("send");
    vehicle.send(&encode(&attitude, 1)).expect("send");

    // The vehicle's receiving side: every SET_ATTITUDE_TARGET's thrust and arrival.
    let (tx, rx) = mpsc::channel::<(f32, Instant)>();
    let receiver = vehicle.try_clone().expect("clone");
    std::thread::spawn(move || {
        let mut buf = [0u8; 512];
        while let Ok(n) = receiver.recv(&mut buf) {
            let at = Instant::now();
            let mut reader = mavlink::MavlinkReader::new(&buf[..n]);
            if let Ok((_, MavMessage::SET_ATTITUDE_TARGET(d))) =
                reader.read_message::<MavMessage>(MavlinkVersion::V2)
                && tx.send((d.thrust, at)).is_err()
            {
                return;
            }
        }
    });

    let mut plant = loop {
        if let Ok(c) = PlantClient::connect(format!("http://{addr}")).await {
            break c;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    };
    let position = |k: usize| {
        MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
            time_boot_ms: 2 + k as u32 * 20,
            x: 3.2,
            ..Default::default()
        })
    };
    vehicle.send(&encode(&position(0), 2)).expect("send");
    let mut stream = loop {
        match plant.stream_state(pb::StreamStateRequest { period_ns: 0 }).await {
            Ok(s) => break s.into_inner(),
            Err(_) => tokio::time::sleep(Duration::from_millis(20)).await,
        }
    };
    let _first = stream.next().await;

    let mut command_ms = Vec::with_capacity(ticks);
    let mut state_ms = Vec::with_capacity(ticks);
    let mut tick = tokio::time::interval(Duration::from_millis(20));
    for k in 1..=ticks {
        tick.tick().await;
        if k % 25 == 0 {
            vehicle.send(&encode(&heartbeat, k as u8)).expect("send");
        }
        // State: LOCAL_POSITION_NED out, its sample in.
        let sent = Instant::now();
        vehicle.send(&encode(&position(k), k as u8)).expect("send");
        let sample = stream.next().await.expect("a sample").expect("ok");
        state_ms.push(sent.elapsed().as_secs_f64() * 1e3);
        assert_eq!(sample.time_ns, k as u64 * 20_000_000, "the sample of this message");

        // Command: ApplyCommand in, its setpoint out (a thrust no other setpoint carries).
        let thrust_mps2 = 5.0 + (k % 1000) as f64 * 0.01;
        let expect = (0.5 * thrust_mps2 / 9.81) as f32;
        let cmd = pb::Command {
            input: Some(pb::ControlInput { thrust_mps2, roll_rad: 0.0, pitch_rad: 0.0 }),
            command_seq: k as u64,
            ..Default::default()
        };
        let start = Instant::now();
        plant.apply_command(cmd).await.expect("applied");
        loop {
            let (thrust, at) = rx.recv_timeout(Duration::from_secs(5)).expect("a setpoint");
            if thrust == expect {
                command_ms.push(at.duration_since(start).as_secs_f64() * 1e3);
                break;
            }
        }
    }
    report("command: ApplyCommand -> SET_ATTITUDE_TARGET on the vehicle's socket", command_ms);
    report("command, the gateway's share: Bridge::apply + Link::send -> on the socket", core_share_ms(ticks));
    report("state: LOCAL_POSITION_NED sent -> StreamState sample received", state_ms);
    let _ = stop.send(());
    let _ = server.await;
}
