//! The MAVLink transport: UDP (`udpin:HOST:PORT` listens and answers the last sender,
//! `udpout:HOST:PORT` sends there, with the `mavlink` crate's blocking connection) or a serial
//! device (`serial:/dev/ttyACM0:921600`, opened here with `serialport`). Reads time out every
//! [`RECV_TIMEOUT`] so that the threads reading them notice a shutdown.
//!
//! A serial device can go away under the gateway: a USB autopilot pulled out, or rebooting
//! (PX4 re-enumerates its USB port when it reboots). Its reads then fail at once and for ever
//! (hang-up, `EIO`, end of file), so a loop that read on would spin a core. The link closes the
//! device instead, says why once (a warning), counts the loss, and opens the same path again,
//! waiting [`REOPEN_BACKOFF_MIN`] doubling to [`REOPEN_BACKOFF_MAX`] between attempts, until
//! the device is back (a `/dev/serial/by-id/...` name survives the re-enumeration). Meanwhile no
//! heartbeat arrives, and the service's heartbeat timeout makes the Plant API `UNAVAILABLE`.
//! The `mavlink` crate's own serial connection is not used: it retries every read error but
//! end of file inside `recv`, so a hung-up device spins there and a quiet one never returns.

use mavbridge::mavlink::dialects::common::MavMessage;
use mavbridge::mavlink::error::{MessageReadError, MessageWriteError};
use mavbridge::mavlink::{
    self, Connectable, ConnectionAddress, MavConnection, MavHeader, MavlinkReader, MavlinkVersion,
};
use std::io;
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

/// How long a read waits before its thread checks whether to stop.
pub const RECV_TIMEOUT: Duration = Duration::from_millis(100);
/// The first wait before a lost serial device is opened again (USB re-enumeration takes
/// about as long), doubled after each failed attempt up to [`REOPEN_BACKOFF_MAX`].
pub const REOPEN_BACKOFF_MIN: Duration = Duration::from_millis(100);
/// The longest wait between two attempts to open a lost serial device: short against the 2 s
/// heartbeat timeout, and a failed `open` a second costs nothing.
pub const REOPEN_BACKOFF_MAX: Duration = Duration::from_secs(1);
/// The pause after a UDP read error other than a timeout (an ICMP refusal on `udpout`), so that
/// a socket failing at once cannot spin the reading thread.
const UDP_ERROR_PAUSE: Duration = Duration::from_millis(10);

/// Why an address cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("--mavlink {address:?}: {reason} (udpin:HOST:PORT, udpout:HOST:PORT or serial:DEVICE:BAUD)")]
    Address { address: String, reason: String },
    #[error("--mavlink {address:?}: {source}")]
    Open { address: String, source: io::Error },
}

/// What the transport has been through, for `GetStatus` and the `UNAVAILABLE` message.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct LinkStatus {
    /// Why the transport is down now (a serial device lost and not yet open again).
    pub down: Option<String>,
    /// Times the serial device was lost (hang-up, I/O error, end of file) and closed.
    pub losses: u64,
    /// Times a lost serial device was opened again.
    pub reopens: u64,
    /// Read errors other than timeouts (each loss is one; on UDP, each refused datagram).
    pub read_errors: u64,
}

/// A MAVLink 2 connection shared by a reading and a writing thread.
#[derive(Clone)]
pub struct Link {
    shared: Arc<Shared>,
    header: MavHeader,
    /// The address as given, a `udpin` one with the port it bound (when it was 0), as the logs
    /// and `Describe` name it.
    pub address: String,
    /// The local address of a `udpin` link (its port when it was 0).
    pub local_addr: Option<std::net::SocketAddr>,
}

struct Shared {
    transport: Transport,
    status: Mutex<LinkStatus>,
}

enum Transport {
    Udp(mavlink::Connection<MavMessage>),
    Serial(Serial),
}

/// A serial device: a reading and a writing descriptor of one open port, as the `mavlink`
/// crate has them, both `None` while the device is lost.
struct Serial {
    device: String,
    baud_rate: u32,
    /// Taken by the reading thread only, which alone closes and reopens the device.
    reader: Mutex<SerialReader>,
    writer: Mutex<Option<serialport::TTYPort>>,
    /// The MAVLink sequence number of the next frame sent.
    sequence: AtomicU8,
}

struct SerialReader {
    port: Option<MavlinkReader<serialport::TTYPort>>,
    /// When a lost device is next opened, and the wait after that attempt if it fails.
    next_open: Instant,
    backoff: Duration,
    lost_at: Instant,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Checks an address without opening it.
pub fn check_address(address: &str) -> Result<(), LinkError> {
    serial_address(address).map(|_| ())
}

/// Checks `address`; a serial one's device and baud rate.
fn serial_address(address: &str) -> Result<Option<(&str, u32)>, LinkError> {
    let bad = |reason: &str| Err(LinkError::Address { address: address.into(), reason: reason.into() });
    let Some((kind, rest)) = address.split_once(':') else { return bad("no transport") };
    match kind {
        "udpin" | "udpout" => match rest.rsplit_once(':').map(|(_, p)| p.parse::<u16>()) {
            Some(Ok(_)) => Ok(None),
            _ => bad("no port"),
        },
        "serial" => match rest.rsplit_once(':').map(|(d, b)| (d, b.parse::<u32>())) {
            Some((device, Ok(baud))) if baud > 0 && !device.is_empty() => Ok(Some((device, baud))),
            Some(("", _)) => bad("no device"),
            _ => bad("no baud rate"),
        },
        _ => bad("unknown transport"),
    }
}

/// Opens a serial device as the `mavlink` crate does (8N1, no flow control), reads timing out
/// after [`RECV_TIMEOUT`]; returns the reading and the writing half.
fn open_serial(
    device: &str,
    baud_rate: u32,
) -> io::Result<(MavlinkReader<serialport::TTYPort>, serialport::TTYPort)> {
    let port = serialport::new(device, baud_rate)
        .data_bits(serialport::DataBits::Eight)
        .parity(serialport::Parity::None)
        .stop_bits(serialport::StopBits::One)
        .flow_control(serialport::FlowControl::None)
        .timeout(RECV_TIMEOUT)
        .open_native()?;
    let writer = port.try_clone_native()?;
    Ok((MavlinkReader::new(port), writer))
}

impl Link {
    /// Opens `address`; this end speaks as `(system_id, component_id)`. A serial device that
    /// cannot be opened now is an error (a wrong path fails at start); once open, a lost
    /// device is opened again by [`Link::recv`].
    pub fn open(address: &str, system_id: u8, component_id: u8) -> Result<Self, LinkError> {
        let serial = serial_address(address)?;
        let open_err = |source| LinkError::Open { address: address.into(), source };
        let mut local_addr = None;
        let transport = if let Some((device, baud_rate)) = serial {
            let (reader, writer) = open_serial(device, baud_rate).map_err(open_err)?;
            Transport::Serial(Serial {
                device: device.into(),
                baud_rate,
                reader: Mutex::new(SerialReader {
                    port: Some(reader),
                    next_open: Instant::now(),
                    backoff: REOPEN_BACKOFF_MIN,
                    lost_at: Instant::now(),
                }),
                writer: Mutex::new(Some(writer)),
                sequence: AtomicU8::new(0),
            })
        } else {
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
                other => other,
            };
            let mut conn = parsed.connect::<MavMessage>().map_err(open_err)?;
            conn.set_protocol_version(MavlinkVersion::V2);
            conn.set_allow_recv_any_version(true);
            Transport::Udp(conn)
        };
        Ok(Self {
            shared: Arc::new(Shared { transport, status: Mutex::new(LinkStatus::default()) }),
            header: MavHeader { system_id: u32::from(system_id), component_id, sequence: 0 },
            address: local_addr.map_or_else(|| address.into(), |at| format!("udpin:{at}")),
            local_addr,
        })
    }

    /// What the transport has been through.
    pub fn status(&self) -> LinkStatus {
        lock(&self.shared.status).clone()
    }

    /// Sends `msg`; an error is returned for the caller to count and log (a datagram that
    /// cannot leave is not retried: the next setpoint follows within a period). While a serial
    /// device is lost the error is `NotConnected`, which the loss's own warning has explained.
    pub fn send(&self, msg: &MavMessage) -> Result<(), MessageWriteError> {
        match &self.shared.transport {
            Transport::Udp(conn) => conn.send(&self.header, msg).map(|_| ()),
            Transport::Serial(serial) => {
                let mut writer = lock(&serial.writer);
                let Some(port) = writer.as_mut() else {
                    return Err(MessageWriteError::Io(io::Error::new(
                        io::ErrorKind::NotConnected,
                        format!("the serial device {} is lost", serial.device),
                    )));
                };
                let header =
                    MavHeader { sequence: serial.sequence.fetch_add(1, Ordering::Relaxed), ..self.header };
                mavlink::write_versioned_msg(port, MavlinkVersion::V2, header, msg).map(|_| ())
            }
        }
    }

    /// The next message, or `None` when none came within [`RECV_TIMEOUT`], a frame was not one
    /// of the common dialect's, or the transport failed. No path returns at once without
    /// having read something or waited: a failing transport cannot spin the reading thread.
    pub fn recv(&self) -> Option<(MavHeader, MavMessage)> {
        match &self.shared.transport {
            Transport::Udp(conn) => self.recv_udp(conn),
            Transport::Serial(serial) => self.recv_serial(serial),
        }
    }

    fn recv_udp(&self, conn: &mavlink::Connection<MavMessage>) -> Option<(MavHeader, MavMessage)> {
        use io::ErrorKind::{TimedOut, WouldBlock};
        match conn.recv() {
            Ok(m) => Some(m),
            // A datagram's frame that the common dialect does not decode was consumed: the
            // next read waits for the next datagram.
            Err(MessageReadError::Parse(_)) => None,
            Err(MessageReadError::Io(e)) if matches!(e.kind(), WouldBlock | TimedOut) => None,
            Err(MessageReadError::Io(e)) => {
                let errors = {
                    let mut status = lock(&self.shared.status);
                    status.read_errors += 1;
                    status.read_errors
                };
                if errors.is_power_of_two() {
                    tracing::warn!(errors, "MAVLink read on {}: {e}", self.address);
                }
                std::thread::sleep(UDP_ERROR_PAUSE);
                None
            }
        }
    }

    fn recv_serial(&self, serial: &Serial) -> Option<(MavHeader, MavMessage)> {
        let mut reader = lock(&serial.reader);
        let Some(port) = reader.port.as_mut() else {
            self.reopen(serial, &mut reader);
            return None;
        };
        match port.read_any_message::<MavMessage>() {
            Ok(m) => {
                // The device works: a later loss starts again from the shortest wait.
                reader.backoff = REOPEN_BACKOFF_MIN;
                Some(m)
            }
            // The undecodable frame was consumed, so this is progress through the bytes that
            // arrived, never a loop on the same ones.
            Err(MessageReadError::Parse(_)) => None,
            Err(MessageReadError::Io(e)) if e.kind() == io::ErrorKind::TimedOut => None,
            // Hang-up (`BrokenPipe`), `EIO`, end of file, ...: the device is gone. Reading on
            // would fail at once, for ever; close it and open it again later.
            Err(MessageReadError::Io(e)) => {
                reader.port = None;
                *lock(&serial.writer) = None;
                let now = Instant::now();
                reader.lost_at = now;
                reader.next_open = now + reader.backoff;
                let reason = format!("serial device {} lost: {e}", serial.device);
                {
                    let mut status = lock(&self.shared.status);
                    status.losses += 1;
                    status.read_errors += 1;
                    status.down = Some(reason.clone());
                }
                tracing::warn!(
                    "{reason}; closed, opening it again every {} ms at most until it is back",
                    REOPEN_BACKOFF_MAX.as_millis()
                );
                None
            }
        }
    }

    /// Opens a lost device again once its backoff has passed; otherwise waits (at most
    /// [`RECV_TIMEOUT`], so that the reading thread still notices a shutdown).
    fn reopen(&self, serial: &Serial, reader: &mut SerialReader) {
        let now = Instant::now();
        if now < reader.next_open {
            std::thread::sleep((reader.next_open - now).min(RECV_TIMEOUT));
            return;
        }
        // Doubled whether this attempt fails or the device opens and fails again at once; a
        // message heard resets it.
        let backoff = reader.backoff;
        reader.backoff = (backoff * 2).min(REOPEN_BACKOFF_MAX);
        match open_serial(&serial.device, serial.baud_rate) {
            Ok((port, writer)) => {
                reader.port = Some(port);
                *lock(&serial.writer) = Some(writer);
                let mut status = lock(&self.shared.status);
                status.reopens += 1;
                status.down = None;
                tracing::info!(
                    "serial device {} open again after {:.1} s",
                    serial.device,
                    reader.lost_at.elapsed().as_secs_f64()
                );
            }
            Err(e) => {
                // Expected while the device is unplugged: the loss was logged once.
                tracing::debug!("serial device {} not back yet: {e}", serial.device);
                reader.next_open = now + reader.backoff;
            }
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
            "serial::921600",
        ] {
            let e = check_address(bad).expect_err(bad).to_string();
            assert!(e.contains("--mavlink") && e.contains(bad), "{e}");
        }
    }

    #[test]
    fn an_ephemeral_udpin_port_is_known_after_opening() {
        let link = Link::open("udpin:127.0.0.1:0", 255, 191).expect("opens");
        assert!(link.local_addr.is_some_and(|a| a.port() != 0));
        assert_eq!(link.address, format!("udpin:{}", link.local_addr.expect("bound")), "named with its port");
        assert!(link.recv().is_none(), "nothing arrived: the read times out");
    }

    /// A pty plays the serial device: its master is the autopilot's end.
    fn pty() -> (rustix::fd::OwnedFd, String) {
        use rustix::pty::{OpenptFlags, grantpt, openpt, ptsname, unlockpt};
        let master = openpt(OpenptFlags::RDWR | OpenptFlags::NOCTTY).expect("a pty");
        grantpt(&master).expect("grantpt");
        unlockpt(&master).expect("unlockpt");
        let name = ptsname(&master, Vec::new()).expect("ptsname");
        (master, name.to_str().expect("utf-8").to_owned())
    }

    #[test]
    fn a_hung_up_serial_device_is_closed_counted_once_and_refuses_sends_while_it_is_gone() {
        let (master, slave) = pty();
        let link = Link::open(&format!("serial:{slave}:921600"), 255, 191).expect("opens the pty");
        let heartbeat = MavMessage::HEARTBEAT(Default::default());
        link.send(&heartbeat).expect("sent while plugged");
        assert!(link.recv().is_none(), "nothing was written: the read times out");
        assert_eq!(link.status(), LinkStatus::default());

        // Unplugged: the slave's reads fail at once (hang-up) from now on.
        drop(master);
        assert!(link.recv().is_none());
        let status = link.status();
        assert_eq!((status.losses, status.reopens, status.read_errors), (1, 0, 1), "{status:?}");
        assert!(
            status.down.as_deref().is_some_and(|d| d.contains(&slave) && d.contains("lost")),
            "{status:?}"
        );
        let Err(MessageWriteError::Io(e)) = link.send(&heartbeat) else { panic!("sent to a lost device") };
        assert_eq!(e.kind(), io::ErrorKind::NotConnected, "{e}");
        // The device node is gone with its master: each attempt to open it again fails and is
        // not another loss; the reads in between wait rather than fail at once.
        for _ in 0..20 {
            assert!(link.recv().is_none());
        }
        let status = link.status();
        assert_eq!((status.losses, status.reopens), (1, 0), "{status:?}");
        assert!(status.down.is_some());
    }
}
