//! Waking at a deadline to tens of microseconds: the one way the services' real-time threads
//! (netem's release thread, the plant's step loop) wait, and the machine's floor the lab
//! measures them against.
//!
//! A thread made real time by [`promote_current_thread`] (`SCHED_FIFO` when permitted, a timer
//! slack of 1 ns) sleeps on `CLOCK_MONOTONIC` until [`SPIN_NS`] before its deadline and then
//! reads the clock in a loop until the deadline ([`plan`] decides which, from the time passed
//! in). The sleep alone is late by the kernel's wake-up latency (a few µs on an idle machine,
//! more when another thread holds the core: the spin covers the usual part of it); a thread
//! left at `SCHED_OTHER` is late by whatever the scheduler makes it wait behind other threads.
//!
//! Deadlines are nanoseconds of `CLOCK_MONOTONIC` ([`monotonic_ns`]), the clock
//! `std::time::Instant` reads on Linux.

/// How long before a deadline a waiting thread stops sleeping and spins reading the clock, ns.
/// It covers the kernel's wake-up latency (timer interrupt, scheduling) measured on the bench's
/// VM with `lab load release` (BENCHMARKS.md, "Release precision").
pub const SPIN_NS: u64 = 50_000;

/// `SCHED_FIFO` priority of the services' real-time threads (1-99): above every normal
/// thread, below the kernel's own real-time threads (50 for threaded interrupts).
pub const FIFO_PRIORITY: u8 = 40;

/// Nice value asked for when `SCHED_FIFO` is refused (it also needs privilege to lower).
pub const FALLBACK_NICE: i32 = -10;

/// What [`promote_current_thread`] obtained for the thread.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Priority {
    /// `SCHED_FIFO` at [`FIFO_PRIORITY`]: the thread preempts every normal thread on waking.
    Fifo,
    /// `SCHED_OTHER` at nice [`FALLBACK_NICE`]: a larger share, no preemption guarantee.
    Nice,
    /// Neither was permitted: the thread competes as any other.
    Normal,
}

impl Priority {
    pub fn as_str(self) -> &'static str {
        match self {
            Priority::Fifo => "SCHED_FIFO",
            Priority::Nice => "nice -10",
            Priority::Normal => "normal",
        }
    }
}

impl std::fmt::Display for Priority {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Makes the calling thread, named `what` in the logs, a real-time one: `SCHED_FIFO` at
/// [`FIFO_PRIORITY`], else nice [`FALLBACK_NICE`] (each refusal logged at `warn`: its
/// deadlines are then as late as the machine's load makes them), and a timer slack of 1 ns (the
/// default 50 µs would let the kernel defer every wake-up by up to that much).
pub fn promote_current_thread(what: &str) -> Priority {
    imp::set_timer_slack(what);
    match imp::set_fifo() {
        Ok(()) => {
            tracing::debug!(thread = what, priority = FIFO_PRIORITY, "real-time thread at SCHED_FIFO");
            Priority::Fifo
        }
        Err(fifo) => match imp::set_nice() {
            Ok(()) => {
                tracing::warn!(
                    thread = what,
                    "SCHED_FIFO refused ({fifo}): running at nice {FALLBACK_NICE}; its deadlines will be as late as other threads make it"
                );
                Priority::Nice
            }
            Err(nice) => {
                tracing::warn!(
                    thread = what,
                    "SCHED_FIFO refused ({fifo}) and nice {FALLBACK_NICE} too ({nice}): running at normal priority; its deadlines will be as late as other threads make it"
                );
                Priority::Normal
            }
        },
    }
}

/// What a thread waiting for a deadline does next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wait {
    /// The deadline has come.
    Due,
    /// Less than the spin margin is left: read the clock again.
    Spin,
    /// Sleep until this time (the deadline less the spin margin), then ask again.
    SleepUntil(u64),
}

/// The step towards `due_ns` at `now_ns` for a thread that spins the last `spin_ns`.
pub fn plan(now_ns: u64, due_ns: u64, spin_ns: u64) -> Wait {
    if now_ns >= due_ns {
        Wait::Due
    } else if due_ns - now_ns <= spin_ns {
        Wait::Spin
    } else {
        Wait::SleepUntil(due_ns - spin_ns)
    }
}

/// `CLOCK_MONOTONIC`, ns.
pub fn monotonic_ns() -> u64 {
    imp::monotonic_ns()
}

/// Sleeps until `CLOCK_MONOTONIC` reads `ns` (`clock_nanosleep` with `TIMER_ABSTIME`, again
/// after an interruption), at once if that is past; returns the clock read on waking.
pub fn sleep_until(ns: u64) -> u64 {
    loop {
        let now = monotonic_ns();
        if now >= ns {
            return now;
        }
        imp::sleep_until(ns);
    }
}

/// Waits until `CLOCK_MONOTONIC` reads `due_ns`: sleeps to `spin_ns` before, then spins.
/// Returns the clock read when the deadline was seen to have come (never before it).
pub fn wait_until(due_ns: u64, spin_ns: u64) -> u64 {
    loop {
        let now = monotonic_ns();
        match plan(now, due_ns, spin_ns) {
            Wait::Due => return now,
            // No `spin_loop` hint: a run of PAUSE instructions makes the hypervisor take the
            // vCPU away (pause-loop exiting), which on the bench's VM put the 99.9th
            // percentile of a 1 kHz spin at 1.8 ms against 0.3 ms without it.
            Wait::Spin => {}
            Wait::SleepUntil(t) => imp::sleep_until(t),
        }
    }
}

#[cfg(target_os = "linux")]
mod imp {
    use rustix::thread::ClockId;
    use rustix::time::Timespec;

    pub fn monotonic_ns() -> u64 {
        let t = rustix::time::clock_gettime(ClockId::Monotonic);
        (t.tv_sec as u64).saturating_mul(1_000_000_000).saturating_add(t.tv_nsec as u64)
    }

    pub fn sleep_until(ns: u64) {
        let t = Timespec { tv_sec: (ns / 1_000_000_000) as i64, tv_nsec: (ns % 1_000_000_000) as i64 };
        // An interrupted sleep returns early; the callers read the clock and wait again.
        let _ = rustix::thread::clock_nanosleep_absolute(ClockId::Monotonic, &t);
    }

    pub fn set_timer_slack(what: &str) {
        if let Err(e) = rustix::thread::set_current_timer_slack(std::num::NonZeroU64::new(1)) {
            tracing::warn!(thread = what, "timer slack stays at its default ({e})");
        }
    }

    pub fn set_fifo() -> Result<(), String> {
        use thread_priority::{
            RealtimeThreadSchedulePolicy, ThreadPriority, ThreadPriorityValue, ThreadSchedulePolicy,
        };
        let value = ThreadPriorityValue::try_from(super::FIFO_PRIORITY).map_err(|e| e.to_string())?;
        thread_priority::set_thread_priority_and_policy(
            thread_priority::thread_native_id(),
            ThreadPriority::Crossplatform(value),
            ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
        )
        .map_err(|e| format!("{e:?}"))
    }

    pub fn set_nice() -> Result<(), String> {
        rustix::process::setpriority_process(Some(rustix::thread::gettid()), super::FALLBACK_NICE)
            .map_err(|e| e.to_string())
    }
}

#[cfg(not(target_os = "linux"))]
mod imp {
    use std::sync::OnceLock;
    use std::time::Instant;

    fn origin() -> Instant {
        static ORIGIN: OnceLock<Instant> = OnceLock::new();
        *ORIGIN.get_or_init(Instant::now)
    }

    pub fn monotonic_ns() -> u64 {
        u64::try_from(origin().elapsed().as_nanos()).unwrap_or(u64::MAX)
    }

    pub fn sleep_until(ns: u64) {
        std::thread::sleep(std::time::Duration::from_nanos(ns.saturating_sub(monotonic_ns())));
    }

    pub fn set_timer_slack(_what: &str) {}

    pub fn set_fifo() -> Result<(), String> {
        Err("not on Linux".into())
    }

    pub fn set_nice() -> Result<(), String> {
        Err("not on Linux".into())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_sleeps_to_the_spin_margin_then_spins_then_is_due() {
        assert_eq!(plan(0, 1_000_000, 50_000), Wait::SleepUntil(950_000));
        assert_eq!(plan(949_999, 1_000_000, 50_000), Wait::SleepUntil(950_000));
        assert_eq!(plan(950_000, 1_000_000, 50_000), Wait::Spin);
        assert_eq!(plan(999_999, 1_000_000, 50_000), Wait::Spin);
        assert_eq!(plan(1_000_000, 1_000_000, 50_000), Wait::Due);
        assert_eq!(plan(2_000_000, 1_000_000, 50_000), Wait::Due);
    }

    #[test]
    fn plan_without_a_spin_margin_sleeps_to_the_deadline() {
        assert_eq!(plan(10, 20, 0), Wait::SleepUntil(20));
        assert_eq!(plan(20, 20, 0), Wait::Due);
    }

    #[test]
    fn a_deadline_closer_than_the_margin_is_spun_for_not_slept_for() {
        assert_eq!(plan(100, 130, 50), Wait::Spin);
    }
}
