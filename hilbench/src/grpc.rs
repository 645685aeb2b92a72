//! Runs over real gRPC: a plant, netem and the controller, each served in this process on its
//! own loopback port (one fresh set of services per run) or running elsewhere ([`Endpoints`]).
//! Paper mode is lockstep; [`TimeMode::RealTime`] runs the same protocol on the wall clock.
//!
//! The controller is started idle (`autostart = false`) so that the telemetry subscription
//! exists before its first cycle; `SetScenario` with the whole scenario then starts the episode
//! (a built-in one or a file's, to a controller started here or elsewhere alike), and the run
//! ends when `ControllerStatus.episode_finished` says so. Everything in the [`RunSummary`]
//! comes from the wire, decoded by `proto`'s convert module: the per-cycle telemetry into
//! `mpc::CycleRecord`s, the plant's last state sample into a `mav::PlantSample`; then
//! `mpc::summarize` (the one summary, the in-process loop's too) makes the numbers.
//!
//! The delays: the scenario's network (`mav::Scenario::network`, seeded with the scenario's
//! seed) becomes netem's two profiles; a netem given by address keeps its own when asked or
//! when the scenario describes none ([`DelayProfileInForce`] says which). `mpc::run_closed_loop`
//! draws its `d_k` from the same `delay::DelayLine` as netem's command direction, so both runs
//! are bit-identical.
//!
//! Real time: the plant integrates on its clock (with its command watchdog), netem releases
//! commands on its own thread, and the controller cycles every `min_cycle_s` of wall time and
//! keeps flying after the goal (it is a service, and a vehicle must not be left uncontrolled),
//! so the run ends here: at the first telemetry cycle whose sample is at the goal (its plant
//! time is the time to the goal), or past the scenario's `max_duration_s` of plant time. The
//! final state is read from the plant just after, so in real time path length and clearance
//! include the few milliseconds between the two. A lost plant link is reported in the
//! controller's status ([`LinkFaults`]); the episode goes on when the link comes back.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::time::{Duration, Instant};

use anyhow::{Context, anyhow, bail};
use hilbench_proto::pb;
use hilbench_proto::pb::controller_client::ControllerClient;
use hilbench_proto::pb::netem_control_client::NetemControlClient;
use hilbench_proto::pb::plant_client::PlantClient;
use hilbench_svc::tls::{Tls, TlsFiles};
use mav::{PlantSample, Scenario};
use mpc::{ControllerMode, CycleRecord, RunSummary};
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tonic::transport::Channel;

pub use crate::scenario_file::TimeMode;

/// How often the driver polls `GetStatus` while telemetry streams in.
const STATUS_POLL: Duration = Duration::from_millis(10);

/// One run over gRPC.
#[derive(Debug, Clone)]
pub struct GrpcRun {
    pub summary: RunSummary,
    /// Every cycle's record, decoded from its telemetry, in order (cycle 0 first).
    pub records: Vec<CycleRecord>,
    /// The plant's state sample when the episode ended.
    pub final_sample: PlantSample,
    pub timing: RunTiming,
    pub faults: LinkFaults,
    /// The delay process netem had in force for the run.
    pub delay_profile: DelayProfileInForce,
}

/// What delayed the run's messages: `summary.json`'s `delay_profile` (a stable key).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DelayProfileInForce {
    /// `scenario`: the scenario's `[scenario.delays]` (set on netem, or run in process);
    /// `netem`: the profile a netem running elsewhere had, left alone (`--keep-netem-profile`,
    /// or a scenario that does not describe its network); `none`: no netem between the
    /// controller and the plant (the link's own delays, unknown to the bench).
    pub source: &'static str,
    /// The process, as a `[scenario.delays]` table (seeds aside: `scenario.seed` or netem's);
    /// a trace read from a file is named by its file, its delays left out.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub delays: Option<delay::DelaysTable>,
}

impl DelayProfileInForce {
    /// The table of `network`, traces from files named rather than listed.
    pub fn of(source: &'static str, network: &delay::NetworkProfile) -> Self {
        fn name_only(t: &mut delay::DelaysTable) {
            if t.file.is_some() {
                t.delays_s = None;
            }
        }
        let mut table = delay::DelaysTable::from_network(network);
        name_only(&mut table);
        for direction in [&mut table.to_plant, &mut table.to_controller].into_iter().flatten() {
            name_only(direction);
        }
        Self { source, delays: Some(table) }
    }
}

/// Faults of a run's plant link, from the controller's status, the telemetry and the plant's
/// last sample (all zero when the link never failed; the `summary.json` keys of
/// docs/output.md's schema).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct LinkFaults {
    /// Outages of the controller's link to the Plant API during the episode: failed calls, or in
    /// real time no completed cycle for longer than the controller's stall timeout.
    pub link_losses: u64,
    /// Wall time from the last completed cycle before each outage to the first after it (the
    /// time to notice included), summed over the outages, s.
    pub link_down_s: f64,
    /// The longest outage, s.
    pub longest_link_down_s: f64,
    /// Cycles that started from a sample in which the plant's watchdog held hover (no command
    /// for longer than its timeout: in real time, the cycles after an outage until their first
    /// command has crossed the delays).
    pub watchdog_cycles: u64,
    /// Plant time the plant's watchdog held hover during the run, s (the plant's own count,
    /// cycles or none).
    pub watchdog_hover_s: f64,
    /// The plant was reset or restarted under the run (which then failed).
    pub plant_resets: u64,
    /// Plant time of the run's last sample before the reset, s (0 without one).
    pub plant_reset_time_s: f64,
}

impl LinkFaults {
    fn of(status: &pb::ControllerStatus, records: &[CycleRecord], last: &PlantSample) -> Self {
        Self {
            link_losses: status.link_losses,
            link_down_s: status.link_down_s,
            longest_link_down_s: status.longest_link_down_s,
            watchdog_cycles: records.iter().filter(|r| r.watchdog_hover).count() as u64,
            watchdog_hover_s: mav::ns_to_s(last.watchdog_hover_ns),
            plant_resets: status.plant_resets,
            plant_reset_time_s: status.plant_reset_time_s,
        }
    }

    /// Adds the keys to a run's `summary.json` entry.
    pub fn add_to(&self, entry: &mut serde_json::Value) {
        if let (Some(entry), serde_json::Value::Object(keys)) =
            (entry.as_object_mut(), serde_json::json!(self))
        {
            entry.extend(keys);
        }
    }
}

/// A run that failed part-way: the error, and what it flew before it (`None` when it failed
/// before its first cycle). The partial run's summary ends with `end_reason` "error", from the
/// last sample its telemetry carried. `R` is the run: the bench's controller's ([`GrpcRun`]) or
/// an external one's (`crate::external::ExternalRun`).
#[derive(Debug)]
pub struct RunFailure<R = GrpcRun> {
    pub error: anyhow::Error,
    pub partial: Option<Box<R>>,
}

impl<R> std::fmt::Display for RunFailure<R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:#}", self.error)
    }
}

impl<R: std::fmt::Debug> std::error::Error for RunFailure<R> {}

impl<R> From<anyhow::Error> for RunFailure<R> {
    fn from(error: anyhow::Error) -> Self {
        Self { error, partial: None }
    }
}

/// Where the wall time of a run went.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct RunTiming {
    /// Starting the three services, connecting and subscribing, s.
    pub setup_s: f64,
    /// From `SetScenario` to the end of the episode (all cycles), s.
    pub episode_s: f64,
    /// Sum of the controller's solve times (from telemetry), s; part of `episode_s`.
    pub solver_s: f64,
    /// Stopping the services, s.
    pub teardown_s: f64,
}

impl RunTiming {
    /// The rest of the episode: gRPC round trips, netem, plant integration, telemetry.
    pub fn loop_overhead_s(&self) -> f64 {
        (self.episode_s - self.solver_s).max(0.0)
    }

    pub fn total_s(&self) -> f64 {
        self.setup_s + self.episode_s + self.teardown_s
    }
}

/// Settings of a gRPC run.
#[derive(Debug, Clone)]
pub struct GrpcSettings {
    /// Bound on the whole episode (wall time); a run that takes longer is an error.
    pub timeout: Duration,
    /// No control cycle for this long (wall time) fails the run, with what the controller says
    /// of its plant link: a plant or netem that died does not leave the run waiting for
    /// `timeout`. Outages shorter than this are survived and counted.
    pub stall_timeout: Duration,
}

impl Default for GrpcSettings {
    fn default() -> Self {
        Self { timeout: Duration::from_secs(600), stall_timeout: Duration::from_secs(30) }
    }
}

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
    config.time_mode = match time_mode {
        TimeMode::Lockstep => netem::TimeModeSetting::Lockstep,
        TimeMode::RealTime => netem::TimeModeSetting::RealTime,
    };
    Ok(config)
}

/// The plant's settings for `scenario` in `time_mode`.
pub fn plant_config(scenario: &Scenario, time_mode: TimeMode) -> plant::PlantConfig {
    match time_mode {
        TimeMode::Lockstep => plant::PlantConfig::lockstep(scenario.clone()),
        TimeMode::RealTime => plant::PlantConfig::real_time(scenario.clone()),
    }
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
    pub live: Option<crate::foxglove_out::Live>,
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

/// `hilbench`'s TLS flags: a directory made by `hilbench certs`, or the files one by one.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct TlsArgs {
    /// Run every link over mutual TLS with the certificates in DIR (`hilbench certs --out
    /// DIR`): ca.pem, and <service>.pem / <service>-key.pem for plant, netem, controller and
    /// hilbench itself (docs/tls.md).
    #[arg(long, value_name = "DIR", conflicts_with_all = ["tls_ca", "tls_cert", "tls_key"])]
    pub tls_dir: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub identity: hilbench_svc::tls::IdentityArgs,
    #[command(flatten)]
    pub trust: hilbench_svc::tls::TrustArgs,
}

impl TlsArgs {
    /// Whether any TLS flag was given.
    pub fn given(&self) -> bool {
        self.tls_dir.is_some()
            || self.identity.tls_cert.is_some()
            || self.identity.tls_key.is_some()
            || self.trust.tls_ca.is_some()
    }

    /// Reads and checks the files (errors name the flag).
    pub fn load(&self) -> anyhow::Result<BenchTls> {
        match &self.tls_dir {
            Some(dir) => BenchTls::from_dir(dir).with_context(|| format!("--tls-dir {}", dir.display())),
            None => BenchTls::shared(&TlsFiles::client(&self.identity, &self.trust)),
        }
    }
}

/// `--plant`, `--netem`, `--controller` of the CLI: services already running.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct EndpointArgs {
    /// A running plant (HOST:PORT) instead of one started here.
    #[arg(long)]
    pub plant: Option<String>,
    /// A running netem (HOST:PORT) instead of one started here; it gets each scenario's
    /// delay profiles through NetemControl.
    #[arg(long)]
    pub netem: Option<String>,
    /// A running controller (HOST:PORT), already pointed at the netem (or plant) it should
    /// fly; needs --plant or --netem to read the final state.
    #[arg(long)]
    pub controller: Option<String>,
    /// Leave the profile of the netem at --netem as it is (the file's [scenario.delays] is
    /// then not used); a file without [scenario.delays] leaves it alone anyway. summary.json's
    /// `delay_profile` says what was in force.
    #[arg(long, requires = "netem")]
    pub keep_netem_profile: bool,
}

impl EndpointArgs {
    pub fn endpoints(self, time_mode: TimeMode) -> Endpoints {
        Endpoints {
            plant: self.plant,
            netem: self.netem,
            controller: self.controller,
            time_mode,
            keep_netem_profile: self.keep_netem_profile,
            live: None,
            tls: Default::default(),
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
    configure_netem: bool,
    /// ...unless told to leave its profile alone.
    keep_netem_profile: bool,
    time_mode: TimeMode,
    /// How this process connects to them.
    client_tls: Tls,
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
        config.time_mode = match endpoints.time_mode {
            TimeMode::Lockstep => controller::TimeModeSetting::Lockstep,
            TimeMode::RealTime => controller::TimeModeSetting::RealTime,
        };
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

/// A plaintext channel to `addr`, retried until `deadline` (the listener is bound before the
/// server task runs, so this normally succeeds at once).
pub async fn connect(addr: &str, deadline: Instant) -> anyhow::Result<Channel> {
    connect_with(addr, &Tls::plaintext(), deadline).await
}

/// As [`connect`], with `tls`'s client side (https with a CA, plaintext without).
pub async fn connect_with(addr: &str, tls: &Tls, deadline: Instant) -> anyhow::Result<Channel> {
    let endpoint = tls
        .endpoint(addr)
        .with_context(|| format!("bad address {addr:?}"))?
        .connect_timeout(Duration::from_secs(2))
        .tcp_nodelay(true);
    loop {
        match endpoint.connect().await {
            Ok(c) => return Ok(c),
            Err(e) if Instant::now() >= deadline || hilbench_svc::tls::is_tls_refusal(&e) => {
                // The chain: tonic's "transport error" keeps the reason (refused, a failed
                // handshake, a certificate for another name) in its sources.
                return Err(anyhow!("cannot connect to {addr}: {}", hilbench_svc::tls::error_chain(&e)));
            }
            Err(_) => tokio::time::sleep(Duration::from_millis(10)).await,
        }
    }
}

/// Runs `scenario` with `mode` over gRPC on a fresh set of services.
pub async fn run_over_grpc(
    scenario: &Scenario,
    mode: ControllerMode,
    settings: &GrpcSettings,
) -> Result<GrpcRun, RunFailure> {
    run_against(scenario, mode, settings, &Endpoints::default()).await
}

/// Runs `scenario` with `mode` over gRPC against `endpoints`, starting what they do not name.
/// A run that fails part-way returns what it flew with the error ([`RunFailure`]).
pub async fn run_against(
    scenario: &Scenario,
    mode: ControllerMode,
    settings: &GrpcSettings,
    endpoints: &Endpoints,
) -> Result<GrpcRun, RunFailure> {
    let started = Instant::now();
    let services = Services::start_missing(scenario, mode, endpoints).await?;
    let mut progress = Progress::default();
    let live = endpoints.live.as_ref();
    let result = drive(&services, scenario, mode, settings, started, &mut progress, live).await;
    let result = match result {
        Ok(run) => Ok(run),
        Err(error) => {
            let partial = partial_run(&services, scenario, mode, progress).await.map(Box::new);
            Err(RunFailure { error, partial })
        }
    };
    let stopping = Instant::now();
    let stopped = services.stop().await;
    let mut run = result?;
    stopped?;
    run.timing.teardown_s = stopping.elapsed().as_secs_f64();
    Ok(run)
}

/// What a run has seen so far, kept outside [`drive`] so that a run that fails part-way can
/// still be summarised.
#[derive(Debug, Default)]
struct Progress {
    /// Telemetry records per episode started after the request.
    episodes: BTreeMap<u64, Vec<CycleRecord>>,
    /// The plant's sample of the newest telemetry record, as it came (already validated with
    /// its record; decoded only if the run fails).
    last_sample: Option<pb::StateSample>,
    /// The controller's status at the last poll.
    status: Option<pb::ControllerStatus>,
    delay_profile: Option<DelayProfileInForce>,
    setup_s: f64,
    episode_started: Option<Instant>,
}

/// The run so far, from `progress` (the controller's status asked once more, briefly: it
/// knows the link faults and a plant reset): `None` before the first cycle.
async fn partial_run(
    services: &Services,
    scenario: &Scenario,
    mode: ControllerMode,
    mut progress: Progress,
) -> Option<GrpcRun> {
    let (episode, records) = progress.episodes.pop_last()?;
    let last = PlantSample::try_from(&progress.last_sample.take()?).ok()?;
    let ask = async {
        let channel =
            connect_with(services.controller_addr(), &services.client_tls, Instant::now()).await.ok()?;
        let status = ControllerClient::new(channel).get_status(pb::GetStatusRequest {}).await.ok()?;
        Some(status.into_inner())
    };
    let status = match tokio::time::timeout(Duration::from_secs(2), ask).await {
        Ok(Some(s)) if s.episode == episode => Some(s),
        _ => progress.status.filter(|s| s.episode == episode),
    }
    .unwrap_or_default();
    let mut summary = mpc::summarize(&scenario.name, mode, &records, &last, None);
    summary.end_reason = "error".to_string();
    let faults = LinkFaults::of(&status, &records, &last);
    let solver_s = records.iter().map(|r| r.solve.solve_ms * 1e-3).sum();
    let episode_s = progress.episode_started.map_or(0.0, |t| t.elapsed().as_secs_f64());
    Some(GrpcRun {
        summary,
        records,
        final_sample: last,
        timing: RunTiming { setup_s: progress.setup_s, episode_s, solver_s, teardown_s: 0.0 },
        faults,
        delay_profile: progress.delay_profile.unwrap_or(DelayProfileInForce { source: "none", delays: None }),
    })
}

/// Gives a netem running elsewhere the scenario's profiles.
async fn configure_netem(
    addr: &str,
    tls: &Tls,
    scenario: &Scenario,
    time_mode: TimeMode,
    deadline: Instant,
) -> anyhow::Result<()> {
    let config = netem_config(addr, scenario, time_mode)?;
    let mut control = NetemControlClient::new(connect_with(addr, tls, deadline).await?);
    for (direction, profile) in [
        (pb::Direction::PlantToController, &config.plant_to_controller),
        (pb::Direction::ControllerToPlant, &config.controller_to_plant),
    ] {
        control
            .set_profile(pb::SetProfileRequest {
                direction: direction as i32,
                profile: Some(pb::DirectionProfile::from(profile)),
                preset: String::new(),
            })
            .await
            .with_context(|| format!("netem SetProfile at {addr}"))?;
    }
    Ok(())
}

/// The profile netem has in force, both directions.
async fn netem_profile(addr: &str, tls: &Tls, deadline: Instant) -> anyhow::Result<delay::NetworkProfile> {
    let mut control = NetemControlClient::new(connect_with(addr, tls, deadline).await?);
    let mut get = async |direction: pb::Direction| -> anyhow::Result<delay::DirectionProfile> {
        let p = control
            .get_profile(pb::GetProfileRequest { direction: direction as i32 })
            .await
            .with_context(|| format!("netem GetProfile at {addr}"))?
            .into_inner();
        hilbench_proto::convert::netem::profile_from_pb(&p).map_err(|e| anyhow!("netem's profile: {e}"))
    };
    let to_plant = get(pb::Direction::ControllerToPlant).await?;
    let to_controller = get(pb::Direction::PlantToController).await?;
    Ok(delay::NetworkProfile { to_plant, to_controller })
}

async fn drive(
    services: &Services,
    scenario: &Scenario,
    mode: ControllerMode,
    settings: &GrpcSettings,
    started: Instant,
    progress: &mut Progress,
    live: Option<&crate::foxglove_out::Live>,
) -> anyhow::Result<GrpcRun> {
    let deadline = Instant::now() + settings.timeout;
    // A panic in a task of this run (an in-process service's, or this driver's own) ends it.
    let mut panicked = crate::panics::watch();
    // A netem running elsewhere gets the scenario's network, unless told to keep its own or
    // the scenario describes none; one started here was started with the scenario's.
    let keep = services.keep_netem_profile || scenario.delays.is_none();
    if services.configure_netem
        && !keep
        && let Some(addr) = services.netem_addr()
    {
        configure_netem(addr, &services.client_tls, scenario, services.time_mode, deadline).await?;
    }
    let delay_profile = match services.netem_addr() {
        Some(addr) => {
            let network = netem_profile(addr, &services.client_tls, deadline).await?;
            DelayProfileInForce::of(
                if services.configure_netem && keep { "netem" } else { "scenario" },
                &network,
            )
        }
        None => DelayProfileInForce { source: "none", delays: None },
    };
    progress.delay_profile = Some(delay_profile.clone());
    let tls = &services.client_tls;
    let mut controller =
        ControllerClient::new(connect_with(services.controller_addr(), tls, deadline).await?);
    // The final state: from the plant, else through netem (an undelayed read).
    let state_addr = services
        .plant_addr()
        .or(services.netem_addr())
        .ok_or_else(|| anyhow!("no plant or netem address to read the final state from"))?;
    let mut plant = PlantClient::new(connect_with(state_addr, tls, deadline).await?);
    let real_time = services.time_mode == TimeMode::RealTime;
    let described = plant.describe(pb::DescribeRequest {}).await.context("plant Describe")?.into_inner();
    let wanted = if real_time { pb::TimeMode::RealTime } else { pb::TimeMode::Lockstep };
    if described.time_mode != wanted as i32 {
        bail!(
            "the plant at {state_addr} runs in {:?}, this run needs {:?}",
            pb::TimeMode::try_from(described.time_mode).unwrap_or(pb::TimeMode::Unspecified),
            wanted
        );
    }
    // Subscribe before the episode starts: the response headers mean the server subscribed.
    let mut stream = controller
        .stream_telemetry(pb::StreamTelemetryRequest {})
        .await
        .context("controller StreamTelemetry")?
        .into_inner();
    let before = controller.get_status(pb::GetStatusRequest {}).await?.into_inner();
    let setup_s = started.elapsed().as_secs_f64();
    progress.setup_s = setup_s;

    let episode_started = Instant::now();
    progress.episode_started = Some(episode_started);
    // The whole scenario travels with the request, so a controller started elsewhere flies a
    // scenario file exactly as a built-in one (and resets the plant with it).
    controller
        .set_scenario(pb::SetScenarioRequest {
            scenario: String::new(),
            mode: mode.name().into(),
            definition: Some(scenario.into()),
        })
        .await
        .context("controller SetScenario")?;
    // The episode that runs this request is the last one started after `before`: one that was
    // running (or about to start at autostart) is restarted by the request, and a pending
    // request is taken before an episode can finish.
    let mut last_cycle_at = Instant::now();
    let mut poll = tokio::time::interval(STATUS_POLL);
    poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    // Real time: the episode whose telemetry ended the run, and the plant time of its goal.
    let mut real_time_end: Option<(u64, Option<u64>)> = None;
    let max_ns = mav::s_to_ns(scenario.max_duration_s).unwrap_or(u64::MAX);
    let (status, telemetry) = loop {
        if Instant::now() >= deadline {
            bail!(
                "{} with {}: the episode did not finish within {:?} ({} cycles seen)",
                scenario.name,
                mode.name(),
                settings.timeout,
                progress.episodes.values().last().map_or(0, Vec::len)
            );
        }
        tokio::select! {
            panic = panicked.changed() => {
                let what = panic.ok().and_then(|()| panicked.borrow().clone());
                bail!("a task of the run panicked: {}", what.unwrap_or_default());
            }
            item = stream.message() => {
                let mut item = item.context("telemetry stream")?
                    .ok_or_else(|| anyhow!("the controller ended the telemetry stream"))?;
                if item.episode <= before.episode {
                    continue;
                }
                let record = CycleRecord::try_from(&item)
                    .map_err(|e| anyhow!("telemetry of cycle {} of episode {}: {e}", item.cycle, item.episode))?;
                hilbench_svc::inject_panic("hilbench-run");
                last_cycle_at = Instant::now();
                if real_time && real_time_end.is_none() {
                    real_time_end = real_time_outcome(scenario, &record, max_ns).map(|t| (item.episode, t));
                }
                let cycles = progress.episodes.entry(item.episode).or_default();
                if record.cycle != cycles.len() as u64 {
                    bail!(
                        "telemetry gap in episode {}: expected cycle {}, got {}",
                        item.episode,
                        cycles.len(),
                        record.cycle
                    );
                }
                if let Some(live) = live {
                    live.cycle(scenario, &record);
                }
                cycles.push(record);
                progress.last_sample = item.sample.take();
            }
            _ = poll.tick() => {
                let s = controller.get_status(pb::GetStatusRequest {}).await
                    .context("controller GetStatus")?.into_inner();
                progress.status = Some(s.clone());
                if let Some((episode, _)) = real_time_end
                    && s.episode == episode
                {
                    let telemetry = progress.episodes.remove(&episode).unwrap_or_default();
                    break (s, telemetry);
                }
                if last_cycle_at.elapsed() > settings.stall_timeout {
                    bail!(
                        "{} with {}: no control cycle for {:.0} s (the controller's plant link is {}; its last error: {})",
                        scenario.name,
                        mode.name(),
                        settings.stall_timeout.as_secs_f64(),
                        if s.plant_connected { "up" } else { "down" },
                        if s.last_error.is_empty() { "none" } else { &s.last_error }
                    );
                }
                if s.episode > before.episode && s.episode_finished && s.finish_reason == "error" {
                    bail!(
                        "{} with {}: the controller's episode ended with an error: {}",
                        scenario.name,
                        mode.name(),
                        s.last_error
                    );
                }
                let seen = progress.episodes.get(&s.episode).map_or(0, Vec::len) as u64;
                if !real_time && s.episode > before.episode && s.episode_finished && seen >= s.cycles {
                    let telemetry = progress.episodes.remove(&s.episode).unwrap_or_default();
                    break (s, telemetry);
                }
            }
        }
    };
    let episode_s = episode_started.elapsed().as_secs_f64();
    if !real_time && telemetry.len() as u64 != status.cycles {
        bail!("{} cycles of telemetry, the controller reports {}", telemetry.len(), status.cycles);
    }
    if status.scenario != scenario.name || status.mode != mode.name() {
        bail!(
            "the controller ran {} with {}, not {} with {}",
            status.scenario,
            status.mode,
            scenario.name,
            mode.name()
        );
    }
    let final_sample = plant.get_state(pb::GetStateRequest {}).await.context("plant GetState")?.into_inner();
    let final_sample =
        PlantSample::try_from(&final_sample).map_err(|e| anyhow!("the plant's last sample: {e}"))?;
    let time_to_goal_ns = match real_time_end {
        Some((_, goal)) => goal,
        None => (status.finish_reason == "reached").then_some(final_sample.time_ns),
    };
    let records = telemetry;
    let mut summary = mpc::summarize(&scenario.name, mode, &records, &final_sample, time_to_goal_ns);
    if !real_time && status.finish_reason == "collided" {
        summary.end_reason = status.finish_reason.clone();
    }
    let faults = LinkFaults::of(&status, &records, &final_sample);
    let solver_s = records.iter().map(|r| r.solve.solve_ms * 1e-3).sum();
    Ok(GrpcRun {
        summary,
        records,
        final_sample,
        timing: RunTiming { setup_s, episode_s, solver_s, teardown_s: 0.0 },
        faults,
        delay_profile,
    })
}

/// Real time: whether the cycle of `record` ends the run: `Some(Some(t))` when its sample is
/// at the goal (plant time `t`), `Some(None)` past the time limit, `None` to go on.
fn real_time_outcome(scenario: &Scenario, record: &CycleRecord, max_ns: u64) -> Option<Option<u64>> {
    if scenario.goal_reached(&mav::State::from(record.state)) {
        return Some(Some(record.sample_time_ns));
    }
    (record.sample_time_ns >= max_ns).then_some(None)
}
