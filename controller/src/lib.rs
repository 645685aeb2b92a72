//! The controller service: the paper's NMPC (from the pure `mpc` crate) driving any endpoint
//! that speaks the `hilbench.v1.Plant` API — the simulated plant, the netem proxy, or a real
//! vehicle gateway; it cannot tell which. It also serves the `hilbench.v1.Controller` API
//! (status, per-cycle telemetry, goal and scenario setting), with health and reflection.
//!
//! - [`config`]: [`ControllerConfig`], validated settings.
//! - [`runner`]: the Plant API client that drives `mpc::Episode` (the one control cycle, shared
//!   with the in-process loop): samples in, commands out, reconnection with backoff, episodes.
//! - [`service`]: the Controller API, a thin shell over the runner's shared state.
//! - [`solve_lines`]: `controller solve`, one JSON problem per line in, one JSON answer out.
//!
//! **Architecture Invariant:** every command that leaves this crate is finite and inside the
//! scenario's input bounds (`mpc::Episode` sends only what the one command sanitiser passed),
//! whatever the solver returned.

pub mod config;
pub mod runner;
pub mod service;
pub mod solve_lines;

pub use config::ControllerConfig;
pub use service::ControllerService;

use hilbench_proto::pb::controller_server::ControllerServer;
use hilbench_svc::{GrpcServer, ServeError};
use std::future::Future;
use tonic::server::NamedService;

/// Why the controller could not serve.
#[derive(Debug, thiserror::Error)]
pub enum ControllerError {
    #[error("invalid configuration: {0}")]
    Config(String),
    #[error(transparent)]
    Serve(#[from] ServeError),
    /// The control loop's task ended by itself (it panicked): the service stopped with it.
    #[error("the control loop {0}")]
    Loop(String),
}

/// Serves the Controller API on `listener` and runs the control loop against
/// `config.plant`, until `shutdown` resolves or the loop's task fails (a panic): the server
/// then stops, and its telemetry streams end, so that its clients see it at once.
pub async fn serve(
    listener: tokio::net::TcpListener,
    config: ControllerConfig,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), ControllerError> {
    config.validate().map_err(ControllerError::Config)?;
    let shared = runner::Shared::new(&config);
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let mut loop_task = tokio::spawn(runner::run(config.clone(), shared.clone(), stop_rx));
    let service =
        ControllerService::new(shared.clone(), config.max_streams, config.connections.max_streams_per_client);

    // TCP_NODELAY as every server of the bench: without it, Nagle's algorithm held each small
    // write (a telemetry item, a GetStatus answer) behind the client's delayed ACK, 40 ms on
    // Linux, which was most of `hilbench reproduce`'s wall time over gRPC (BENCHMARKS.md).
    let server = GrpcServer::new(
        "controller",
        listener,
        true,
        &config.tls,
        &config.connections,
        &[ControllerServer::<ControllerService>::NAME],
    )
    .await?;
    let addr = server.addr;
    tracing::info!(%addr, plant = %config.plant, scenario = %config.scenario.name, mode = config.episode.mode.name(), "controller serving");
    let mut loop_failure = None;
    let mut loop_joined = false;
    let result = server
        .serve(|router| router.add_service(ControllerServer::new(service)), async {
            tokio::select! {
                () = shutdown => {}
                ended = &mut loop_task => {
                    loop_joined = true;
                    if let Err(e) = ended {
                        let failure = hilbench_svc::task_failure(e);
                        tracing::error!("the control loop {failure}; the controller stops");
                        loop_failure = Some(failure);
                    }
                }
            }
            let _ = stop_tx.send(true);
            // Ends the telemetry streams, so that the server's graceful stop does not wait for
            // subscribers that never leave.
            shared.close();
        })
        .await;
    shared.close();
    if !loop_joined {
        let _ = loop_task.await;
    }
    tracing::info!("controller stopped");
    result?;
    loop_failure.map_or(Ok(()), |f| Err(ControllerError::Loop(f)))
}
