//! The gateway's overhead on loopback at 50 Hz (BENCHMARKS.md), each path twice: with the
//! gRPC client's side (its runtime's hand-overs, the same for any server it calls) and without
//! it (the gateway's own: from bytes into its sockets to bytes out of them).
//! - command: from just before a Plant API `ApplyCommand` call, and from the client's last write
//!   of that request to its TCP socket, to the `SET_ATTITUDE_TARGET` carrying it arriving at the
//!   vehicle's UDP socket, stamped by the kernel on arrival (`SO_TIMESTAMPNS`); beside them, to
//!   the vehicle's thread woken by it (which adds that thread's wake-up, the vehicle's business);
//! - state: from a `LOCAL_POSITION_NED` leaving the vehicle's UDP socket to the Plant API sample
//!   made of it arriving in the client's TCP socket (the kernel's stamp) and in the client's
//!   `StreamState` stream.
//!
//! On loopback a write's bytes are in the receiving socket when the write returns, so the
//! client's write stamps and the kernel's read stamps bound the gateway's share. The client
//! stamps its traffic through a connector of its own ([`StampedStream`]), commands and state on
//! two connections so that each stamp belongs to one path. The "vehicle" is a plain UDP socket
//! with the `mavlink` crate's encoder, nothing of the gateway's. Run:
//! `cargo bench -p gateway --bench overhead -- [TICKS] [--multi-thread-client]`.

use gateway::{GatewayConfig, Link};
use hilbench_proto::pb;
use hilbench_proto::pb::plant_client::PlantClient;
use mavbridge::mavlink::dialects::common::{
    ATTITUDE_DATA, HEARTBEAT_DATA, LOCAL_POSITION_NED_DATA, MavAutopilot, MavMessage, MavModeFlag, MavState,
    MavType,
};
use mavbridge::mavlink::{self, MavHeader, MavlinkVersion};
use nix::sys::socket::sockopt::ReceiveTimestampns;
use nix::sys::socket::{ControlMessageOwned, MsgFlags, SockaddrStorage, recvmsg, setsockopt};
use nix::sys::time::TimeSpec;
use std::io::IoSliceMut;
use std::net::{SocketAddr, UdpSocket};
use std::os::fd::AsRawFd;
use std::pin::Pin;
use std::sync::{Arc, Mutex, mpsc};
use std::task::{Context, Poll, ready};
use std::time::{Duration, Instant, SystemTime};
use tokio::io::{AsyncRead, AsyncWrite, Interest, ReadBuf};
use tokio_stream::StreamExt;
use tonic::transport::{Channel, Endpoint, Uri};

fn encode(msg: &MavMessage, seq: u8) -> Vec<u8> {
    let mut bytes = Vec::new();
    let header = MavHeader { system_id: 1, component_id: 1, sequence: seq };
    mavlink::write_v2_msg(&mut bytes, header, msg).expect("encodes");
    bytes
}

/// The realtime clock in ns, the clock of the kernel's `SO_TIMESTAMPNS` stamps.
fn realtime_ns() -> u128 {
    SystemTime::now().duration_since(SystemTime::UNIX_EPOCH).expect("after 1970").as_nanos()
}

/// The kernel's arrival stamp (realtime, ns) in a `recvmsg`'s control messages.
fn arrival_ns(cmsgs: impl Iterator<Item = ControlMessageOwned>) -> Option<u128> {
    cmsgs.into_iter().find_map(|c| match c {
        ControlMessageOwned::ScmTimestampns(t) => {
            Some(t.tv_sec() as u128 * 1_000_000_000 + t.tv_nsec() as u128)
        }
        _ => None,
    })
}

/// What passed a [`StampedStream`], in the realtime clock's ns.
#[derive(Default)]
struct Stamps {
    /// Just before each write that wrote something.
    writes_ns: Vec<u128>,
    /// The kernel's arrival stamp of the last segment each read took (`SO_TIMESTAMPNS` on TCP).
    reads_ns: Vec<u128>,
}

/// A client's TCP connection that stamps its traffic into a shared [`Stamps`].
struct StampedStream {
    tcp: tokio::net::TcpStream,
    stamps: Arc<Mutex<Stamps>>,
}

impl AsyncRead for StampedStream {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let this = self.get_mut();
        loop {
            ready!(this.tcp.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            let fd = this.tcp.as_raw_fd();
            let read = this.tcp.try_io(Interest::READABLE, || {
                let mut iov = [IoSliceMut::new(unfilled)];
                let mut control = nix::cmsg_space!(TimeSpec);
                let msg = recvmsg::<()>(fd, &mut iov, Some(&mut control), MsgFlags::empty())?;
                Ok((msg.bytes, arrival_ns(msg.cmsgs())))
            });
            match read {
                Ok((n, stamp)) => {
                    buf.advance(n);
                    if let Some(ns) = stamp {
                        this.stamps.lock().expect("not poisoned").reads_ns.push(ns);
                    }
                    return Poll::Ready(Ok(()));
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => continue,
                Err(e) => return Poll::Ready(Err(e)),
            }
        }
    }
}

impl StampedStream {
    fn stamp_write(&self, before_ns: u128, written: &Poll<std::io::Result<usize>>) {
        if matches!(written, Poll::Ready(Ok(n)) if *n > 0) {
            self.stamps.lock().expect("not poisoned").writes_ns.push(before_ns);
        }
    }
}

impl AsyncWrite for StampedStream {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<std::io::Result<usize>> {
        let this = self.get_mut();
        let before_ns = realtime_ns();
        let written = Pin::new(&mut this.tcp).poll_write(cx, buf);
        this.stamp_write(before_ns, &written);
        written
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        let this = self.get_mut();
        let before_ns = realtime_ns();
        let written = Pin::new(&mut this.tcp).poll_write_vectored(cx, bufs);
        this.stamp_write(before_ns, &written);
        written
    }

    fn is_write_vectored(&self) -> bool {
        self.tcp.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().tcp).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.get_mut().tcp).poll_shutdown(cx)
    }
}

/// A channel to `addr` whose traffic is stamped into `stamps` (nodelay, as tonic's own
/// connector sets it).
async fn stamped_channel(
    addr: SocketAddr,
    stamps: Arc<Mutex<Stamps>>,
) -> Result<Channel, tonic::transport::Error> {
    let connector = tower::service_fn(move |_: Uri| {
        let stamps = stamps.clone();
        async move {
            let tcp = tokio::net::TcpStream::connect(addr).await?;
            tcp.set_nodelay(true)?;
            setsockopt(tcp.as_raw_fd(), ReceiveTimestampns, &true)?;
            Ok::<_, std::io::Error>(hyper_util::rt::TokioIo::new(StampedStream { tcp, stamps }))
        }
    });
    Endpoint::from_shared(format!("http://{addr}"))
        .expect("a valid URI")
        .connect_with_connector(connector)
        .await
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
    let px4 = mavbridge::mavlink::dialects::common::HEARTBEAT_DATA {
        autopilot: mavbridge::mavlink::dialects::common::MavAutopilot::MAV_AUTOPILOT_PX4,
        ..Default::default()
    };
    bridge.on_message(None, &header, &MavMessage::HEARTBEAT(px4), 0);
    bridge.on_message(
        None,
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

/// `overhead [TICKS] [--multi-thread-client]`: the client on a current-thread runtime (one
/// thread, no hand-over between the caller and the HTTP/2 connection's task), or on a
/// multi-thread one (2 workers, tokio's default here).
fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let ticks: usize = args.iter().find_map(|a| a.parse().ok()).unwrap_or(1000);
    let multi_thread = args.iter().any(|a| a == "--multi-thread-client");
    let mut builder = if multi_thread {
        let mut b = tokio::runtime::Builder::new_multi_thread();
        b.worker_threads(2);
        b
    } else {
        tokio::runtime::Builder::new_current_thread()
    };
    let client_runtime = builder.enable_all().build().expect("the client's runtime");
    println!("client runtime: {}", if multi_thread { "multi-thread, 2 workers" } else { "current-thread" });
    client_runtime.block_on(run(ticks));
}

async fn run(ticks: usize) {
    let scenario = mav::Scenario::paper_2();
    let link = Link::open("udpin:127.0.0.1:0", 255, 191).expect("a loopback UDP port");
    let gateway_udp = link.local_addr.expect("bound");
    // The gateway on a runtime of its own, as its binary's (`#[tokio::main]`), apart from the
    // client's (this one), as in two processes.
    let gateway_runtime = tokio::runtime::Runtime::new().expect("the gateway's runtime");
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("port");
    listener.set_nonblocking(true).expect("nonblocking");
    let addr = listener.local_addr().expect("address");
    let config = GatewayConfig::new(format!("udpin:{gateway_udp}"), scenario);
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = gateway_runtime.spawn(async move {
        let listener = tokio::net::TcpListener::from_std(listener).expect("a tokio listener");
        gateway::serve_with_link(listener, config, link, async {
            let _ = stopped.await;
        })
        .await
    });

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

    // The vehicle's receiving side: every SET_ATTITUDE_TARGET's thrust, the kernel's arrival
    // stamp (realtime clock, ns) and the instant the thread woke with it.
    let (tx, rx) = mpsc::channel::<(f32, u128, Instant)>();
    let receiver = vehicle.try_clone().expect("clone");
    setsockopt(receiver.as_raw_fd(), ReceiveTimestampns, &true).expect("SO_TIMESTAMPNS");
    std::thread::spawn(move || {
        let mut buf = [0u8; 512];
        let mut control = nix::cmsg_space!(TimeSpec);
        loop {
            let (n, arrived_ns) = {
                let mut iov = [IoSliceMut::new(&mut buf)];
                let Ok(msg) = recvmsg::<SockaddrStorage>(
                    receiver.as_raw_fd(),
                    &mut iov,
                    Some(&mut control),
                    MsgFlags::empty(),
                ) else {
                    return;
                };
                (msg.bytes, arrival_ns(msg.cmsgs()).expect("a kernel arrival stamp"))
            };
            let woke = Instant::now();
            let mut reader = mavlink::MavlinkReader::new(&buf[..n]);
            if let Ok((_, MavMessage::SET_ATTITUDE_TARGET(d))) =
                reader.read_message::<MavMessage>(MavlinkVersion::V2)
                && tx.send((d.thrust, arrived_ns, woke)).is_err()
            {
                return;
            }
        }
    });

    let command_stamps = Arc::new(Mutex::new(Stamps::default()));
    let state_stamps = Arc::new(Mutex::new(Stamps::default()));
    let connect = |stamps: Arc<Mutex<Stamps>>| async move {
        loop {
            if let Ok(c) = stamped_channel(addr, stamps.clone()).await {
                break PlantClient::new(c);
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    };
    let mut plant = connect(command_stamps.clone()).await;
    let mut state_plant = connect(state_stamps.clone()).await;
    let position = |k: usize| {
        MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
            time_boot_ms: 2 + k as u32 * 20,
            x: 3.2,
            ..Default::default()
        })
    };
    vehicle.send(&encode(&position(0), 2)).expect("send");
    let mut stream = loop {
        match state_plant.stream_state(pb::StreamStateRequest { period_ns: 0 }).await {
            Ok(s) => break s.into_inner(),
            Err(_) => tokio::time::sleep(Duration::from_millis(20)).await,
        }
    };
    let _first = stream.next().await;

    let mut command_ms = Vec::with_capacity(ticks);
    let mut command_own_ms = Vec::with_capacity(ticks);
    let mut command_woken_ms = Vec::with_capacity(ticks);
    let mut state_ms = Vec::with_capacity(ticks);
    let mut state_own_ms = Vec::with_capacity(ticks);
    let mut tick = tokio::time::interval(Duration::from_millis(20));
    for k in 1..=ticks {
        tick.tick().await;
        if k % 25 == 0 {
            vehicle.send(&encode(&heartbeat, k as u8)).expect("send");
        }
        // State: LOCAL_POSITION_NED out, its sample in.
        let bytes = encode(&position(k), k as u8);
        state_stamps.lock().expect("not poisoned").reads_ns.clear();
        let sent = Instant::now();
        let sent_ns = realtime_ns();
        vehicle.send(&bytes).expect("send");
        let sample = stream.next().await.expect("a sample").expect("ok");
        state_ms.push(sent.elapsed().as_secs_f64() * 1e3);
        let arrived_ns = *state_stamps.lock().expect("not poisoned").reads_ns.last().expect("a stamped read");
        state_own_ms.push(arrived_ns.saturating_sub(sent_ns) as f64 / 1e6);
        assert_eq!(sample.time_ns, k as u64 * 20_000_000, "the sample of this message");

        // Command: ApplyCommand in, its setpoint out (a thrust no other setpoint carries).
        let thrust_mps2 = 5.0 + (k % 1000) as f64 * 0.01;
        let expect = (0.5 * thrust_mps2 / 9.81) as f32;
        let cmd = pb::Command {
            input: Some(pb::ControlInput { thrust_mps2, roll_rad: 0.0, pitch_rad: 0.0 }),
            command_seq: k as u64,
            ..Default::default()
        };
        command_stamps.lock().expect("not poisoned").writes_ns.clear();
        let start = Instant::now();
        let start_ns = realtime_ns();
        plant.apply_command(cmd).await.expect("applied");
        loop {
            let (thrust, arrived_ns, woke) = rx.recv_timeout(Duration::from_secs(5)).expect("a setpoint");
            if thrust == expect {
                command_ms.push(arrived_ns.saturating_sub(start_ns) as f64 / 1e6);
                // The request's last write before its setpoint arrived: the gateway could not
                // act on it earlier.
                let written_ns = command_stamps
                    .lock()
                    .expect("not poisoned")
                    .writes_ns
                    .iter()
                    .copied()
                    .filter(|&w| w < arrived_ns)
                    .max()
                    .expect("the request was written");
                command_own_ms.push((arrived_ns - written_ns) as f64 / 1e6);
                command_woken_ms.push(woke.duration_since(start).as_secs_f64() * 1e3);
                break;
            }
        }
    }
    report("command: ApplyCommand -> SET_ATTITUDE_TARGET in the vehicle's socket (kernel stamp)", command_ms);
    report("command: ApplyCommand -> the vehicle's thread woken by it", command_woken_ms);
    report(
        "command, the gateway's own: request written -> SET_ATTITUDE_TARGET in the vehicle's socket",
        command_own_ms,
    );
    report("command, the gateway's core: Bridge::apply + Link::send -> on the socket", core_share_ms(ticks));
    report("state: LOCAL_POSITION_NED sent -> StreamState sample received", state_ms);
    report(
        "state, the gateway's own: LOCAL_POSITION_NED sent -> sample in the client's socket (kernel stamp)",
        state_own_ms,
    );
    let _ = stop.send(());
    let _ = server.await;
    gateway_runtime.shutdown_background();
}
