//! The services of a run: a plant, netem and the controller, each served in this process on
//! its own loopback port (one fresh set per run) or running elsewhere ([`Endpoints`]), with
//! their TLS ([`BenchTls`]); and connecting to them.

use std::future::Future;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, anyhow, bail};
use hilbench_svc::loopback::{Served, Shutdown, serve_loopback};
use hilbench_svc::tls::{Tls, TlsFiles};
use mav::{Scenario, TimeMode};
use mpc::ControllerMode;
use tonic::transport::Channel;

use crate::run::CycleSink;

/// netem's settings for `scenario`: its network (seeded with the scenario's seed; none when
/// the scenario describes no network), in `time_mode`.
pub fn netem_config(
    upstream: &str,
    scenario: &Scenario,
    time_mode: TimeMode,
) -> anyhow::Result<netem::Config> {
    let network = scenario.network()?.unwrap_or_else(|| delay::NetworkProfile::none(scenario.seed));
    let mut config = netem::Config::new(upstream).with_preset("none", scenario.seed)?;
    config.controller_to_plant = network.to_plant;
    config.plant_to_controller = network.to_controller;
    config.time_mode = time_mode.into();
    Ok(config)
}

/// The plant's settings for `scenario` in `time_mode`.
pub fn plant_config(scenario: &Scenario, time_mode: TimeMode) -> plant::PlantConfig {
    plant::PlantConfig { time_mode, ..plant::PlantConfig::lockstep(scenario.clone()) }
}

/// A service served in this process on a loopback port, its error as text (so that the
/// plant's, netem's and the controller's are one type).
pub(crate) type Running = Served<String>;

/// How long a service started here gets to stop.
const STOP_PATIENCE: Duration = Duration::from_secs(10);

/// A plant served in this process on a loopback port: the task and its address.
pub(crate) async fn start_plant(config: plant::PlantConfig) -> anyhow::Result<(Running, String)> {
    start("plant", |listener, shutdown| plant::serve(listener, config, shutdown)).await
}

/// A netem served in this process on a loopback port: the task and its address.
pub(crate) async fn start_netem(config: netem::Config) -> anyhow::Result<(Running, String)> {
    start("netem", |listener, shutdown| netem::serve(listener, config, shutdown)).await
}

/// `serve` on a loopback port (`svc::loopback`, the tests' way too): the task and its address.
async fn start<E, F>(
    name: &'static str,
    serve: impl FnOnce(tokio::net::TcpListener, Shutdown) -> F,
) -> anyhow::Result<(Running, String)>
where
    E: std::fmt::Display,
    F: Future<Output = Result<(), E>> + Send + 'static,
{
    let running = serve_loopback(name, |listener, shutdown| {
        let served = serve(listener, shutdown);
        async move { served.await.map_err(|e| e.to_string()) }
    })
    .await
    .context("cannot bind a loopback port")?;
    let addr = running.addr.to_string();
    Ok((running, addr))
}

/// Stops a service started here: its error, or why it did not stop.
pub(crate) async fn stop(running: Running) -> anyhow::Result<()> {
    let name = running.name;
    match running.stop(STOP_PATIENCE).await {
        Ok(Ok(())) => Ok(()),
        Ok(Err(e)) => Err(anyhow!("{name} failed: {e}")),
        Err(e) => Err(e.into()),
    }
}

/// Services already running elsewhere (`HOST:PORT` or `http://...`); what is not given is
/// started in this process.
///
/// - no `controller`: a controller is started (idle until `SetScenario`) against `netem`, or
///   against a netem started here in front of `plant` (started here too when not given);
/// - a `controller`: nothing is started; it must already be pointed at the Plant API it should
///   fly (normally the given netem). The final state is read from `plant`, else from `netem`
///   (an undelayed `GetState`), so one of them is required.
///
/// A netem at a given address gets the scenario's profiles (both directions, with the
/// scenario's seed) through `NetemControl.SetProfile` before the run.
///
/// `time_mode` is how the services started here run; given ones must run the same way (the
/// plant's, or netem's, `Describe` is checked before the run).
#[derive(Debug, Clone, Default)]
pub struct Endpoints {
    pub plant: Option<String>,
    pub netem: Option<String>,
    pub controller: Option<String>,
    pub time_mode: TimeMode,
    /// Leave the profile of the netem at `netem` alone (what `delay_profile` then reports).
    pub keep_netem_profile: bool,
    /// Where every cycle also goes as it arrives: the live Foxglove view (`--foxglove-ws`).
    pub live: Option<Arc<dyn CycleSink>>,
    /// TLS of the run's links (default: plaintext); shared, as the endpoints are cloned per run.
    pub tls: std::sync::Arc<BenchTls>,
    /// Each run starts where the vehicle at `plant` is (`--start-from-vehicle`).
    pub start_from_vehicle: bool,
}

/// TLS of a run's links: how this process connects to every service (its trust and client
/// certificate), and what each service started here serves with and trusts. [`Default`]:
/// plaintext everywhere.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BenchTls {
    /// hilbench's own connections (to the controller, netem and plant, started here or not).
    pub client: Tls,
    pub plant: Tls,
    pub netem: Tls,
    pub controller: Tls,
}

impl BenchTls {
    /// The layout of `hilbench certs --out DIR`: `ca.pem` trusted everywhere (servers require
    /// client certificates it signed), each started service serves with `<service>.pem` and
    /// `<service>-key.pem` (and presents them as a client), hilbench presents `hilbench.pem`.
    pub fn from_dir(dir: &std::path::Path) -> Result<Self, hilbench_svc::tls::TlsError> {
        let client = TlsFiles { client_ca: None, ..TlsFiles::in_dir(dir, "hilbench") }.load()?;
        let plant = TlsFiles { ca: None, ..TlsFiles::in_dir(dir, "plant") }.load()?;
        let netem = TlsFiles::in_dir(dir, "netem").load()?;
        let controller = TlsFiles::in_dir(dir, "controller").load()?;
        Ok(Self { client, plant, netem, controller })
    }

    /// Every service started here with the client's identity, requiring client certificates
    /// from the client's CA (one CA for the deployment); plaintext when the client has no TLS.
    /// A client that trusts a CA without an identity of its own cannot start TLS services.
    pub fn shared(files: &TlsFiles) -> anyhow::Result<Self> {
        let client = files.load()?;
        if files.cert.is_none() || files.ca.is_none() {
            return Ok(Self { client, ..Self::default() });
        }
        let served = TlsFiles { client_ca: files.ca.clone(), ..files.clone() }.load()?;
        Ok(Self { client, plant: served.clone(), netem: served.clone(), controller: served })
    }

    /// Whether services started here serve what the client expects: TLS on both sides, or on
    /// neither.
    fn check_started(&self, service: &str, served: &Tls) -> anyhow::Result<()> {
        match (self.client.connects_with_tls(), served.serves_tls()) {
            (true, false) => bail!(
                "--tls-ca without --tls-cert and --tls-key: the {service} started here cannot serve TLS (give a certificate, or --tls-dir)"
            ),
            (false, true) => bail!("the {service} started here serves TLS but hilbench has no --tls-ca"),
            _ => Ok(()),
        }
    }
}

impl Endpoints {
    pub fn is_local(&self) -> bool {
        self.plant.is_none() && self.netem.is_none() && self.controller.is_none()
    }
}

/// The services of one run: those started here, and every address.
pub struct Services {
    plant: Option<Running>,
    netem: Option<Running>,
    controller: Option<Running>,
    plant_addr: Option<String>,
    netem_addr: Option<String>,
    controller_addr: String,
    /// netem runs elsewhere: give it the scenario's profiles before the run.
    pub(super) configure_netem: bool,
    /// ...unless told to leave its profile alone.
    pub(super) keep_netem_profile: bool,
    pub(super) time_mode: TimeMode,
    /// How this process connects to them.
    pub(super) client_tls: Tls,
    /// Each run starts where the plant's vehicle is (see [`Endpoints::start_from_vehicle`]).
    pub(super) start_from_vehicle: bool,
}

impl Services {
    /// Plant (lockstep), netem and controller (idle until `SetScenario`), all on loopback.
    pub async fn start(scenario: &Scenario, mode: ControllerMode) -> anyhow::Result<Self> {
        Self::start_missing(scenario, mode, &Endpoints::default()).await
    }

    /// Starts what `endpoints` does not name (see [`Endpoints`]).
    pub async fn start_missing(
        scenario: &Scenario,
        mode: ControllerMode,
        endpoints: &Endpoints,
    ) -> anyhow::Result<Self> {
        // A scheme that contradicts the TLS set-up is refused here, naming the flag: a netem
        // started here in front of such a --plant would refuse it and die, and the run would
        // only say, 30 s later, that the netem could not be reached.
        for (flag, address) in [
            ("--plant", &endpoints.plant),
            ("--netem", &endpoints.netem),
            ("--controller", &endpoints.controller),
        ] {
            if let Some(address) = address {
                endpoints.tls.client.uri(address).with_context(|| flag.to_string())?;
            }
        }
        if let Some(controller_addr) = &endpoints.controller {
            if endpoints.plant.is_none() && endpoints.netem.is_none() {
                bail!(
                    "with a controller address, a plant or netem address is needed too (to read the final state)"
                );
            }
            return Ok(Self {
                plant: None,
                netem: None,
                controller: None,
                plant_addr: endpoints.plant.clone(),
                netem_addr: endpoints.netem.clone(),
                controller_addr: controller_addr.clone(),
                configure_netem: endpoints.netem.is_some(),
                keep_netem_profile: endpoints.keep_netem_profile,
                time_mode: endpoints.time_mode,
                client_tls: endpoints.tls.client.clone(),
                start_from_vehicle: endpoints.start_from_vehicle,
            });
        }
        let tls = &endpoints.tls;
        let (plant, plant_addr) = match &endpoints.plant {
            Some(addr) => (None, addr.clone()),
            None => {
                tls.check_started("plant", &tls.plant)?;
                let config = plant::PlantConfig {
                    tls: tls.plant.clone(),
                    ..plant_config(scenario, endpoints.time_mode)
                };
                let (running, addr) = start_plant(config).await?;
                (Some(running), addr)
            }
        };
        let (netem, netem_addr) = match &endpoints.netem {
            Some(addr) => (None, addr.clone()),
            None => {
                tls.check_started("netem", &tls.netem)?;
                let mut config = netem_config(&plant_addr, scenario, endpoints.time_mode)?;
                config.tls = tls.netem.clone();
                let (running, addr) = start_netem(config).await?;
                (Some(running), addr)
            }
        };
        let mut config = controller::ControllerConfig::new(netem_addr.clone(), scenario.clone(), mode);
        config.time_mode = endpoints.time_mode.into();
        config.autostart = false;
        tls.check_started("controller", &tls.controller)?;
        config.tls = tls.controller.clone();
        let (controller, controller_addr) =
            start("controller", |listener, shutdown| controller::serve(listener, config, shutdown)).await?;
        Ok(Self {
            plant,
            netem,
            controller: Some(controller),
            plant_addr: Some(plant_addr),
            configure_netem: endpoints.netem.is_some(),
            keep_netem_profile: endpoints.keep_netem_profile,
            netem_addr: Some(netem_addr),
            controller_addr,
            time_mode: endpoints.time_mode,
            client_tls: tls.client.clone(),
            start_from_vehicle: endpoints.start_from_vehicle,
        })
    }

    pub fn plant_addr(&self) -> Option<&str> {
        self.plant_addr.as_deref()
    }

    pub fn netem_addr(&self) -> Option<&str> {
        self.netem_addr.as_deref()
    }

    pub fn controller_addr(&self) -> &str {
        &self.controller_addr
    }

    /// Stops what was started here: the controller first (it is the client), then netem, then
    /// the plant.
    pub async fn stop(self) -> anyhow::Result<()> {
        let mut result = Ok(());
        for running in [self.controller, self.netem, self.plant].into_iter().flatten() {
            let r = stop(running).await;
            if result.is_ok() {
                result = r;
            }
        }
        result
    }
}

/// How long a connection to a service is retried (a service of another machine or container
/// still starting); the run's own deadline may be shorter.
pub const CONNECT_PATIENCE: Duration = Duration::from_secs(30);
/// After this long without a connection, a line says what the command waits for.
const CONNECT_SAY_AFTER: Duration = Duration::from_secs(2);

/// A plaintext channel to `addr`, retried until `deadline` or [`CONNECT_PATIENCE`] (the
/// listener of a service started here is bound before its task runs, so this normally
/// succeeds at once).
pub async fn connect(addr: &str, deadline: Instant) -> anyhow::Result<Channel> {
    connect_with(addr, &Tls::plaintext(), deadline).await
}

/// How often a client's connection pings its service (HTTP/2 PING).
pub const KEEPALIVE_INTERVAL: Duration = Duration::from_secs(5);
/// How long a ping may go unanswered before the connection is given up.
pub const KEEPALIVE_TIMEOUT: Duration = Duration::from_secs(5);

/// As [`connect`], with `tls`'s client side (https with a CA, plaintext without). A service
/// that does not answer within 2 s is said to be waited for, on stderr, with the reason.
pub async fn connect_with(addr: &str, tls: &Tls, deadline: Instant) -> anyhow::Result<Channel> {
    let endpoint = tls
        .endpoint(addr)
        .with_context(|| format!("bad address {addr:?}"))?
        .connect_timeout(Duration::from_secs(2))
        .tcp_nodelay(true)
        // HTTP/2 pings: a peer that stopped answering (a frozen process, a paused VM, a cut
        // link that drops packets) fails the connection's calls and streams within about
        // 10 s instead of leaving them waiting on TCP for good.
        .http2_keep_alive_interval(KEEPALIVE_INTERVAL)
        .keep_alive_timeout(KEEPALIVE_TIMEOUT)
        .keep_alive_while_idle(true);
    let started = Instant::now();
    let deadline = deadline.min(started + CONNECT_PATIENCE);
    let (mut said, mut pause) = (false, Duration::from_millis(10));
    loop {
        match endpoint.connect().await {
            Ok(c) => return Ok(c),
            Err(e) if Instant::now() >= deadline || hilbench_svc::tls::is_tls_refusal(&e) => {
                // The chain: tonic's "transport error" keeps the reason (refused, a failed
                // handshake, a certificate for another name) in its sources.
                let waited = if said {
                    format!(" (tried for {:.0} s)", started.elapsed().as_secs_f64())
                } else {
                    String::new()
                };
                return Err(anyhow!("cannot connect to {addr}{waited}: {}", hilbench_svc::error_chain(&e)));
            }
            Err(e) => {
                if !said && started.elapsed() >= CONNECT_SAY_AFTER {
                    said = true;
                    eprintln!(
                        "waiting for {addr} ({}); trying for up to {:.0} s",
                        hilbench_svc::error_chain(&e),
                        deadline.saturating_duration_since(started).as_secs_f64()
                    );
                }
                tokio::time::sleep(pause).await;
                // Quick at first (a service of this process about to serve), then gentle.
                pause = (pause * 2).min(Duration::from_millis(250));
            }
        }
    }
}
