//! MSP frames and their encoding.
//!
//! - v1: `$M` + direction + size (u8) + command (u8) + payload + XOR of size, command and
//!   payload. A payload of 255 bytes or more is a *jumbo* frame: size 255, then the real size as
//!   a u16 (little endian) after the command, inside the XOR. Betaflight sends jumbo replies
//!   (`mspSerialEncode`) but accepts no request larger than its 192-byte input buffer.
//! - v2: `$X` + direction + flags (u8) + command (u16) + size (u16) + payload + CRC-8/DVB-S2 of
//!   everything from the flags to the payload's end. Little endian throughout.
//!
//! The direction is `<` (to the flight controller), `>` (its reply) or `!` (its reply saying
//! the command failed or is unknown: Betaflight's `MSP_RESULT_ERROR`).

/// The first byte of every frame.
pub const START: u8 = b'$';
/// A v1 size byte that announces a jumbo frame's u16 size.
pub const JUMBO_SIZE: u8 = 255;

/// Which framing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Version {
    /// `$M`: u8 command, XOR checksum.
    V1,
    /// `$X`: u16 command, flags, CRC-8/DVB-S2.
    V2,
}

impl Version {
    /// The byte after `$`.
    pub const fn marker(self) -> u8 {
        match self {
            Version::V1 => b'M',
            Version::V2 => b'X',
        }
    }
}

/// Who sent the frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// `<`: a request or command to the flight controller.
    ToFc,
    /// `>`: the flight controller's reply.
    FromFc,
    /// `!`: the flight controller's error reply (an unknown command, a bad payload).
    Error,
}

impl Direction {
    /// The byte after the version marker.
    pub const fn byte(self) -> u8 {
        match self {
            Direction::ToFc => b'<',
            Direction::FromFc => b'>',
            Direction::Error => b'!',
        }
    }

    /// The direction a byte stands for (`None`: not a direction).
    pub const fn from_byte(b: u8) -> Option<Self> {
        match b {
            b'<' => Some(Direction::ToFc),
            b'>' => Some(Direction::FromFc),
            b'!' => Some(Direction::Error),
            _ => None,
        }
    }
}

/// One frame, checked.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Frame {
    pub version: Version,
    pub direction: Direction,
    /// v2's flags byte (0 in v1).
    pub flags: u8,
    /// The command (a u8 in v1).
    pub command: u16,
    pub payload: Vec<u8>,
}

impl Frame {
    /// A request to the flight controller.
    pub fn request(version: Version, command: u16, payload: Vec<u8>) -> Self {
        Self { version, direction: Direction::ToFc, flags: 0, command, payload }
    }

    /// Appends the frame's bytes to `out`.
    pub fn encode(&self, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        encode(self.version, self.direction, self.flags, self.command, &self.payload, out)
    }

    /// The frame's bytes.
    pub fn to_bytes(&self) -> Result<Vec<u8>, EncodeError> {
        let mut out = Vec::with_capacity(self.payload.len() + 9);
        self.encode(&mut out)?;
        Ok(out)
    }
}

/// A frame that cannot be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    #[error("MSP v1 carries commands 0-255, not {0} (use v2)")]
    CommandTooLarge(u16),
    #[error("MSP v1 carries no flags (got {0:#04x}; use v2)")]
    FlagsInV1(u8),
    #[error("a payload of {0} bytes is more than a frame's u16 size can say")]
    PayloadTooLarge(usize),
}

/// Appends one frame to `out`; nothing is appended on an error.
pub fn encode(
    version: Version,
    direction: Direction,
    flags: u8,
    command: u16,
    payload: &[u8],
    out: &mut Vec<u8>,
) -> Result<(), EncodeError> {
    let size = u16::try_from(payload.len()).map_err(|_| EncodeError::PayloadTooLarge(payload.len()))?;
    match version {
        Version::V1 => {
            let command = u8::try_from(command).map_err(|_| EncodeError::CommandTooLarge(command))?;
            if flags != 0 {
                return Err(EncodeError::FlagsInV1(flags));
            }
            out.extend_from_slice(&[START, b'M', direction.byte()]);
            let header_at = out.len();
            if size >= u16::from(JUMBO_SIZE) {
                out.extend_from_slice(&[JUMBO_SIZE, command]);
                out.extend_from_slice(&size.to_le_bytes());
            } else {
                out.extend_from_slice(&[size as u8, command]);
            }
            out.extend_from_slice(payload);
            let checksum = xor(&out[header_at..]);
            out.push(checksum);
        }
        Version::V2 => {
            out.extend_from_slice(&[START, b'X', direction.byte(), flags]);
            let header_at = out.len() - 1;
            out.extend_from_slice(&command.to_le_bytes());
            out.extend_from_slice(&size.to_le_bytes());
            out.extend_from_slice(payload);
            let crc = crc8_dvb_s2(0, &out[header_at..]);
            out.push(crc);
        }
    }
    Ok(())
}

/// v1's checksum: the XOR of the bytes.
pub fn xor(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0, |acc, b| acc ^ b)
}

/// v2's checksum: CRC-8/DVB-S2 (polynomial 0xD5, no reflection, no final XOR), continued from
/// `crc`.
pub fn crc8_dvb_s2(crc: u8, bytes: &[u8]) -> u8 {
    bytes.iter().fold(crc, |mut crc, &b| {
        crc ^= b;
        for _ in 0..8 {
            crc = if crc & 0x80 != 0 { (crc << 1) ^ 0xD5 } else { crc << 1 };
        }
        crc
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc8_dvb_s2_matches_the_catalogued_check_value() {
        // The CRC catalogue's check value for CRC-8/DVB-S2 over "123456789".
        assert_eq!(crc8_dvb_s2(0, b"123456789"), 0xBC);
    }

    #[test]
    fn a_v1_request_without_payload_is_six_bytes_with_the_xor_of_size_and_command() {
        let f = Frame::request(Version::V1, 1, vec![]);
        assert_eq!(f.to_bytes(), Ok(vec![b'$', b'M', b'<', 0, 1, 1]));
        let f = Frame::request(Version::V1, 200, vec![0xDC, 0x05]);
        assert_eq!(f.to_bytes(), Ok(vec![b'$', b'M', b'<', 2, 200, 0xDC, 0x05, 2 ^ 200 ^ 0xDC ^ 0x05]));
    }

    #[test]
    fn a_v1_payload_of_255_bytes_or_more_is_a_jumbo_frame_whose_size_is_inside_the_checksum() {
        let payload: Vec<u8> = (0..300u16).map(|i| i as u8).collect();
        let f = Frame { direction: Direction::FromFc, ..Frame::request(Version::V1, 116, payload.clone()) };
        let bytes = f.to_bytes().expect("encodes");
        assert_eq!(&bytes[..7], &[b'$', b'M', b'>', 255, 116, 44, 1]);
        assert_eq!(bytes.len(), 3 + 4 + 300 + 1);
        assert_eq!(*bytes.last().expect("a checksum"), xor(&bytes[3..bytes.len() - 1]));
        // 254 bytes still fit the size byte.
        let short = Frame::request(Version::V1, 116, vec![0; 254]).to_bytes().expect("encodes");
        assert_eq!(short[3], 254);
        assert_eq!(short.len(), 6 + 254);
    }

    #[test]
    fn a_v2_frame_has_flags_u16_command_and_size_and_a_crc_over_them_and_the_payload() {
        let f = Frame { flags: 0, ..Frame::request(Version::V2, 0x3003, vec![1, 2, 3]) };
        let bytes = f.to_bytes().expect("encodes");
        assert_eq!(&bytes[..8], &[b'$', b'X', b'<', 0, 0x03, 0x30, 3, 0]);
        assert_eq!(bytes[11], crc8_dvb_s2(0, &bytes[3..11]));
    }

    #[test]
    fn what_v1_cannot_say_is_refused_and_nothing_is_written() {
        let mut out = vec![7];
        assert_eq!(
            encode(Version::V1, Direction::ToFc, 0, 256, &[], &mut out),
            Err(EncodeError::CommandTooLarge(256))
        );
        assert_eq!(encode(Version::V1, Direction::ToFc, 1, 1, &[], &mut out), Err(EncodeError::FlagsInV1(1)));
        assert_eq!(
            encode(Version::V2, Direction::ToFc, 0, 1, &vec![0; 70_000], &mut out),
            Err(EncodeError::PayloadTooLarge(70_000))
        );
        assert_eq!(out, vec![7]);
    }
}
