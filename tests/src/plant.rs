//! Start a plant service in-process on an ephemeral loopback port, and stop it with a oneshot.

use crate::server::{self, Running};
use hilbench_proto::pb;
use hilbench_proto::pb::plant_client::PlantClient;
use plant::{Clock, PlantConfig, PlantError, WallClock};
use std::sync::Arc;
use std::time::Duration;
use tonic::transport::Channel;

/// A plant served on `127.0.0.1:<ephemeral>`.
pub type RunningPlant = Running<PlantError>;

/// Starts a plant on the wall clock.
pub async fn start_plant(config: PlantConfig) -> RunningPlant {
    start_plant_with_clock(config, Arc::new(WallClock::new())).await
}

/// Starts a plant whose real-time mode reads `clock`.
pub async fn start_plant_with_clock(config: PlantConfig, clock: Arc<dyn Clock>) -> RunningPlant {
    server::start("plant server", |listener, shutdown| {
        plant::serve_with_clock(listener, config, clock, shutdown)
    })
    .await
}

impl Running<PlantError> {
    pub async fn client(&self) -> PlantClient<Channel> {
        PlantClient::new(self.channel().await)
    }
}

/// Polls the plant's state every `period` until `pred` holds and returns that sample; panics
/// with `what` and the last sample when `patience` runs out.
pub async fn wait_for_state(
    client: &mut PlantClient<Channel>,
    what: &str,
    patience: Duration,
    period: Duration,
    pred: impl Fn(&pb::StateSample) -> bool,
) -> pb::StateSample {
    let deadline = tokio::time::Instant::now() + patience;
    loop {
        let s = match client.get_state(pb::GetStateRequest {}).await {
            Ok(r) => r.into_inner(),
            Err(e) => panic!("plant GetState: {e}"),
        };
        if pred(&s) {
            return s;
        }
        if tokio::time::Instant::now() >= deadline {
            panic!("timed out waiting for {what} ({patience:?}); last sample: {s:?}");
        }
        tokio::time::sleep(period).await;
    }
}
