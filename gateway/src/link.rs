//! The MAVLink transport: UDP (`udpin:HOST:PORT` listens and answers the address it is told
//! to, [`Link::answer`]: the vehicle the gateway locked to, never merely the last sender;
//! `udpout:HOST:PORT` sends there from any port and hears anyone; a datagram carries one or more
//! frames, each handed out with its sender, [`Frame`]) or a serial device
//! (`serial:/dev/ttyACM0:921600`, opened here with `serialport`). Blocking reads
//! ([`Link::recv`]) time out every [`RECV_TIMEOUT`] so that the threads reading them notice a
//! shutdown; a UDP link is also read without blocking ([`Link::try_recv`]) when its socket
//! ([`Link::udp_socket`]) is ready, so that a runtime's worker reads it.
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
//!
//! With a signing key ([`Link::open_signed`]) every frame sent is signed and every frame read
//! is checked ([`mavbridge::signing`], the wall clock passed in) before it is decoded: an
//! unsigned, badly signed or replayed one is handed out as [`Frame::Refused`].

use mavbridge::mavlink::dialects::common::MavMessage;
use mavbridge::mavlink::error::{MessageReadError, MessageWriteError};
use mavbridge::mavlink::{self, MAVLinkMessageRaw, MavHeader, MavlinkReader, MavlinkVersion, Message};
use mavbridge::{Peer, Refusal, Signer, SigningKey, Verifier};
use rustix::event::{PollFd, PollFlags, Timespec};
use rustix::net::RecvFlags;
use std::collections::VecDeque;
use std::io;
use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
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
/// a socket failing at once cannot spin its reader.
pub const UDP_ERROR_PAUSE: Duration = Duration::from_millis(10);
/// The longest MAVLink frame (v2, 255 bytes of payload, signed).
const MAX_FRAME_BYTES: usize = 280;
/// The largest UDP payload: a datagram is read whole, however many frames it packs.
const MAX_DATAGRAM_BYTES: usize = 65_507;

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
    /// The MAVLink sequence number of the next frame sent.
    sequence: AtomicU8,
    /// With a signing key: what signs the frames sent and checks those read.
    signer: Option<Mutex<Signer>>,
    verifier: Option<Mutex<Verifier>>,
}

/// What one frame of the link is.
#[derive(Debug)]
#[expect(
    clippy::large_enum_variant,
    reason = "handed out by value and consumed at once, as the message itself would be"
)]
pub enum Frame {
    /// A frame decoded, from `Peer`.
    Message(Peer, MavHeader, MavMessage),
    /// Bytes from `Peer` not decoded: no frame the common dialect decodes
    /// ([`Refusal::Undecodable`]), or a signature refused.
    Refused(Peer, Refusal),
}

/// The signature timestamp of now (the wall clock, as the protocol wants).
fn signing_stamp() -> u64 {
    let unix_us = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_micros()).unwrap_or(u64::MAX));
    mavbridge::signing::stamp_of_unix_us(unix_us)
}

enum Transport {
    Udp(Udp),
    Serial(Serial),
}

/// A non-blocking UDP socket (so that a runtime may wait on it; [`Link::recv`] waits in
/// `poll`, up to [`RECV_TIMEOUT`]).
struct Udp {
    socket: UdpSocket,
    /// Where frames go: `udpout`'s address, or on `udpin` the address [`Link::answer`] named
    /// (none before).
    destination: Mutex<Option<SocketAddr>>,
    /// `udpin`: the destination is whom [`Link::answer`] names.
    answers: bool,
    reader: Mutex<UdpReader>,
}

/// One reader at a time takes a datagram and hands out its frames.
struct UdpReader {
    datagram: Vec<u8>,
    /// The frames of the last datagram not handed out yet.
    pending: VecDeque<Frame>,
}

/// What [`Link::try_recv`] found.
#[derive(Debug)]
#[expect(
    clippy::large_enum_variant,
    reason = "returned by value and consumed at once, as `recv`'s `Option` of the same size"
)]
pub enum TryRecv {
    Frame(Frame),
    /// Nothing waits on the socket now.
    Empty,
    /// A read failed (counted in [`LinkStatus::read_errors`] and logged): the caller pauses
    /// [`UDP_ERROR_PAUSE`] before the next, so that a failing socket cannot spin it.
    Failed,
}

/// A serial device: a reading and a writing descriptor of one open port, as the `mavlink`
/// crate has them, both `None` while the device is lost.
struct Serial {
    device: String,
    baud_rate: u32,
    /// Taken by the reading thread only, which alone closes and reopens the device.
    reader: Mutex<SerialReader>,
    writer: Mutex<Option<serialport::TTYPort>>,
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
        Self::open_signed(address, system_id, component_id, None)
    }

    /// As [`Link::open`], signing every frame sent with `key` and refusing every frame read
    /// that is not signed with it (link id 0).
    pub fn open_signed(
        address: &str,
        system_id: u8,
        component_id: u8,
        key: Option<SigningKey>,
    ) -> Result<Self, LinkError> {
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
            })
        } else {
            let (socket, destination, answers) = match address.split_once(':') {
                Some(("udpin", at)) => (UdpSocket::bind(at).map_err(open_err)?, None, true),
                Some((_, to)) => {
                    // IPv4 first: `localhost` may list `::1` first, and a vehicle heard on IPv4
                    // only would get nothing, silently (an unconnected socket reports no
                    // refusal).
                    let addrs: Vec<SocketAddr> = to.to_socket_addrs().map_err(open_err)?.collect();
                    let resolved = addrs.iter().find(|a| a.is_ipv4()).or(addrs.first()).copied();
                    let to = resolved.ok_or_else(|| {
                        open_err(io::Error::new(
                            io::ErrorKind::NotFound,
                            format!("{to} resolves to no address"),
                        ))
                    })?;
                    let any: SocketAddr =
                        if to.is_ipv4() { ([0u8; 4], 0).into() } else { ([0u16; 8], 0).into() };
                    (UdpSocket::bind(any).map_err(open_err)?, Some(to), false)
                }
                None => unreachable!("checked by serial_address"),
            };
            socket.set_nonblocking(true).map_err(open_err)?;
            if answers {
                // Known here when the port was 0 (tests use ephemeral ports).
                local_addr = Some(socket.local_addr().map_err(open_err)?);
            }
            Transport::Udp(Udp {
                socket,
                destination: Mutex::new(destination),
                answers,
                reader: Mutex::new(UdpReader {
                    datagram: vec![0; MAX_DATAGRAM_BYTES],
                    pending: VecDeque::new(),
                }),
            })
        };
        Ok(Self {
            shared: Arc::new(Shared {
                transport,
                status: Mutex::new(LinkStatus::default()),
                sequence: AtomicU8::new(0),
                signer: key.clone().map(|k| Mutex::new(Signer::new(k, 0))),
                verifier: key.map(|k| Mutex::new(Verifier::new(k, signing_stamp()))),
            }),
            header: MavHeader { system_id: u32::from(system_id), component_id, sequence: 0 },
            address: local_addr.map_or_else(|| address.into(), |at| format!("udpin:{at}")),
            local_addr,
        })
    }

    /// What the transport has been through.
    pub fn status(&self) -> LinkStatus {
        lock(&self.shared.status).clone()
    }

    /// Whether frames are signed and checked.
    pub fn signs(&self) -> bool {
        self.shared.signer.is_some()
    }

    /// A `udpin` link sends to `peer` from now on (the vehicle it locked to); a `udpout` or
    /// serial link keeps its destination.
    pub fn answer(&self, peer: Peer) {
        if let (Transport::Udp(udp), Some(at)) = (&self.shared.transport, peer)
            && udp.answers
        {
            *lock(&udp.destination) = Some(at);
        }
    }

    /// `msg` as one MAVLink 2 frame with the next sequence number in `buf`, signed when the
    /// link signs: its length.
    fn encode(&self, msg: &MavMessage, buf: &mut [u8; MAX_FRAME_BYTES]) -> Result<usize, MessageWriteError> {
        let header =
            MavHeader { sequence: self.shared.sequence.fetch_add(1, Ordering::Relaxed), ..self.header };
        let mut cursor = &mut buf[..];
        let n = mavlink::write_versioned_msg(&mut cursor, MavlinkVersion::V2, header, msg)?;
        Ok(match &self.shared.signer {
            Some(signer) => {
                lock(signer).sign(buf, n, MavMessage::extra_crc(msg.message_id()), signing_stamp())
            }
            None => n,
        })
    }

    /// One frame read: checked against the signing key (when the link signs), then decoded.
    fn frame(&self, peer: Peer, raw: &MAVLinkMessageRaw) -> Frame {
        let header = MavHeader {
            system_id: raw.system_id(),
            component_id: raw.component_id(),
            sequence: raw.sequence(),
        };
        if let Some(verifier) = &self.shared.verifier {
            let bytes = match raw {
                MAVLinkMessageRaw::V1(v1) => v1.raw_bytes(),
                MAVLinkMessageRaw::V2(v2) => v2.raw_bytes(),
            };
            if let Err(why) =
                lock(verifier).check(bytes, header.system_id, header.component_id, signing_stamp())
            {
                return Frame::Refused(peer, why);
            }
        }
        match MavMessage::parse(raw.version(), raw.message_id(), raw.payload()) {
            Ok(msg) => Frame::Message(peer, header, msg),
            Err(_) => Frame::Refused(peer, Refusal::Undecodable),
        }
    }

    /// Sends `msg`; an error is returned for the caller to count and log (a datagram that
    /// cannot leave is not retried: the next setpoint follows within a period). While a serial
    /// device is lost the error is `NotConnected`, which the loss's own warning has explained.
    /// A `udpin` link that has heard nobody yet has nobody to answer: `NotConnected` too.
    pub fn send(&self, msg: &MavMessage) -> Result<(), MessageWriteError> {
        // Numbered once it is encoded to leave: a frame refused before (nobody heard yet, a
        // serial device lost) leaves no gap for the vehicle to count as lost; one the socket
        // then fails to send (a full send buffer: the socket is non-blocking) does.
        match &self.shared.transport {
            Transport::Udp(udp) => {
                let Some(destination) = *lock(&udp.destination) else {
                    return Err(MessageWriteError::Io(io::Error::new(
                        io::ErrorKind::NotConnected,
                        format!("{} has locked to no vehicle yet to answer", self.address),
                    )));
                };
                let mut frame = [0u8; MAX_FRAME_BYTES];
                let n = self.encode(msg, &mut frame)?;
                udp.socket.send_to(&frame[..n], destination)?;
                Ok(())
            }
            Transport::Serial(serial) => {
                let mut writer = lock(&serial.writer);
                let Some(port) = writer.as_mut() else {
                    return Err(MessageWriteError::Io(io::Error::new(
                        io::ErrorKind::NotConnected,
                        format!("the serial device {} is lost", serial.device),
                    )));
                };
                let mut frame = [0u8; MAX_FRAME_BYTES];
                let n = self.encode(msg, &mut frame)?;
                io::Write::write_all(port, &frame[..n])?;
                Ok(())
            }
        }
    }

    /// The next frame, or `None` when none came within [`RECV_TIMEOUT`] or the transport
    /// failed. No path returns at once without having read something or waited: a failing
    /// transport cannot spin the reading thread.
    pub fn recv(&self) -> Option<Frame> {
        match &self.shared.transport {
            Transport::Udp(udp) => match self.recv_udp(udp, true) {
                TryRecv::Frame(frame) => Some(frame),
                TryRecv::Empty => None,
                TryRecv::Failed => {
                    std::thread::sleep(UDP_ERROR_PAUSE);
                    None
                }
            },
            Transport::Serial(serial) => self.recv_serial(serial),
        }
    }

    /// A UDP link's socket (a handle on the same socket), for a runtime to wait until it is
    /// readable and then call [`Link::try_recv`]; `None` for a serial link.
    pub fn udp_socket(&self) -> io::Result<Option<UdpSocket>> {
        match &self.shared.transport {
            Transport::Udp(udp) => udp.socket.try_clone().map(Some),
            Transport::Serial(_) => Ok(None),
        }
    }

    /// The next message of a UDP link, without blocking: [`TryRecv::Empty`] when no frame
    /// waits (and always on a serial link, which only [`Link::recv`] reads). It takes the
    /// reader's lock, which [`Link::recv`] holds through its wait: read a link one way only.
    pub fn try_recv(&self) -> TryRecv {
        match &self.shared.transport {
            Transport::Udp(udp) => self.recv_udp(udp, false),
            Transport::Serial(_) => TryRecv::Empty,
        }
    }

    /// The next frame: one left from the last datagram, or the first of the next datagram
    /// (waiting for it up to [`RECV_TIMEOUT`] when `wait`). A frame the common dialect does
    /// not decode is refused with the datagram's others kept; a datagram of no frame at all is
    /// one refusal.
    fn recv_udp(&self, udp: &Udp, wait: bool) -> TryRecv {
        let mut reader = lock(&udp.reader);
        if let Some(frame) = reader.pending.pop_front() {
            return TryRecv::Frame(frame);
        }
        if wait {
            let mut fds = [PollFd::new(&udp.socket, PollFlags::IN)];
            let timeout = Timespec::try_from(RECV_TIMEOUT).expect("a short timeout");
            // A timeout or an interruption leaves the socket empty: the read says so.
            let _ = rustix::event::poll(&mut fds, Some(&timeout));
        }
        let UdpReader { datagram, pending } = &mut *reader;
        let received = loop {
            match rustix::net::recvfrom(&udp.socket, &mut datagram[..], RecvFlags::empty()) {
                Err(rustix::io::Errno::INTR) => continue,
                other => break other,
            }
        };
        let (n, sender) = match received {
            Ok((n, _, sender)) => (n, sender),
            // Nothing waiting (after the wait, a timeout).
            Err(rustix::io::Errno::AGAIN) => return TryRecv::Empty,
            Err(e) => {
                let errors = {
                    let mut status = lock(&self.shared.status);
                    status.read_errors += 1;
                    status.read_errors
                };
                if errors.is_power_of_two() {
                    tracing::warn!(errors, "MAVLink read on {}: {}", self.address, io::Error::from(e));
                }
                return TryRecv::Failed;
            }
        };
        let peer: Peer = sender.and_then(|a| SocketAddr::try_from(a).ok());
        let mut frames = MavlinkReader::new(&datagram[..n]);
        loop {
            match frames.read_any_raw_message::<MavMessage>() {
                Ok(raw) => pending.push_back(self.frame(peer, &raw)),
                // The frame was consumed; the datagram's next ones follow.
                Err(MessageReadError::Parse(_)) => {
                    pending.push_back(Frame::Refused(peer, Refusal::Undecodable))
                }
                // The end of the datagram (a frame cut short there is dropped with it).
                Err(MessageReadError::Io(_)) => break,
            }
        }
        TryRecv::Frame(pending.pop_front().unwrap_or(Frame::Refused(peer, Refusal::Undecodable)))
    }

    fn recv_serial(&self, serial: &Serial) -> Option<Frame> {
        let mut reader = lock(&serial.reader);
        let Some(port) = reader.port.as_mut() else {
            self.reopen(serial, &mut reader);
            return None;
        };
        match port.read_any_raw_message::<MavMessage>() {
            Ok(raw) => {
                // The device works: a later loss starts again from the shortest wait.
                reader.backoff = REOPEN_BACKOFF_MIN;
                Some(self.frame(None, &raw))
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

    fn frame(msg: &MavMessage, sequence: u8) -> Vec<u8> {
        let mut bytes = Vec::new();
        let header = MavHeader { system_id: 1, component_id: 1, sequence };
        mavlink::write_v2_msg(&mut bytes, header, msg).expect("encodes");
        bytes
    }

    fn attitude(time_boot_ms: u32) -> MavMessage {
        MavMessage::ATTITUDE(mavlink::dialects::common::ATTITUDE_DATA { time_boot_ms, ..Default::default() })
    }

    fn time_boot_ms(received: Option<Frame>) -> u32 {
        match received {
            Some(Frame::Message(_, _, MavMessage::ATTITUDE(a))) => a.time_boot_ms,
            other => panic!("not an ATTITUDE: {other:?}"),
        }
    }

    #[test]
    fn a_datagram_of_several_frames_gives_each_in_order_refusing_one_the_dialect_cannot_decode() {
        let link = Link::open("udpin:127.0.0.1:0", 255, 191).expect("opens");
        let vehicle = UdpSocket::bind("127.0.0.1:0").expect("vehicle");
        // A valid frame of a message id the common dialect does not know (a dialect's unknown
        // id has CRC extra 0): it passes the CRC and fails to decode.
        let mut unknown = frame(&attitude(0), 0);
        unknown[7..10].copy_from_slice(&[0xAA, 0xBB, 0xCC]);
        let crc_at = unknown.len() - 2;
        let crc = mavlink::calculate_crc(&unknown[1..crc_at], 0);
        unknown[crc_at..].copy_from_slice(&crc.to_le_bytes());
        assert!(matches!(
            MavlinkReader::new(&unknown[..]).read_any_message::<MavMessage>(),
            Err(MessageReadError::Parse(_))
        ));
        let datagram =
            [frame(&attitude(1), 1), unknown, frame(&attitude(2), 2), frame(&attitude(3), 3)].concat();
        vehicle.send_to(&datagram, link.local_addr.expect("bound")).expect("sent");
        assert_eq!(time_boot_ms(link.recv()), 1);
        let from = vehicle.local_addr().ok();
        assert!(matches!(link.recv(), Some(Frame::Refused(p, Refusal::Undecodable)) if p == from));
        assert_eq!(time_boot_ms(link.recv()), 2);
        assert_eq!(time_boot_ms(link.recv()), 3);
        assert!(link.recv().is_none(), "nothing more: the read times out");
    }

    #[test]
    fn try_recv_never_blocks_and_takes_what_waits() {
        let link = Link::open("udpin:127.0.0.1:0", 255, 191).expect("opens");
        let started = Instant::now();
        assert!(matches!(link.try_recv(), TryRecv::Empty));
        assert!(started.elapsed() < RECV_TIMEOUT, "returned without waiting for the timeout");
        let vehicle = UdpSocket::bind("127.0.0.1:0").expect("vehicle");
        vehicle.send_to(&frame(&attitude(7), 0), link.local_addr.expect("bound")).expect("sent");
        vehicle.send_to(&[0xFE, 0x00], link.local_addr.expect("bound")).expect("sent");
        vehicle.send_to(&frame(&attitude(8), 1), link.local_addr.expect("bound")).expect("sent");
        let TryRecv::Frame(first) = link.try_recv() else { panic!("the first datagram waits") };
        assert_eq!(time_boot_ms(Some(first)), 7);
        assert!(
            matches!(link.try_recv(), TryRecv::Frame(Frame::Refused(_, Refusal::Undecodable))),
            "a datagram of no frame is refused, not the end"
        );
        let TryRecv::Frame(third) = link.try_recv() else { panic!("the third datagram waits") };
        assert_eq!(time_boot_ms(Some(third)), 8);
        assert!(matches!(link.try_recv(), TryRecv::Empty));
    }

    #[test]
    fn udpin_answers_whom_it_is_told_never_merely_the_last_sender_and_nobody_before() {
        let link = Link::open("udpin:127.0.0.1:0", 255, 191).expect("opens");
        let heartbeat = MavMessage::HEARTBEAT(Default::default());
        let Err(MessageWriteError::Io(e)) = link.send(&heartbeat) else { panic!("sent to nobody") };
        assert_eq!(e.kind(), io::ErrorKind::NotConnected);
        assert!(e.to_string().contains(&link.address), "names the link: {e}");
        let mut buf = [0u8; 512];
        let vehicle = UdpSocket::bind("127.0.0.1:0").expect("vehicle");
        vehicle.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
        vehicle.send_to(&frame(&attitude(0), 0), link.local_addr.expect("bound")).expect("sent");
        assert_eq!(time_boot_ms(link.recv()), 0);
        assert!(link.send(&heartbeat).is_err(), "heard, not told to answer");
        link.answer(vehicle.local_addr().ok());
        let other = UdpSocket::bind("127.0.0.1:0").expect("another sender");
        other.set_read_timeout(Some(Duration::from_millis(200))).expect("timeout");
        for k in 0..2u32 {
            // Another sender speaks last: the answers still go to the vehicle.
            other.send_to(&[0x00], link.local_addr.expect("bound")).expect("sent");
            assert!(matches!(link.recv(), Some(Frame::Refused(..))));
            link.send(&heartbeat).expect("sent");
            let n = vehicle.recv(&mut buf).expect("the answer reaches the vehicle");
            let (header, msg) =
                MavlinkReader::new(&buf[..n]).read_any_message::<MavMessage>().expect("a frame");
            assert!(matches!(msg, MavMessage::HEARTBEAT(_)));
            assert_eq!((header.system_id, header.component_id, header.sequence), (255, 191, k as u8));
        }
        assert!(other.recv(&mut buf).is_err(), "the other sender got nothing");
    }

    #[test]
    fn a_signed_link_signs_what_it_sends_and_refuses_unsigned_wrongly_signed_and_replayed_frames() {
        let key = SigningKey::new([9; 32]);
        let gateway = Link::open_signed("udpin:127.0.0.1:0", 255, 191, Some(key.clone())).expect("opens");
        let at = gateway.local_addr.expect("bound");
        let vehicle = Link::open_signed(&format!("udpout:{at}"), 1, 1, Some(key)).expect("opens");
        let stranger =
            Link::open_signed(&format!("udpout:{at}"), 1, 1, Some(SigningKey::new([8; 32]))).expect("opens");
        vehicle.send(&attitude(1)).expect("sent");
        assert_eq!(time_boot_ms(gateway.recv()), 1, "signed with the key: decoded");
        stranger.send(&attitude(2)).expect("sent");
        assert!(matches!(gateway.recv(), Some(Frame::Refused(_, Refusal::BadSignature))));
        let plain = UdpSocket::bind("127.0.0.1:0").expect("socket");
        plain.send_to(&frame(&attitude(3), 0), at).expect("sent");
        assert!(matches!(gateway.recv(), Some(Frame::Refused(_, Refusal::Unsigned))));
        // A signed frame captured and sent again.
        let tap = UdpSocket::bind("127.0.0.1:0").expect("tap");
        let copy = Link::open_signed(
            &format!("udpout:{}", tap.local_addr().expect("bound")),
            1,
            1,
            Some(SigningKey::new([9; 32])),
        )
        .expect("opens");
        copy.send(&attitude(4)).expect("sent");
        let mut buf = [0u8; 512];
        let n = tap.recv(&mut buf).expect("captured");
        plain.send_to(&buf[..n], at).expect("sent");
        assert_eq!(time_boot_ms(gateway.recv()), 4, "the first time");
        plain.send_to(&buf[..n], at).expect("sent");
        assert!(matches!(gateway.recv(), Some(Frame::Refused(_, Refusal::Replayed))));
        // What the gateway sends is signed: a verifier with the key, opened before, takes it.
        let mut check = mavbridge::Verifier::new(SigningKey::new([9; 32]), signing_stamp());
        gateway.answer(tap.local_addr().ok());
        gateway.send(&attitude(5)).expect("sent");
        let n = tap.recv(&mut buf).expect("received");
        assert_eq!(check.check(&buf[..n], 255, 191, signing_stamp()), Ok(()));
    }

    #[test]
    fn udpout_sends_to_its_address_and_hears_the_reply() {
        let vehicle = UdpSocket::bind("127.0.0.1:0").expect("vehicle");
        vehicle.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
        let link =
            Link::open(&format!("udpout:{}", vehicle.local_addr().expect("bound")), 255, 191).expect("opens");
        link.send(&MavMessage::HEARTBEAT(Default::default())).expect("sent");
        let mut buf = [0u8; 512];
        let (_, from) = vehicle.recv_from(&mut buf).expect("the heartbeat arrives");
        vehicle.send_to(&frame(&attitude(5), 0), from).expect("replied");
        assert_eq!(time_boot_ms(link.recv()), 5);
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
