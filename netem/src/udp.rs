//! netem for datagrams (`netem --udp-listen HOST:PORT --udp-forward HOST:PORT`): a UDP proxy
//! that puts a MAVLink link (or any datagram link) under the same delay lines as the gRPC
//! proxy: the same [`crate::Net`], so the same profiles per direction (every kind, traces,
//! regimes), loss, duplication, ordering, seeds and `[scenario.delays]` tables, and the same
//! `NetemControl` (run-time profiles, statistics, per-datagram deliveries with their stamps).
//!
//! Two sockets: the listen socket, where the client's datagrams arrive, and the forward socket
//! (an ephemeral port), which sends to the forward address and hears its answers. A datagram
//! is one message of its direction: drawn on the line, each copy released by the release
//! thread, which sends it (to the forward address, or back to the client) at its release.
//! The release thread only sends: what became of the copy is counted by a task
//! ([`keep_books`]), as the gRPC path counts a command in its forwarder, so that the real-time
//! thread never waits for netem's lock while a task of the runtime holds it (a normal thread
//! preempted under load kept it waiting for milliseconds: `lab load release`, BENCHMARKS.md).
//!
//! **Who may talk** ([`Peers`], pure): as any UDP proxy, netem learns its client from the first
//! datagram on the listen socket, and from then on forwards only that address's datagrams;
//! answers go back to it alone. Datagrams on the listen socket from anyone else, on the forward
//! socket from anyone but the forward address, and from the forward address before a client is
//! known (nowhere to send them) are refused and counted (`NetemStats.udp`), never forwarded;
//! the log names the first of each kind and then each power of two. A client that restarts on
//! another port needs netem restarted too (the spirit of the gateway's trust rules,
//! docs/gateway.md "Trust": the first one wins, nobody else is believed).
//!
//! Directions: the plant (the vehicle, the autopilot) is on one side ([`Side`], `--udp-plant-side`),
//! so datagrams towards it are the controller-to-plant line (`to_plant`, "commands") and
//! datagrams from it the plant-to-controller line (`to_controller`, "samples"). A datagram's
//! `payload_seq` is its number on its direction since start.

use std::net::SocketAddr;
use std::sync::Arc;

use delay::Direction;

use crate::core::{Msg, Net};
pub use crate::peers::{
    DEFAULT_MAX_HELD_BYTES, HELD_CAP_REASON, Peers, Refusal, Side, UdpConfig, UdpFlagError, parse_address,
};

/// The largest datagram: a UDP payload fits in 65,535 bytes (IPv4's is at most 65,507), so a
/// buffer this size never truncates one.
pub const MAX_DATAGRAM: usize = 65_535;

/// The UDP proxy's sockets, bound: run it with [`run`].
pub struct Sockets {
    listen: Arc<std::net::UdpSocket>,
    forward: Arc<std::net::UdpSocket>,
    pub listen_addr: SocketAddr,
}

impl Sockets {
    /// Binds the listen socket at `config.listen` and the forward socket at an ephemeral port
    /// of the forward address's family.
    pub fn bind(config: &UdpConfig) -> std::io::Result<Self> {
        let listen = std::net::UdpSocket::bind(config.listen)?;
        let any: SocketAddr = if config.forward.is_ipv4() {
            (std::net::Ipv4Addr::UNSPECIFIED, 0).into()
        } else {
            (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
        };
        let forward = std::net::UdpSocket::bind(any)?;
        // Non-blocking: the receivers are tokio's, and a send that would block (a full socket
        // buffer) is a drop, counted, rather than a stalled release thread.
        listen.set_nonblocking(true)?;
        forward.set_nonblocking(true)?;
        let listen_addr = listen.local_addr()?;
        Ok(Self { listen: Arc::new(listen), forward: Arc::new(forward), listen_addr })
    }
}

/// Forwards datagrams both ways until the returned future is dropped (netem aborts it at
/// shutdown; copies still held go with the release thread).
pub async fn run(net: Arc<Net>, sockets: Sockets, config: UdpConfig) -> std::io::Result<()> {
    net.lock().udp = Some(Peers::new(&config, sockets.listen_addr));
    let listen_rx = tokio::net::UdpSocket::from_std(sockets.listen.try_clone()?)?;
    let forward_rx = tokio::net::UdpSocket::from_std(sockets.forward.try_clone()?)?;
    let (sent_tx, sent_rx) = tokio::sync::mpsc::unbounded_channel();
    let client_side = receive(
        net.clone(),
        listen_rx,
        config.plant_side.client_to_forward(),
        Out { socket: sockets.forward.clone(), sent: sent_tx.clone() },
        ListenOrForward::Listen,
    );
    let forward_side = receive(
        net.clone(),
        forward_rx,
        config.plant_side.forward_to_client(),
        Out { socket: sockets.listen.clone(), sent: sent_tx },
        ListenOrForward::Forward,
    );
    let books = keep_books(net, sent_rx);
    tokio::try_join!(client_side, forward_side, books).map(|_| ())
}

/// A copy the release thread sent, or failed to send (where to, and why).
struct Sent {
    msg: Msg,
    bytes: u64,
    release_error_ns: i64,
    failed: Option<(SocketAddr, std::io::Error)>,
}

/// Where one direction's copies leave, and where the release thread reports them.
struct Out {
    socket: Arc<std::net::UdpSocket>,
    sent: tokio::sync::mpsc::UnboundedSender<Sent>,
}

/// Counts what the release thread sent (`delivered`, with its release error) or could not
/// (`dropped`, a send error), under netem's lock, off the real-time thread.
async fn keep_books(
    net: Arc<Net>,
    mut sent: tokio::sync::mpsc::UnboundedReceiver<Sent>,
) -> std::io::Result<()> {
    let mut batch = Vec::with_capacity(64);
    while sent.recv_many(&mut batch, 64).await > 0 {
        let mut inner = net.lock();
        for s in batch.drain(..) {
            if let Some(p) = inner.udp.as_mut() {
                p.release(s.bytes);
            }
            match s.failed {
                None => inner.delivered(&s.msg, s.release_error_ns),
                Some((to, e)) => {
                    if let Some(p) = inner.udp.as_mut() {
                        p.send_errors += 1;
                    }
                    inner.dropped(&s.msg, &format!("send to {to} failed: {e}"));
                }
            }
        }
    }
    Ok(())
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ListenOrForward {
    Listen,
    Forward,
}

/// Reads one socket: each datagram admitted by [`Peers`] goes through the line of `dir` and
/// its copies are sent from `out` at their releases.
async fn receive(
    net: Arc<Net>,
    socket: tokio::net::UdpSocket,
    dir: Direction,
    out: Out,
    side: ListenOrForward,
) -> std::io::Result<()> {
    let mut buf = vec![0u8; MAX_DATAGRAM];
    loop {
        let (n, from) = match socket.recv_from(&mut buf).await {
            Ok(r) => r,
            // An ICMP refusal of an earlier send surfaces here on some systems: not this
            // socket's failure.
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => continue,
            Err(e) => return Err(e),
        };
        let now = net.clock.now_ns();
        let mut inner = net.lock();
        let Some(peers) = inner.udp.as_mut() else { return Ok(()) };
        let admitted = match side {
            ListenOrForward::Listen => {
                let first = peers.client.is_none();
                peers.from_client(from).map(|()| {
                    if first {
                        tracing::info!(client = %from, "UDP client learned: only its datagrams are forwarded");
                    }
                    peers.forward
                })
            }
            ListenOrForward::Forward => peers.from_forward(from),
        };
        let to = match admitted {
            Ok(to) => to,
            Err(why) => {
                let count = peers.refused(why);
                if count.is_power_of_two() {
                    tracing::warn!(from = %from, refused = count, reason = ?why, client = ?peers.client, "UDP datagram refused");
                }
                continue;
            }
        };
        let payload_seq = peers.take(dir);
        let d = inner.decide(dir, now, payload_seq);
        drop(inner);
        for m in Msg::copies(&d, dir, payload_seq) {
            let bytes = n as u64;
            {
                let mut inner = net.lock();
                let held = inner.udp.as_mut().is_some_and(|p| p.hold(bytes));
                if !held {
                    let count = inner.udp.as_ref().map_or(0, |p| p.dropped_held_cap);
                    if count.is_power_of_two() {
                        tracing::warn!(dropped = count, "UDP datagram dropped: {HELD_CAP_REASON}");
                    }
                    inner.dropped(&m, HELD_CAP_REASON);
                    continue;
                }
            }
            let (socket, sent, datagram) = (out.socket.clone(), out.sent.clone(), buf[..n].to_vec());
            let action = Box::new(move |release_error_ns: i64| {
                let failed = socket.send_to(&datagram, to).err().map(|e| (to, e));
                let _ = sent.send(Sent { msg: m, bytes, release_error_ns, failed });
            });
            if net.releaser.schedule(m.release_ns, action).is_err() {
                let mut inner = net.lock();
                if let Some(p) = inner.udp.as_mut() {
                    p.release(bytes);
                }
                inner.dropped(&m, "netem is shutting down");
            }
        }
    }
}

#[cfg(test)]
mod tests;
