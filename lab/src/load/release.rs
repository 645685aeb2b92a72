//! `lab load release`: how late netem releases, beside what no emulator on this machine can
//! beat, on the same deadlines; and the plant's real-time step jitter.
//!
//! For each message rate and delay kind (constant, Gamma), netem runs in real time in front of
//! the echo plant (samples streamed one way, commands sent the other, both at the rate) with a
//! trace of every decision. Its release error is each delivered copy's `release_error_ns`
//! (actual minus scheduled, measured by the release thread when it runs the copy's release).
//! The copies' scheduled release times are then replayed, shifted to now, by bare threads
//! that only sleep to each deadline and read the clock: the machine's floor, in three
//! variants (a plain thread; a `SCHED_FIFO` thread; a `SCHED_FIFO` thread that sleeps to
//! [`SPIN_NS`] before and spins, as netem's release thread does). The plant's step loop runs
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
}

impl Floor {
    const ALL: [Floor; 3] = [Floor::Plain, Floor::Fifo, Floor::FifoSpin];

    fn name(self) -> String {
        match self {
            Floor::Plain => "floor: clock_nanosleep, normal thread".into(),
            Floor::Fifo => "floor: clock_nanosleep, real-time thread".into(),
            Floor::FifoSpin => format!("floor: sleep + {} µs spin, real-time thread", SPIN_NS / 1000),
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
                Floor::Fifo | Floor::FifoSpin => realtime::promote_current_thread("lab-floor"),
            };
            let origin = realtime::monotonic_ns() + 20_000_000;
            let mut late = Window::default();
            for d in deadlines {
                let due = origin + (d - first);
                let now = match floor {
                    Floor::Plain | Floor::Fifo => realtime::sleep_until(due),
                    Floor::FifoSpin => realtime::wait_until(due, SPIN_NS),
                };
                late.push(now - due);
            }
            (late, priority)
        })?;
        t.join().map_err(|_| anyhow::anyhow!("the floor's thread panicked"))
    })
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
            let run =
                super::real_time(DirectionProfile::with_delay(delay.clone(), 42), args.seconds, rate, true)
                    .await
                    .with_context(|| case.clone())?;
            lost |= run.check().is_err();
            let delivered: Vec<&pb::TraceRecord> = run.records.iter().filter(|r| !r.dropped).collect();
            let mut errors = Window::default();
            let mut early = 0u64;
            for r in &delivered {
                early += u64::from(r.release_error_ns < 0);
                errors.push(r.release_error_ns.unsigned_abs());
            }
            let mut deadlines: Vec<u64> = delivered.iter().map(|r| r.release_time_ns).collect();
            deadlines.sort_unstable();
            for floor in Floor::ALL {
                let d = deadlines.clone();
                let (late, priority) = tokio::task::spawn_blocking(move || replay(&d, floor)).await??;
                row(
                    &format!("{case} | {}", floor.name()),
                    late.count(),
                    late.percentiles().unwrap_or_default(),
                    priority.as_str(),
                );
            }
            let note =
                format!("{} of {} copies delivered; {early} early", delivered.len(), run.records.len());
            row(
                &format!("{case} | netem, gRPC path"),
                errors.count(),
                errors.percentiles().unwrap_or_default(),
                &note,
            );
        }
    }
    let seconds = args.seconds;
    let steps = tokio::task::spawn_blocking(move || plant_steps(seconds)).await??;
    row(
        "1000 Hz | plant step loop",
        steps.lateness.count(),
        steps.lateness.percentiles().unwrap_or_default(),
        &format!("{}; {} steps a step late or more", steps.priority, steps.late_steps),
    );
    println!();
    println!("load average at the end {}", load_average());
    if lost {
        anyhow::bail!("netem lost messages (see above)");
    }
    Ok(())
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
