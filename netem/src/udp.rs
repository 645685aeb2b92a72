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

use std::net::{SocketAddr, ToSocketAddrs};
use std::sync::Arc;

use delay::Direction;

use crate::core::{Msg, Net};

/// The largest datagram: a UDP payload fits in 65,535 bytes (IPv4's is at most 65,507), so a
/// buffer this size never truncates one.
pub const MAX_DATAGRAM: usize = 65_535;

/// Which address the plant (the vehicle) is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Side {
    /// The plant is the client: it sends first, to `--udp-listen` (PX4 SITL sending to 14540,
    /// a radio's UDP bridge sending to a ground station's port).
    #[default]
    Listen,
    /// The plant is at `--udp-forward` (PX4 SITL's own port 14580, answered by whom it hears).
    Forward,
}

impl Side {
    pub fn name(self) -> &'static str {
        match self {
            Side::Listen => "listen",
            Side::Forward => "forward",
        }
    }

    /// The direction of datagrams from the client (the listen side) to the forward address.
    pub fn client_to_forward(self) -> Direction {
        match self {
            Side::Listen => Direction::PlantToController,
            Side::Forward => Direction::ControllerToPlant,
        }
    }

    /// The direction of datagrams from the forward address back to the client.
    pub fn forward_to_client(self) -> Direction {
        match self {
            Side::Listen => Direction::ControllerToPlant,
            Side::Forward => Direction::PlantToController,
        }
    }
}

/// The UDP proxy's addresses, checked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UdpConfig {
    /// Where the client's datagrams arrive (port 0: any free port, logged).
    pub listen: SocketAddr,
    /// Where they go, and whose answers go back to the client.
    pub forward: SocketAddr,
    pub plant_side: Side,
    /// Most bytes of delayed datagrams netem holds at once; a datagram past it is dropped,
    /// counted (`UdpStats.dropped_held_cap`, and as a drop with [`HELD_CAP_REASON`]).
    pub max_held_bytes: u64,
}

/// Default of [`UdpConfig::max_held_bytes`]: 64 MiB, a second of a 500 Mbit/s link held.
/// Whoever speaks first would otherwise make netem hold every delayed datagram (20,000 of
/// 60 kB at a 30 s delay took it to 1.2 GB).
pub const DEFAULT_MAX_HELD_BYTES: u64 = 64 << 20;

/// The drop reason of a datagram past [`UdpConfig::max_held_bytes`].
pub const HELD_CAP_REASON: &str = "netem holds --udp-max-held-bytes of delayed datagrams already";

/// A UDP flag that cannot be used, naming the flag.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{flag} {value:?}: {reason}")]
pub struct UdpFlagError {
    pub flag: &'static str,
    pub value: String,
    pub reason: String,
}

/// `HOST:PORT` (a name is resolved, its first address taken) of `flag`.
pub fn parse_address(flag: &'static str, value: &str) -> Result<SocketAddr, UdpFlagError> {
    let err = |reason: String| UdpFlagError { flag, value: value.to_string(), reason };
    if value.rsplit_once(':').is_none_or(|(host, port)| host.is_empty() || port.is_empty()) {
        return Err(err("expected HOST:PORT (e.g. 127.0.0.1:14540, [::1]:14540)".into()));
    }
    let mut addrs = value.to_socket_addrs().map_err(|e| err(format!("not an address: {e}")))?;
    addrs.next().ok_or_else(|| err("the name resolves to no address".into()))
}

impl UdpConfig {
    /// From the flags' values: both or neither (`None`), each `HOST:PORT`, the forward address
    /// one that can be sent to (a port, a host), and not the listen address itself.
    pub fn from_flags(
        listen: Option<&str>,
        forward: Option<&str>,
        plant_side: Side,
    ) -> Result<Option<Self>, UdpFlagError> {
        let (listen, forward) = match (listen, forward) {
            (None, None) => return Ok(None),
            (Some(l), Some(f)) => (l, f),
            (Some(l), None) => {
                return Err(UdpFlagError {
                    flag: "--udp-listen",
                    value: l.into(),
                    reason: "needs --udp-forward HOST:PORT too (where the datagrams go)".into(),
                });
            }
            (None, Some(f)) => {
                return Err(UdpFlagError {
                    flag: "--udp-forward",
                    value: f.into(),
                    reason: "needs --udp-listen HOST:PORT too (where the client's datagrams arrive)".into(),
                });
            }
        };
        let shown = forward;
        let listen = parse_address("--udp-listen", listen)?;
        let forward = parse_address("--udp-forward", forward)?;
        let err =
            |reason: &str| UdpFlagError { flag: "--udp-forward", value: shown.into(), reason: reason.into() };
        if forward.port() == 0 {
            return Err(err("port 0 is no destination: give the port datagrams go to"));
        }
        if forward.ip().is_unspecified() {
            return Err(err(
                "an unspecified host (0.0.0.0, ::) is no destination: give the host datagrams go to",
            ));
        }
        if forward == listen {
            return Err(err("is --udp-listen itself: netem would send every datagram to itself"));
        }
        Ok(Some(Self { listen, forward, plant_side, max_held_bytes: DEFAULT_MAX_HELD_BYTES }))
    }
}

/// Why a datagram was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// On the listen socket, from another address than the client's.
    ForeignClient,
    /// On the forward socket, from another address than the forward address.
    ForeignForward,
    /// From the forward address before any client was learned.
    NoClient,
}

/// Who may talk through the proxy, and what was refused. Pure: the shell says where a datagram
/// came from; nothing here reads a socket or a clock.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Peers {
    pub listen: SocketAddr,
    pub forward: SocketAddr,
    pub plant_side: Side,
    /// The client, learned from the first datagram on the listen socket.
    pub client: Option<SocketAddr>,
    pub refused_foreign_client: u64,
    pub refused_foreign_forward: u64,
    pub refused_no_client: u64,
    /// Released copies the socket did not take.
    pub send_errors: u64,
    /// Bytes of the copies held for their release now.
    pub held_bytes: u64,
    /// [`UdpConfig::max_held_bytes`].
    pub max_held_bytes: u64,
    /// Copies dropped because `held_bytes` would have passed `max_held_bytes`.
    pub dropped_held_cap: u64,
    /// Datagrams taken per direction (`Direction::index`): the next one's `payload_seq`.
    pub taken: [u64; 2],
}

impl Peers {
    /// `listen` as bound.
    pub fn new(config: &UdpConfig, listen: SocketAddr) -> Self {
        Self {
            listen,
            forward: config.forward,
            plant_side: config.plant_side,
            client: None,
            refused_foreign_client: 0,
            refused_foreign_forward: 0,
            refused_no_client: 0,
            send_errors: 0,
            held_bytes: 0,
            max_held_bytes: config.max_held_bytes,
            dropped_held_cap: 0,
            taken: [0; 2],
        }
    }

    /// A copy of `bytes` to hold until its release: taken (counted as held) when it fits
    /// under the cap, else refused and counted.
    pub fn hold(&mut self, bytes: u64) -> bool {
        if self.held_bytes.saturating_add(bytes) > self.max_held_bytes {
            self.dropped_held_cap += 1;
            return false;
        }
        self.held_bytes += bytes;
        true
    }

    /// A held copy of `bytes` left netem (sent, failed, or dropped at shutdown).
    pub fn release(&mut self, bytes: u64) {
        self.held_bytes = self.held_bytes.saturating_sub(bytes);
    }

    /// A datagram on the listen socket from `from`: taken (learning the client from the first
    /// one), or refused.
    pub fn from_client(&mut self, from: SocketAddr) -> Result<(), Refusal> {
        match self.client {
            None => {
                self.client = Some(from);
                Ok(())
            }
            Some(c) if c == from => Ok(()),
            Some(_) => {
                self.refused_foreign_client += 1;
                Err(Refusal::ForeignClient)
            }
        }
    }

    /// A datagram on the forward socket from `from`: the client to send it to, or refused.
    pub fn from_forward(&mut self, from: SocketAddr) -> Result<SocketAddr, Refusal> {
        if from != self.forward {
            self.refused_foreign_forward += 1;
            return Err(Refusal::ForeignForward);
        }
        self.client.ok_or_else(|| {
            self.refused_no_client += 1;
            Refusal::NoClient
        })
    }

    /// The count of a refusal's kind.
    pub fn refused(&self, why: Refusal) -> u64 {
        match why {
            Refusal::ForeignClient => self.refused_foreign_client,
            Refusal::ForeignForward => self.refused_foreign_forward,
            Refusal::NoClient => self.refused_no_client,
        }
    }

    /// The next `payload_seq` of `dir`.
    pub fn take(&mut self, dir: Direction) -> u64 {
        let n = self.taken[dir.index()];
        self.taken[dir.index()] += 1;
        n
    }

    /// The refusal counts start again (`NetemControl.ResetStats`); the client stays learned.
    pub fn reset_counts(&mut self) {
        self.refused_foreign_client = 0;
        self.refused_foreign_forward = 0;
        self.refused_no_client = 0;
        self.send_errors = 0;
        self.dropped_held_cap = 0;
    }
}

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
