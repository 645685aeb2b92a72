//! A service served in this process on a loopback port, stopped with a oneshot: the one way
//! `hilbench` starts the services of a run and the tests start theirs (tonic's integration
//! tests' shape: bind `127.0.0.1:0`, hand the listener and a shutdown future to the service's
//! `serve(listener, ..., shutdown)`). The listener is bound before the task starts, so clients
//! can connect at once.

use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::time::Duration;

use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tokio::task::{JoinError, JoinHandle};

/// The shutdown signal handed to a service's `serve`: resolves on [`Served::stop`] or when the
/// [`Served`] is dropped.
pub type Shutdown = Pin<Box<dyn Future<Output = ()> + Send>>;

/// A service whose `serve` returns `Result<(), E>`, served on [`Served::addr`] until stopped
/// (or dropped: the shutdown signal fires, the task finishes on its own).
pub struct Served<E> {
    pub addr: SocketAddr,
    /// What errors call it (`plant`, `controller`).
    pub name: &'static str,
    stop: Option<oneshot::Sender<()>>,
    task: Option<JoinHandle<Result<(), E>>>,
}

/// Why a served task did not end with what its `serve` returned.
#[derive(Debug, thiserror::Error)]
pub enum StopError {
    #[error("{name} task failed: {source}")]
    Task { name: &'static str, source: JoinError },
    #[error("{name} did not stop within {} s", .after.as_secs_f64())]
    Timeout { name: &'static str, after: Duration },
}

/// Binds `127.0.0.1:0`: the listener and its address.
pub async fn bind_loopback() -> std::io::Result<(TcpListener, SocketAddr)> {
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    let addr = listener.local_addr()?;
    Ok((listener, addr))
}

/// Binds a loopback port and spawns `serve(listener, shutdown)` on it.
pub async fn serve_loopback<E, F>(
    name: &'static str,
    serve: impl FnOnce(TcpListener, Shutdown) -> F,
) -> std::io::Result<Served<E>>
where
    E: Send + 'static,
    F: Future<Output = Result<(), E>> + Send + 'static,
{
    let (listener, _) = bind_loopback().await?;
    serve_on(name, listener, serve)
}

/// Spawns `serve(listener, shutdown)` on a listener the caller bound (a fixed port, for a
/// service that must come back at the same address).
pub fn serve_on<E, F>(
    name: &'static str,
    listener: TcpListener,
    serve: impl FnOnce(TcpListener, Shutdown) -> F,
) -> std::io::Result<Served<E>>
where
    E: Send + 'static,
    F: Future<Output = Result<(), E>> + Send + 'static,
{
    let addr = listener.local_addr()?;
    let (stop, stopped) = oneshot::channel::<()>();
    let task = tokio::spawn(serve(
        listener,
        Box::pin(async {
            let _ = stopped.await;
        }),
    ));
    Ok(Served { addr, name, stop: Some(stop), task: Some(task) })
}

impl<E> Served<E> {
    /// Fires the shutdown signal and waits up to `patience` for the task: what `serve`
    /// returned, or why there is nothing (it panicked, or hangs at shutdown).
    pub async fn stop(mut self, patience: Duration) -> Result<Result<(), E>, StopError> {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        let Some(task) = self.task.take() else { return Ok(Ok(())) };
        match tokio::time::timeout(patience, task).await {
            Ok(Ok(result)) => Ok(result),
            Ok(Err(source)) => Err(StopError::Task { name: self.name, source }),
            Err(_) => Err(StopError::Timeout { name: self.name, after: patience }),
        }
    }
}

impl<E> Drop for Served<E> {
    fn drop(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_served_task_gets_its_shutdown_and_its_result_comes_back()
    -> Result<(), Box<dyn std::error::Error>> {
        let served = serve_loopback("echo", |listener, shutdown| async move {
            shutdown.await;
            drop(listener);
            Err::<(), _>("stopped")
        })
        .await?;
        assert!(served.addr.ip().is_loopback() && served.addr.port() != 0);
        assert_eq!(served.stop(Duration::from_secs(5)).await?, Err("stopped"));
        let hung =
            serve_loopback("hung", |_listener, _shutdown| std::future::pending::<Result<(), ()>>()).await?;
        let e = hung.stop(Duration::from_millis(10)).await.expect_err("it hangs");
        assert_eq!(e.to_string(), "hung did not stop within 0.01 s");
        Ok(())
    }
}
