//! Start a plant service in-process on an ephemeral loopback port, and stop it with a oneshot.

use hilbench_proto::pb::plant_client::PlantClient;
use plant::{Clock, PlantConfig, PlantError, WallClock};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tonic::transport::Channel;

/// How long `stop` waits for a clean shutdown before calling it a failure.
const STOP_TIMEOUT: Duration = Duration::from_secs(30);

/// A plant served on `127.0.0.1:<ephemeral>`; stopped on `stop()` (or when dropped).
pub struct RunningPlant {
    pub addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: Option<JoinHandle<Result<(), PlantError>>>,
}

/// Starts a plant on the wall clock.
pub async fn start_plant(config: PlantConfig) -> RunningPlant {
    start_plant_with_clock(config, Arc::new(WallClock::new())).await
}

/// Starts a plant whose real-time mode reads `clock`.
pub async fn start_plant_with_clock(config: PlantConfig, clock: Arc<dyn Clock>) -> RunningPlant {
    let listener = match tokio::net::TcpListener::bind("127.0.0.1:0").await {
        Ok(l) => l,
        Err(e) => panic!("cannot bind a loopback port: {e}"),
    };
    let addr = match listener.local_addr() {
        Ok(a) => a,
        Err(e) => panic!("no local address: {e}"),
    };
    let (stop, stopped) = oneshot::channel::<()>();
    let task = tokio::spawn(plant::serve_with_clock(listener, config, clock, async {
        let _ = stopped.await;
    }));
    RunningPlant { addr, stop: Some(stop), task: Some(task) }
}

impl RunningPlant {
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
                Err(e) => panic!("cannot connect to the plant at {}: {e}", self.addr),
            },
            Err(e) => panic!("bad uri: {e}"),
        }
    }

    pub async fn client(&self) -> PlantClient<Channel> {
        PlantClient::new(self.channel().await)
    }

    /// Shuts the server down and returns what `serve` returned. Panics if it does not stop
    /// within 30 s (a hang at shutdown is a bug).
    pub async fn stop(mut self) -> Result<(), PlantError> {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        let Some(task) = self.task.take() else { return Ok(()) };
        match tokio::time::timeout(STOP_TIMEOUT, task).await {
            Ok(Ok(result)) => result,
            Ok(Err(join)) => panic!("plant server task failed: {join}"),
            Err(_) => panic!("plant server did not shut down within {STOP_TIMEOUT:?}"),
        }
    }
}

impl Drop for RunningPlant {
    fn drop(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
    }
}
