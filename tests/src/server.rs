//! A service served in-process on an ephemeral loopback port and stopped with a oneshot
//! (`hilbench_svc::loopback`, the way `hilbench` starts its services too), with the tests'
//! conveniences: a connected channel, and a panic for a set-up failure or a hang at shutdown.

use std::future::Future;
use std::net::SocketAddr;
use std::time::Duration;

use hilbench_svc::loopback::{self, Served};
use tokio::net::TcpListener;
use tonic::transport::Channel;

pub use hilbench_svc::loopback::Shutdown;

/// How long `stop` waits for a clean shutdown before calling it a failure.
const STOP_TIMEOUT: Duration = Duration::from_secs(30);

/// A service served on `127.0.0.1:<port>` whose `serve` returns `Result<(), E>`; stopped on
/// `stop()` (or when dropped).
pub struct Running<E> {
    pub addr: SocketAddr,
    served: Served<E>,
}

/// Binds an ephemeral loopback port (panics if it cannot: a test set-up failure).
pub async fn bind_loopback() -> (TcpListener, SocketAddr) {
    loopback::bind_loopback().await.unwrap_or_else(|e| panic!("cannot bind a loopback port: {e}"))
}

/// Binds a loopback port and spawns `serve(listener, shutdown)`. The listener is bound before
/// the task starts, so clients can connect at once.
pub async fn start<E, F>(name: &'static str, serve: impl FnOnce(TcpListener, Shutdown) -> F) -> Running<E>
where
    E: Send + 'static,
    F: Future<Output = Result<(), E>> + Send + 'static,
{
    let (listener, _) = bind_loopback().await;
    start_on(name, listener, serve)
}

/// Spawns `serve(listener, shutdown)` on a listener bound by the caller (a fixed port, for a
/// service that comes back at the same address).
pub fn start_on<E, F>(
    name: &'static str,
    listener: TcpListener,
    serve: impl FnOnce(TcpListener, Shutdown) -> F,
) -> Running<E>
where
    E: Send + 'static,
    F: Future<Output = Result<(), E>> + Send + 'static,
{
    match loopback::serve_on(name, listener, serve) {
        Ok(served) => Running { addr: served.addr, served },
        Err(e) => panic!("the {name}'s listener has no address: {e}"),
    }
}

impl<E> Running<E> {
    /// `http://127.0.0.1:<port>`.
    pub fn uri(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// A connected channel (the listener is bound before the server starts, so this succeeds
    /// as soon as the server task runs).
    pub async fn channel(&self) -> Channel {
        match Channel::from_shared(self.uri()) {
            Ok(endpoint) => match endpoint.connect().await {
                Ok(c) => c,
                Err(e) => panic!("cannot connect to the {} at {}: {e}", self.served.name, self.addr),
            },
            Err(e) => panic!("bad uri: {e}"),
        }
    }

    /// Shuts the server (and whatever it runs) down and returns what `serve` returned. Panics
    /// if its task panicked or it does not stop within 30 s (a hang at shutdown is a bug).
    pub async fn stop(self) -> Result<(), E> {
        self.served.stop(STOP_TIMEOUT).await.unwrap_or_else(|e| panic!("{e}"))
    }
}
