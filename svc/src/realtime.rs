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

/// How long before a deadline a waiting thread stops sleeping and spins reading the clock, ns,
/// until a [`SpinMargin`] has learned the machine's own: the kernel's wake-up latency (timer
/// interrupt, scheduling) on an idle machine, measured with `lab load release`.
pub const SPIN_NS: u64 = 50_000;

/// The least and the most a [`SpinMargin`] spins before a deadline, ns.
pub const MIN_SPIN_NS: u64 = 20_000;
pub const MAX_SPIN_NS: u64 = 1_000_000;

/// How many of the last sleeps a [`SpinMargin`] learns from.
const MARGIN_WINDOW: usize = 256;

/// A spin margin learned from this thread's own oversleeps: the 99th percentile of how late
/// its last [`MARGIN_WINDOW`] sleeps ended, plus a guard of [`MIN_SPIN_NS`], within
/// [`MIN_SPIN_NS`, `MAX_SPIN_NS`] and at most a quarter of the usual gap between deadlines.
///
/// Why learned: how late a sleep ends is the machine's, not the bench's. On the bench's VM an
/// idle vCPU halts, and waking it takes the hypervisor 100-300 µs at a 50 Hz rate, against
/// tens of µs at 1 kHz where the vCPU stays warm: a fixed margin is either too short for the
/// first (every release late by the rest) or spins for nothing at the second. The quarter of
/// the gap bounds the CPU a spin may take (25 % of a core at most, about 1-2 % at 50 Hz).
#[derive(Debug, Clone)]
pub struct SpinMargin {
    oversleep_ns: [u32; MARGIN_WINDOW],
    filled: usize,
    next: usize,
    since_update: usize,
    last_due_ns: Option<u64>,
    /// Exponential mean of the gap between successive deadlines, ns.
    gap_ns: f64,
    margin_ns: u64,
}

impl Default for SpinMargin {
    fn default() -> Self {
        Self::new()
    }
}

impl SpinMargin {
    /// Starts at [`SPIN_NS`] until the first sleeps are measured.
    pub fn new() -> Self {
        Self {
            oversleep_ns: [0; MARGIN_WINDOW],
            filled: 0,
            next: 0,
            since_update: 0,
            last_due_ns: None,
            gap_ns: 0.0,
            margin_ns: SPIN_NS,
        }
    }

    /// How long before a deadline to stop sleeping and spin, ns.
    pub fn margin_ns(&self) -> u64 {
        self.margin_ns
    }

    /// A sleep meant to end at `planned_ns`, for the deadline `due_ns`, ended at `woke_ns`.
    /// Sleeps cut short (a new job woke the thread) are not passed here: they say nothing of
    /// the machine's lateness.
    pub fn record(&mut self, due_ns: u64, planned_ns: u64, woke_ns: u64) {
        let late = woke_ns.saturating_sub(planned_ns).min(u64::from(u32::MAX)) as u32;
        self.oversleep_ns[self.next] = late;
        self.next = (self.next + 1) % MARGIN_WINDOW;
        self.filled = (self.filled + 1).min(MARGIN_WINDOW);
        if let Some(last) = self.last_due_ns.filter(|&last| due_ns > last) {
            let gap = (due_ns - last) as f64;
            self.gap_ns = if self.gap_ns == 0.0 { gap } else { 0.95 * self.gap_ns + 0.05 * gap };
        }
        self.last_due_ns = Some(due_ns);
        self.since_update += 1;
        // The percentile is recomputed every 16 sleeps (a selection over 256 numbers, about a
        // microsecond): often enough to follow the machine, cheap beside a release.
        if self.since_update >= 16 {
            self.since_update = 0;
            self.margin_ns = self.learned();
        }
    }

    fn learned(&self) -> u64 {
        let mut window = self.oversleep_ns;
        let seen = &mut window[..self.filled];
        let k = (seen.len() * 99).div_ceil(100).saturating_sub(1);
        let (_, p99, _) = seen.select_nth_unstable(k);
        let mut margin = u64::from(*p99) + MIN_SPIN_NS;
        if self.gap_ns > 0.0 {
            margin = margin.min((self.gap_ns / 4.0) as u64);
        }
        margin.clamp(MIN_SPIN_NS, MAX_SPIN_NS)
    }
}

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
    wait(due_ns, spin_ns, |_, _| {})
}

/// [`wait_until`] with the margin `margin` learned, each sleep's end told to it.
pub fn wait_until_learning(due_ns: u64, margin: &mut SpinMargin) -> u64 {
    let spin_ns = margin.margin_ns();
    wait(due_ns, spin_ns, |planned, woke| margin.record(due_ns, planned, woke))
}

fn wait(due_ns: u64, spin_ns: u64, mut slept: impl FnMut(u64, u64)) -> u64 {
    loop {
        let now = monotonic_ns();
        match plan(now, due_ns, spin_ns) {
            Wait::Due => return now,
            // No `spin_loop` hint: a run of PAUSE instructions makes the hypervisor take the
            // vCPU away (pause-loop exiting), which on the bench's VM put the 99.9th
            // percentile of a 1 kHz spin at 1.8 ms against 0.3 ms without it.
            Wait::Spin => {}
            Wait::SleepUntil(t) => {
                imp::sleep_until(t);
                // A sleep cut short (a signal) says nothing of how late the machine wakes.
                let woke = monotonic_ns();
                if woke >= t {
                    slept(t, woke);
                }
            }
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

    /// Feeds `margin` sleeps at `gap_ns` apart, each `late_ns(k)` late.
    fn feed(margin: &mut SpinMargin, n: u64, gap_ns: u64, late_ns: impl Fn(u64) -> u64) {
        for k in 0..n {
            let due = 1_000_000_000 + k * gap_ns;
            let planned = due - margin.margin_ns();
            margin.record(due, planned, planned + late_ns(k));
        }
    }

    #[test]
    fn a_spin_margin_covers_the_99th_percentile_of_the_oversleeps_plus_the_guard() {
        let mut m = SpinMargin::new();
        assert_eq!(m.margin_ns(), SPIN_NS);
        // 50 Hz, every sleep 100 µs late but 1 in 128 that is 5 ms late: the margin covers
        // the usual 100 µs and does not chase the outliers (2 in 256 is under 1 %).
        feed(&mut m, 512, 20_000_000, |k| if k % 128 == 0 { 5_000_000 } else { 100_000 });
        assert_eq!(m.margin_ns(), 100_000 + MIN_SPIN_NS);
        // The machine gets quicker: the margin follows within a window.
        feed(&mut m, 256, 20_000_000, |_| 10_000);
        assert_eq!(m.margin_ns(), 10_000 + MIN_SPIN_NS);
    }

    #[test]
    fn a_spin_margin_stays_within_its_bounds_and_a_quarter_of_the_gap() {
        let mut m = SpinMargin::new();
        feed(&mut m, 256, 20_000_000, |_| 0);
        assert_eq!(m.margin_ns(), MIN_SPIN_NS);
        feed(&mut m, 256, 20_000_000, |_| 50_000_000);
        assert_eq!(m.margin_ns(), MAX_SPIN_NS);
        // 1 kHz: a quarter of 1 ms, however late the sleeps.
        let mut fast = SpinMargin::new();
        feed(&mut fast, 256, 1_000_000, |_| 800_000);
        assert_eq!(fast.margin_ns(), 250_000);
    }

    #[test]
    fn waiting_while_learning_never_returns_before_the_deadline() {
        let mut m = SpinMargin::new();
        for _ in 0..40 {
            let due = monotonic_ns() + 300_000;
            assert!(wait_until_learning(due, &mut m) >= due);
        }
        assert!((MIN_SPIN_NS..=MAX_SPIN_NS).contains(&m.margin_ns()));
    }

    #[test]
    fn a_deadline_closer_than_the_margin_is_spun_for_not_slept_for() {
        assert_eq!(plan(100, 130, 50), Wait::Spin);
    }
}
