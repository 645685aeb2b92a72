//! The netem service: a gRPC proxy of the `hilbench.v1.Plant` API that injects a delay per
//! message and direction, loss and duplication, decided by the pure `delay` crate.
//!
//! The controller connects to netem exactly as it would to a plant; netem is a client of the
//! upstream plant and a server of the Plant API (see [`proxy`] for what each call does in
//! lockstep and in real time) and of `NetemControl` ([`control`]), to change profiles, read
//! statistics and record traces at run time.
//!
//! - [`Config`]: validated settings with documented defaults.
//! - [`serve`]: runs both services (plus health and reflection) on a bound listener until
//!   `shutdown` resolves; the `netem` binary and the tests start it this way.
//! - [`serve_udp`]: the same delay lines on a datagram link instead ([`udp`]: a MAVLink
//!   link between an autopilot and its gateway or ground station), with `NetemControl`.
//!
//! **Architecture Invariant:** every random decision is made by `delay::DelayLine`, which is
//! pure and seeded; this crate only moves messages and reads clocks. Lockstep never reads a
//! clock, so a lockstep run through netem is as deterministic as the plant behind it.
//!
//! Stamps: see the header of `netem.proto`. Unary answers carry `netem-command-*` /
//! `netem-sample-*` metadata, written and read only through `proto`'s
//! `convert::netem::Stamp`; stream items are described on `NetemControl.StreamDeliveries`.

pub mod clock;
pub mod command_times;
pub mod control;
mod core;
pub mod peers;
pub mod proxy;
pub mod release;
pub mod udp;

use std::future::Future;
use std::time::Duration;

use delay::{DirectionProfile, ProfileError};
use hilbench_proto::pb::netem_control_server::NetemControlServer;
use hilbench_proto::pb::plant_server::PlantServer;
use hilbench_svc::{GrpcServer, ServeError};
use mav::{TimeMode, TimeModeChoice};
use tonic::server::NamedService;

pub use control::Control;
pub use proxy::Proxy;

/// Default of [`Config::stream_buffer`], samples: a quarter second at 1 kHz, and 12.8 ms at
/// the 20,000 samples/s netem must carry without loss (with 64, a reader on this 2-core VM
/// under load lost 0.2-1 % of them to scheduling stalls); about 90 KB for a stream whose
/// reader stopped (BENCHMARKS.md, "netem's memory per idle stream"). The same as the plant's.
pub const DEFAULT_STREAM_BUFFER: usize = 256;

/// Default of [`Config::deliveries_buffer`], records: 2 s of a 1 kHz run's two directions,
/// allocated once (about 0.5 MB) and shared by every reader.
pub const DEFAULT_DELIVERIES_BUFFER: usize = 4096;

/// Settings of a netem instance.
#[derive(Debug, Clone)]
pub struct Config {
    /// Upstream plant, `HOST:PORT` (or a full `http://` URI).
    pub upstream: String,
    /// Lockstep, real time, or whatever the upstream plant says (`Auto`, the default: asked
    /// with `Describe`, and followed across resets).
    pub time_mode: TimeModeChoice,
    /// Profile of state samples, plant to controller (default: no delay).
    pub plant_to_controller: DirectionProfile,
    /// Profile of commands, controller to plant (default: no delay).
    pub controller_to_plant: DirectionProfile,
    /// Seed given to presets chosen at run time through `NetemControl.SetProfile` (default 42).
    pub seed: u64,
    /// How often a gone upstream is polled, ms (default 200).
    pub probe_interval_ms: u64,
    /// Samples a real-time `StreamState` holds for its reader (default
    /// [`DEFAULT_STREAM_BUFFER`]): when the reader falls that far behind, the oldest is
    /// dropped for the newest ("subscriber too slow", `stream_overflow_dropped`).
    pub stream_buffer: usize,
    /// Records of the `StreamDeliveries` channel, one ring shared by every reader (default
    /// [`DEFAULT_DELIVERIES_BUFFER`]); a reader that falls further behind misses the oldest,
    /// counted in `NetemStats.deliveries_lagged`.
    pub deliveries_buffer: usize,
    /// Server streams open at once (`StreamState` and `StreamDeliveries` together); one more
    /// is refused with `RESOURCE_EXHAUSTED` (`--max-streams`, default 64).
    pub max_streams: usize,
    /// TLS of netem's server and of its upstream connection (default: plaintext both ways).
    pub tls: hilbench_svc::tls::Tls,
    /// Limits on the server's connections and on the streams one client holds
    /// (`--max-connections`, `--handshake-timeout-s`, `--idle-timeout-s`,
    /// `--max-streams-per-client`).
    pub connections: hilbench_svc::connections::ConnectionLimits,
}

impl Config {
    /// No delay either way, seed 42.
    pub fn new(upstream: impl Into<String>) -> Self {
        Self {
            upstream: upstream.into(),
            time_mode: TimeModeChoice::Auto,
            plant_to_controller: DirectionProfile::default(),
            controller_to_plant: DirectionProfile::default(),
            seed: 42,
            probe_interval_ms: 200,
            max_streams: hilbench_svc::streams::DEFAULT_MAX_STREAMS,
            stream_buffer: DEFAULT_STREAM_BUFFER,
            deliveries_buffer: DEFAULT_DELIVERIES_BUFFER,
            tls: hilbench_svc::tls::Tls::plaintext(),
            connections: hilbench_svc::connections::ConnectionLimits::default(),
        }
    }

    /// Both directions from a named preset (`paper`, `paper-split`, `none`) with `seed`.
    pub fn with_preset(mut self, name: &str, seed: u64) -> Result<Self, ProfileError> {
        let p = delay::preset(name, seed)?;
        self.seed = seed;
        Ok(self.with_network(p))
    }

    /// Both directions from `network` (its seeds are its profiles').
    pub fn with_network(mut self, network: delay::NetworkProfile) -> Self {
        self.plant_to_controller = network.to_controller;
        self.controller_to_plant = network.to_plant;
        self
    }

    pub fn validate(&self) -> Result<(), NetemError> {
        self.plant_to_controller.validate().map_err(NetemError::Profile)?;
        self.controller_to_plant.validate().map_err(NetemError::Profile)?;
        if self.probe_interval_ms == 0 {
            return Err(NetemError::Config("probe_interval_ms must be > 0".into()));
        }
        if self.max_streams == 0 {
            return Err(NetemError::Config("max_streams must be at least 1".into()));
        }
        if self.stream_buffer == 0 {
            return Err(NetemError::Config("stream_buffer must be at least 1".into()));
        }
        if self.deliveries_buffer == 0 {
            return Err(NetemError::Config("deliveries_buffer must be at least 1".into()));
        }
        Ok(())
    }
}

/// Why netem could not serve.
#[derive(Debug, thiserror::Error)]
pub enum NetemError {
    #[error("profile: {0}")]
    Profile(ProfileError),
    #[error("config: {0}")]
    Config(String),
    #[error("upstream: {0}")]
    Upstream(hilbench_svc::tls::TlsError),
    #[error("io: {0}")]
    Io(#[from] std::io::Error),
    #[error("UDP: {0}")]
    Udp(String),
    #[error(transparent)]
    Serve(#[from] ServeError),
}

/// `shutdown`, then health `NOT_SERVING`, then netem's open streams told to end.
async fn shutdown_signal(
    shutdown: impl Future<Output = ()> + Send,
    not_serving: impl Future<Output = ()> + Send,
    closing: tokio::sync::watch::Sender<bool>,
) {
    shutdown.await;
    tracing::info!("netem shutting down");
    not_serving.await;
    closing.send_replace(true);
}

/// Serves netem on `listener` until `shutdown` resolves.
pub async fn serve(
    listener: tokio::net::TcpListener,
    config: Config,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), NetemError> {
    config.validate()?;
    let endpoint = config
        .tls
        .endpoint(&config.upstream)
        .map_err(NetemError::Upstream)?
        .connect_timeout(Duration::from_secs(1))
        .tcp_nodelay(true);
    let channel = endpoint.connect_lazy();
    let client = hilbench_proto::pb::plant_client::PlantClient::new(channel);
    let (shared, forward_rx) = core::Shared::new(client, &config)?;
    let forwarder = tokio::spawn(core::run_forwarder(shared.clone(), forward_rx));
    let probe =
        tokio::spawn(core::run_probe(shared.clone(), Duration::from_millis(config.probe_interval_ms)));

    let server = GrpcServer::new(
        "netem",
        listener,
        true,
        &config.tls,
        &config.connections,
        &[PlantServer::<Proxy>::NAME, NetemControlServer::<Control>::NAME],
    )
    .await?;
    let (addr, not_serving) = (server.addr, server.not_serving());

    tracing::info!(
        %addr,
        upstream = %config.upstream,
        time_mode = ?config.time_mode,
        plant_to_controller = ?config.plant_to_controller,
        controller_to_plant = ?config.controller_to_plant,
        "netem serving"
    );
    let signal = shutdown_signal(shutdown, not_serving, shared.closing.clone());
    let result = server
        .serve(
            |router| {
                router
                    .add_service(PlantServer::new(Proxy { shared: shared.clone() }))
                    .add_service(NetemControlServer::new(Control { shared: shared.net.clone() }))
            },
            signal,
        )
        .await;
    forwarder.abort();
    probe.abort();
    result?;
    tracing::info!("netem stopped");
    Ok(())
}

/// Serves the UDP proxy `udp` (real time) and `NetemControl` (plus health and reflection) on
/// `listener` until `shutdown` resolves; the delay lines are `config`'s, as in [`serve`]
/// (`config.upstream` is not used: there is no Plant API in this mode).
pub async fn serve_udp(
    listener: tokio::net::TcpListener,
    config: Config,
    udp: udp::UdpConfig,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), NetemError> {
    config.validate()?;
    if config.time_mode == TimeModeChoice::Fixed(TimeMode::Lockstep) {
        return Err(NetemError::Config(
            "--time-mode lockstep needs a plant whose time netem moves; the UDP proxy runs in real time"
                .into(),
        ));
    }
    let net = core::Net::new(&config, Some(TimeMode::RealTime))?;
    let sockets = udp::Sockets::bind(&udp)
        .map_err(|e| NetemError::Udp(format!("--udp-listen {}: cannot bind: {e}", udp.listen)))?;
    let server = GrpcServer::new(
        "netem",
        listener,
        true,
        &config.tls,
        &config.connections,
        &[NetemControlServer::<Control>::NAME],
    )
    .await?;
    let (addr, not_serving) = (server.addr, server.not_serving());
    tracing::info!(
        %addr,
        udp_listen = %sockets.listen_addr,
        udp_forward = %udp.forward,
        plant_side = udp.plant_side.name(),
        plant_to_controller = ?config.plant_to_controller,
        controller_to_plant = ?config.controller_to_plant,
        "netem serving a UDP link"
    );
    let mut proxy = tokio::spawn(udp::run(net.clone(), sockets, udp));
    let signal = shutdown_signal(shutdown, not_serving, net.closing.clone());
    let served =
        server.serve(|router| router.add_service(NetemControlServer::new(Control { shared: net })), signal);
    let result = tokio::select! {
        r = served => r.map_err(NetemError::from),
        r = &mut proxy => Err(NetemError::Udp(match r {
            Ok(Ok(())) => "the proxy stopped".into(),
            Ok(Err(e)) => format!("the proxy stopped: {e}"),
            Err(e) => format!("the proxy failed: {e}"),
        })),
    };
    proxy.abort();
    result?;
    tracing::info!("netem stopped");
    Ok(())
}
