//! The services of a run: a plant, netem and the controller, each served in this process on
//! its own loopback port (one fresh set per run) or running elsewhere ([`Endpoints`]), with
//! their TLS ([`BenchTls`]); and connecting to them.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, anyhow, bail};
use hilbench_svc::tls::{Tls, TlsFiles};
use mav::{Scenario, TimeMode};
use mpc::ControllerMode;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
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

/// A plant served in this process on a loopback port: the task and its address.
pub(crate) async fn start_plant(config: plant::PlantConfig) -> anyhow::Result<(Running, String)> {
    let (listener, addr) = bind().await?;
    let (stop, stopped) = oneshot::channel::<()>();
    let task = tokio::spawn(async move {
        plant::serve(listener, config, async {
            let _ = stopped.await;
        })
        .await
        .map_err(|e| e.to_string())
    });
    Ok((Running { name: "plant", stop: Some(stop), task: Some(task) }, addr.to_string()))
}

/// A netem served in this process on a loopback port: the task and its address.
pub(crate) async fn start_netem(config: netem::Config) -> anyhow::Result<(Running, String)> {
    let (listener, addr) = bind().await?;
    let (stop, stopped) = oneshot::channel::<()>();
    let task = tokio::spawn(async move {
        netem::serve(listener, config, async {
            let _ = stopped.await;
        })
        .await
        .map_err(|e| e.to_string())
    });
    Ok((Running { name: "netem", stop: Some(stop), task: Some(task) }, addr.to_string()))
}

/// A service task with its stop signal.
pub(crate) struct Running {
    name: &'static str,
    stop: Option<oneshot::Sender<()>>,
    task: Option<JoinHandle<Result<(), String>>>,
}

impl Running {
    pub(crate) async fn stop(mut self) -> anyhow::Result<()> {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        let Some(task) = self.task.take() else { return Ok(()) };
        match tokio::time::timeout(Duration::from_secs(10), task).await {
            Ok(Ok(Ok(()))) => Ok(()),
            Ok(Ok(Err(e))) => Err(anyhow!("{} failed: {e}", self.name)),
            Ok(Err(join)) => Err(anyhow!("{} task failed: {join}", self.name)),
            Err(_) => Err(anyhow!("{} did not stop within 10 s", self.name)),
        }
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
    }
}

async fn bind() -> anyhow::Result<(tokio::net::TcpListener, SocketAddr)> {
    let listener =
        tokio::net::TcpListener::bind("127.0.0.1:0").await.context("cannot bind a loopback port")?;
    let addr = listener.local_addr()?;
    Ok((listener, addr))
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
        let (listener, controller_addr) = bind().await?;
        let (stop, stopped) = oneshot::channel::<()>();
        let mut config = controller::ControllerConfig::new(netem_addr.clone(), scenario.clone(), mode);
        config.time_mode = endpoints.time_mode.into();
        config.autostart = false;
        tls.check_started("controller", &tls.controller)?;
        config.tls = tls.controller.clone();
        let task = tokio::spawn(async move {
            controller::serve(listener, config, async {
                let _ = stopped.await;
            })
            .await
            .map_err(|e| e.to_string())
        });
        let controller = Running { name: "controller", stop: Some(stop), task: Some(task) };
        Ok(Self {
            plant,
            netem,
            controller: Some(controller),
            plant_addr: Some(plant_addr),
            configure_netem: endpoints.netem.is_some(),
            keep_netem_profile: endpoints.keep_netem_profile,
            netem_addr: Some(netem_addr),
            controller_addr: controller_addr.to_string(),
            time_mode: endpoints.time_mode,
            client_tls: tls.client.clone(),
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
            let r = running.stop().await;
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

/// As [`connect`], with `tls`'s client side (https with a CA, plaintext without). A service
/// that does not answer within 2 s is said to be waited for, on stderr, with the reason.
pub async fn connect_with(addr: &str, tls: &Tls, deadline: Instant) -> anyhow::Result<Channel> {
    let endpoint = tls
        .endpoint(addr)
        .with_context(|| format!("bad address {addr:?}"))?
        .connect_timeout(Duration::from_secs(2))
        .tcp_nodelay(true);
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
                return Err(anyhow!(
                    "cannot connect to {addr}{waited}: {}",
                    hilbench_svc::tls::error_chain(&e)
                ));
            }
            Err(e) => {
                if !said && started.elapsed() >= CONNECT_SAY_AFTER {
                    said = true;
                    eprintln!(
                        "waiting for {addr} ({}); trying for up to {:.0} s",
                        hilbench_svc::tls::error_chain(&e),
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
