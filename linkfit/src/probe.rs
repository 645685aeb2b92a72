//! Recording a live link: the pure part of `hilbench trace record` and `trace echo`, and of the
//! gateway's `--record-link`.
//!
//! - The probe datagram ([`encode_probe`], [`decode`], [`encode_reply`]): a magic, a version, a
//!   sequence number and the sender's send time; the echo's reply carries the same bytes back
//!   with its own receive and send times (its clock), so that the two directions can be told
//!   apart. Every time is integer nanoseconds of the stamping side's monotonic clock. A plain
//!   echo that returns the datagram unchanged (`socat`, a router's UDP echo) is read as a reply
//!   without the far side's times: the round trip only.
//! - The [`Ledger`]: probes sent, replies matched to them, and each probe settled in send
//!   order as answered or lost (no reply within the timeout); late replies, duplicates and
//!   replies to probes never sent are counted, never taken.
//! - [`directions`]: the two one-way delays of each answered probe, irtt's way: the clock
//!   offset between the two sides from the probes with the shortest round trip (on those the
//!   two legs are taken as equal), one estimate per window of the recording and linearly
//!   interpolated between them, so that the clocks' drift (a few ppm: 1.5 ms in 300 s at
//!   5 ppm) does not end up in the delays.
//!
//! No clock is read here: every time is an argument.

use std::collections::VecDeque;

use delay::LOST_S;

/// The first bytes of every probe and reply.
pub const MAGIC: [u8; 4] = *b"HBLP";
/// The datagram format's version.
pub const VERSION: u8 = 1;
/// Bytes of the header; a probe is at least this long.
pub const HEADER_BYTES: usize = 40;
/// The longest probe: a UDP payload that fits an Ethernet frame unfragmented (1500 - 20 - 8).
pub const MAX_PROBE_BYTES: usize = 1472;

const KIND_PROBE: u8 = 1;
const KIND_REPLY: u8 = 2;

/// A probe: its number and the time it was sent, ns of the sender's clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Probe {
    pub seq: u64,
    pub sent_ns: u64,
}

/// The far side's times of a reply, ns of its own clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FarStamps {
    /// When the probe arrived there.
    pub received_ns: u64,
    /// When the reply left.
    pub sent_ns: u64,
}

/// A datagram read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Packet {
    /// A probe (to answer; or our own probe returned by a plain echo).
    Probe(Probe),
    /// A reply to a probe, with the far side's times.
    Reply(Probe, FarStamps),
}

/// A datagram that is not a probe or a reply of this format.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ProbeError {
    #[error("{0} bytes: shorter than the {HEADER_BYTES}-byte header")]
    Short(usize),
    #[error("not a hilbench probe (no magic)")]
    Magic,
    #[error("probe format version {0}, this hilbench reads {VERSION}")]
    Version(u8),
    #[error("unknown packet kind {0}")]
    Kind(u8),
    #[error("probe size {0} bytes: must be in [{HEADER_BYTES}, {MAX_PROBE_BYTES}]")]
    Size(usize),
}

fn write_header(kind: u8, probe: Probe, far: FarStamps, bytes: usize, out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&MAGIC);
    out.push(VERSION);
    out.push(kind);
    out.extend_from_slice(&[0, 0]);
    out.extend_from_slice(&probe.seq.to_le_bytes());
    out.extend_from_slice(&probe.sent_ns.to_le_bytes());
    out.extend_from_slice(&far.received_ns.to_le_bytes());
    out.extend_from_slice(&far.sent_ns.to_le_bytes());
    out.resize(bytes.max(HEADER_BYTES), 0);
}

/// Checks a probe size, bytes.
pub fn check_size(bytes: usize) -> Result<usize, ProbeError> {
    if (HEADER_BYTES..=MAX_PROBE_BYTES).contains(&bytes) { Ok(bytes) } else { Err(ProbeError::Size(bytes)) }
}

/// Writes `probe` as a datagram of `bytes` bytes (zero padding) into `out`.
pub fn encode_probe(probe: Probe, bytes: usize, out: &mut Vec<u8>) -> Result<(), ProbeError> {
    check_size(bytes)?;
    write_header(KIND_PROBE, probe, FarStamps { received_ns: 0, sent_ns: 0 }, bytes, out);
    Ok(())
}

/// Reads a datagram.
pub fn decode(datagram: &[u8]) -> Result<Packet, ProbeError> {
    if datagram.len() < HEADER_BYTES {
        return Err(ProbeError::Short(datagram.len()));
    }
    if datagram[..4] != MAGIC {
        return Err(ProbeError::Magic);
    }
    if datagram[4] != VERSION {
        return Err(ProbeError::Version(datagram[4]));
    }
    let word = |at: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&datagram[at..at + 8]);
        u64::from_le_bytes(b)
    };
    let probe = Probe { seq: word(8), sent_ns: word(16) };
    match datagram[5] {
        KIND_PROBE => Ok(Packet::Probe(probe)),
        KIND_REPLY => Ok(Packet::Reply(probe, FarStamps { received_ns: word(24), sent_ns: word(32) })),
        k => Err(ProbeError::Kind(k)),
    }
}

/// The echo's answer to `datagram` (a probe), of the same length, with the far side's times
/// `far`, written into `out`. Anything but a probe is refused (the echo answers nothing else,
/// so it cannot be made to reflect other traffic, and never more bytes than it received).
pub fn encode_reply(datagram: &[u8], far: FarStamps, out: &mut Vec<u8>) -> Result<Probe, ProbeError> {
    match decode(datagram)? {
        Packet::Probe(p) => {
            write_header(KIND_REPLY, p, far, datagram.len(), out);
            Ok(p)
        }
        Packet::Reply(..) => Err(ProbeError::Kind(KIND_REPLY)),
    }
}

/// One probe, settled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Exchange {
    pub seq: u64,
    /// Sent at, ns of the recorder's clock.
    pub sent_ns: u64,
    pub outcome: Outcome,
}

/// What became of a probe.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// No reply within the timeout.
    Lost,
    /// Answered: the reply arrived at `received_ns` (the recorder's clock), with the far side's
    /// times when the far side stamps them.
    Answered { received_ns: u64, far: Option<FarStamps> },
}

impl Exchange {
    /// The round trip, ns: the reply's arrival minus the probe's departure, less the time the
    /// far side held the probe when it says (as irtt does: the network's round trip).
    pub fn round_trip_ns(&self) -> Option<u64> {
        match self.outcome {
            Outcome::Lost => None,
            Outcome::Answered { received_ns, far } => {
                let rtt = received_ns.saturating_sub(self.sent_ns);
                let held = far.map_or(0, |f| f.sent_ns.saturating_sub(f.received_ns));
                Some(rtt.saturating_sub(held))
            }
        }
    }

    /// Whether the far side claims to have held the probe longer than its whole round trip
    /// (its stamps are wrong): [`Exchange::round_trip_ns`] is then 0.
    pub fn held_past_round_trip(&self) -> bool {
        match self.outcome {
            Outcome::Answered { received_ns, far: Some(f) } => {
                f.sent_ns.saturating_sub(f.received_ns) > received_ns.saturating_sub(self.sent_ns)
            }
            _ => false,
        }
    }

    /// The round trip in s, or [`LOST_S`]: a trace entry.
    pub fn trace_entry(&self) -> f64 {
        self.round_trip_ns().map_or(LOST_S, |ns| ns as f64 * 1e-9)
    }
}

/// What the ledger counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct Counts {
    pub sent: u64,
    pub answered: u64,
    pub lost: u64,
    /// Replies after their probe's timeout (the probe is lost).
    pub late: u64,
    /// Second replies to an answered probe.
    pub duplicates: u64,
    /// Replies to probes this ledger never sent.
    pub unknown: u64,
}

/// A reply taken or why not.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Matched {
    /// The probe's first reply in time: its round trip, ns.
    Answered(u64),
    Late,
    Duplicate,
    Unknown,
}

#[derive(Debug, Clone, Copy)]
struct Slot {
    sent_ns: u64,
    reply: Option<(u64, Option<FarStamps>)>,
}

/// The probes of one recording, numbered from 0 in send order, settled in that order.
#[derive(Debug, Clone)]
pub struct Ledger {
    timeout_ns: u64,
    /// Probes sent and not settled: `window[0]` is probe `settled.len()`.
    window: VecDeque<Slot>,
    settled: Vec<Exchange>,
    counts: Counts,
}

impl Ledger {
    /// A ledger whose probes are lost when no reply came within `timeout_ns` (> 0).
    pub fn new(timeout_ns: u64) -> Self {
        Self {
            timeout_ns: timeout_ns.max(1),
            window: VecDeque::new(),
            settled: Vec::new(),
            counts: Counts::default(),
        }
    }

    pub fn timeout_ns(&self) -> u64 {
        self.timeout_ns
    }

    /// A probe sent at `now_ns` (not before the previous one): its number.
    pub fn send(&mut self, now_ns: u64) -> Probe {
        let seq = self.settled.len() as u64 + self.window.len() as u64;
        let sent_ns = self.window.back().map_or(now_ns, |s| s.sent_ns.max(now_ns));
        self.window.push_back(Slot { sent_ns, reply: None });
        self.counts.sent += 1;
        Probe { seq, sent_ns }
    }

    /// The number of the probe sent at `sent_ns`, if it is waiting for its reply (a protocol
    /// that echoes the send time rather than a number: MAVLink's `TIMESYNC`).
    pub fn waiting_sent_at(&self, sent_ns: u64) -> Option<u64> {
        let i = self.window.binary_search_by_key(&sent_ns, |s| s.sent_ns).ok()?;
        Some(self.settled.len() as u64 + i as u64)
    }

    /// A reply to probe `seq` arrived at `now_ns`.
    pub fn answer(&mut self, seq: u64, now_ns: u64, far: Option<FarStamps>) -> Matched {
        let first = self.settled.len() as u64;
        if seq < first {
            return match self.settled.get(seq as usize).map(|e| e.outcome) {
                Some(Outcome::Lost) => {
                    self.counts.late += 1;
                    Matched::Late
                }
                _ => {
                    self.counts.duplicates += 1;
                    Matched::Duplicate
                }
            };
        }
        let Some(slot) = self.window.get_mut((seq - first) as usize) else {
            self.counts.unknown += 1;
            return Matched::Unknown;
        };
        if slot.reply.is_some() {
            self.counts.duplicates += 1;
            return Matched::Duplicate;
        }
        if now_ns.saturating_sub(slot.sent_ns) > self.timeout_ns {
            self.counts.late += 1;
            return Matched::Late;
        }
        slot.reply = Some((now_ns, far));
        let e =
            Exchange { seq, sent_ns: slot.sent_ns, outcome: Outcome::Answered { received_ns: now_ns, far } };
        Matched::Answered(e.round_trip_ns().unwrap_or(0))
    }

    /// Settles, in send order, every probe answered or older than the timeout at `now_ns`;
    /// returns how many are settled in all.
    pub fn settle(&mut self, now_ns: u64) -> usize {
        while let Some(front) = self.window.front().copied() {
            let outcome = match front.reply {
                Some((received_ns, far)) => Outcome::Answered { received_ns, far },
                None if now_ns.saturating_sub(front.sent_ns) > self.timeout_ns => Outcome::Lost,
                None => break,
            };
            match outcome {
                Outcome::Lost => self.counts.lost += 1,
                Outcome::Answered { .. } => self.counts.answered += 1,
            }
            let seq = self.settled.len() as u64;
            self.settled.push(Exchange { seq, sent_ns: front.sent_ns, outcome });
            self.window.pop_front();
        }
        self.settled.len()
    }

    /// Probes sent and not settled yet.
    pub fn waiting(&self) -> usize {
        self.window.len()
    }

    /// Whether every probe sent is answered (nothing to wait for).
    pub fn all_answered(&self) -> bool {
        self.window.iter().all(|s| s.reply.is_some())
    }

    pub fn counts(&self) -> Counts {
        self.counts
    }

    /// The probes settled so far, in send order.
    pub fn settled(&self) -> &[Exchange] {
        &self.settled
    }

    /// Ends the recording at `now_ns`: settles what can be, and leaves out the probes still
    /// waiting within their timeout (a recording cut short: they are neither answered nor
    /// lost yet). Returns the exchanges and how many were left out.
    pub fn finish(mut self, now_ns: u64) -> (Vec<Exchange>, Counts, usize) {
        self.settle(now_ns);
        let left_out = self.window.len();
        (self.settled, self.counts, left_out)
    }
}

/// The round trips of `exchanges` as trace entries (s, [`LOST_S`] for a lost probe).
pub fn round_trips_s(exchanges: &[Exchange]) -> Vec<f64> {
    exchanges.iter().map(Exchange::trace_entry).collect()
}

/// The two one-way delays of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Directions {
    /// Recorder to far side, s, one entry per exchange ([`LOST_S`] for a lost probe: which leg
    /// lost it is not known, so both directions mark it).
    pub up_s: Vec<f64>,
    /// Far side to recorder, s.
    pub down_s: Vec<f64>,
    /// The offset estimates, `(recorder time, far clock - recorder clock)`, ns, one per window.
    pub offsets: Vec<(u64, i64)>,
    /// One-way delays that came out below zero (the offset's error) and were set to 0.
    pub clamped: usize,
}

/// The one-way delays of `exchanges`, or `None` when some answered probe lacks the far side's
/// times (a plain echo) or none is answered. The clock offset `far - recorder` is estimated in
/// each `window_ns` of the recording (by send time) from its probe with the shortest round
/// trip, where the two legs are taken as equal: `((t2 - t1) - (t4 - t3)) / 2`; a probe's
/// offset is the estimates' linear interpolation at its send time (extrapolated beyond the
/// first and last). A path whose shortest legs differ puts half the difference into each direction,
/// as in every such estimate (irtt's, NTP's).
pub fn directions(exchanges: &[Exchange], window_ns: u64) -> Option<Directions> {
    let window_ns = window_ns.max(1);
    let mut answered = Vec::new();
    for e in exchanges {
        if let Outcome::Answered { received_ns, far } = e.outcome {
            answered.push((e, received_ns, far?));
        }
    }
    let first = answered.first()?.0.sent_ns;
    // Per window: the probe with the shortest round trip -> (its send time, offset).
    let mut offsets: Vec<(u64, i64)> = Vec::new();
    // The current window's best: (window, round trip, send time, offset).
    let mut best: Option<(u64, u64, u64, i64)> = None;
    for (e, t4, far) in &answered {
        let w = (e.sent_ns - first) / window_ns;
        let up_raw = i128::from(far.received_ns) - i128::from(e.sent_ns);
        let down_raw = i128::from(*t4) - i128::from(far.sent_ns);
        let offset = ((up_raw - down_raw) / 2) as i64;
        let here = (w, e.round_trip_ns().unwrap_or(u64::MAX), e.sent_ns, offset);
        best = match best {
            Some(b) if b.0 != w => {
                offsets.push((b.2, b.3));
                Some(here)
            }
            Some(b) if b.1 <= here.1 => Some(b),
            _ => Some(here),
        };
    }
    if let Some(b) = best {
        offsets.push((b.2, b.3));
    }
    // Linear between neighbouring estimates, and beyond the first and last along the line of
    // the two nearest (the drift goes on to the recording's ends).
    let offset_at = |t: u64| -> f64 {
        if offsets.len() == 1 {
            return offsets[0].1 as f64;
        }
        let i = offsets.partition_point(|&(ot, _)| ot <= t).clamp(1, offsets.len() - 1);
        let (t0, o0) = offsets[i - 1];
        let (t1, o1) = offsets[i];
        let f = (t as f64 - t0 as f64) / (t1 as f64 - t0 as f64).max(1.0);
        o0 as f64 + f * (o1 as f64 - o0 as f64)
    };
    let (mut up_s, mut down_s, mut clamped) = (Vec::new(), Vec::new(), 0);
    for e in exchanges {
        match e.outcome {
            Outcome::Lost => {
                up_s.push(LOST_S);
                down_s.push(LOST_S);
            }
            Outcome::Answered { received_ns, far } => {
                let far = far?;
                let theta = offset_at(e.sent_ns);
                let up = (far.received_ns as f64 - e.sent_ns as f64) - theta;
                let down = (received_ns as f64 - far.sent_ns as f64) + theta;
                for (v, out) in [(up, &mut up_s), (down, &mut down_s)] {
                    if v < 0.0 {
                        clamped += 1;
                    }
                    out.push(v.max(0.0) * 1e-9);
                }
            }
        }
    }
    Some(Directions { up_s, down_s, offsets, clamped })
}

/// `YYYY-MM-DDTHH:MM:SSZ` of `unix_s` seconds since 1970 (UTC): a recording's `when`.
pub fn iso8601_utc(unix_s: u64) -> String {
    let (days, rem) = ((unix_s / 86_400) as i64, unix_s % 86_400);
    // Howard Hinnant's days-to-civil.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z", rem / 3600, rem % 3600 / 60, rem % 60)
}

#[cfg(test)]
mod tests;
