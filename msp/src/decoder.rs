//! The incremental decoder: bytes in, in any chunking, checked frames out.
//!
//! Bytes outside a frame are skipped until the next `$`. A candidate frame that turns out bad
//! (unknown direction, a size over [`DecoderSettings::max_payload`], a wrong checksum) is
//! dropped and counted, and the search for the next `$` resumes *one byte after its `$`*, so a
//! real frame that a corrupted one seemed to swallow is still found. Error replies (`!`) are
//! checked like any frame, returned (the caller must know its request failed) and counted.
//!
//! ## Memory allocation
//! The buffer is allocated once, in [`Decoder::new`], with room for one frame of
//! `max_payload` bytes and its header and checksum (`max_payload + 9` bytes); it never grows,
//! whatever the input. Each frame returned owns its payload (one allocation per frame).
//!
//! A v2 frame carried inside a v1 frame (v1 command 255, "v2 over v1") is returned as the v1
//! frame it is; Betaflight answers in the version it was asked in, so a client that sends
//! native v1 or v2 never sees one.

use crate::frame::{self, Direction, Frame, START, Version};

/// Settings of a [`Decoder`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DecoderSettings {
    /// The largest payload accepted, bytes; a frame announcing more is dropped as
    /// [`Dropped::oversize`] as soon as its size is read. Betaflight's replies are at most 512
    /// bytes (`MSP_PORT_OUTBUF_SIZE` without a flash chip, 4,112 with one).
    pub max_payload: usize,
}

impl Default for DecoderSettings {
    fn default() -> Self {
        Self { max_payload: 4_112 }
    }
}

/// An invalid setting.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SettingsError {
    #[error("max_payload must be 1 to 65535 bytes (a frame's u16 size), got {0}")]
    MaxPayload(usize),
}

impl DecoderSettings {
    pub fn validate(&self) -> Result<(), SettingsError> {
        if self.max_payload == 0 || self.max_payload > usize::from(u16::MAX) {
            return Err(SettingsError::MaxPayload(self.max_payload));
        }
        Ok(())
    }
}

/// What the decoder dropped, by why.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Dropped {
    /// Bytes skipped outside any frame (before a `$`, a `$` followed by neither `M` nor `X`,
    /// and the rest of a dropped frame up to the next `$`).
    pub garbage_bytes: u64,
    /// Frames whose checksum (v1 XOR, v2 CRC-8/DVB-S2) did not match.
    pub bad_checksum: u64,
    /// Frames announcing a payload larger than `max_payload`.
    pub oversize: u64,
    /// `$M` or `$X` followed by a byte that is not `<`, `>` or `!`.
    pub unknown_direction: u64,
}

impl Dropped {
    /// Frames dropped (garbage bytes are bytes, not frames, and are not in it).
    pub fn frames(&self) -> u64 {
        self.bad_checksum + self.oversize + self.unknown_direction
    }
}

/// What the decoder saw since it was made.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Checked frames returned, error replies among them.
    pub frames: u64,
    /// Error replies (`!`) among them.
    pub error_replies: u64,
    pub dropped: Dropped,
}

/// The decoder: feed it bytes, take frames.
#[derive(Debug, Clone)]
pub struct Decoder {
    max_payload: usize,
    buf: Vec<u8>,
    counters: Counters,
}

/// What the buffer's start holds.
enum Step {
    /// An incomplete candidate (or nothing).
    NeedMore,
    /// A bad candidate: its `$` is dropped.
    Drop,
    /// A frame of this many bytes.
    Frame(Frame, usize),
}

impl Decoder {
    pub fn new(settings: DecoderSettings) -> Result<Self, SettingsError> {
        settings.validate()?;
        Ok(Self {
            max_payload: settings.max_payload,
            buf: Vec::with_capacity(Self::capacity(settings.max_payload)),
            counters: Counters::default(),
        })
    }

    /// The buffer's size: the longest frame (a v2 header of 8 bytes, the payload, the CRC).
    const fn capacity(max_payload: usize) -> usize {
        max_payload + 9
    }

    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    /// Bytes held of a frame not complete yet.
    pub fn buffered(&self) -> usize {
        self.buf.len()
    }

    /// Forgets the bytes held (a reconnection); the counters stay.
    pub fn clear(&mut self) {
        self.buf.clear();
    }

    /// The frames `bytes` completes, in order; bytes of an incomplete frame at the end are kept
    /// for the next call. The iterator reads `bytes` as it goes: dropped unfinished, the bytes
    /// it did not reach are not taken.
    pub fn feed<'d, 'b>(&'d mut self, bytes: &'b [u8]) -> Frames<'d, 'b> {
        Frames { decoder: self, input: bytes }
    }

    /// Decodes what the buffer holds up to the next frame.
    fn next_buffered(&mut self) -> Option<Frame> {
        loop {
            // Skip to the next `$`.
            match self.buf.iter().position(|&b| b == START) {
                Some(0) => {}
                Some(at) => {
                    self.counters.dropped.garbage_bytes += at as u64;
                    self.buf.drain(..at);
                }
                None => {
                    self.counters.dropped.garbage_bytes += self.buf.len() as u64;
                    self.buf.clear();
                    return None;
                }
            }
            match self.step() {
                Step::NeedMore => return None,
                Step::Drop => {
                    self.buf.drain(..1);
                }
                Step::Frame(frame, len) => {
                    self.buf.drain(..len);
                    self.counters.frames += 1;
                    if frame.direction == Direction::Error {
                        self.counters.error_replies += 1;
                    }
                    return Some(frame);
                }
            }
        }
    }

    /// Reads the candidate at the buffer's start (`buf[0] == '$'`).
    fn step(&mut self) -> Step {
        let b = &self.buf;
        let Some(&marker) = b.get(1) else { return Step::NeedMore };
        let version = match marker {
            b'M' => Version::V1,
            b'X' => Version::V2,
            _ => {
                self.counters.dropped.garbage_bytes += 1;
                return Step::Drop;
            }
        };
        let Some(&dir) = b.get(2) else { return Step::NeedMore };
        let Some(direction) = Direction::from_byte(dir) else {
            self.counters.dropped.unknown_direction += 1;
            return Step::Drop;
        };
        let (flags, command, size, header) = match version {
            Version::V1 => {
                if b.len() < 5 {
                    return Step::NeedMore;
                }
                if b[3] == frame::JUMBO_SIZE {
                    if b.len() < 7 {
                        return Step::NeedMore;
                    }
                    (0, u16::from(b[4]), usize::from(u16::from_le_bytes([b[5], b[6]])), 7)
                } else {
                    (0, u16::from(b[4]), usize::from(b[3]), 5)
                }
            }
            Version::V2 => {
                if b.len() < 8 {
                    return Step::NeedMore;
                }
                (b[3], u16::from_le_bytes([b[4], b[5]]), usize::from(u16::from_le_bytes([b[6], b[7]])), 8)
            }
        };
        if size > self.max_payload {
            self.counters.dropped.oversize += 1;
            return Step::Drop;
        }
        let len = header + size + 1;
        if b.len() < len {
            return Step::NeedMore;
        }
        let checksum = match version {
            Version::V1 => frame::xor(&b[3..len - 1]),
            Version::V2 => frame::crc8_dvb_s2(0, &b[3..len - 1]),
        };
        if checksum != b[len - 1] {
            self.counters.dropped.bad_checksum += 1;
            return Step::Drop;
        }
        let payload = b[header..header + size].to_vec();
        Step::Frame(Frame { version, direction, flags, command, payload }, len)
    }
}

/// Bytes moved from the input into the buffer at a time.
const FEED_SLICE: usize = 256;

/// The frames of one [`Decoder::feed`].
pub struct Frames<'d, 'b> {
    decoder: &'d mut Decoder,
    input: &'b [u8],
}

impl Iterator for Frames<'_, '_> {
    type Item = Frame;

    fn next(&mut self) -> Option<Frame> {
        loop {
            if let Some(frame) = self.decoder.next_buffered() {
                return Some(frame);
            }
            if self.input.is_empty() {
                return None;
            }
            // The buffer holds at most an incomplete candidate, shorter than the capacity. Input
            // goes in by slices of at most `FEED_SLICE` bytes, so that taking a frame off the
            // buffer's front moves little behind it.
            let room = Decoder::capacity(self.decoder.max_payload) - self.decoder.buf.len();
            let (now, later) = self.input.split_at(room.min(FEED_SLICE).min(self.input.len()));
            self.decoder.buf.extend_from_slice(now);
            self.input = later;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decoder() -> Decoder {
        Decoder::new(DecoderSettings::default()).expect("valid settings")
    }

    fn reply(command: u16, payload: &[u8]) -> Vec<u8> {
        let f =
            Frame { direction: Direction::FromFc, ..Frame::request(Version::V1, command, payload.to_vec()) };
        f.to_bytes().expect("encodes")
    }

    #[test]
    fn a_frame_fed_byte_by_byte_comes_out_once_complete() {
        let mut d = decoder();
        let bytes = reply(1, &[0, 1, 47]);
        for &b in &bytes[..bytes.len() - 1] {
            assert_eq!(d.feed(&[b]).count(), 0);
        }
        let frames: Vec<_> = d.feed(&bytes[bytes.len() - 1..]).collect();
        assert_eq!(frames.len(), 1);
        assert_eq!((frames[0].command, &frames[0].payload[..]), (1, &[0, 1, 47][..]));
        assert_eq!(d.buffered(), 0);
        assert_eq!(d.counters().frames, 1);
    }

    #[test]
    fn a_bad_checksum_is_dropped_and_counted_and_the_next_frame_still_decodes() {
        let mut d = decoder();
        let mut bad = reply(108, &[1, 0, 2, 0, 3, 0]);
        *bad.last_mut().expect("a checksum") ^= 0x55;
        let good = reply(108, &[4, 0, 5, 0, 6, 0]);
        let stream = [bad.clone(), good.clone()].concat();
        let frames: Vec<_> = d.feed(&stream).collect();
        assert_eq!(frames.len(), 1);
        assert_eq!(frames[0].payload, vec![4, 0, 5, 0, 6, 0]);
        assert_eq!(d.counters().dropped.bad_checksum, 1);
        // The bad frame's bytes after its `$` were skipped as garbage.
        assert_eq!(d.counters().dropped.garbage_bytes, bad.len() as u64 - 1);
    }

    #[test]
    fn a_frame_hidden_inside_a_bad_one_is_found_again() {
        // A corrupted header announces 20 bytes; a real frame starts inside them.
        let good = reply(105, &[0xDC, 0x05]);
        let mut stream = vec![b'$', b'M', b'>', 20, 105];
        stream.extend_from_slice(&good);
        stream.extend_from_slice(&[0; 20]);
        let frames: Vec<_> = decoder().feed(&stream).collect();
        assert_eq!(frames.len(), 1);
        assert_eq!(frames[0].payload, vec![0xDC, 0x05]);
    }

    #[test]
    fn oversize_and_unknown_direction_are_dropped_at_the_header_and_counted() {
        let mut d = Decoder::new(DecoderSettings { max_payload: 16 }).expect("valid");
        let big = reply(116, &[b'a'; 17]);
        let mut stream = big.clone();
        stream.extend_from_slice(b"$M?");
        stream.extend_from_slice(&reply(1, &[0, 1, 47]));
        let frames: Vec<_> = d.feed(&stream).collect();
        assert_eq!(frames.len(), 1);
        let c = d.counters();
        assert_eq!((c.dropped.oversize, c.dropped.unknown_direction, c.dropped.frames()), (1, 1, 2));
        // An oversize frame never fills the buffer: its size is refused on sight.
        let mut d = Decoder::new(DecoderSettings { max_payload: 16 }).expect("valid");
        assert_eq!(d.feed(&[b'$', b'X', b'>', 0, 1, 0, 0xFF, 0xFF]).count(), 0);
        assert_eq!(d.counters().dropped.oversize, 1);
        assert!(d.buffered() < 8);
    }

    #[test]
    fn an_error_reply_is_returned_and_counted() {
        let mut d = decoder();
        let mut bytes = reply(200, &[]);
        bytes[2] = b'!';
        let frames: Vec<_> = d.feed(&bytes).collect();
        assert_eq!(frames.len(), 1);
        assert_eq!(frames[0].direction, Direction::Error);
        assert_eq!(d.counters().error_replies, 1);
    }

    #[test]
    fn the_buffer_never_grows_past_one_frame_whatever_the_input() {
        let mut d = Decoder::new(DecoderSettings { max_payload: 32 }).expect("valid");
        let cap = d.buf.capacity();
        // `$X>` headers announcing 32 bytes, each cut short by the next (a random byte passes
        // CRC-8 one time in 256, so a few "frames" of junk come out: what any 8-bit check lets
        // through).
        let mut junk = Vec::new();
        for i in 0..1000u32 {
            junk.extend_from_slice(&[b'$', b'X', b'>', 0, 1, 0, 32, 0]);
            junk.extend_from_slice(&i.to_le_bytes());
        }
        let frames = d.feed(&junk).count() as u64;
        assert!(frames < 20, "{frames}");
        assert!(d.counters().dropped.bad_checksum > 900);
        assert_eq!(d.buf.capacity(), cap);
        assert!(d.buffered() <= 32 + 9);
    }

    #[test]
    fn settings_are_validated() {
        assert_eq!(
            Decoder::new(DecoderSettings { max_payload: 0 }).err(),
            Some(SettingsError::MaxPayload(0))
        );
        assert!(Decoder::new(DecoderSettings { max_payload: 70_000 }).is_err());
        assert!(Decoder::new(DecoderSettings { max_payload: 65_535 }).is_ok());
    }
}
