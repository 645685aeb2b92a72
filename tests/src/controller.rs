//! Start a controller service in-process on an ephemeral loopback port, and stop it with a
//! oneshot.

use crate::server::{self, Running};
use controller::{ControllerConfig, ControllerError};
use hilbench_proto::pb::controller_client::ControllerClient;
use tonic::transport::Channel;

/// A controller served on `127.0.0.1:<ephemeral>`; `stop()` shuts the server and its loop down.
pub type RunningController = Running<ControllerError>;

/// Starts a controller with `config` (its control loop starts at once when `autostart`).
pub async fn start_controller(config: ControllerConfig) -> RunningController {
    server::start("controller", |listener, shutdown| controller::serve(listener, config, shutdown)).await
}

impl Running<ControllerError> {
    pub async fn client(&self) -> ControllerClient<Channel> {
        ControllerClient::new(self.channel().await)
    }
}
