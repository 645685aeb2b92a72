//! MAVLink 2 message signing (<https://mavlink.io/en/guide/message_signing.html>): a frame
//! carries a link id, a 48-bit timestamp (10 µs units since 2015-01-01 UTC) and the first 6
//! bytes of SHA-256 over the secret key and the frame up to them. [`Signer`] signs what the
//! gateway (or `mavsim`) sends, [`Verifier`] refuses unsigned frames, bad signatures and
//! replayed timestamps. Time is passed in (the shell reads the wall clock, [`stamp_of_unix_us`]);
//! the key file's permissions are the shell's to check.

use crate::trust::Refusal;
use sha2::{Digest, Sha256};
use std::collections::HashMap;

/// The incompatibility flag of a signed MAVLink 2 frame.
const IFLAG_SIGNED: u8 = 0x01;
/// Link id, timestamp and signature.
const SIGNATURE_BLOCK: usize = 13;
/// The MAVLink 2 header, its start byte included.
const HEADER: usize = 10;
/// A minute in signature timestamp units (10 µs): a new stream may start this far behind the
/// newest timestamp seen (the protocol's rule).
const NEW_STREAM_SLACK: u64 = 60 * 100_000;
/// 2015-01-01T00:00:00Z in Unix seconds: the signature timestamps' epoch.
const EPOCH_UNIX_S: u64 = 1_420_070_400;

/// The signature timestamp (10 µs units since 2015-01-01 UTC) of a wall-clock time in µs since
/// the Unix epoch.
pub fn stamp_of_unix_us(unix_us: u64) -> u64 {
    unix_us.saturating_sub(EPOCH_UNIX_S * 1_000_000) / 10
}

/// A 32-byte secret key, shared with the vehicle.
#[derive(Clone, PartialEq, Eq)]
pub struct SigningKey([u8; 32]);

impl std::fmt::Debug for SigningKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("SigningKey(..)")
    }
}

/// Why a key file's contents are not a key.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum KeyError {
    #[error("is empty: a signing key is 32 bytes, or 64 hex digits")]
    Empty,
    #[error(
        "holds {0} bytes: a signing key is 32 bytes, or 64 hex digits (e.g. `sha256sum` of a passphrase)"
    )]
    Length(usize),
}

impl SigningKey {
    pub fn new(key: [u8; 32]) -> Self {
        Self(key)
    }

    /// A key file's contents: 32 bytes, or 64 hex digits (surrounding white space ignored).
    pub fn parse(contents: &[u8]) -> Result<Self, KeyError> {
        if contents.is_empty() {
            return Err(KeyError::Empty);
        }
        if let Ok(key) = <[u8; 32]>::try_from(contents) {
            return Ok(Self(key));
        }
        let text = contents.trim_ascii();
        let hex = |c: u8| (c as char).to_digit(16);
        if text.len() == 64 && text.iter().all(|&c| hex(c).is_some()) {
            let mut key = [0u8; 32];
            for (k, pair) in key.iter_mut().zip(text.chunks(2)) {
                *k = (hex(pair[0]).unwrap_or(0) * 16 + hex(pair[1]).unwrap_or(0)) as u8;
            }
            return Ok(Self(key));
        }
        Err(KeyError::Length(contents.len()))
    }

    /// The first 6 bytes of SHA-256 over the key and `signed` (the frame up to its signature).
    fn signature(&self, signed: &[u8]) -> [u8; 6] {
        let digest = Sha256::new().chain_update(self.0).chain_update(signed).finalize();
        let mut out = [0u8; 6];
        out.copy_from_slice(&digest[..6]);
        out
    }
}

/// Signs outgoing frames with increasing timestamps.
#[derive(Debug, Clone)]
pub struct Signer {
    key: SigningKey,
    link_id: u8,
    last_stamp: u64,
}

impl Signer {
    pub fn new(key: SigningKey, link_id: u8) -> Self {
        Self { key, link_id, last_stamp: 0 }
    }

    /// Signs the unsigned MAVLink 2 frame in `buf[..len]` (as the `mavlink` crate writes it)
    /// at wall time `now_stamp` ([`stamp_of_unix_us`]): sets the signed flag, recomputes the
    /// checksum with the message's `extra_crc`, and appends link id, timestamp and signature;
    /// returns the signed length (`len` + 13; `buf` must hold it: a frame's 280 bytes at most).
    /// The timestamp is the clock's, or one more than the last when the clock did not move on.
    pub fn sign(&mut self, buf: &mut [u8], len: usize, extra_crc: u8, now_stamp: u64) -> usize {
        let stamp = now_stamp.max(self.last_stamp + 1);
        self.last_stamp = stamp;
        buf[2] |= IFLAG_SIGNED;
        let crc_at = len - 2;
        let crc = mavlink::calculate_crc(&buf[1..crc_at], extra_crc);
        buf[crc_at..len].copy_from_slice(&crc.to_le_bytes());
        buf[len] = self.link_id;
        buf[len + 1..len + 7].copy_from_slice(&stamp.to_le_bytes()[..6]);
        let signature = self.key.signature(&buf[..len + 7]);
        buf[len + 7..len + SIGNATURE_BLOCK].copy_from_slice(&signature);
        len + SIGNATURE_BLOCK
    }
}

/// Checks incoming frames: signed with the key, each stream's timestamps increasing.
///
/// A stream not heard before is new, and its first frame must be stamped no earlier than the
/// verifier was opened: the table of streams starts empty (at every start of the gateway), so a
/// frame signed before then, however recent, is a capture being replayed, never the vehicle's
/// next frame. The cost: a vehicle whose clock lags the gateway's is refused until its clock
/// passes the gateway's start (the protocol already asks the two to agree within a minute).
#[derive(Debug, Clone)]
pub struct Verifier {
    key: SigningKey,
    /// The last timestamp of each stream: (link id, system, component).
    streams: HashMap<(u8, u32, u8), u64>,
    /// The newest timestamp seen, or the clock's.
    newest: u64,
    /// The wall time the verifier was opened, as a signature timestamp.
    opened: u64,
}

impl Verifier {
    /// A verifier with `key`, opened at wall time `opened_stamp` (a signature timestamp,
    /// [`stamp_of_unix_us`]).
    pub fn new(key: SigningKey, opened_stamp: u64) -> Self {
        Self { key, streams: HashMap::new(), newest: opened_stamp, opened: opened_stamp }
    }

    /// Whether `frame` (a whole MAVLink frame, checksum already checked) from `system`,
    /// `component` is to be believed, at wall time `now_stamp`.
    pub fn check(&mut self, frame: &[u8], system: u32, component: u8, now_stamp: u64) -> Result<(), Refusal> {
        self.newest = self.newest.max(now_stamp);
        let signed = frame.first() == Some(&0xFD)
            && frame.get(2).is_some_and(|f| f & IFLAG_SIGNED != 0)
            && frame.len() >= HEADER + 2 + SIGNATURE_BLOCK;
        if !signed {
            return Err(Refusal::Unsigned);
        }
        let (covered, signature) = frame.split_at(frame.len() - 6);
        let link_id = frame[frame.len() - SIGNATURE_BLOCK];
        let mut stamp = [0u8; 8];
        stamp[..6].copy_from_slice(&covered[covered.len() - 6..]);
        let stamp = u64::from_le_bytes(stamp);
        if self.key.signature(covered) != signature {
            return Err(Refusal::BadSignature);
        }
        let stream = (link_id, system, component);
        let fresh = match self.streams.get(&stream) {
            Some(&last) => stamp > last,
            None => stamp >= self.opened && stamp + NEW_STREAM_SLACK >= self.newest,
        };
        if !fresh {
            return Err(Refusal::Replayed);
        }
        self.streams.insert(stream, stamp);
        self.newest = self.newest.max(stamp);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::{HEARTBEAT_DATA, MavMessage};
    use mavlink::{MavHeader, Message};

    fn frame(sequence: u8) -> (Vec<u8>, u8) {
        let msg = MavMessage::HEARTBEAT(HEARTBEAT_DATA::default());
        let mut bytes = Vec::new();
        let header = MavHeader { system_id: 1, component_id: 1, sequence };
        mavlink::write_v2_msg(&mut bytes, header, &msg).expect("encodes");
        (bytes, MavMessage::extra_crc(msg.message_id()))
    }

    /// `frame` signed by `signer` at `now`.
    fn signed(signer: &mut Signer, frame: (Vec<u8>, u8), now: u64) -> Vec<u8> {
        let (mut bytes, extra) = frame;
        let len = bytes.len();
        bytes.resize(len + SIGNATURE_BLOCK, 0);
        let n = signer.sign(&mut bytes, len, extra, now);
        bytes.truncate(n);
        bytes
    }

    const NOW: u64 = 3_500_000_000_000;

    #[test]
    fn keys_are_32_bytes_or_64_hex_digits() {
        assert_eq!(SigningKey::parse(&[7; 32]), Ok(SigningKey::new([7; 32])));
        let hex = format!("{}\n", "0a".repeat(32));
        assert_eq!(SigningKey::parse(hex.as_bytes()), Ok(SigningKey::new([10; 32])));
        assert_eq!(SigningKey::parse(b""), Err(KeyError::Empty));
        assert_eq!(SigningKey::parse(&[7; 16]), Err(KeyError::Length(16)));
        assert_eq!(SigningKey::parse(&[b'g'; 64]), Err(KeyError::Length(64)));
        assert!(!format!("{:?}", SigningKey::new([7; 32])).contains('7'), "never printed");
    }

    #[test]
    fn the_unix_epoch_of_2015_is_stamp_zero_and_a_second_is_100_000() {
        assert_eq!(stamp_of_unix_us(EPOCH_UNIX_S * 1_000_000), 0);
        assert_eq!(stamp_of_unix_us((EPOCH_UNIX_S + 1) * 1_000_000), 100_000);
        assert_eq!(stamp_of_unix_us(0), 0);
    }

    #[test]
    fn a_signed_frame_still_decodes_and_verifies_once_and_a_replay_a_wrong_key_or_no_signature_is_refused() {
        let key = SigningKey::new([3; 32]);
        let mut signer = Signer::new(key.clone(), 0);
        let first = signed(&mut signer, frame(0), NOW);
        let (_, msg) = mavlink::MavlinkReader::new(&first[..])
            .read_any_message::<MavMessage>()
            .expect("the checksum holds with the flag set");
        assert!(matches!(msg, MavMessage::HEARTBEAT(_)));
        let mut verifier = Verifier::new(key, NOW);
        assert_eq!(verifier.check(&first, 1, 1, NOW), Ok(()));
        assert_eq!(verifier.check(&first, 1, 1, NOW), Err(Refusal::Replayed), "the same timestamp again");
        // The clock did not move: the next frame's timestamp is one more.
        let next = signed(&mut signer, frame(1), NOW);
        assert_eq!(verifier.check(&next, 1, 1, NOW), Ok(()));
        let (unsigned, _) = frame(2);
        assert_eq!(verifier.check(&unsigned, 1, 1, NOW), Err(Refusal::Unsigned));
        let mut tampered = next.clone();
        tampered[HEADER] ^= 1;
        assert_eq!(verifier.check(&tampered, 1, 1, NOW), Err(Refusal::BadSignature));
        let mut wrong = Signer::new(SigningKey::new([4; 32]), 0);
        let other = signed(&mut wrong, frame(3), NOW + 10);
        assert_eq!(verifier.check(&other, 1, 1, NOW + 10), Err(Refusal::BadSignature));
    }

    #[test]
    fn a_new_stream_more_than_a_minute_behind_the_newest_timestamp_is_a_replay() {
        let key = SigningKey::new([3; 32]);
        // Opened a minute and a half ago, the newest timestamp is now's.
        let opened = NOW - 3 * NEW_STREAM_SLACK / 2;
        let mut verifier = Verifier::new(key.clone(), opened);
        let mut old = Signer::new(key.clone(), 1);
        let stale = signed(&mut old, frame(0), NOW - NEW_STREAM_SLACK - 1);
        assert_eq!(verifier.check(&stale, 1, 1, NOW), Err(Refusal::Replayed));
        let mut recent = Signer::new(key, 2);
        let ok = signed(&mut recent, frame(0), NOW - NEW_STREAM_SLACK);
        assert_eq!(verifier.check(&ok, 1, 1, NOW), Ok(()));
    }

    #[test]
    fn a_new_stream_stamped_before_the_verifier_opened_is_a_replay_however_recent() {
        let key = SigningKey::new([3; 32]);
        // Frames of a vehicle captured in the second before a gateway restarted...
        let mut vehicle = Signer::new(key.clone(), 0);
        let captured: Vec<Vec<u8>> = (0..3).map(|i| signed(&mut vehicle, frame(i), NOW - 100_000)).collect();
        // ...replayed to the restarted gateway, whose table of streams is empty.
        let mut restarted = Verifier::new(key.clone(), NOW);
        for frame in &captured {
            assert_eq!(restarted.check(frame, 1, 1, NOW + 10), Err(Refusal::Replayed));
        }
        // The vehicle's next frame is stamped after the restart: its stream starts.
        let next = signed(&mut vehicle, frame(3), NOW + 20);
        assert_eq!(restarted.check(&next, 1, 1, NOW + 20), Ok(()));
        // The gateway that was running when they were captured took them.
        let mut running = Verifier::new(key, NOW - 200_000);
        assert_eq!(running.check(&captured[0], 1, 1, NOW - 100_000), Ok(()));
    }
}
