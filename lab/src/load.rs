//! Load benchmarks of netem on loopback (recorded in BENCHMARKS.md). Run in release:
//!
//! ```text
//! cargo run --release -p lab -- load throughput --messages 200000 [--rate-hz 20000]
//! cargo run --release -p lab -- load commands --messages 20000
//! cargo run --release -p lab -- load real-time --seconds 60 --rate-hz 1000 --delay-ms 20
//! cargo run --release -p lab -- load release --seconds 20     (or scripts/bench-release.sh)
//! cargo build --release -p plant -p netem
//! cargo run --release -p lab -- load idle-streams --streams 60
//! cargo run --release -p lab -- load step-rate --clients 1,4,16
//! ```
//!
//! The first three put a minimal in-process Plant ("echo plant") behind an in-process netem:
//! it answers at once and streams samples as fast as asked, so the numbers measure netem and
//! gRPC, not the MAV simulation. `idle-streams` and `step-rate` start the release binaries
//! `plant` and `netem` as processes (as a user runs them), so that netem's memory is its own
//! and the round trips cross process boundaries as they do for a controller in another
//! language. Nothing here asserts timings; the program prints what it measured and exits
//! non-zero only if a message was lost or a call failed.

use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering as AtomicOrdering};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::Subcommand;
use delay::{DirectionProfile, Distribution};
use hilbench_proto::pb;
use hilbench_proto::pb::netem_control_client::NetemControlClient;
use hilbench_proto::pb::plant_client::PlantClient;
use hilbench_svc::loopback::{Served, serve_loopback};
use tokio::sync::mpsc;
use tokio_stream::StreamExt;
use tokio_stream::wrappers::ReceiverStream;
use tonic::transport::{Channel, Server};
use tonic::{Request, Response, Status};

mod release;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    bench: Bench,
}

#[derive(Debug, Subcommand)]
enum Bench {
    /// State samples streamed through netem as fast as they go (zero delay); what the reader
    /// cannot take is discarded by the stream's buffer and counted.
    Throughput {
        #[arg(long, default_value_t = 200_000)]
        messages: u64,
        /// Send at this rate instead (a burst of rate/1000 every millisecond); 0: as fast as
        /// netem reads them.
        #[arg(long, default_value_t = 0)]
        rate_hz: u64,
        /// netem's `Config::stream_buffer`, samples.
        #[arg(long, default_value_t = netem::DEFAULT_STREAM_BUFFER)]
        stream_buffer: usize,
    },
    /// Commands (unary ApplyCommand, zero delay, FIFO) from concurrent controllers.
    Commands {
        #[arg(long, default_value_t = 20_000)]
        messages: u64,
        #[arg(long, default_value_t = 8)]
        clients: u64,
    },
    /// Samples streamed and commands sent at a fixed rate with a constant delay both ways.
    RealTime {
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
        #[arg(long, default_value_t = 1000.0)]
        rate_hz: f64,
        #[arg(long, default_value_t = 20.0)]
        delay_ms: f64,
    },
    /// netem's release error, gRPC and UDP paths, beside the machine's floor (bare sleeps to
    /// the same deadlines) at each rate, constant and Gamma delays, and the plant's real-time
    /// step jitter.
    Release(release::Args),
    /// Memory of a netem process (`VmRSS`) before and after `--streams` StateStream
    /// subscribers that read their first sample and then never read again, in front of a
    /// real-time plant at 1 kHz (plant and netem are the release binaries); with `--direct`,
    /// of the plant with the subscribers on it.
    IdleStreams {
        #[arg(long, default_value_t = 60)]
        streams: usize,
        /// How long the subscribers stay idle, s; the RSS is printed every `--every-s`.
        #[arg(long, default_value_t = 30.0)]
        seconds: f64,
        #[arg(long, default_value_t = 5.0)]
        every_s: f64,
        /// The subscribers' HTTP/2 stream window, KiB (default: tonic's, 2 MiB, which lets
        /// netem hand about 19,000 samples per stream to the client before it stops).
        #[arg(long)]
        client_window_kib: Option<u32>,
        /// Subscribe to the plant itself and measure its RSS instead (no netem).
        #[arg(long)]
        direct: bool,
        #[command(flatten)]
        bins: Binaries,
    },
    /// Lockstep `Step` round trips per second (a command, 1 ms of plant time, the sample)
    /// through a netem process in front of a lockstep plant process, from concurrent
    /// clients, each on its own connection.
    StepRate {
        /// Numbers of concurrent clients, one measurement each.
        #[arg(long, value_delimiter = ',', default_value = "1,4,16")]
        clients: Vec<usize>,
        /// Length of each measurement, s (after a warm-up of a tenth of it).
        #[arg(long, default_value_t = 5.0)]
        seconds: f64,
        /// netem's `--profile` (its delays hold commands in lockstep, which does not change the
        /// number of round trips).
        #[arg(long, default_value = "none")]
        profile: String,
        /// Also measure the same clients against the plant directly.
        #[arg(long)]
        direct: bool,
        #[command(flatten)]
        bins: Binaries,
    },
}

/// Where the `plant` and `netem` release binaries are.
#[derive(Debug, clap::Args)]
struct Binaries {
    /// Directory of the `plant` and `netem` binaries (default: this program's, i.e.
    /// `target/release`).
    #[arg(long)]
    bin_dir: Option<std::path::PathBuf>,
    /// Extra flags for netem, e.g. `--netem-arg=--max-streams=128`.
    #[arg(long, allow_hyphen_values = true)]
    netem_arg: Vec<String>,
    /// Extra flags for the plant.
    #[arg(long, allow_hyphen_values = true)]
    plant_arg: Vec<String>,
}

/// The echo plant: real-time, answers at once, streams `period_ns`-spaced samples (or as
/// fast as the reader takes them when the period is 0), `limit` samples per stream.
#[derive(Clone)]
struct EchoPlant {
    limit: Arc<AtomicU64>,
    /// Samples sent at each period's tick.
    burst: u64,
    applied: Arc<AtomicU64>,
}

fn sample(seq: u64) -> pb::StateSample {
    pb::StateSample {
        seq,
        time_ns: seq,
        state: Some(pb::MavState { x: vec![0.0; 8] }),
        last_command: Some(pb::AppliedCommand::default()),
        ..Default::default()
    }
}

type Samples = Pin<Box<dyn tokio_stream::Stream<Item = Result<pb::StateSample, Status>> + Send>>;

#[tonic::async_trait]
impl pb::plant_server::Plant for EchoPlant {
    async fn reset(&self, _r: Request<pb::ResetRequest>) -> Result<Response<pb::ResetResponse>, Status> {
        Ok(Response::new(pb::ResetResponse { description: None, sample: Some(sample(0)) }))
    }
    type StreamStateStream = Samples;
    async fn stream_state(&self, r: Request<pb::StreamStateRequest>) -> Result<Response<Samples>, Status> {
        let period = r.into_inner().period_ns;
        let (limit, burst) = (self.limit.load(AtomicOrdering::Relaxed), self.burst.max(1));
        let (tx, rx) = mpsc::channel(1024);
        tokio::spawn(async move {
            let mut tick = (period > 0).then(|| tokio::time::interval(Duration::from_nanos(period)));
            for seq in 0..limit {
                if let Some(t) = &mut tick
                    && seq % burst == 0
                {
                    t.tick().await;
                }
                if tx.send(Ok(sample(seq))).await.is_err() {
                    return;
                }
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }
    async fn get_state(&self, _r: Request<pb::GetStateRequest>) -> Result<Response<pb::StateSample>, Status> {
        Ok(Response::new(sample(0)))
    }
    async fn apply_command(
        &self,
        r: Request<pb::Command>,
    ) -> Result<Response<pb::ApplyCommandResponse>, Status> {
        self.applied.fetch_add(1, AtomicOrdering::Relaxed);
        let c = r.into_inner();
        Ok(Response::new(pb::ApplyCommandResponse {
            applied: Some(pb::AppliedCommand {
                input: c.input,
                command_seq: c.command_seq,
                ..Default::default()
            }),
        }))
    }
    async fn advance(
        &self,
        _r: Request<pb::AdvanceRequest>,
    ) -> Result<Response<pb::AdvanceResponse>, Status> {
        Err(Status::failed_precondition("real time"))
    }
    async fn step(&self, _r: Request<pb::StepRequest>) -> Result<Response<pb::AdvanceResponse>, Status> {
        Err(Status::failed_precondition("real time"))
    }
    async fn describe(
        &self,
        _r: Request<pb::DescribeRequest>,
    ) -> Result<Response<pb::PlantDescription>, Status> {
        Ok(Response::new(pb::PlantDescription {
            time_mode: pb::TimeMode::RealTime as i32,
            implementation: "netem load echo plant".into(),
            ..Default::default()
        }))
    }
}

struct Rig {
    plant: EchoPlant,
    netem: Channel,
    /// netem and the plant, stopped when dropped (netem first).
    stops: (Served<netem::NetemError>, Served<tonic::transport::Error>),
}

/// A constant `delay_s` (seed 42).
fn constant(delay_s: f64) -> DirectionProfile {
    DirectionProfile::with_delay(Distribution::Constant { delay_s }, 42)
}

/// netem with `profile` both ways in front of an echo plant whose streams send `limit`
/// samples, `burst` at each tick of the period asked for.
async fn rig(profile: DirectionProfile, limit: u64, burst: u64, stream_buffer: usize) -> anyhow::Result<Rig> {
    let plant =
        EchoPlant { limit: Arc::new(AtomicU64::new(limit)), burst, applied: Arc::new(AtomicU64::new(0)) };
    let svc = pb::plant_server::PlantServer::new(plant.clone());
    let served_plant = serve_loopback("echo plant", |listener, shutdown| async move {
        let incoming = tonic::transport::server::TcpIncoming::from(listener).with_nodelay(Some(true));
        Server::builder().add_service(svc).serve_with_incoming_shutdown(incoming, shutdown).await
    })
    .await?;
    let mut config = netem::Config::new(served_plant.addr.to_string());
    config.time_mode = mav::TimeModeChoice::Fixed(mav::TimeMode::RealTime);
    config.stream_buffer = stream_buffer;
    config.plant_to_controller = profile.clone();
    config.controller_to_plant = profile;
    let served_netem = serve_loopback("netem", |listener, shutdown| async move {
        let served = netem::serve(listener, config, shutdown).await;
        if let Err(e) = &served {
            eprintln!("netem failed: {e}");
        }
        served
    })
    .await?;
    let netem =
        Channel::from_shared(format!("http://{}", served_netem.addr))?.tcp_nodelay(true).connect().await?;
    Ok(Rig { plant, netem, stops: (served_netem, served_plant) })
}

async fn stats(ch: &Channel) -> anyhow::Result<pb::NetemStats> {
    Ok(NetemControlClient::new(ch.clone()).get_stats(pb::GetStatsRequest {}).await?.into_inner())
}

fn print_dir(name: &str, d: &pb::DirectionStats) {
    println!(
        "  {name}: sent {} delivered {} dropped {} in flight {} | delay p50 {:.3} ms p99 {:.3} ms max {:.3} ms | release error p99 {:.1} us max {:.1} us",
        d.sent,
        d.delivered,
        d.dropped,
        d.in_flight,
        d.delay_p50_s * 1e3,
        d.delay_p99_s * 1e3,
        d.delay_max_s * 1e3,
        d.release_error_p99_s * 1e6,
        d.release_error_max_s * 1e6
    );
}

fn command(seq: u64) -> pb::Command {
    pb::Command {
        input: Some(pb::ControlInput { thrust_mps2: 9.81, roll_rad: 0.0, pitch_rad: 0.0 }),
        command_seq: seq,
        ..Default::default()
    }
}

/// A child process this program started; killed when dropped.
struct Proc {
    name: &'static str,
    child: std::process::Child,
    addr: String,
}

impl Proc {
    fn pid(&self) -> u32 {
        self.child.id()
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A loopback address nothing listens on right now (bound, then released).
fn free_addr() -> anyhow::Result<String> {
    let l = std::net::TcpListener::bind("127.0.0.1:0")?;
    Ok(l.local_addr()?.to_string())
}

impl Binaries {
    fn dir(&self) -> anyhow::Result<std::path::PathBuf> {
        if let Some(d) = &self.bin_dir {
            return Ok(d.clone());
        }
        let exe = std::env::current_exe()?;
        exe.parent().map(std::path::Path::to_path_buf).context("this program's path has no directory")
    }

    /// Starts `name` (a binary in [`Binaries::dir`]) on a free loopback port with `args`,
    /// its logs at `warn` to stderr, and waits until it answers `Describe`.
    async fn start(&self, name: &'static str, args: &[String]) -> anyhow::Result<Proc> {
        let bin = self.dir()?.join(name);
        if !bin.exists() {
            bail!("{} is missing: build it first (cargo build --release -p plant -p netem)", bin.display());
        }
        let addr = free_addr()?;
        let extra = if name == "netem" { &self.netem_arg } else { &self.plant_arg };
        let child = std::process::Command::new(&bin)
            .arg("--listen")
            .arg(&addr)
            .args(args)
            .args(extra)
            .env("RUST_LOG", "warn")
            .stdout(std::process::Stdio::null())
            .spawn()
            .with_context(|| format!("cannot start {}", bin.display()))?;
        let proc = Proc { name, child, addr };
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            if let Ok(ch) = connect(&proc.addr).await
                && PlantClient::new(ch).describe(pb::DescribeRequest {}).await.is_ok()
            {
                return Ok(proc);
            }
            if Instant::now() > deadline {
                bail!("{} did not answer on {} within 30 s", proc.name, proc.addr);
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
}

async fn connect(addr: &str) -> anyhow::Result<Channel> {
    Ok(Channel::from_shared(format!("http://{addr}"))?.tcp_nodelay(true).connect().await?)
}

/// Resident set size of process `pid`, KiB (`VmRSS` in /proc; Linux only).
fn rss_kib(pid: u32) -> anyhow::Result<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status"))
        .with_context(|| format!("/proc/{pid}/status (the RSS is read on Linux only)"))?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .context("no VmRSS line")
}

async fn idle_streams(
    streams: usize,
    seconds: f64,
    every_s: f64,
    client_window_kib: Option<u32>,
    direct: bool,
    bins: &Binaries,
) -> anyhow::Result<()> {
    let plant = bins.start("plant", &["--time-mode".into(), "real-time".into()]).await?;
    let netem = match direct {
        true => None,
        false => Some(
            bins.start("netem", &["--plant".into(), plant.addr.clone(), "--profile".into(), "none".into()])
                .await?,
        ),
    };
    let measured = netem.as_ref().unwrap_or(&plant);
    let mut probe = PlantClient::new(connect(&measured.addr).await?);
    probe.get_state(pb::GetStateRequest {}).await?;
    tokio::time::sleep(Duration::from_secs(1)).await;
    let before = rss_kib(measured.pid())?;
    println!(
        "idle streams: {} RSS before: {before} KiB (plant at 1 kHz real time, profile none)",
        measured.name
    );
    // Each subscriber on its own connection, as separate controllers would be.
    let mut idle = Vec::with_capacity(streams);
    let mut refused = 0usize;
    for _ in 0..streams {
        let endpoint = Channel::from_shared(format!("http://{}", measured.addr))?.tcp_nodelay(true);
        let endpoint = match client_window_kib {
            Some(kib) => endpoint.initial_stream_window_size(kib * 1024),
            None => endpoint,
        };
        let mut client = PlantClient::new(endpoint.connect().await?);
        match client.stream_state(pb::StreamStateRequest { period_ns: 0 }).await {
            Ok(r) => {
                let mut s = r.into_inner();
                match tokio::time::timeout(Duration::from_secs(10), s.next()).await {
                    Ok(Some(Ok(_))) => idle.push(s),
                    other => bail!("a stream gave no first sample: {other:?}"),
                }
            }
            Err(status) if status.code() == tonic::Code::ResourceExhausted => {
                refused += 1;
                if refused == 1 {
                    println!("  refused: {}", status.message());
                }
            }
            Err(status) => bail!("StreamState: {status}"),
        }
    }
    println!("  {} streams open, {refused} refused (RESOURCE_EXHAUSTED)", idle.len());
    let t0 = Instant::now();
    let mut last = before;
    while t0.elapsed().as_secs_f64() < seconds {
        tokio::time::sleep(Duration::from_secs_f64(every_s.min(seconds))).await;
        last = rss_kib(measured.pid())?;
        let Some(netem) = &netem else {
            println!(
                "  after {:>5.1} s idle: RSS {last} KiB (+{} KiB)",
                t0.elapsed().as_secs_f64(),
                last.saturating_sub(before)
            );
            continue;
        };
        let st = stats(&connect(&netem.addr).await?).await?;
        let p = st.plant_to_controller.context("stats")?;
        println!(
            "  after {:>5.1} s idle: RSS {last} KiB (+{} KiB) | plant->controller sent {} delivered {} dropped {} stream overflow {} in flight {}",
            t0.elapsed().as_secs_f64(),
            last.saturating_sub(before),
            p.sent,
            p.delivered,
            p.dropped,
            p.stream_overflow_dropped,
            p.in_flight,
        );
    }
    if let Some(netem) = &netem {
        // netem's statistics keep the last 2^20 delays and release errors per direction (up
        // to 16 MiB, whatever the streams): free them to see what the streams hold.
        NetemControlClient::new(connect(&netem.addr).await?).reset_stats(pb::ResetStatsRequest {}).await?;
        tokio::time::sleep(Duration::from_secs(1)).await;
        let reset = rss_kib(netem.pid())?;
        println!(
            "  after ResetStats: RSS {reset} KiB (+{} KiB): {:.0} KiB per idle stream",
            reset.saturating_sub(before),
            reset.saturating_sub(before) as f64 / idle.len().max(1) as f64
        );
    }
    let n = idle.len().max(1) as f64;
    println!(
        "  {} RSS {before} -> {last} KiB: {:.0} KiB per idle stream ({} streams, {seconds} s)",
        measured.name,
        last.saturating_sub(before) as f64 / n,
        idle.len()
    );
    drop(idle);
    drop(netem);
    drop(plant);
    Ok(())
}

/// Lockstep `Step`s of 1 ms with a command from `clients` concurrent clients on `addr` for
/// `seconds`; returns the round trips completed.
async fn step_clients(addr: &str, clients: usize, seconds: f64) -> anyhow::Result<(u64, f64)> {
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let mut tasks = Vec::new();
    for c in 0..clients {
        let mut client = PlantClient::new(connect(addr).await?);
        let stop = stop.clone();
        tasks.push(tokio::spawn(async move {
            let mut n = 0u64;
            while !stop.load(AtomicOrdering::Relaxed) {
                let seq = (c as u64) << 32 | n;
                client
                    .step(pb::StepRequest {
                        command: Some(command(seq)),
                        duration_ns: 1_000_000,
                        ..Default::default()
                    })
                    .await?;
                n += 1;
            }
            anyhow::Ok(n)
        }));
    }
    let t0 = Instant::now();
    tokio::time::sleep(Duration::from_secs_f64(seconds)).await;
    stop.store(true, AtomicOrdering::Relaxed);
    let mut total = 0;
    for t in tasks {
        total += t.await??;
    }
    Ok((total, t0.elapsed().as_secs_f64()))
}

async fn step_rate(
    clients: &[usize],
    seconds: f64,
    profile: &str,
    direct: bool,
    bins: &Binaries,
) -> anyhow::Result<()> {
    let plant = bins.start("plant", &["--time-mode".into(), "lockstep".into()]).await?;
    let netem = bins
        .start("netem", &["--plant".into(), plant.addr.clone(), "--profile".into(), profile.into()])
        .await?;
    let mut targets = vec![("netem", netem.addr.clone())];
    if direct {
        targets.push(("plant", plant.addr.clone()));
    }
    println!("step rate: lockstep Step (command + 1 ms + sample), netem --profile {profile}");
    for (name, addr) in &targets {
        for &c in clients {
            step_clients(addr, c, seconds / 10.0).await?;
            let (n, dt) = step_clients(addr, c, seconds).await?;
            println!("  {name:>5}, {c:>2} clients: {n} round trips in {dt:.2} s = {:.0}/s", n as f64 / dt);
        }
    }
    drop(netem);
    drop(plant);
    Ok(())
}

/// What [`real_time`] measured.
struct RealTimeRun {
    /// Samples the plant streamed and commands the controller sent, each.
    sent: u64,
    received: u64,
    applied: u64,
    plant_to_controller: pb::DirectionStats,
    controller_to_plant: pb::DirectionStats,
    /// Every decision, when traced.
    records: Vec<pb::TraceRecord>,
}

impl RealTimeRun {
    /// An error when a message was lost on the way.
    fn check(&self) -> anyhow::Result<()> {
        if self.received != self.sent
            || self.applied != self.sent
            || self.plant_to_controller.dropped + self.controller_to_plant.dropped != 0
        {
            bail!("lost messages");
        }
        Ok(())
    }
}

/// netem in real time with `profile` both ways: samples streamed plant to controller and
/// commands sent controller to plant at `rate_hz` each for `seconds`; with `trace`, netem's
/// record of every decision.
async fn real_time(
    profile: DirectionProfile,
    seconds: f64,
    rate_hz: f64,
    trace: bool,
) -> anyhow::Result<RealTimeRun> {
    let n = (seconds * rate_hz).round() as u64;
    let period = Duration::from_secs_f64(1.0 / rate_hz);
    let rig = rig(profile, n, 1, netem::DEFAULT_STREAM_BUFFER).await?;
    let mut control = NetemControlClient::new(rig.netem.clone());
    if trace {
        control.start_trace(pb::StartTraceRequest {}).await?;
    }
    let mut client = PlantClient::new(rig.netem.clone());
    let mut s = client
        .stream_state(pb::StreamStateRequest { period_ns: period.as_nanos() as u64 })
        .await?
        .into_inner();
    let reader = tokio::spawn(async move {
        let mut got = 0u64;
        while got < n {
            match tokio::time::timeout(Duration::from_secs(10), s.next()).await {
                Ok(Some(Ok(_))) => got += 1,
                _ => break,
            }
        }
        got
    });
    // A held command's ApplyCommand returns at once.
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
    for k in 0..n {
        tick.tick().await;
        client.apply_command(command(k)).await?;
    }
    let received = reader.await?;
    // Until every copy still held has been released (or 30 s, and the check fails).
    let deadline = Instant::now() + Duration::from_secs(30);
    let st = loop {
        let st = stats(&rig.netem).await?;
        let held = |d: &Option<pb::DirectionStats>| d.as_ref().map_or(0, |d| d.in_flight);
        if held(&st.plant_to_controller) + held(&st.controller_to_plant) == 0 || Instant::now() > deadline {
            break st;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let records = match trace {
        true => control.stop_trace(pb::StopTraceRequest {}).await?.into_inner().records,
        false => Vec::new(),
    };
    let run = RealTimeRun {
        sent: n,
        received,
        applied: rig.plant.applied.load(AtomicOrdering::Relaxed),
        plant_to_controller: st.plant_to_controller.context("stats")?,
        controller_to_plant: st.controller_to_plant.context("stats")?,
        records,
    };
    drop(rig.stops);
    Ok(run)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    tokio::runtime::Builder::new_multi_thread().enable_all().build()?.block_on(bench(args.bench))
}

async fn bench(bench: Bench) -> anyhow::Result<()> {
    match bench {
        Bench::Throughput { messages, rate_hz, stream_buffer } => {
            let rig = rig(constant(0.0), messages, rate_hz / 1000, stream_buffer).await?;
            let mut client = PlantClient::new(rig.netem.clone());
            let t0 = Instant::now();
            let period_ns = if rate_hz > 0 { 1_000_000 } else { 0 };
            let mut s = client.stream_state(pb::StreamStateRequest { period_ns }).await?.into_inner();
            // The echo plant sends as fast as netem reads, faster than gRPC carries samples to
            // this reader: netem's bounded stream buffer then discards the oldest, and the
            // stream ends after the newest (the echo plant's stream ends).
            let mut got = 0u64;
            loop {
                match tokio::time::timeout(Duration::from_secs(10), s.next()).await {
                    Ok(Some(Ok(_))) => got += 1,
                    Ok(Some(Err(e))) if e.code() == tonic::Code::Unavailable => break,
                    Ok(None) => break,
                    other => bail!("stream stopped after {got} samples: {other:?}"),
                }
            }
            let dt = t0.elapsed().as_secs_f64();
            let st = stats(&rig.netem).await?;
            let p = st.plant_to_controller.context("stats")?;
            println!(
                "throughput: {got} of {messages} samples through netem to the reader in {dt:.3} s = {:.0} msg/s; \
                 {} discarded by the stream's buffer (a reader slower than the source)",
                got as f64 / dt,
                p.stream_overflow_dropped
            );
            print_dir("plant->controller", &p);
            if p.dropped != p.stream_overflow_dropped || got + p.stream_overflow_dropped != messages {
                bail!("lost messages");
            }
            drop(rig.stops);
        }
        Bench::Commands { messages, clients } => {
            let rig = rig(constant(0.0), 0, 1, netem::DEFAULT_STREAM_BUFFER).await?;
            let per = messages / clients;
            let t0 = Instant::now();
            let mut tasks = Vec::new();
            for c in 0..clients {
                let ch = rig.netem.clone();
                tasks.push(tokio::spawn(async move {
                    let mut client = PlantClient::new(ch);
                    for k in 0..per {
                        client.apply_command(command(c * per + k)).await?;
                    }
                    anyhow::Ok(())
                }));
            }
            for t in tasks {
                t.await??;
            }
            let dt = t0.elapsed().as_secs_f64();
            let n = per * clients;
            let st = stats(&rig.netem).await?;
            println!(
                "commands: {n} ApplyCommand through netem ({clients} clients) in {dt:.3} s = {:.0} msg/s",
                n as f64 / dt
            );
            let c = st.controller_to_plant.context("stats")?;
            print_dir("controller->plant", &c);
            let applied = rig.plant.applied.load(AtomicOrdering::Relaxed);
            println!("  applied by the plant: {applied}");
            if c.dropped != 0 || applied != n {
                bail!("lost messages");
            }
            drop(rig.stops);
        }
        Bench::RealTime { seconds, rate_hz, delay_ms } => {
            let run = real_time(constant(delay_ms / 1e3), seconds, rate_hz, false).await?;
            println!(
                "real time: {seconds} s at {rate_hz} Hz, constant {delay_ms} ms each way; samples received {}/{}",
                run.received, run.sent
            );
            print_dir("plant->controller", &run.plant_to_controller);
            print_dir("controller->plant", &run.controller_to_plant);
            println!("  commands applied by the plant: {}/{}", run.applied, run.sent);
            run.check()?;
        }
        Bench::Release(args) => release::run(args).await?,
        Bench::IdleStreams { streams, seconds, every_s, client_window_kib, direct, bins } => {
            idle_streams(streams, seconds, every_s, client_window_kib, direct, &bins).await?;
        }
        Bench::StepRate { clients, seconds, profile, direct, bins } => {
            step_rate(&clients, seconds, &profile, direct, &bins).await?;
        }
    }
    Ok(())
}
