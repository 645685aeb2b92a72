//! Lockstep over gRPC on loopback: one round trip = apply a command + advance 1 ms + read the
//! state, i.e. one `Step` call (the way a lockstep driver uses the plant), plus the same work as
//! three separate calls (`ApplyCommand`, `Advance`, `GetState`) for comparison.
//! Target (BENCHMARKS.md): at least 5,000 round trips per second. `step_..._mtls`: the same
//! `Step` over mutual TLS (svc's set-up, certificates made here with rcgen), for its cost.

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

/// A CA and one identity for 127.0.0.1 (the plant's, presented by the client too), in a
/// temporary directory: the files of a plant that requires client certificates, and of its
/// client.
fn mtls_files() -> (hilbench_svc::tls::TlsFiles, hilbench_svc::tls::TlsFiles) {
    use rcgen::{BasicConstraints, CertificateParams, CertifiedIssuer, IsCa, KeyPair};
    let dir = std::env::temp_dir().join(format!("plant-bench-mtls-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let mut ca_params = CertificateParams::new(Vec::<String>::new()).expect("params");
    ca_params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    let ca = CertifiedIssuer::self_signed(ca_params, KeyPair::generate().expect("key")).expect("CA");
    let key = KeyPair::generate().expect("key");
    let cert = CertificateParams::new(vec!["127.0.0.1".to_string()])
        .expect("params")
        .signed_by(&key, &ca)
        .expect("certificate");
    for (name, pem) in
        [("ca.pem", ca.pem()), ("plant.pem", cert.pem()), ("plant-key.pem", key.serialize_pem())]
    {
        std::fs::write(dir.join(name), pem).expect("write");
    }
    let files = hilbench_svc::tls::TlsFiles::in_dir(&dir, "plant");
    let server = hilbench_svc::tls::TlsFiles { ca: None, ..files.clone() };
    let client = hilbench_svc::tls::TlsFiles { client_ca: None, ..files };
    (server, client)
}

/// A plant in lockstep on loopback with `tls`, and a client of it with `client_tls`.
async fn plant_and_client(
    tls: hilbench_svc::tls::Tls,
    client_tls: &hilbench_svc::tls::Tls,
    stopped: tokio::sync::oneshot::Receiver<()>,
) -> (PlantClient<Channel>, tokio::task::JoinHandle<Result<(), plant::PlantError>>) {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("bind loopback");
    let addr = listener.local_addr().expect("bound address");
    let config = PlantConfig { tls, ..PlantConfig::default() };
    let server = tokio::spawn(plant::serve(listener, config, async {
        let _ = stopped.await;
    }));
    let channel = client_tls.endpoint(&addr.to_string()).expect("endpoint").connect().await.expect("connect");
    (PlantClient::new(channel), server)
}

fn roundtrip(c: &mut Criterion) {
    let rt = match tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build() {
        Ok(rt) => rt,
        Err(e) => panic!("tokio runtime: {e}"),
    };
    let plaintext = hilbench_svc::tls::Tls::plaintext();
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let (mut client, server) = rt.block_on(plant_and_client(plaintext.clone(), &plaintext, stopped));
    let (server_files, client_files) = mtls_files();
    let (server_tls, client_tls) =
        (server_files.load().expect("server TLS"), client_files.load().expect("client TLS"));
    let (stop_mtls, stopped_mtls) = tokio::sync::oneshot::channel::<()>();
    let (mut mtls_client, mtls_server) = rt.block_on(plant_and_client(server_tls, &client_tls, stopped_mtls));

    let mut group = c.benchmark_group("plant_lockstep_grpc");
    group.throughput(Throughput::Elements(1));
    let mut seq = 0u64;
    for (name, client) in
        [("step_apply_advance_1ms_read", &mut client), ("step_apply_advance_1ms_read_mtls", &mut mtls_client)]
    {
        group.bench_function(name, |b| {
            b.iter(|| {
                seq += 1;
                let req = pb::StepRequest {
                    command: Some(command(seq)),
                    duration_ns: 1_000_000,
                    ..Default::default()
                };
                let r = rt.block_on(client.step(req)).expect("step");
                black_box(r.into_inner());
            })
        });
    }
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
    let _ = stop_mtls.send(());
    let _ = rt.block_on(server);
    let _ = rt.block_on(mtls_server);
}

criterion_group!(benches, roundtrip);
criterion_main!(benches);
