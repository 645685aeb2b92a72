//! The decoder's contract on streams: any chunking of a stream of frames gives the same frames;
//! garbage between frames is skipped and counted; a corrupted frame is dropped, counted, and
//! costs no other frame.

use msp::{Decoder, DecoderSettings, Direction, Frame, Version};
use proptest::prelude::*;

fn direction() -> impl Strategy<Value = Direction> {
    prop_oneof![Just(Direction::ToFc), Just(Direction::FromFc), Just(Direction::Error)]
}

/// Any frame: v1 (commands 0-255, up to 300 bytes so jumbo frames occur) or v2.
fn frame() -> impl Strategy<Value = Frame> {
    let v1 = (direction(), any::<u8>(), prop::collection::vec(any::<u8>(), 0..300)).prop_map(
        |(direction, c, payload)| Frame {
            version: Version::V1,
            direction,
            flags: 0,
            command: u16::from(c),
            payload,
        },
    );
    let v2 = (direction(), any::<u8>(), any::<u16>(), prop::collection::vec(any::<u8>(), 0..300)).prop_map(
        |(direction, flags, command, payload)| Frame {
            version: Version::V2,
            direction,
            flags,
            command,
            payload,
        },
    );
    prop_oneof![v1, v2]
}

/// Splits `bytes` at the given cut points (any positions, sorted and deduplicated).
fn chunks(bytes: &[u8], mut cuts: Vec<usize>) -> Vec<&[u8]> {
    cuts.iter_mut().for_each(|c| *c %= bytes.len().max(1));
    cuts.sort_unstable();
    cuts.dedup();
    let mut out = Vec::new();
    let mut at = 0;
    for c in cuts {
        out.push(&bytes[at..c]);
        at = c;
    }
    out.push(&bytes[at..]);
    out
}

fn decode_chunked(chunks: &[&[u8]]) -> (Vec<Frame>, Decoder) {
    let mut d = Decoder::new(DecoderSettings::default()).expect("valid");
    let mut frames = Vec::new();
    for c in chunks {
        frames.extend(d.feed(c));
    }
    (frames, d)
}

proptest! {
    #[test]
    fn any_chunking_of_a_stream_of_frames_gives_the_same_frames(
        frames in prop::collection::vec(frame(), 1..12),
        cuts in prop::collection::vec(any::<usize>(), 0..40),
    ) {
        let bytes: Vec<u8> = frames.iter().flat_map(|f| f.to_bytes().expect("encodes")).collect();
        let (decoded, d) = decode_chunked(&chunks(&bytes, cuts));
        prop_assert_eq!(&decoded, &frames);
        prop_assert_eq!(d.counters().frames, frames.len() as u64);
        prop_assert_eq!(d.counters().error_replies, frames.iter().filter(|f| f.direction == Direction::Error).count() as u64);
        prop_assert_eq!(d.counters().dropped, msp::Dropped::default());
        prop_assert_eq!(d.buffered(), 0);
    }

    #[test]
    fn garbage_between_frames_is_skipped_and_counted_byte_for_byte(
        frames in prop::collection::vec(frame(), 1..8),
        // Garbage without `$`: nothing in it can start a frame.
        garbage in prop::collection::vec(prop::collection::vec(any::<u8>().prop_filter("no $", |b| *b != b'$'), 0..50), 8),
        cuts in prop::collection::vec(any::<usize>(), 0..20),
    ) {
        let mut bytes = Vec::new();
        let mut junk = 0;
        for (f, g) in frames.iter().zip(&garbage) {
            bytes.extend_from_slice(g);
            junk += g.len();
            bytes.extend(f.to_bytes().expect("encodes"));
        }
        let (decoded, d) = decode_chunked(&chunks(&bytes, cuts));
        prop_assert_eq!(&decoded, &frames);
        prop_assert_eq!(d.counters().dropped.garbage_bytes, junk as u64);
        prop_assert_eq!(d.counters().dropped.frames(), 0);
    }

    #[test]
    fn a_corrupted_frame_is_dropped_and_counted_and_its_neighbours_come_through(
        before in frame(), after in frame(),
        // Payload bytes without `$`, so the dropped frame's body holds no false start.
        payload in prop::collection::vec(any::<u8>().prop_filter("no $", |b| *b != b'$'), 0..100),
        v2 in any::<bool>(),
        flip in 1u8..=255,
        cuts in prop::collection::vec(any::<usize>(), 0..20),
    ) {
        let version = if v2 { Version::V2 } else { Version::V1 };
        let mut bad = Frame { direction: Direction::FromFc, ..Frame::request(version, 108, payload) }
            .to_bytes().expect("encodes");
        let last = bad.len() - 1;
        bad[last] ^= flip;
        prop_assume!(bad[last] != b'$');
        let bytes = [before.to_bytes().expect("encodes"), bad, after.to_bytes().expect("encodes")].concat();
        let (decoded, d) = decode_chunked(&chunks(&bytes, cuts));
        prop_assert_eq!(decoded, vec![before, after]);
        prop_assert_eq!(d.counters().dropped.bad_checksum, 1);
    }
}
