//! A service's connections against peers that hold them without speaking: the handshake
//! deadline, the connection cap, HTTP/2 keep-alive, and refused TLS handshakes counted and
//! logged with the peer. Each test starts a real `GrpcServer` (health and reflection) on
//! loopback and talks to it with raw TCP or a tonic client.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use hilbench_svc::GrpcServer;
use hilbench_svc::connections::{ConnectionLimits, ConnectionStats};
use hilbench_svc::tls::{Tls, TlsFiles};
use rcgen::{BasicConstraints, CertificateParams, CertifiedIssuer, DnType, IsCa, KeyPair};
use tonic_health::pb::HealthCheckRequest;
use tonic_health::pb::health_client::HealthClient;

/// HTTP/2's client connection preface (RFC 9113, 3.4).
const PREFACE: &[u8] = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n";
/// An empty SETTINGS frame: length 0, type 4, flags 0, stream 0.
const EMPTY_SETTINGS: [u8; 9] = [0, 0, 0, 4, 0, 0, 0, 0, 0];
/// Far above every deadline the tests set: a read still blocked after this is a hold.
const PATIENCE: Duration = Duration::from_secs(15);

struct Running {
    addr: SocketAddr,
    stats: Arc<ConnectionStats>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<Result<(), hilbench_svc::ServeError>>,
}

impl Running {
    async fn start(tls: &Tls, limits: ConnectionLimits) -> Self {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("bind");
        let server =
            GrpcServer::new("test", listener, false, tls, &limits, &["test.Test"]).await.expect("server");
        let (addr, stats) = (server.addr, server.connections.clone());
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let task = tokio::spawn(server.serve(|router| router, async {
            let _ = stopped.await;
        }));
        Self { addr, stats, stop: Some(stop), task }
    }

    /// `[served, refused_at_cap, handshake_timeouts, tls_refused, evicted]`.
    fn counts(&self) -> [u64; 5] {
        self.stats.snapshot()
    }

    /// The counts once they equal `expected` (a connection is closed just before its refusal
    /// is counted), or as they are after [`PATIENCE`].
    async fn counts_become(&self, expected: [u64; 5]) -> [u64; 5] {
        let start = std::time::Instant::now();
        while self.counts() != expected && start.elapsed() < PATIENCE {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        self.counts()
    }

    async fn stop(mut self) {
        let _ = self.stop.take().map(|s| s.send(()));
        self.task.await.expect("server task").expect("server");
    }
}

fn limits(handshake_s: f64) -> ConnectionLimits {
    ConnectionLimits {
        handshake_timeout: Duration::from_secs_f64(handshake_s),
        ..ConnectionLimits::default()
    }
}

/// Reads until the server closes the connection (EOF or reset) and says how long that took,
/// or `None` when it is still open after [`PATIENCE`]. Blocking: run it off the runtime.
fn wait_for_close(mut tcp: TcpStream) -> Option<Duration> {
    let start = std::time::Instant::now();
    tcp.set_read_timeout(Some(PATIENCE)).expect("timeout");
    let mut buf = [0u8; 4096];
    loop {
        match tcp.read(&mut buf) {
            Ok(0) => return Some(start.elapsed()),
            Ok(_) => continue,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {
                return None;
            }
            Err(_) => return Some(start.elapsed()),
        }
    }
}

async fn closed(tcp: TcpStream) -> Option<Duration> {
    tokio::task::spawn_blocking(move || wait_for_close(tcp)).await.expect("reader")
}

async fn health(addr: SocketAddr) -> Result<i32, Box<dyn std::error::Error>> {
    let channel = tonic::transport::Channel::from_shared(format!("http://{addr}"))?.connect().await?;
    let answer = HealthClient::new(channel).check(HealthCheckRequest { service: "test.Test".into() }).await?;
    Ok(answer.into_inner().status)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_connection_that_sends_nothing_is_closed_at_the_handshake_deadline_and_counted() {
    let server = Running::start(&Tls::plaintext(), limits(0.3)).await;
    let silent = TcpStream::connect(server.addr).expect("connect");
    assert!(closed(silent).await.is_some(), "a silent connection was held past {PATIENCE:?}");
    assert_eq!(
        server.counts_become([1, 0, 1, 0, 0]).await,
        [1, 0, 1, 0, 0],
        "served, at cap, handshake timeouts, TLS refused, evicted"
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_connection_that_sends_only_the_http2_preface_is_closed_at_the_handshake_deadline() {
    let server = Running::start(&Tls::plaintext(), limits(0.3)).await;
    let mut half = TcpStream::connect(server.addr).expect("connect");
    half.write_all(PREFACE).expect("preface");
    assert!(closed(half).await.is_some(), "a connection that sent only the preface was held");
    assert_eq!(
        server.counts_become([1, 0, 1, 0, 0]).await,
        [1, 0, 1, 0, 0],
        "the handshake timeout is counted"
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn at_the_cap_a_new_connection_evicts_the_oldest_still_in_its_handshake_so_silent_peers_cannot_keep_a_client_off()
 {
    // A deadline far beyond the test: only eviction can free a place.
    let server =
        Running::start(&Tls::plaintext(), ConnectionLimits { max_connections: 4, ..limits(60.0) }).await;
    let silent: Vec<TcpStream> = (0..4).map(|_| TcpStream::connect(server.addr).expect("connect")).collect();
    tokio::time::sleep(Duration::from_millis(200)).await;
    // The cap is held by four silent peers that never time out here: a client is served.
    let status = health(server.addr).await.expect("a client is served while silent peers hold the cap");
    assert_eq!(status, tonic_health::pb::health_check_response::ServingStatus::Serving as i32);
    let [served, at_cap, timeouts, _, evicted] = server.counts();
    assert_eq!((served, at_cap, timeouts, evicted), (5, 0, 0, 1), "served, at cap, timeouts, evicted");
    // The oldest silent one was closed for it, the others are still open.
    let mut silent = silent.into_iter();
    assert!(closed(silent.next().expect("first")).await.is_some(), "the oldest was not evicted");
    for s in silent {
        s.set_nonblocking(true).expect("nonblocking");
        // Open: data waiting (the server's SETTINGS) or none yet; closed: EOF or an error.
        let still_open = match s.peek(&mut [0u8; 1]) {
            Ok(n) => n > 0,
            Err(e) => e.kind() == std::io::ErrorKind::WouldBlock,
        };
        assert!(still_open, "a newer silent connection was closed");
    }
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn at_the_cap_with_every_connection_through_its_handshake_a_new_one_is_closed_at_once_and_counted() {
    let server =
        Running::start(&Tls::plaintext(), ConnectionLimits { max_connections: 2, ..limits(60.0) }).await;
    let mut clients = Vec::new();
    for _ in 0..2 {
        let channel = tonic::transport::Channel::from_shared(format!("http://{}", server.addr))
            .expect("uri")
            .connect()
            .await
            .expect("connect");
        let mut client = HealthClient::new(channel);
        client.check(HealthCheckRequest { service: "test.Test".into() }).await.expect("served");
        clients.push(client);
    }
    let third = TcpStream::connect(server.addr).expect("the kernel accepts it");
    assert!(closed(third).await.is_some(), "the connection over the cap was held");
    assert_eq!(
        server.counts_become([2, 1, 0, 0, 0]).await,
        [2, 1, 0, 0, 0],
        "served, at cap, timeouts, TLS, evicted"
    );
    for client in &mut clients {
        client.check(HealthCheckRequest { service: "test.Test".into() }).await.expect("still served");
    }
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_idle_past_the_handshake_deadline_keeps_its_connection() {
    let server = Running::start(&Tls::plaintext(), limits(0.2)).await;
    let channel = tonic::transport::Channel::from_shared(format!("http://{}", server.addr))
        .expect("uri")
        .connect()
        .await
        .expect("connect");
    let mut client = HealthClient::new(channel);
    let request = || HealthCheckRequest { service: "test.Test".into() };
    client.check(request()).await.expect("first call");
    tokio::time::sleep(Duration::from_millis(800)).await;
    client.check(request()).await.expect("a call after the deadline");
    assert_eq!(server.counts(), [1, 0, 0, 0, 0], "one connection, never timed out");
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_peer_through_the_handshake_that_answers_no_ping_is_closed_after_the_idle_timeout() {
    let limits = ConnectionLimits { idle_timeout: Duration::from_millis(600), ..limits(5.0) };
    let server = Running::start(&Tls::plaintext(), limits).await;
    let mut mute = TcpStream::connect(server.addr).expect("connect");
    mute.write_all(PREFACE).expect("preface");
    mute.write_all(&EMPTY_SETTINGS).expect("settings");
    assert!(closed(mute).await.is_some(), "a peer that answers no ping was held past {PATIENCE:?}");
    assert_eq!(server.counts(), [1, 0, 0, 0, 0], "through the handshake: not a handshake timeout");
    server.stop().await;
}

/// A CA, and a server identity and a client identity it issued, in a temporary directory.
struct Pki {
    dir: std::path::PathBuf,
}

impl Pki {
    fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("svc-connections-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let mut params = CertificateParams::new(Vec::<String>::new()).expect("params");
        params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
        params.distinguished_name.push(DnType::CommonName, "test CA");
        let ca = CertifiedIssuer::self_signed(params, KeyPair::generate().expect("key")).expect("CA");
        std::fs::write(dir.join("ca.pem"), ca.pem()).expect("write");
        for id in ["server", "client"] {
            let mut params = CertificateParams::new(vec!["localhost".to_string()]).expect("params");
            params.distinguished_name.push(DnType::CommonName, id);
            let key = KeyPair::generate().expect("key");
            let cert = params.signed_by(&key, &ca).expect("sign");
            std::fs::write(dir.join(format!("{id}.pem")), cert.pem()).expect("write");
            std::fs::write(dir.join(format!("{id}-key.pem")), key.serialize_pem()).expect("write");
        }
        Self { dir }
    }

    /// The server: its identity, client certificates required.
    fn server(&self) -> Tls {
        let files = TlsFiles {
            cert: Some(self.dir.join("server.pem")),
            key: Some(self.dir.join("server-key.pem")),
            client_ca: Some(self.dir.join("ca.pem")),
            ca: None,
        };
        files.load().expect("server TLS")
    }

    /// A client trusting the CA, with the client identity or without one.
    fn client(&self, with_identity: bool) -> Tls {
        let files = TlsFiles {
            cert: with_identity.then(|| self.dir.join("client.pem")),
            key: with_identity.then(|| self.dir.join("client-key.pem")),
            client_ca: None,
            ca: Some(self.dir.join("ca.pem")),
        };
        files.load().expect("client TLS")
    }
}

impl Drop for Pki {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Log lines written while `f` runs (this thread's subscriber: the tests' runtime is
/// current-thread, so the server's tasks log here too).
#[derive(Clone, Default)]
struct Captured(Arc<Mutex<Vec<u8>>>);

impl Write for Captured {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().expect("log buffer").extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl<'a> tracing_subscriber::fmt::MakeWriter<'a> for Captured {
    type Writer = Captured;
    fn make_writer(&'a self) -> Self::Writer {
        self.clone()
    }
}

impl Captured {
    fn text(&self) -> String {
        String::from_utf8_lossy(&self.0.lock().expect("log buffer")).into_owned()
    }
}

#[tokio::test]
async fn refused_tls_handshakes_are_counted_and_logged_with_the_peer_and_the_reason() {
    let log = Captured::default();
    let subscriber = tracing_subscriber::fmt().with_writer(log.clone()).with_ansi(false).finish();
    let _guard = tracing::subscriber::set_default(subscriber);
    let pki = Pki::new("refused");
    let server = Running::start(&pki.server(), limits(5.0)).await;
    let endpoint = |tls: &Tls| tls.endpoint(&format!("localhost:{}", server.addr.port())).expect("endpoint");

    // A client without a certificate: refused at the handshake.
    let anonymous = endpoint(&pki.client(false)).connect().await;
    if let Ok(channel) = anonymous {
        // TLS 1.3: the client learns of the refusal at its first call.
        let call = HealthClient::new(channel).check(HealthCheckRequest { service: "test.Test".into() }).await;
        assert!(call.is_err(), "a client without a certificate was served");
    }
    // A plaintext client: refused too.
    let plaintext = health(server.addr).await;
    assert!(plaintext.is_err(), "a plaintext client was served by a TLS server");
    // A client with the CA's certificate is served.
    let channel = endpoint(&pki.client(true)).connect().await.expect("a client with a certificate connects");
    let status = HealthClient::new(channel).check(HealthCheckRequest { service: "test.Test".into() }).await;
    assert!(status.is_ok(), "a client with a certificate was refused: {status:?}");

    let [served, _, _, tls_refused, _] = server.counts();
    assert_eq!(served, 1, "only the client with a certificate is served");
    // Two refused clients; a client may try its handshake again once.
    assert!(tls_refused >= 2, "{tls_refused} refused handshakes counted, 2 clients were refused");
    let text = log.text();
    assert!(text.contains("TLS handshake refused"), "no refusal logged: {text}");
    assert!(text.contains("peer=127.0.0.1:"), "the refusal does not name the peer: {text}");
    assert!(text.to_lowercase().contains("certificate"), "the reason is not given: {text}");
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_connection_that_sends_no_tls_client_hello_is_closed_at_the_handshake_deadline() {
    let pki = Pki::new("silent");
    let server = Running::start(&pki.server(), limits(0.3)).await;
    let silent = TcpStream::connect(server.addr).expect("connect");
    assert!(closed(silent).await.is_some(), "a silent TLS connection was held past {PATIENCE:?}");
    assert_eq!(
        server.counts_become([0, 0, 1, 0, 0]).await,
        [0, 0, 1, 0, 0],
        "served, at cap, handshake timeouts, TLS refused, evicted"
    );
    server.stop().await;
}

#[tokio::test]
async fn a_burst_of_one_kind_is_logged_once_then_counted_a_second_later() {
    let log = Captured::default();
    let subscriber = tracing_subscriber::fmt().with_writer(log.clone()).with_ansi(false).finish();
    let _guard = tracing::subscriber::set_default(subscriber);
    let server = Running::start(&Tls::plaintext(), limits(0.1)).await;
    let silent: Vec<TcpStream> = (0..3).map(|_| TcpStream::connect(server.addr).expect("connect")).collect();
    for s in silent {
        assert!(closed(s).await.is_some(), "a silent connection was held");
    }
    let lines = |text: &str, what: &str| text.lines().filter(|l| l.contains(what)).count();
    let before = log.text();
    assert_eq!(lines(&before, "no HTTP/2 preface within 0.1 s"), 1, "one line for the burst: {before}");
    // The two left out are said once the second is over, without another event.
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let after = log.text();
    assert!(
        after.contains("no HTTP/2 preface within 0.1 s (--handshake-timeout-s): 2 more in the last second"),
        "{after}"
    );
    server.stop().await;
}
