//! The MAVLink transport: UDP (`udpin:HOST:PORT` listens and answers the last sender,
//! `udpout:HOST:PORT` sends there) or a serial device (`serial:/dev/ttyACM0:921600`), with
//! the `mavlink` crate's blocking connections. Reads time out every [`RECV_TIMEOUT`] so that
//! the threads reading them notice a shutdown.

use mavbridge::mavlink::dialects::common::MavMessage;
use mavbridge::mavlink::{self, Connectable, ConnectionAddress, MavConnection, MavHeader, MavlinkVersion};
use std::sync::Arc;
use std::time::Duration;

/// How long a read waits before its thread checks whether to stop.
pub const RECV_TIMEOUT: Duration = Duration::from_millis(100);

/// Why an address cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("--mavlink {address:?}: {reason} (udpin:HOST:PORT, udpout:HOST:PORT or serial:DEVICE:BAUD)")]
    Address { address: String, reason: String },
    #[error("--mavlink {address:?}: {source}")]
    Open { address: String, source: std::io::Error },
}

/// A MAVLink 2 connection shared by a reading and a writing thread.
#[derive(Clone)]
pub struct Link {
    conn: Arc<mavlink::Connection<MavMessage>>,
    header: MavHeader,
    pub address: String,
    /// The local address of a `udpin` link (its port when it was 0).
    pub local_addr: Option<std::net::SocketAddr>,
}

/// Checks an address without opening it.
pub fn check_address(address: &str) -> Result<(), LinkError> {
    let bad = |reason: &str| Err(LinkError::Address { address: address.into(), reason: reason.into() });
    let Some((kind, rest)) = address.split_once(':') else { return bad("no transport") };
    match kind {
        "udpin" | "udpout" => match rest.rsplit_once(':').map(|(_, p)| p.parse::<u16>()) {
            Some(Ok(_)) => Ok(()),
            _ => bad("no port"),
        },
        "serial" => match rest.rsplit_once(':').map(|(_, b)| b.parse::<u32>()) {
            Some(Ok(b)) if b > 0 => Ok(()),
            _ => bad("no baud rate"),
        },
        _ => bad("unknown transport"),
    }
}

impl Link {
    /// Opens `address`; this end speaks as `(system_id, component_id)`.
    pub fn open(address: &str, system_id: u8, component_id: u8) -> Result<Self, LinkError> {
        check_address(address)?;
        let open_err = |source| LinkError::Open { address: address.into(), source };
        let mut local_addr = None;
        let parsed = match address.strip_prefix("udpin:") {
            // Bound here, so that the port is known when it was 0 (tests use ephemeral ports).
            Some(at) => {
                let socket = std::net::UdpSocket::bind(at).map_err(open_err)?;
                local_addr = Some(socket.local_addr().map_err(open_err)?);
                ConnectionAddress::Udp(
                    mavlink::UdpConfig::from_socket(socket, mavlink::UdpMode::Udpin).map_err(open_err)?,
                )
            }
            None => ConnectionAddress::parse_address(address).map_err(open_err)?,
        };
        let parsed = match parsed {
            ConnectionAddress::Udp(c) => ConnectionAddress::Udp(c.read_timeout(RECV_TIMEOUT)),
            ConnectionAddress::Serial(c) => ConnectionAddress::Serial(c.timeout(RECV_TIMEOUT)),
            other => other,
        };
        let mut conn = parsed.connect::<MavMessage>().map_err(open_err)?;
        conn.set_protocol_version(MavlinkVersion::V2);
        conn.set_allow_recv_any_version(true);
        Ok(Self {
            conn: Arc::new(conn),
            header: MavHeader { system_id: u32::from(system_id), component_id, sequence: 0 },
            address: address.into(),
            local_addr,
        })
    }

    /// Sends `msg`; an error is returned for the caller to count and log (a datagram that
    /// cannot leave is not retried: the next setpoint follows within a period).
    pub fn send(&self, msg: &MavMessage) -> Result<(), mavlink::error::MessageWriteError> {
        self.conn.send(&self.header, msg).map(|_| ())
    }

    /// The next message, or `None` when the read timed out or the frame was not one of the
    /// common dialect's. A transport that fails at once (a serial device unplugged) is retried
    /// every 10 ms rather than in a busy loop.
    pub fn recv(&self) -> Option<(MavHeader, MavMessage)> {
        use std::io::ErrorKind::{TimedOut, WouldBlock};
        match self.conn.recv() {
            Ok(m) => Some(m),
            Err(mavlink::error::MessageReadError::Io(e)) if !matches!(e.kind(), WouldBlock | TimedOut) => {
                tracing::debug!("MAVLink read on {}: {e}", self.address);
                std::thread::sleep(Duration::from_millis(10));
                None
            }
            Err(_) => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_are_checked_naming_the_flag_before_anything_opens() {
        for ok in ["udpin:0.0.0.0:14540", "udpout:127.0.0.1:14550", "serial:/dev/ttyACM0:921600"] {
            assert!(check_address(ok).is_ok(), "{ok}");
        }
        for bad in [
            "14540",
            "tcpin:0.0.0.0:5760",
            "udpin:0.0.0.0",
            "udpout:host:port",
            "serial:/dev/ttyACM0",
            "serial:/dev/x:0",
        ] {
            let e = check_address(bad).expect_err(bad).to_string();
            assert!(e.contains("--mavlink") && e.contains(bad), "{e}");
        }
    }

    #[test]
    fn an_ephemeral_udpin_port_is_known_after_opening() {
        let link = Link::open("udpin:127.0.0.1:0", 255, 191).expect("opens");
        assert!(link.local_addr.is_some_and(|a| a.port() != 0));
        assert!(link.recv().is_none(), "nothing arrived: the read times out");
    }
}
