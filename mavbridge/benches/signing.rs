//! What MAVLink 2 signing costs the gateway per frame (issue 34, BENCHMARKS.md "The gateway"):
//! a `SET_ATTITUDE_TARGET` encoded as the gateway sends it, unsigned and signed, and a
//! `LOCAL_POSITION_NED` as it arrives, parsed alone and parsed and verified. Run:
//! `cargo bench -p mavbridge --bench signing`.

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use mavbridge::mavlink::dialects::common::{LOCAL_POSITION_NED_DATA, MavMessage, SET_ATTITUDE_TARGET_DATA};
use mavbridge::mavlink::{self, MavHeader, Message};
use mavbridge::signing::{Signer, SigningKey, Verifier};
use std::hint::black_box;

/// A signature timestamp in 2026 (10 µs units since 2015).
const NOW: u64 = 3_500_000_000_000;
const HEADER: MavHeader = MavHeader { system_id: 255, component_id: 191, sequence: 0 };

fn encode(msg: &MavMessage, out: &mut Vec<u8>) -> usize {
    out.clear();
    mavlink::write_v2_msg(out, HEADER, msg).expect("encodes")
}

fn bench(c: &mut Criterion) {
    let key = SigningKey::new([7; 32]);
    let setpoint = MavMessage::SET_ATTITUDE_TARGET(SET_ATTITUDE_TARGET_DATA {
        q: [1.0, 0.0, 0.0, 0.0],
        thrust: 0.5,
        ..Default::default()
    });
    let extra = MavMessage::extra_crc(setpoint.message_id());
    let mut buf = Vec::with_capacity(300);
    c.bench_function("setpoint encoded, unsigned", |b| b.iter(|| black_box(encode(&setpoint, &mut buf))));
    let mut signer = Signer::new(key.clone(), 0);
    let mut now = NOW;
    c.bench_function("setpoint encoded and signed", |b| {
        b.iter(|| {
            let len = encode(&setpoint, &mut buf);
            buf.resize(len + 13, 0);
            now += 1;
            black_box(signer.sign(&mut buf, len, extra, now))
        })
    });

    let state = MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
        x: 1.0,
        y: 2.0,
        z: -3.0,
        ..Default::default()
    });
    let state_extra = MavMessage::extra_crc(state.message_id());
    let mut state_signer = Signer::new(key.clone(), 0);
    let mut stamp = NOW;
    let mut signed_state = || {
        let mut frame = Vec::with_capacity(300);
        let len = mavlink::write_v2_msg(
            &mut frame,
            MavHeader { system_id: 1, component_id: 1, sequence: 0 },
            &state,
        )
        .expect("encodes");
        frame.resize(len + 13, 0);
        stamp += 1;
        let n = state_signer.sign(&mut frame, len, state_extra, stamp);
        frame.truncate(n);
        frame
    };
    let unsigned = {
        let mut frame = Vec::new();
        mavlink::write_v2_msg(&mut frame, MavHeader { system_id: 1, component_id: 1, sequence: 0 }, &state)
            .expect("encodes");
        frame
    };
    c.bench_function("state parsed, unsigned", |b| {
        b.iter(|| {
            let parsed =
                mavlink::MavlinkReader::new(black_box(&unsigned[..])).read_any_message::<MavMessage>();
            black_box(parsed.is_ok())
        })
    });
    let mut verifier = Verifier::new(key, NOW);
    c.bench_function("state parsed and verified", |b| {
        b.iter_batched(
            &mut signed_state,
            |frame| {
                let parsed = mavlink::MavlinkReader::new(&frame[..]).read_any_message::<MavMessage>();
                let verified = verifier.check(&frame, 1, 1, NOW);
                black_box((parsed.is_ok(), verified.is_ok()))
            },
            BatchSize::SmallInput,
        )
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
