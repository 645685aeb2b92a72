//! Lockstep over gRPC on loopback: one round trip = apply a command + advance 1 ms + read the
//! state, i.e. one `Step` call (the way a lockstep driver uses the plant), plus the same work as
//! three separate calls (`ApplyCommand`, `Advance`, `GetState`) for comparison.
//! Target (BENCHMARKS.md): at least 5,000 round trips per second.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use hilbench_proto::pb;
use hilbench_proto::pb::plant_client::PlantClient;
use plant::PlantConfig;
use std::hint::black_box;
use tonic::transport::Channel;

fn command(seq: u64) -> pb::Command {
    pb::Command {
        input: Some(pb::ControlInput {
            thrust_mps2: 9.81 + 0.01 * (seq % 10) as f64,
            roll_rad: 0.01,
            pitch_rad: 0.0,
        }),
        command_seq: seq,
        based_on_sample_seq: seq,
        based_on_sample_time_ns: seq * 1_000_000,
    }
}

fn roundtrip(c: &mut Criterion) {
    let rt = match tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build() {
        Ok(rt) => rt,
        Err(e) => panic!("tokio runtime: {e}"),
    };
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let (mut client, server) = rt.block_on(async {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("bind loopback");
        let addr = listener.local_addr().expect("bound address");
        let server = tokio::spawn(plant::serve(listener, PlantConfig::default(), async {
            let _ = stopped.await;
        }));
        let channel =
            Channel::from_shared(format!("http://{addr}")).expect("uri").connect().await.expect("connect");
        (PlantClient::new(channel), server)
    });

    let mut group = c.benchmark_group("plant_lockstep_grpc");
    group.throughput(Throughput::Elements(1));
    let mut seq = 0u64;
    group.bench_function("step_apply_advance_1ms_read", |b| {
        b.iter(|| {
            seq += 1;
            let req =
                pb::StepRequest { command: Some(command(seq)), duration_ns: 1_000_000, ..Default::default() };
            let r = rt.block_on(client.step(req)).expect("step");
            black_box(r.into_inner());
        })
    });
    group.bench_function("apply_then_advance_1ms_then_get_state", |b| {
        b.iter(|| {
            seq += 1;
            rt.block_on(async {
                client.apply_command(command(seq)).await.expect("apply");
                client
                    .advance(pb::AdvanceRequest { duration_ns: 1_000_000, ..Default::default() })
                    .await
                    .expect("advance");
                black_box(client.get_state(pb::GetStateRequest {}).await.expect("state").into_inner());
            })
        })
    });
    group.finish();
    let _ = stop.send(());
    let _ = rt.block_on(server);
}

criterion_group!(benches, roundtrip);
criterion_main!(benches);
