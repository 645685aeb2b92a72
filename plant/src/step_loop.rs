//! The real-time step loop: a thread of its own that calls [`PlantService::tick`] when plant
//! time reaches each step boundary, woken as every real-time thread of the bench is
//! ([`hilbench_svc::realtime`]: `SCHED_FIFO` when permitted, a sleep on `CLOCK_MONOTONIC` to
//! shortly before the deadline, then a spin). A tokio interval would wake on its timer wheel's
//! 1 ms grid, a whole step late.
//!
//! The deadlines are the plant's own step boundaries (multiples of the step since the last
//! reset, [`PlantService::until_next_step_ns`]), asked again before every wait, so that a
//! reset moves them: each step's sample then reaches the state streams within the wake-up's
//! lateness of its plant time. (A schedule of its own, from the loop's start, put every tick at
//! a fixed phase within the step: each step's sample waited for the next tick, up to a step.)
//!
//! Its step jitter (the lateness of each wake-up against its boundary) is kept in
//! [`StepStats`], returned when the loop stops; `serve` logs it then. A thread that wakes more
//! than a step late integrates and publishes every step it passed, at once; those steps are
//! counted as late ([`StepStats::late_steps`]), none is lost.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use hilbench_svc::realtime::{self, Priority};

use crate::PlantService;

/// What the step loop measured.
#[derive(Debug, Clone)]
pub struct StepStats {
    /// The scheduling the loop's thread obtained.
    pub priority: Priority,
    /// Ticks run.
    pub ticks: u64,
    /// Steps integrated and published a step or more after their time, by a tick that woke
    /// that late (every step is published; these came in a burst).
    pub late_steps: u64,
    /// Lateness of each tick's wake-up against its step boundary, ns.
    pub lateness: delay::Window,
}

impl std::fmt::Display for StepStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let p = self.lateness.percentiles().unwrap_or_default();
        write!(
            f,
            "{} ticks ({}), {} steps a step late or more, lateness p50 {:.1} µs p99 {:.1} µs max {:.1} µs",
            self.ticks,
            self.priority,
            self.late_steps,
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
    /// Starts ticking `service` at its step boundaries on a thread of its own.
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
    let mut lateness = delay::Window::default();
    let (mut ticks, mut late_steps) = (0, 0);
    let mut margin = realtime::SpinMargin::new();
    while !stop.load(Ordering::Acquire) {
        // The service's clock is read before `CLOCK_MONOTONIC`, so the deadline is never
        // before the boundary on the wall clock (`Instant`, the same clock on Linux): a tick
        // never stops just short of it, which would leave its sample to the next tick.
        let wait = service.until_next_step_ns();
        let due = realtime::monotonic_ns() + wait;
        let now = realtime::wait_until_learning(due, &mut margin);
        lateness.push(now - due);
        late_steps += service.tick().saturating_sub(1);
        ticks += 1;
    }
    StepStats { priority, ticks, late_steps, lateness }
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
