//! Connections that cannot exhaust a service: a cap on how many are open at once, a deadline
//! for the handshakes (TLS, then HTTP/2's preface and first frame), HTTP/2 keep-alive pings
//! that close a peer gone silent, and a log line for every connection refused (peer, reason),
//! rate-limited so that a flood cannot flood the log too.
//!
//! At the cap, a new connection takes the place of the oldest one still in its handshakes
//! (that one is closed, counted as evicted); only when every open connection is through its
//! handshakes is the new one refused. So peers that open connections and say nothing cannot
//! keep a client off by holding the cap: each new connection pushes one of theirs out, and a
//! client's handshake (a millisecond on a LAN) finishes before the flood reaches it.
//!
//! Why here and not in tonic: tonic's server holds a connection that never sends a byte (or
//! only HTTP/2's preface, or no TLS ClientHello) forever, logs a refused TLS handshake only at
//! debug level and without the peer, and takes every connection the listener gives it: 200
//! half-open connections were held forever, and with about 1,000 a real client timed out
//! (the process ran out of file descriptors) with nothing logged. So [`Incoming`] accepts, does
//! the TLS handshake itself (tokio-rustls, the same config tonic would build) and hands tonic
//! connections that are through it; tonic still sees a `TlsStream`, so
//! `Request::peer_certs` and `remote_addr` work as before.

use std::collections::HashMap;
use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::task::{Context, Poll, ready};
use std::time::{Duration, Instant};

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::task::JoinSet;
use tokio_rustls::TlsAcceptor;
use tokio_rustls::server::TlsStream;
use tokio_stream::Stream;
use tonic::transport::server::Connected;

/// Default of `--max-connections`: connections open at once, handshakes included. Below the
/// usual 1,024 file descriptors a process may hold, so that a flood of connections cannot
/// take the ones the service needs for its own files and upstream links.
pub const DEFAULT_MAX_CONNECTIONS: usize = 256;
/// Default of `--handshake-timeout-s`: a new connection must be through its TLS handshake and
/// have sent HTTP/2's preface and first frame within this long.
pub const DEFAULT_HANDSHAKE_TIMEOUT_S: f64 = 10.0;
/// Default of `--idle-timeout-s`: a peer that answers nothing for this long is closed (an
/// HTTP/2 ping every half of it, closed when one goes unanswered for the other half).
pub const DEFAULT_IDLE_TIMEOUT_S: f64 = 60.0;
/// Default of `--max-streams-per-client`: server streams one client may hold open at once,
/// so that one client cannot take every slot of `--max-streams`.
pub const DEFAULT_MAX_STREAMS_PER_CLIENT: usize = 16;

/// HTTP/2's client connection preface (24 bytes) and a frame header (9 bytes): a connection
/// that has sent this much is through its handshake (RFC 9113, 3.4: the preface is followed
/// by a SETTINGS frame).
const HTTP2_PREFACE_AND_FRAME_HEADER: u64 = 24 + 9;

/// Limits on a service's connections, validated ([`ConnectionArgs::limits`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConnectionLimits {
    /// Connections open at once, handshakes included; one more is closed at once and logged.
    pub max_connections: usize,
    /// Time from accept to the end of the handshakes (TLS, HTTP/2 preface and first frame).
    pub handshake_timeout: Duration,
    /// Time a peer may answer nothing (HTTP/2 keep-alive: a ping every half of it).
    pub idle_timeout: Duration,
    /// Server streams one client (certificate or address, see [`client_of`]) may hold.
    pub max_streams_per_client: usize,
}

impl Default for ConnectionLimits {
    fn default() -> Self {
        Self {
            max_connections: DEFAULT_MAX_CONNECTIONS,
            handshake_timeout: Duration::from_secs_f64(DEFAULT_HANDSHAKE_TIMEOUT_S),
            idle_timeout: Duration::from_secs_f64(DEFAULT_IDLE_TIMEOUT_S),
            max_streams_per_client: DEFAULT_MAX_STREAMS_PER_CLIENT,
        }
    }
}

/// The flags of [`ConnectionLimits`], flattened into every service's server flags.
#[derive(Debug, Clone, clap::Args)]
pub struct ConnectionArgs {
    /// Connections open at once, handshakes included; one more is closed at once and logged.
    #[arg(long, default_value_t = DEFAULT_MAX_CONNECTIONS, value_name = "N")]
    pub max_connections: usize,
    /// A new connection must finish its TLS handshake and send HTTP/2's preface within this
    /// many seconds, or it is closed and logged.
    #[arg(long, default_value_t = DEFAULT_HANDSHAKE_TIMEOUT_S, value_name = "S")]
    pub handshake_timeout_s: f64,
    /// A peer that answers nothing (not even HTTP/2 pings) for this many seconds is closed.
    #[arg(long, default_value_t = DEFAULT_IDLE_TIMEOUT_S, value_name = "S")]
    pub idle_timeout_s: f64,
    /// Server streams one client may hold open at once (a client is its certificate's name
    /// under mutual TLS, else its IP address); one more is refused with RESOURCE_EXHAUSTED.
    #[arg(long, default_value_t = DEFAULT_MAX_STREAMS_PER_CLIENT, value_name = "N")]
    pub max_streams_per_client: usize,
}

impl Default for ConnectionArgs {
    fn default() -> Self {
        let d = ConnectionLimits::default();
        Self {
            max_connections: d.max_connections,
            handshake_timeout_s: d.handshake_timeout.as_secs_f64(),
            idle_timeout_s: d.idle_timeout.as_secs_f64(),
            max_streams_per_client: d.max_streams_per_client,
        }
    }
}

/// A connection flag out of its range, named.
#[derive(Debug, thiserror::Error)]
#[error("{flag} {value}: {why}")]
pub struct LimitError {
    flag: &'static str,
    value: String,
    why: &'static str,
}

impl ConnectionArgs {
    /// The limits, each checked: counts 1..=65,536, times in [0.001, 86,400] s.
    pub fn limits(&self) -> Result<ConnectionLimits, LimitError> {
        let count = |flag, n: usize| {
            if (1..=65_536).contains(&n) {
                Ok(n)
            } else {
                Err(LimitError { flag, value: n.to_string(), why: "must be 1 to 65536" })
            }
        };
        let seconds = |flag, s: f64| {
            if (0.001..=86_400.0).contains(&s) {
                Ok(Duration::from_secs_f64(s))
            } else {
                Err(LimitError { flag, value: delay::Number(s).to_string(), why: "must be 0.001 to 86400 s" })
            }
        };
        Ok(ConnectionLimits {
            max_connections: count("--max-connections", self.max_connections)?,
            handshake_timeout: seconds("--handshake-timeout-s", self.handshake_timeout_s)?,
            idle_timeout: seconds("--idle-timeout-s", self.idle_timeout_s)?,
            max_streams_per_client: count("--max-streams-per-client", self.max_streams_per_client)?,
        })
    }
}

/// What a service's connections met since it started: every refusal counted by reason.
#[derive(Debug, Default)]
pub struct ConnectionStats {
    /// Connections accepted and handed to the gRPC server (through their TLS handshake).
    pub served: AtomicU64,
    /// Closed at accept: `--max-connections` were open.
    pub refused_at_cap: AtomicU64,
    /// Closed: no TLS handshake, or no HTTP/2 preface and first frame, within the deadline.
    pub handshake_timeouts: AtomicU64,
    /// Closed: the TLS handshake failed (a plaintext client, a certificate refused, ...).
    pub tls_refused: AtomicU64,
    /// Closed at the cap while still in its handshakes, for a newer connection.
    pub evicted: AtomicU64,
}

impl ConnectionStats {
    fn bump(counter: &AtomicU64) {
        counter.fetch_add(1, Ordering::Relaxed);
    }

    /// `[served, refused_at_cap, handshake_timeouts, tls_refused, evicted]` now.
    pub fn snapshot(&self) -> [u64; 5] {
        [&self.served, &self.refused_at_cap, &self.handshake_timeouts, &self.tls_refused, &self.evicted]
            .map(|c| c.load(Ordering::Relaxed))
    }
}

/// A kind of log line: its reason and detail.
type LogKind = (&'static str, String);

/// At most one warning a second per kind (reason and detail); the events of a kind left out
/// in that second are said a second after its first line, with their count.
struct RateLimitedLog {
    service: &'static str,
    /// Per kind: when its last line was written, and the events left out since.
    last: Arc<Mutex<HashMap<LogKind, (Instant, u64)>>>,
}

impl RateLimitedLog {
    const EVERY: Duration = Duration::from_secs(1);

    fn warn(&self, reason: &'static str, peer: SocketAddr, detail: &str) {
        let service = self.service;
        let key = (reason, detail.to_string());
        let first_left_out = {
            let mut last = self.last.lock().unwrap_or_else(PoisonError::into_inner);
            let now = Instant::now();
            match last.get_mut(&key) {
                Some((at, left_out)) if now.duration_since(*at) < Self::EVERY => {
                    *left_out += 1;
                    *left_out == 1
                }
                _ => {
                    last.insert(key.clone(), (now, 0));
                    tracing::warn!(%peer, "{service}: {reason}: {detail}");
                    return;
                }
            }
        };
        if first_left_out {
            // Say how many were left out once the second is over, whether or not another
            // event of the kind comes.
            let last = self.last.clone();
            tokio::spawn(async move {
                tokio::time::sleep(Self::EVERY).await;
                let left_out = last
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .get_mut(&key)
                    .map(|(_, n)| std::mem::take(n))
                    .unwrap_or(0);
                if left_out > 0 {
                    let (reason, detail) = key;
                    tracing::warn!("{service}: {reason}: {detail}: {left_out} more in the last second");
                }
            });
        }
    }
}

/// A connection still in its handshakes, which a newer one may evict at the cap.
#[derive(Default)]
struct Pending {
    /// Through its handshakes, or closed: not to be evicted.
    done: std::sync::atomic::AtomicBool,
    /// Told to close (a stored permit when nothing waits yet, so no eviction is lost).
    evict: Arc<tokio::sync::Notify>,
}

impl Pending {
    fn finish(&self) {
        self.done.store(true, Ordering::Release);
    }
}

/// The connections a gRPC server serves: accepted under the cap, through the TLS handshake
/// when `tls` is given, and watched until through HTTP/2's handshake. `IO` is `TcpStream`
/// for plaintext, `TlsStream<TcpStream>` for TLS.
pub struct Incoming<IO> {
    listener: TcpListener,
    nodelay: bool,
    limits: ConnectionLimits,
    permits: Arc<Semaphore>,
    handshake: fn(TlsAcceptorOrNone, TcpStream) -> Handshake<IO>,
    tls: TlsAcceptorOrNone,
    pending: JoinSet<Option<Watched<IO>>>,
    shared: Arc<Shared>,
}

struct Shared {
    stats: Arc<ConnectionStats>,
    log: RateLimitedLog,
    /// Connections in their handshakes, oldest first (finished ones are dropped lazily).
    pending: Mutex<std::collections::VecDeque<Arc<Pending>>>,
}

impl Shared {
    /// Tells the oldest connection still in its handshakes to close; false when there is none.
    fn evict_oldest(&self) -> bool {
        let mut pending = self.pending.lock().unwrap_or_else(PoisonError::into_inner);
        while let Some(oldest) = pending.pop_front() {
            if !oldest.done.load(Ordering::Acquire) {
                oldest.finish();
                oldest.evict.notify_one();
                return true;
            }
        }
        false
    }

    /// Keeps `new` in the queue of connections in their handshakes.
    fn push_pending(&self, new: Arc<Pending>) {
        let mut pending = self.pending.lock().unwrap_or_else(PoisonError::into_inner);
        while pending.front().is_some_and(|p| p.done.load(Ordering::Acquire)) {
            pending.pop_front();
        }
        pending.push_back(new);
    }
}

type TlsAcceptorOrNone = Option<TlsAcceptor>;
type Handshake<IO> = Pin<Box<dyn Future<Output = std::io::Result<IO>> + Send>>;

fn plaintext(_: TlsAcceptorOrNone, tcp: TcpStream) -> Handshake<TcpStream> {
    Box::pin(async move { Ok(tcp) })
}

fn tls_handshake(tls: TlsAcceptorOrNone, tcp: TcpStream) -> Handshake<TlsStream<TcpStream>> {
    Box::pin(async move {
        match tls {
            Some(acceptor) => acceptor.accept(tcp).await,
            None => Err(std::io::Error::other("no TLS acceptor")),
        }
    })
}

impl Incoming<TcpStream> {
    /// Plaintext connections on `listener`.
    pub fn plaintext(
        listener: TcpListener,
        nodelay: bool,
        limits: ConnectionLimits,
        service: &'static str,
        stats: Arc<ConnectionStats>,
    ) -> Self {
        Self::new(listener, nodelay, limits, service, stats, None, plaintext)
    }
}

impl Incoming<TlsStream<TcpStream>> {
    /// TLS connections on `listener`, with `config` (ALPN `h2` added).
    pub fn tls(
        listener: TcpListener,
        nodelay: bool,
        limits: ConnectionLimits,
        service: &'static str,
        stats: Arc<ConnectionStats>,
        mut config: tokio_rustls::rustls::ServerConfig,
    ) -> Self {
        config.alpn_protocols = vec![b"h2".to_vec()];
        let acceptor = TlsAcceptor::from(Arc::new(config));
        Self::new(listener, nodelay, limits, service, stats, Some(acceptor), tls_handshake)
    }
}

impl<IO: AsyncRead + AsyncWrite + Unpin + Send + 'static> Incoming<IO> {
    fn new(
        listener: TcpListener,
        nodelay: bool,
        limits: ConnectionLimits,
        service: &'static str,
        stats: Arc<ConnectionStats>,
        tls: TlsAcceptorOrNone,
        handshake: fn(TlsAcceptorOrNone, TcpStream) -> Handshake<IO>,
    ) -> Self {
        Self {
            listener,
            nodelay,
            permits: Arc::new(Semaphore::new(limits.max_connections)),
            limits,
            handshake,
            tls,
            pending: JoinSet::new(),
            shared: Arc::new(Shared {
                stats,
                log: RateLimitedLog { service, last: Arc::new(Mutex::new(HashMap::new())) },
                pending: Mutex::new(std::collections::VecDeque::new()),
            }),
        }
    }

    /// Takes a new TCP connection: at the cap, in the place of the oldest connection still in
    /// its handshakes, or closed at once when there is none; then its handshake is started.
    fn take(&mut self, tcp: TcpStream, peer: SocketAddr) {
        let permit = match self.permits.clone().try_acquire_owned() {
            Ok(permit) => Some(permit),
            Err(_) if self.shared.evict_oldest() => None,
            Err(_) => {
                ConnectionStats::bump(&self.shared.stats.refused_at_cap);
                let max = self.limits.max_connections;
                self.shared.log.warn(
                    "connection refused",
                    peer,
                    &format!(
                        "{max} connections are open and through their handshakes, the most it serves at once \
                         (--max-connections {max})"
                    ),
                );
                return;
            }
        };
        if self.nodelay {
            let _ = tcp.set_nodelay(true);
        }
        let deadline = tokio::time::Instant::now() + self.limits.handshake_timeout;
        let timeout_s = self.limits.handshake_timeout.as_secs_f64();
        let handshake = (self.handshake)(self.tls.clone(), tcp);
        let (shared, permits) = (self.shared.clone(), self.permits.clone());
        let pending = Arc::new(Pending::default());
        shared.push_pending(pending.clone());
        let is_tls = self.tls.is_some();
        self.pending.spawn(async move {
            let handshake = async {
                // In the place of an evicted connection: its place is free once it is closed.
                let permit = match permit {
                    Some(permit) => permit,
                    None => permits.acquire_owned().await.map_err(std::io::Error::other)?,
                };
                Ok::<_, std::io::Error>((handshake.await?, permit))
            };
            let outcome = tokio::select! {
                outcome = tokio::time::timeout_at(deadline, handshake) => outcome,
                () = pending.evict.notified() => {
                    ConnectionStats::bump(&shared.stats.evicted);
                    shared.log.warn("connection closed", peer, "evicted in its handshake by a newer connection at --max-connections");
                    return None;
                }
            };
            match outcome {
                Ok(Ok((io, permit))) => Some(Watched::new(io, peer, deadline, timeout_s, permit, shared, pending)),
                Ok(Err(e)) => {
                    pending.finish();
                    ConnectionStats::bump(&shared.stats.tls_refused);
                    shared.log.warn("TLS handshake refused", peer, &crate::error_chain(&e));
                    None
                }
                Err(_) => {
                    pending.finish();
                    ConnectionStats::bump(&shared.stats.handshake_timeouts);
                    let what = if is_tls { "no TLS handshake" } else { "no handshake" };
                    shared.log.warn(
                        "connection closed",
                        peer,
                        &format!("{what} within {} s (--handshake-timeout-s)", delay::Number(timeout_s)),
                    );
                    None
                }
            }
        });
    }
}

impl<IO: AsyncRead + AsyncWrite + Unpin + Send + 'static> Stream for Incoming<IO> {
    type Item = std::io::Result<Watched<IO>>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        loop {
            // Connections through their handshake first: they are what clients wait for.
            match self.pending.poll_join_next(cx) {
                Poll::Ready(Some(Ok(Some(io)))) => return Poll::Ready(Some(Ok(io))),
                Poll::Ready(Some(Ok(None))) => continue,
                Poll::Ready(Some(Err(e))) => {
                    tracing::error!(
                        "{}: a connection's handshake task {}",
                        self.shared.log.service,
                        crate::task_failure(e)
                    );
                    continue;
                }
                Poll::Ready(None) | Poll::Pending => {}
            }
            match ready!(self.listener.poll_accept(cx)) {
                Ok((tcp, peer)) => self.take(tcp, peer),
                // Accept errors are the listener's or the process's (out of file
                // descriptors): log, and accept again in 10 ms (tokio registers no waker on an
                // error, and retrying at once would spin).
                Err(e) => {
                    tracing::warn!("{}: accept: {e}", self.shared.log.service);
                    let waker = cx.waker().clone();
                    tokio::spawn(async move {
                        tokio::time::sleep(Duration::from_millis(10)).await;
                        waker.wake();
                    });
                    return Poll::Pending;
                }
            }
        }
    }
}

/// When a connection's handshakes must be over.
type Deadline = Pin<Box<tokio::time::Sleep>>;
/// A newer connection's request that this one close.
type Eviction = Pin<Box<tokio::sync::futures::OwnedNotified>>;

/// A connection through its TLS handshake, still held to the handshake's deadline until it
/// has sent HTTP/2's preface and first frame header; it holds its place under the cap until
/// dropped.
pub struct Watched<IO> {
    io: IO,
    peer: SocketAddr,
    /// Until HTTP/2's preface and a frame header were read: the deadline, and the eviction.
    handshake: Option<(Deadline, Eviction)>,
    pending: Arc<Pending>,
    timeout_s: f64,
    read: u64,
    shared: Arc<Shared>,
    _permit: OwnedSemaphorePermit,
}

impl<IO> Watched<IO> {
    fn new(
        io: IO,
        peer: SocketAddr,
        deadline: tokio::time::Instant,
        timeout_s: f64,
        permit: OwnedSemaphorePermit,
        shared: Arc<Shared>,
        pending: Arc<Pending>,
    ) -> Self {
        ConnectionStats::bump(&shared.stats.served);
        // Told to close after the TLS handshake: the notification waits here (an eviction
        // between the handshake task's end and the first poll is a stored permit).
        let evicted = Box::pin(pending.evict.clone().notified_owned());
        Self {
            io,
            peer,
            handshake: Some((Box::pin(tokio::time::sleep_until(deadline)), evicted)),
            pending,
            timeout_s,
            read: 0,
            shared,
            _permit: permit,
        }
    }

    /// An error when the handshake's deadline passed, or a newer connection evicted this one,
    /// before HTTP/2's preface came in.
    fn check_deadline(&mut self, cx: &mut Context<'_>) -> std::io::Result<()> {
        let Some((sleep, evicted)) = self.handshake.as_mut() else { return Ok(()) };
        let (counter, reason, detail) = if evicted.as_mut().poll(cx).is_ready() {
            (
                &self.shared.stats.evicted,
                "evicted in its handshake by a newer connection at --max-connections".to_string(),
                "evicted in its handshake",
            )
        } else if sleep.as_mut().poll(cx).is_ready() {
            (
                &self.shared.stats.handshake_timeouts,
                format!(
                    "no HTTP/2 preface within {} s (--handshake-timeout-s)",
                    delay::Number(self.timeout_s)
                ),
                "no HTTP/2 preface before the handshake deadline",
            )
        } else {
            return Ok(());
        };
        self.handshake = None;
        self.pending.finish();
        ConnectionStats::bump(counter);
        self.shared.log.warn("connection closed", self.peer, &reason);
        Err(std::io::Error::new(std::io::ErrorKind::TimedOut, detail))
    }
}

impl<IO> Drop for Watched<IO> {
    fn drop(&mut self) {
        self.pending.finish();
    }
}

impl<IO: AsyncRead + Unpin> AsyncRead for Watched<IO> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        self.check_deadline(cx)?;
        let before = buf.filled().len();
        ready!(Pin::new(&mut self.io).poll_read(cx, buf))?;
        if self.handshake.is_some() {
            self.read += (buf.filled().len() - before) as u64;
            if self.read >= HTTP2_PREFACE_AND_FRAME_HEADER {
                self.handshake = None;
                self.pending.finish();
            }
        }
        Poll::Ready(Ok(()))
    }
}

impl<IO: AsyncWrite + Unpin> AsyncWrite for Watched<IO> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        data: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        self.check_deadline(cx)?;
        Pin::new(&mut self.io).poll_write(cx, data)
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.io).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.io).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        self.check_deadline(cx)?;
        Pin::new(&mut self.io).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.io.is_write_vectored()
    }
}

/// tonic sees the connection it wraps: `TcpConnectInfo` for plaintext,
/// `TlsConnectInfo<TcpConnectInfo>` for TLS, so `Request::remote_addr` and `peer_certs`
/// answer as with tonic's own listener.
impl<IO: Connected> Connected for Watched<IO> {
    type ConnectInfo = IO::ConnectInfo;

    fn connect_info(&self) -> Self::ConnectInfo {
        self.io.connect_info()
    }
}

/// Who a request comes from, for the per-client stream cap: the common name of its client
/// certificate under mutual TLS, else its IP address (every plaintext client on one host is
/// one client), else `unknown` (a request made in process, without a connection).
pub fn client_of<T>(request: &tonic::Request<T>) -> String {
    if let Ok(name) = crate::tls::client_common_name(request) {
        return format!("certificate {name}");
    }
    match request.remote_addr() {
        Some(addr) => format!("address {}", addr.ip()),
        None => "unknown".to_string(),
    }
}
