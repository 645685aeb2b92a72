//! `lab load release`: how late netem releases, beside what no emulator on this machine can
//! beat, on the same deadlines; and the plant's real-time step jitter.
//!
//! For each message rate and delay kind (constant, Gamma), netem runs in real time in front of
//! the echo plant (samples streamed one way, commands sent the other, both at the rate) with a
//! trace of every decision. Its release error is each delivered copy's `release_error_ns`
//! (actual minus scheduled, measured by the release thread when it runs the copy's release).
//! Then the same for netem's UDP path ([`udp_run`]: `netem::serve_udp` in process, a client
//! sending numbered datagrams at the rate, the far side echoing each one back, so both
//! directions carry the rate), with the receivers' view beside it: each datagram's arrival
//! minus its scheduled release, less the smallest such difference (the clocks' offset and the
//! fastest loopback crossing), so the forwarding and the receiver's wake-up included.
//! The copies' scheduled release times are then replayed, shifted to now, by bare threads
//! that only sleep to each deadline and read the clock: the machine's floor, in three
//! variants (a plain thread; a `SCHED_FIFO` thread; a `SCHED_FIFO` thread that sleeps to
//! a fixed [`SPIN_NS`] before and spins; one that learns its margin from its own sleeps, as
//! netem's release thread and the plant's step loop do, [`realtime::SpinMargin`]). The plant's step loop runs
//! as the `plant` service runs it, at 1 kHz on the wall clock, for the same time.
//! Nothing here asserts a timing: it prints what it measured.

use std::sync::Arc;

use anyhow::Context;
use delay::{DirectionProfile, Distribution, Percentiles, Window};
use hilbench_proto::pb;
use hilbench_svc::realtime::{self, Priority, SPIN_NS};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Length of each measurement, s.
    #[arg(long, default_value_t = 20.0)]
    seconds: f64,
    /// Message rates, Hz (each direction), one measurement each.
    #[arg(long, value_delimiter = ',', default_value = "50,1000")]
    rates_hz: Vec<f64>,
    /// The constant delay each way, ms.
    #[arg(long, default_value_t = 20.0)]
    delay_ms: f64,
    /// The Gamma delay each way: shape (default paper-split's direction, Gamma(6, 15 ms)).
    #[arg(long, default_value_t = 6.0)]
    gamma_shape: f64,
    /// The Gamma delay's scale, ms.
    #[arg(long, default_value_t = 15.0)]
    gamma_scale_ms: f64,
}

/// A bare thread's way of waiting for a deadline.
#[derive(Debug, Clone, Copy)]
enum Floor {
    /// `clock_nanosleep` on a thread as it comes (`SCHED_OTHER`, the default timer slack).
    Plain,
    /// `clock_nanosleep` on a thread made real time (`SCHED_FIFO`, slack 1 ns).
    Fifo,
    /// The same, sleeping to [`SPIN_NS`] before the deadline and spinning to it.
    FifoSpin,
    /// The same with the margin learned from the thread's own sleeps, as the services wait.
    FifoLearned,
}

impl Floor {
    const ALL: [Floor; 4] = [Floor::Plain, Floor::Fifo, Floor::FifoSpin, Floor::FifoLearned];

    fn name(self) -> String {
        match self {
            Floor::Plain => "floor: clock_nanosleep, normal thread".into(),
            Floor::Fifo => "floor: clock_nanosleep, real-time thread".into(),
            Floor::FifoSpin => format!("floor: sleep + {} µs spin, real-time thread", SPIN_NS / 1000),
            Floor::FifoLearned => "floor: sleep + learned spin, real-time thread".into(),
        }
    }
}

/// Wakes at each of `deadlines` (ns, sorted, from any origin) shifted to start shortly from
/// now, on a new thread waiting as `floor` says; the lateness of each wake-up.
fn replay(deadlines: &[u64], floor: Floor) -> anyhow::Result<(Window, Priority)> {
    let first = deadlines.first().copied().unwrap_or(0);
    std::thread::scope(|s| {
        let t = std::thread::Builder::new().name("lab-floor".into()).spawn_scoped(s, || {
            let priority = match floor {
                Floor::Plain => Priority::Normal,
                Floor::Fifo | Floor::FifoSpin | Floor::FifoLearned => {
                    realtime::promote_current_thread("lab-floor")
                }
            };
            let origin = realtime::monotonic_ns() + 20_000_000;
            let mut late = Window::default();
            let mut margin = realtime::SpinMargin::new();
            for d in deadlines {
                let due = origin + (d - first);
                let now = match floor {
                    Floor::Plain | Floor::Fifo => realtime::sleep_until(due),
                    Floor::FifoSpin => realtime::wait_until(due, SPIN_NS),
                    Floor::FifoLearned => realtime::wait_until_learning(due, &mut margin),
                };
                late.push(now - due);
            }
            (late, priority)
        })?;
        t.join().map_err(|_| anyhow::anyhow!("the floor's thread panicked"))
    })
}

/// The time the hypervisor ran something else while this VM's vCPUs wanted to run, summed
/// over them ("steal" in /proc/stat, USER_HZ = 100 ticks a second on Linux), ms; `None` where
/// there is no /proc/stat.
fn steal_ms() -> Option<u64> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let cpu = stat.lines().next()?.strip_prefix("cpu ")?;
    cpu.split_whitespace().nth(7)?.parse::<u64>().ok().map(|ticks| ticks * 10)
}

/// Steal time since `from` (a [`steal_ms`] reading), per second of `seconds`, for a note.
fn steal_since(from: Option<u64>, seconds: f64) -> String {
    match (from, steal_ms()) {
        (Some(a), Some(b)) => format!("steal {:.0} ms/s", (b.saturating_sub(a)) as f64 / seconds.max(1e-3)),
        _ => "steal unknown".into(),
    }
}

fn row(what: &str, n: u64, p: Percentiles, note: &str) {
    let us = |ns: u64| ns as f64 / 1e3;
    println!("| {what} | {n} | {:.1} | {:.1} | {:.1} | {note} |", us(p.p50_ns), us(p.p99_ns), us(p.max_ns));
}

fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|c| {
            c.lines().find_map(|l| {
                l.strip_prefix("model name").map(|m| m.trim_start_matches([' ', '\t', ':']).to_string())
            })
        })
        .unwrap_or_else(|| "unknown CPU".into())
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|l| l.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".into())
}

pub async fn run(args: Args) -> anyhow::Result<()> {
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    println!(
        "release precision: {} s per measurement; {} ({cores} cores), load average {}",
        args.seconds,
        cpu_model(),
        load_average()
    );
    println!("lateness, µs: actual minus scheduled time of each release (netem) or wake-up (floor, plant)");
    println!();
    println!("| rate, delay | what | n | p50 | p99 | max | note |");
    println!("|---|---|---|---|---|---|---|");
    let kinds = [
        (format!("constant {} ms", args.delay_ms), Distribution::Constant { delay_s: args.delay_ms / 1e3 }),
        (
            format!("Gamma({}, {} ms)", args.gamma_shape, args.gamma_scale_ms),
            Distribution::Gamma { shape: args.gamma_shape, scale_s: args.gamma_scale_ms / 1e3 },
        ),
    ];
    let mut lost = false;
    for &rate in &args.rates_hz {
        if !(rate.is_finite() && rate > 0.0) {
            anyhow::bail!("--rates-hz: {rate} is not a positive rate");
        }
        for (kind, delay) in &kinds {
            let case = format!("{rate} Hz, {kind}");
            let steal = steal_ms();
            let run =
                super::real_time(DirectionProfile::with_delay(delay.clone(), 42), args.seconds, rate, true)
                    .await
                    .with_context(|| case.clone())?;
            let grpc_steal = steal_since(steal, args.seconds);
            lost |= run.check().is_err();
            let delivered: Vec<&pb::TraceRecord> = run.records.iter().filter(|r| !r.dropped).collect();
            let errors = ReleaseErrors::of(&run.records);
            let mut deadlines: Vec<u64> = delivered.iter().map(|r| r.release_time_ns).collect();
            deadlines.sort_unstable();
            for floor in Floor::ALL {
                let d = deadlines.clone();
                let steal = steal_ms();
                let (late, priority) = tokio::task::spawn_blocking(move || replay(&d, floor)).await??;
                row(
                    &format!("{case} | {}", floor.name()),
                    late.count(),
                    late.percentiles().unwrap_or_default(),
                    &format!("{}; {}", priority.as_str(), steal_since(steal, args.seconds)),
                );
            }
            let note = format!(
                "{} of {} copies delivered; {} early; {}; {grpc_steal}",
                delivered.len(),
                run.records.len(),
                errors.early,
                errors.bunches()
            );
            row(
                &format!("{case} | netem, gRPC path"),
                errors.all.count(),
                errors.all.percentiles().unwrap_or_default(),
                &note,
            );
            let profile = DirectionProfile::with_delay(delay.clone(), 42);
            let steal = steal_ms();
            let udp = udp_run(profile, args.seconds, rate).await.with_context(|| format!("{case}, UDP"))?;
            let udp_steal = steal_since(steal, args.seconds);
            lost |= udp.lost();
            let errors = ReleaseErrors::of(&udp.records);
            let seen = udp.received.percentiles().unwrap_or_default();
            let us = |ns: u64| ns as f64 / 1e3;
            let note = format!(
                "{} of {} datagrams delivered; {} early; {}; receivers' view, above its fastest: {:.1} / {:.1} / {:.1}; {udp_steal}",
                errors.all.count(),
                2 * udp.sent,
                errors.early,
                errors.bunches(),
                us(seen.p50_ns),
                us(seen.p99_ns),
                us(seen.max_ns)
            );
            row(
                &format!("{case} | netem, UDP path"),
                errors.all.count(),
                errors.all.percentiles().unwrap_or_default(),
                &note,
            );
        }
    }
    let seconds = args.seconds;
    let steal = steal_ms();
    let steps = tokio::task::spawn_blocking(move || plant_steps(seconds)).await??;
    row(
        "1000 Hz | plant step loop",
        steps.lateness.count(),
        steps.lateness.percentiles().unwrap_or_default(),
        &format!(
            "{}; {} steps a step late or more; {}",
            steps.priority,
            steps.late_steps,
            steal_since(steal, seconds)
        ),
    );
    println!();
    println!("load average at the end {}", load_average());
    if lost {
        anyhow::bail!("netem lost messages (see above)");
    }
    Ok(())
}

/// The release errors of the delivered copies of `records` (their magnitudes).
struct ReleaseErrors {
    /// Every delivered copy.
    all: Window,
    /// The copies first at their release time on their direction: the timer's error alone.
    /// A FIFO line releases a message no earlier than the one before it, so under Gamma
    /// delays at 1 kHz runs of copies share one release time (the 99th percentile of a
    /// copy's place in its run is about 110 at Gamma(6, 15 ms)), and the copies behind the
    /// first wait for those before them to be sent: a cost per copy, not the timer's.
    first_of_bunch: Window,
    /// Copies released before their time (there should be none).
    early: u64,
}

impl ReleaseErrors {
    fn of(records: &[pb::TraceRecord]) -> Self {
        let mut delivered: Vec<&pb::TraceRecord> = records.iter().filter(|r| !r.dropped).collect();
        delivered.sort_by_key(|r| (r.direction, r.release_time_ns));
        let (mut all, mut first_of_bunch, mut early) = (Window::default(), Window::default(), 0u64);
        let mut previous: Option<(i32, u64)> = None;
        for r in delivered {
            early += u64::from(r.release_error_ns < 0);
            let error = r.release_error_ns.unsigned_abs();
            all.push(error);
            if previous != Some((r.direction, r.release_time_ns)) {
                first_of_bunch.push(error);
            }
            previous = Some((r.direction, r.release_time_ns));
        }
        Self { all, first_of_bunch, early }
    }

    /// The note's words on the first copies of each release time.
    fn bunches(&self) -> String {
        let p = self.first_of_bunch.percentiles().unwrap_or_default();
        let us = |ns: u64| ns as f64 / 1e3;
        format!(
            "first copy of each release time ({} of {}): {:.1} / {:.1} / {:.1}",
            self.first_of_bunch.count(),
            self.all.count(),
            us(p.p50_ns),
            us(p.p99_ns),
            us(p.max_ns)
        )
    }
}

/// What [`udp_run`] measured.
struct UdpRun {
    /// Datagrams the client sent (and the far side echoed as many).
    sent: u64,
    /// Every decision of both directions.
    records: Vec<pb::TraceRecord>,
    /// The receivers' view: each datagram's arrival minus its scheduled release (netem's
    /// clock), less the smallest of them, ns.
    received: Window,
}

impl UdpRun {
    fn lost(&self) -> bool {
        self.records.iter().any(|r| r.dropped) || self.received.count() != 2 * self.sent
    }
}

/// netem's UDP proxy in process with `profile` both ways: a client sends datagrams numbered
/// `0..n` at `rate_hz` for `seconds` to its listen port, the far side (its forward address)
/// echoes each one back numbered by arrival, and both receivers stamp each arrival.
async fn udp_run(profile: DirectionProfile, seconds: f64, rate_hz: f64) -> anyhow::Result<UdpRun> {
    use std::net::UdpSocket;
    use std::time::{Duration, Instant};
    let n = (seconds * rate_hz).round() as u64;
    let period = Duration::from_secs_f64(1.0 / rate_hz);
    let far = UdpSocket::bind("127.0.0.1:0")?;
    let client = UdpSocket::bind("127.0.0.1:0")?;
    let udp = netem::udp::UdpConfig {
        listen: "127.0.0.1:0".parse()?,
        forward: far.local_addr()?,
        plant_side: netem::udp::Side::Listen,
        max_held_bytes: netem::udp::DEFAULT_MAX_HELD_BYTES,
    };
    let mut config = netem::Config::new("unused");
    config.plant_to_controller = profile.clone();
    config.controller_to_plant = profile;
    let control_listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let control_addr = control_listener.local_addr()?;
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let netem = tokio::spawn(netem::serve_udp(control_listener, config, udp, async {
        let _ = stopped.await;
    }));
    let channel = tonic::transport::Channel::from_shared(format!("http://{control_addr}"))?.connect().await?;
    let mut control = hilbench_proto::pb::netem_control_client::NetemControlClient::new(channel);
    let stats = control.get_stats(pb::GetStatsRequest {}).await?.into_inner();
    let listen: std::net::SocketAddr =
        stats.udp.context("UDP stats")?.listen_address.parse().context("netem's listen address")?;
    control.start_trace(pb::StartTraceRequest {}).await?;

    // Each receiver keeps (number, arrival); the far side echoes what it gets, numbered by
    // arrival (the number netem gives the echo, its `payload_seq`).
    let origin = Instant::now();
    let receive =
        |socket: &UdpSocket, echo: bool| -> anyhow::Result<std::thread::JoinHandle<Vec<(u64, u64)>>> {
            let socket = socket.try_clone()?;
            socket.set_read_timeout(Some(Duration::from_secs(2)))?;
            Ok(std::thread::spawn(move || {
                let mut got = Vec::with_capacity(n as usize);
                let mut buf = [0u8; 64];
                while (got.len() as u64) < n {
                    let Ok((len, from)) = socket.recv_from(&mut buf) else { break };
                    let at = origin.elapsed().as_nanos() as u64;
                    if len != 8 {
                        continue;
                    }
                    let k = u64::from_le_bytes(buf[..8].try_into().unwrap_or_default());
                    if echo {
                        let _ = socket.send_to(&(got.len() as u64).to_le_bytes(), from);
                    }
                    got.push((k, at));
                }
                got
            }))
        };
    let at_far = receive(&far, true)?;
    let at_client = receive(&client, false)?;
    let sender = std::thread::spawn(move || {
        let start = Instant::now();
        for k in 0..n {
            let due = start + period.mul_f64(k as f64);
            std::thread::sleep(due.saturating_duration_since(Instant::now()));
            if client.send_to(&k.to_le_bytes(), listen).is_err() {
                break;
            }
        }
    });
    tokio::task::spawn_blocking(move || sender.join())
        .await?
        .map_err(|_| anyhow::anyhow!("sender panicked"))?;
    let at_far = tokio::task::spawn_blocking(move || at_far.join())
        .await?
        .map_err(|_| anyhow::anyhow!("reader panicked"))?;
    let at_client = tokio::task::spawn_blocking(move || at_client.join())
        .await?
        .map_err(|_| anyhow::anyhow!("reader panicked"))?;
    // Until netem has counted every copy (a task counts them after the release thread sent
    // them), or 30 s and the run shows the loss.
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let st = control.get_stats(pb::GetStatsRequest {}).await?.into_inner();
        let held = |d: &Option<pb::DirectionStats>| d.as_ref().map_or(0, |d| d.in_flight);
        if held(&st.plant_to_controller) + held(&st.controller_to_plant) == 0 || Instant::now() > deadline {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let records = control.stop_trace(pb::StopTraceRequest {}).await?.into_inner().records;
    let _ = stop.send(());
    let _ = netem.await;

    // Scheduled releases per direction and number (no loss or duplicates are configured: one
    // copy each). The client's datagrams go to the far side: plant_to_controller
    // (`--udp-plant-side listen`); the echoes come back: controller_to_plant.
    let release = |dir: pb::Direction| -> std::collections::HashMap<u64, u64> {
        records
            .iter()
            .filter(|r| r.direction == dir as i32 && !r.dropped)
            .map(|r| (r.payload_seq, r.release_time_ns))
            .collect()
    };
    let (to_far, to_client) =
        (release(pb::Direction::PlantToController), release(pb::Direction::ControllerToPlant));
    let raw: Vec<i128> = at_far
        .iter()
        .filter_map(|(k, at)| to_far.get(k).map(|r| *at as i128 - *r as i128))
        .chain(at_client.iter().filter_map(|(k, at)| to_client.get(k).map(|r| *at as i128 - *r as i128)))
        .collect();
    let fastest = raw.iter().copied().min().unwrap_or(0);
    let mut received = Window::default();
    for d in raw {
        received.push((d - fastest) as u64);
    }
    Ok(UdpRun { sent: n, records, received })
}

/// The plant's real-time step loop at 1 kHz on the wall clock for `seconds` (paper-1, no
/// clients), as `plant --time-mode real-time` runs it.
fn plant_steps(seconds: f64) -> anyhow::Result<plant::StepStats> {
    let service = plant::PlantService::new(
        plant::PlantConfig::real_time(mav::Scenario::paper_1()),
        Arc::new(plant::WallClock::new()),
    )?;
    let steps = plant::StepLoop::start(service)?;
    std::thread::sleep(std::time::Duration::from_secs_f64(seconds));
    Ok(steps.stop())
}
