//! The UDP proxy's pure part (`crate::udp` is its shell): its addresses checked from the flags
//! ([`UdpConfig`]), which side the plant is on ([`Side`]), and who may talk ([`Peers`]: the
//! client learned from its first datagram, everyone else refused and counted). Nothing here
//! reads a socket or a clock.

use std::net::{SocketAddr, ToSocketAddrs};

use delay::Direction;

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
