//! The real-time step loop: a thread of its own that calls [`PlantService::tick`] at every
//! multiple of the integration step, woken as every real-time thread of the bench is
//! ([`hilbench_svc::realtime`]: `SCHED_FIFO` when permitted, a sleep on `CLOCK_MONOTONIC` to
//! shortly before the deadline, then a spin). A tokio interval would wake on its timer wheel's
//! 1 ms grid, a whole step late.
//!
//! Its step jitter (the lateness of each wake-up against its deadline) is kept in
//! [`StepStats`], returned when the loop stops; `serve` logs it then. A thread that wakes
//! more than a step late skips the steps it missed rather than running them back to back
//! (the tick catches the simulation up to the clock either way), and counts them.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use hilbench_svc::realtime::{self, Periodic, Priority};

use crate::PlantService;

/// What the step loop measured.
#[derive(Debug, Clone)]
pub struct StepStats {
    /// The scheduling the loop's thread obtained.
    pub priority: Priority,
    /// Ticks run.
    pub ticks: u64,
    /// Deadlines passed over because the thread woke more than a step late.
    pub skipped: u64,
    /// Lateness of each tick's wake-up against its deadline, ns.
    pub lateness: delay::Window,
}

impl std::fmt::Display for StepStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let p = self.lateness.percentiles().unwrap_or_default();
        write!(
            f,
            "{} ticks ({}), {} skipped, lateness p50 {:.1} µs p99 {:.1} µs max {:.1} µs",
            self.ticks,
            self.priority,
            self.skipped,
            p.p50_ns as f64 / 1e3,
            p.p99_ns as f64 / 1e3,
            p.max_ns as f64 / 1e3
        )
    }
}

/// A running step loop; [`StepLoop::stop`] ends it.
pub struct StepLoop {
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<StepStats>,
}

impl StepLoop {
    /// Starts ticking `service` every [`PlantService::step_ns`] on a thread of its own.
    pub fn start(service: PlantService) -> std::io::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let stopping = stop.clone();
        let thread =
            std::thread::Builder::new().name("plant-steps".into()).spawn(move || run(&service, &stopping))?;
        Ok(Self { stop, thread })
    }

    /// Stops the loop (within a step) and returns what it measured.
    pub fn stop(self) -> StepStats {
        self.stop.store(true, Ordering::Release);
        match self.thread.join() {
            Ok(stats) => stats,
            Err(panic) => std::panic::resume_unwind(panic),
        }
    }
}

fn run(service: &PlantService, stop: &AtomicBool) -> StepStats {
    let priority = realtime::promote_current_thread("plant-steps");
    let mut schedule = Periodic::new(realtime::monotonic_ns(), service.step_ns());
    let mut lateness = delay::Window::default();
    let mut ticks = 0;
    while !stop.load(Ordering::Acquire) {
        let now = realtime::wait_until(schedule.due_ns(), realtime::SPIN_NS);
        lateness.push(schedule.woke(now));
        service.tick();
        ticks += 1;
    }
    StepStats { priority, ticks, skipped: schedule.skipped, lateness }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ManualClock, PlantConfig};

    #[test]
    fn the_step_loop_ticks_the_service_and_measures_every_wake_up() {
        let clock = Arc::new(ManualClock::new(0));
        let service = PlantService::new(PlantConfig::real_time(mav::Scenario::paper_1()), clock.clone())
            .expect("valid");
        let steps = StepLoop::start(service.clone()).expect("thread");
        // The service's own clock says 5 ms have passed: the loop's ticks integrate to there.
        clock.advance(5_000_000);
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
        while service.plant_time_ns() < 5_000_000 && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        let stats = steps.stop();
        assert_eq!(service.plant_time_ns(), 5_000_000);
        assert!(stats.ticks >= 1);
        assert_eq!(stats.lateness.count(), stats.ticks);
    }
}
