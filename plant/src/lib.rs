//! The plant service (see ARCHITECTURE.md): the MAV truth simulation of `mav` behind the
//! `hilbench.v1.Plant` API, with gRPC health checking and server reflection.
//!
//! - [`config`]: [`PlantConfig`], validated settings with documented defaults.
//! - [`clock`]: the injectable clock; the simulation never reads a clock.
//! - [`service`]: [`PlantService`], a small handle around the simulation and its subscribers.
//! - [`serve`]: runs the service on a bound listener until `shutdown` resolves; the `plant`
//!   binary and the tests both start it this way.
//!
//! Time modes: in lockstep plant time moves only through `Advance`/`Step`, so runs are
//! deterministic and bit-identical to the in-process simulation. In real time the
//! [`step_loop`] thread calls [`PlantService::tick`] at the integration rate, which catches the
//! simulation up to the clock (plant time = time since the last reset), and `Advance`/`Step`
//! with a duration are refused with `FAILED_PRECONDITION`.

pub mod clock;
pub mod config;
pub mod service;
pub mod step_loop;

pub use clock::{Clock, ManualClock, WallClock};
pub use config::{ConfigError, PlantConfig};
pub use service::PlantService;
pub use step_loop::{StepLoop, StepStats};

use hilbench_proto::pb::plant_server::PlantServer;
use hilbench_svc::{GrpcServer, ServeError};
use mav::TimeMode;
use std::future::Future;
use std::sync::Arc;
use tonic::server::NamedService;

/// Why the plant could not serve.
#[derive(Debug, thiserror::Error)]
pub enum PlantError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Serve(#[from] ServeError),
    #[error("real-time step loop: {0}")]
    StepLoop(std::io::Error),
}

/// Serves the plant on `listener` until `shutdown` resolves, on the wall clock.
pub async fn serve(
    listener: tokio::net::TcpListener,
    config: PlantConfig,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), PlantError> {
    serve_with_clock(listener, config, Arc::new(WallClock::new()), shutdown).await
}

/// As [`serve`], with the clock that real-time mode reads.
pub async fn serve_with_clock(
    listener: tokio::net::TcpListener,
    config: PlantConfig,
    clock: Arc<dyn Clock>,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), PlantError> {
    let scenario = config.scenario.name.clone();
    let rate_hz = config.rate_hz;
    let (tls, limits) = (config.tls.clone(), config.connections);
    let service = PlantService::new(config, clock)?;

    let server =
        GrpcServer::new("plant", listener, true, &tls, &limits, &[PlantServer::<PlantService>::NAME]).await?;
    let (addr, not_serving) = (server.addr, server.not_serving());

    let steps = match service.time_mode() {
        TimeMode::Lockstep => None,
        TimeMode::RealTime => Some(StepLoop::start(service.clone()).map_err(PlantError::StepLoop)?),
    };

    let signal = {
        let service = service.clone();
        async move {
            shutdown.await;
            tracing::info!("plant shutting down");
            not_serving.await;
            // Open state streams would otherwise keep the graceful shutdown waiting forever.
            service.close();
        }
    };
    tracing::info!(%addr, mode = %service.time_mode(), %scenario, rate_hz, "plant serving");
    let result = server.serve(|router| router.add_service(PlantServer::new(service)), signal).await;
    if let Some(steps) = steps {
        // Joining waits for the loop's current step to end.
        match tokio::task::spawn_blocking(move || steps.stop()).await {
            Ok(stats) => tracing::info!("real-time steps: {stats}"),
            Err(e) => tracing::warn!("real-time step loop: {e}"),
        }
    }
    result?;
    tracing::info!("plant stopped");
    Ok(())
}
