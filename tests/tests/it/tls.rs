//! Mutual TLS on every server (plant, netem, controller, gateway), each set up by svc's shared
//! code from files made at test time (`hilbench::certs`, no key committed): a client without a
//! certificate, with one from another CA, or speaking plaintext is refused; one with a
//! certificate from the servers' CA is served; netem reaches its plant over mutual TLS.

use std::path::{Path, PathBuf};
use std::time::Duration;

use gateway::{GatewayConfig, GatewayError, Link};
use hilbench_proto::pb;
use hilbench_proto::pb::plant_client::PlantClient;
use hilbench_svc::error_chain;
use hilbench_svc::tls::{Tls, TlsFiles};
use hilbench_tests::server::{self, Running};
use hilbench_tests::{RunningController, RunningPlant, start_controller, start_plant};
use mav::Scenario;
use mpc::ControllerMode;
use plant::PlantConfig;
use tonic_health::pb::HealthCheckRequest;
use tonic_health::pb::health_check_response::ServingStatus;
use tonic_health::pb::health_client::HealthClient;

/// A fresh `hilbench certs` directory (a CA of its own) under the test's temporary directory.
fn certificates(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("tls-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    hilbench::commands::certs::write_dir(&dir, &[], hilbench::commands::certs::DEFAULT_DAYS)
        .expect("certificates");
    dir
}

/// Server `name`'s TLS from `dir`: its identity, client certificates required from the CA,
/// and (for the services that are clients too) the CA trusted upstream.
fn server_tls(dir: &Path, name: &str, is_client: bool) -> Tls {
    let files = TlsFiles::in_dir(dir, name);
    let files = if is_client { files } else { TlsFiles { ca: None, ..files } };
    files.load().expect("the server's TLS files load")
}

/// Every server, over mutual TLS with the certificates of `dir`: a plant, a netem in front of
/// it, a controller flying through netem (idle), and a gateway.
struct Servers {
    plant: RunningPlant,
    netem: Running<netem::NetemError>,
    controller: RunningController,
    gateway: Running<GatewayError>,
}

impl Servers {
    async fn start(dir: &Path) -> Self {
        let plant =
            start_plant(PlantConfig { tls: server_tls(dir, "plant", false), ..PlantConfig::default() }).await;
        let mut netem_config = netem::Config::new(plant.addr.to_string());
        netem_config.tls = server_tls(dir, "netem", true);
        let netem =
            server::start("netem", move |listener, shutdown| netem::serve(listener, netem_config, shutdown))
                .await;
        let mut controller_config = controller::ControllerConfig::new(
            netem.addr.to_string(),
            Scenario::paper_1(),
            ControllerMode::Nmpc,
        );
        controller_config.autostart = false;
        controller_config.tls = server_tls(dir, "controller", true);
        let controller = start_controller(controller_config).await;
        let link = Link::open("udpin:127.0.0.1:0", 255, 191).expect("a loopback UDP port");
        let port = link.local_addr.expect("bound").port();
        let mut gateway_config = GatewayConfig::new(format!("udpin:127.0.0.1:{port}"), Scenario::paper_1());
        gateway_config.tls = server_tls(dir, "gateway", false);
        let gateway = server::start("gateway", move |listener, shutdown| {
            gateway::serve_with_link(listener, gateway_config, link, shutdown)
        })
        .await;
        Self { plant, netem, controller, gateway }
    }

    fn addresses(&self) -> [(&'static str, String); 4] {
        [
            ("plant", self.plant.addr.to_string()),
            ("netem", self.netem.addr.to_string()),
            ("controller", self.controller.addr.to_string()),
            ("gateway", self.gateway.addr.to_string()),
        ]
    }
}

/// The health check of `address` as `tls`'s client: its status, or why the call failed (the
/// connection, the handshake, or the call after it).
async fn health(address: &str, tls: &Tls) -> Result<i32, String> {
    let endpoint = tls.endpoint(address).map_err(|e| e.to_string())?.connect_timeout(Duration::from_secs(5));
    let channel = endpoint.connect().await.map_err(|e| error_chain(&e))?;
    let answer = HealthClient::new(channel)
        .check(HealthCheckRequest { service: String::new() })
        .await
        .map_err(|e| format!("{e}"))?;
    Ok(answer.into_inner().status)
}

/// The control of each refusal: the same server serves a client with the right certificate
/// (so a refusal is the TLS set-up's, not a server that failed to start).
async fn served_with_the_right_certificate(dir: &Path, name: &str, address: &str) {
    let status = health(address, &client(dir, dir)).await;
    assert_eq!(status, Ok(ServingStatus::Serving as i32), "{name} at {address}");
}

/// hilbench's identity in `identity_dir`, trusting the CA of `ca_dir`.
fn client(identity_dir: &Path, ca_dir: &Path) -> Tls {
    TlsFiles {
        ca: Some(ca_dir.join("ca.pem")),
        client_ca: None,
        ..TlsFiles::in_dir(identity_dir, "hilbench")
    }
    .load()
    .expect("the client's TLS files load")
}

#[tokio::test]
async fn every_server_serves_a_client_with_a_certificate_from_its_ca_and_netem_reaches_its_plant_over_mtls() {
    let dir = certificates("served");
    let servers = Servers::start(&dir).await;
    let tls = client(&dir, &dir);
    for (name, address) in servers.addresses() {
        let status = health(&address, &tls).await;
        assert_eq!(status, Ok(ServingStatus::Serving as i32), "{name} at {address}");
    }
    // Describe through netem is answered by the plant behind it: netem's upstream link (its
    // certificate presented to the plant, the plant's checked against the CA) works.
    let channel =
        tls.endpoint(&servers.netem.addr.to_string()).expect("endpoint").connect().await.expect("netem");
    let described = PlantClient::new(channel).describe(pb::DescribeRequest {}).await;
    assert!(described.is_ok(), "Describe through netem over mutual TLS: {described:?}");
}

#[tokio::test]
async fn every_server_refuses_a_client_without_a_certificate() {
    let dir = certificates("no-client-cert");
    let servers = Servers::start(&dir).await;
    let trusting_only =
        TlsFiles { ca: Some(dir.join("ca.pem")), ..TlsFiles::default() }.load().expect("loads");
    for (name, address) in servers.addresses() {
        served_with_the_right_certificate(&dir, name, &address).await;
        let status = health(&address, &trusting_only).await;
        assert!(status.is_err(), "{name} served a client without a certificate: {status:?}");
    }
}

#[tokio::test]
async fn every_server_refuses_a_client_certificate_from_another_ca() {
    let dir = certificates("served-by-one-ca");
    let other = certificates("another-ca");
    let servers = Servers::start(&dir).await;
    // The client trusts the servers' CA, and presents a certificate another CA signed.
    let stranger = client(&other, &dir);
    for (name, address) in servers.addresses() {
        served_with_the_right_certificate(&dir, name, &address).await;
        let status = health(&address, &stranger).await;
        assert!(status.is_err(), "{name} served a client certified by another CA: {status:?}");
    }
}

#[tokio::test]
async fn every_server_refuses_a_plaintext_client_and_a_client_refuses_a_server_of_another_ca() {
    let dir = certificates("plaintext-refused");
    let other = certificates("untrusted-servers");
    let servers = Servers::start(&dir).await;
    let wary = client(&other, &other);
    for (name, address) in servers.addresses() {
        served_with_the_right_certificate(&dir, name, &address).await;
        let plaintext = health(&address, &Tls::plaintext()).await;
        assert!(plaintext.is_err(), "{name} served a plaintext client: {plaintext:?}");
        let untrusted = health(&address, &wary).await;
        let why = untrusted.expect_err("a server certified by an untrusted CA is refused");
        assert!(why.contains("certificate"), "{name}: the refusal says why: {why}");
        let endpoint = wary.endpoint(&address).expect("endpoint");
        let refusal = endpoint.connect().await.expect_err("refused");
        assert!(
            hilbench_svc::tls::is_tls_refusal(&refusal),
            "{name}: not told from a server not up yet: {refusal:?}"
        );
    }
}

/// Waits up to 15 s for `log` to hold `text`.
fn log_says(log: &Path, text: &str) -> bool {
    let deadline = std::time::Instant::now() + Duration::from_secs(15);
    while std::time::Instant::now() < deadline {
        if std::fs::read_to_string(log).is_ok_and(|l| l.contains(text)) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    false
}

const PLAINTEXT_WARNING: &str = "serving plaintext gRPC on an address other than loopback";

/// Plaintext stays the default, with a warning when the address is reachable from elsewhere:
/// every server binary (plant, netem, controller, gateway) started on 0.0.0.0 without TLS says
/// so in its log; on loopback it does not.
#[test]
fn every_server_warns_when_it_serves_plaintext_beyond_loopback_and_not_on_loopback() {
    let dir = hilbench_tests::TempDir::new("plaintext-warning");
    let any = |loopback: &str| loopback.replace("127.0.0.1", "0.0.0.0");
    // The plant on loopback: served (the others reach it), no warning.
    let plant_addr = hilbench_tests::free_loopback_address();
    let plant_log = dir.join("plant-loopback.log");
    let _plant = hilbench_tests::Service::start_logged("plant", &["--listen", &plant_addr], &plant_log);
    assert!(log_says(&plant_log, "plant serving"), "{:?}", std::fs::read_to_string(&plant_log));
    let servers: [(&str, Vec<String>); 4] = [
        ("plant", vec![]),
        ("netem", vec!["--plant".into(), plant_addr.clone()]),
        ("controller", vec!["--plant".into(), plant_addr.clone()]),
        ("gateway", vec!["--mavlink".into(), "udpin:127.0.0.1:0".into()]),
    ];
    let mut running = Vec::new();
    for (name, extra) in servers {
        let log = dir.join(format!("{name}-any.log"));
        let listen = any(&hilbench_tests::free_loopback_address());
        let mut args = vec!["--listen".to_string(), listen];
        args.extend(extra);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        running.push(hilbench_tests::Service::start_logged(name, &args, &log));
        assert!(log_says(&log, PLAINTEXT_WARNING), "{name} on 0.0.0.0: {:?}", std::fs::read_to_string(&log));
    }
    // The warning comes before the plant serves.
    let said = std::fs::read_to_string(&plant_log).expect("the plant's log");
    assert!(!said.contains(PLAINTEXT_WARNING), "{said}");
}
