//! A service served in-process on an ephemeral loopback port and stopped with a oneshot: the
//! shape every service's test helper shares (see `controller.rs`, `plant.rs`).

use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tonic::transport::Channel;

/// How long `stop` waits for a clean shutdown before calling it a failure.
const STOP_TIMEOUT: Duration = Duration::from_secs(30);

/// The shutdown signal handed to a service's `serve`: resolves on `stop()` or drop.
pub type Shutdown = Pin<Box<dyn Future<Output = ()> + Send>>;

/// A service served on `127.0.0.1:<ephemeral>` whose `serve` returns `Result<(), E>`; stopped
/// on `stop()` (or when dropped).
pub struct Running<E> {
    pub addr: SocketAddr,
    /// What the panics call it ("plant server", "controller").
    name: &'static str,
    stop: Option<oneshot::Sender<()>>,
    task: Option<JoinHandle<Result<(), E>>>,
}

/// Binds an ephemeral loopback port (panics if it cannot: a test set-up failure).
pub async fn bind_loopback() -> (TcpListener, SocketAddr) {
    let listener = match TcpListener::bind("127.0.0.1:0").await {
        Ok(l) => l,
        Err(e) => panic!("cannot bind a loopback port: {e}"),
    };
    match listener.local_addr() {
        Ok(addr) => (listener, addr),
        Err(e) => panic!("no local address: {e}"),
    }
}

/// Binds a loopback port and spawns `serve(listener, shutdown)`. The listener is bound before
/// the task starts, so clients can connect at once.
pub async fn start<E, F>(name: &'static str, serve: impl FnOnce(TcpListener, Shutdown) -> F) -> Running<E>
where
    E: Send + 'static,
    F: Future<Output = Result<(), E>> + Send + 'static,
{
    let (listener, addr) = bind_loopback().await;
    let (stop, stopped) = oneshot::channel::<()>();
    let task = tokio::spawn(serve(
        listener,
        Box::pin(async {
            let _ = stopped.await;
        }),
    ));
    Running { addr, name, stop: Some(stop), task: Some(task) }
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
                Err(e) => panic!("cannot connect to the {} at {}: {e}", self.name, self.addr),
            },
            Err(e) => panic!("bad uri: {e}"),
        }
    }

    /// Shuts the server (and whatever it runs) down and returns what `serve` returned. Panics
    /// if it does not stop within 30 s (a hang at shutdown is a bug).
    pub async fn stop(mut self) -> Result<(), E> {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        let Some(task) = self.task.take() else { return Ok(()) };
        match tokio::time::timeout(STOP_TIMEOUT, task).await {
            Ok(Ok(result)) => result,
            Ok(Err(join)) => panic!("{} task failed: {join}", self.name),
            Err(_) => panic!("{} did not shut down within {STOP_TIMEOUT:?}", self.name),
        }
    }
}

impl<E> Drop for Running<E> {
    fn drop(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
    }
}
