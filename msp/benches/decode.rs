//! What decoding costs per frame: a stream of the replies a gateway reads at its telemetry
//! rate (MSP_STATUS_EX, MSP_ATTITUDE, MSP_RC, MSP_MOTOR, an empty MSP_SET_RAW_RC ack), fed in
//! one piece and in TCP-like chunks of 64 bytes, and the same stream with garbage between the
//! frames. Run: `cargo bench -p msp --bench decode`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use msp::messages::{Attitude, Motor, Rc};
use msp::{Decoder, DecoderSettings, Direction, Frame, Version, command};
use std::hint::black_box;

fn reply(version: Version, command: u16, payload: Vec<u8>) -> Vec<u8> {
    Frame { direction: Direction::FromFc, ..Frame::request(version, command, payload) }
        .to_bytes()
        .expect("encodes")
}

fn stream(garbage: bool) -> (Vec<u8>, u64) {
    let mut out = Vec::new();
    let mut frames = 0;
    for i in 0..200u16 {
        let version = if i % 2 == 0 { Version::V1 } else { Version::V2 };
        let status = vec![0x7d, 0, 0, 0, 0x23, 0, 3, 0, 0, 0, 0, 0, 0, 4, 0, 0, 0x1d, 0, 0, 0, 0, 0, 0, 0, 4];
        let attitude = Attitude { roll_decideg: i as i16, pitch_decideg: -(i as i16), yaw_deg: 90 }.encode();
        let rc = Rc(vec![1500 + i; 18]).encode();
        let motor = Motor([1000 + i; 8]).encode();
        for (c, p) in [
            (command::STATUS_EX, status),
            (command::ATTITUDE, attitude),
            (command::RC, rc),
            (command::MOTOR, motor),
            (command::SET_RAW_RC, vec![]),
        ] {
            out.extend(reply(version, c, p));
            frames += 1;
            if garbage {
                out.extend_from_slice(b"\x00\xffnoise\r\n");
            }
        }
    }
    (out, frames)
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("decode");
    for (name, garbage) in [("clean", false), ("with garbage", true)] {
        let (bytes, frames) = stream(garbage);
        group.throughput(Throughput::Elements(frames));
        group.bench_function(format!("{name}, one piece"), |b| {
            let mut d = Decoder::new(DecoderSettings::default()).expect("valid");
            b.iter(|| black_box(d.feed(black_box(&bytes)).count()))
        });
        group.bench_function(format!("{name}, 64-byte chunks"), |b| {
            let mut d = Decoder::new(DecoderSettings::default()).expect("valid");
            b.iter(|| bytes.chunks(64).map(|chunk| d.feed(black_box(chunk)).count()).sum::<usize>())
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
