//! Start a controller service in-process on an ephemeral loopback port, and stop it with a
//! oneshot.

use controller::{ControllerConfig, ControllerError};
use hilbench_proto::pb::controller_client::ControllerClient;
use std::net::SocketAddr;
use std::time::Duration;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tonic::transport::Channel;

const STOP_TIMEOUT: Duration = Duration::from_secs(30);

/// A controller served on `127.0.0.1:<ephemeral>`; stopped on `stop()` (or when dropped).
pub struct RunningController {
    pub addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: Option<JoinHandle<Result<(), ControllerError>>>,
}

/// Starts a controller with `config` (its control loop starts at once when `autostart`).
pub async fn start_controller(config: ControllerConfig) -> RunningController {
    let listener = match tokio::net::TcpListener::bind("127.0.0.1:0").await {
        Ok(l) => l,
        Err(e) => panic!("cannot bind a loopback port: {e}"),
    };
    let addr = match listener.local_addr() {
        Ok(a) => a,
        Err(e) => panic!("no local address: {e}"),
    };
    let (stop, stopped) = oneshot::channel::<()>();
    let task = tokio::spawn(controller::serve(listener, config, async {
        let _ = stopped.await;
    }));
    RunningController { addr, stop: Some(stop), task: Some(task) }
}

impl RunningController {
    pub async fn client(&self) -> ControllerClient<Channel> {
        match Channel::from_shared(format!("http://{}", self.addr)) {
            Ok(endpoint) => match endpoint.connect().await {
                Ok(c) => ControllerClient::new(c),
                Err(e) => panic!("cannot connect to the controller at {}: {e}", self.addr),
            },
            Err(e) => panic!("bad uri: {e}"),
        }
    }

    /// Shuts the server and its loop down and returns what `serve` returned. Panics if it does
    /// not stop within 30 s.
    pub async fn stop(mut self) -> Result<(), ControllerError> {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        let Some(task) = self.task.take() else { return Ok(()) };
        match tokio::time::timeout(STOP_TIMEOUT, task).await {
            Ok(Ok(result)) => result,
            Ok(Err(join)) => panic!("controller task failed: {join}"),
            Err(_) => panic!("controller did not shut down within {STOP_TIMEOUT:?}"),
        }
    }
}

impl Drop for RunningController {
    fn drop(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
    }
}
