//! Real-time releases: one OS thread holds every scheduled copy in a [`ReleaseQueue`] and runs
//! its release action at the scheduled time.
//!
//! A thread rather than a tokio timer: tokio's timer wheel has a 1 ms resolution, twenty times
//! the 50 µs release-error target. The thread is made real time by
//! [`hilbench_svc::realtime::promote_current_thread`] (`SCHED_FIFO` when permitted, a timer
//! slack of 1 ns) and waits for the next release as every real-time thread of the bench does
//! ([`hilbench_svc::realtime::plan`]): it parks with a timeout (a futex, unparked at once by a
//! new job, which may be due earlier) until a margin before the release, then spins reading
//! the clock, still taking new jobs ([`Inbox`]: never waiting for a scheduler), until the
//! release is due. The
//! margin is learned from how late its own sleeps end ([`SpinMargin`]): the machine's wake-up
//! latency, which on a VM depends on how busy the vCPU is.
//!
//! ## What a release costs
//! The release actions run on this thread one after the other, so they must be short (a
//! channel send, a push into a stream's buffer, a datagram's `send_to`): the release error of
//! a copy includes the actions of the copies due before it. They should not take netem's lock
//! either: a task holding it may be preempted, and the thread would wait for it (the UDP path
//! did, p99 in milliseconds under load, until its copies were counted by a task instead).

use std::sync::{Arc, Mutex, OnceLock, TryLockError, Weak};

use delay::ReleaseQueue;
use hilbench_svc::realtime::{self, Priority, SpinMargin, Wait};

use crate::clock::Clock;

/// A release action; it gets the release error (actual minus scheduled time), ns.
pub type Action = Box<dyn FnOnce(i64) + Send>;

struct Job {
    due_ns: u64,
    action: Action,
}

/// Where schedulers leave jobs for the release thread.
///
/// Not a channel: `std::sync::mpsc` (and crossbeam's, which it is) lets a receiver claim a
/// slot a sender has reserved but not yet written and then wait for the write, spinning and
/// yielding. A `SCHED_FIFO` receiver that preempted that sender on its CPU keeps it from
/// finishing, and yielding does not let a lower priority run: the release thread waited
/// milliseconds for a preempted tokio worker, every release behind it late (`lab load
/// release`, BENCHMARKS.md "Release precision"). Here the release thread only ever
/// `try_lock`s the inbox and moves on when a scheduler holds it: that scheduler unparks it
/// after unlocking, so no job is missed, and no wait of the release thread depends on a
/// thread of lower priority.
struct Inbox {
    jobs: Mutex<Vec<Job>>,
    /// The release thread, to unpark; set when it starts.
    thread: OnceLock<std::thread::Thread>,
    /// False once the release thread has ended (its queue dropped with it).
    alive: std::sync::atomic::AtomicBool,
}

impl Drop for Inbox {
    /// The last handle is gone: wake the thread, whose next look finds the inbox gone.
    fn drop(&mut self) {
        if let Some(t) = self.thread.get() {
            t.unpark();
        }
    }
}

/// Marks the inbox dead when the release thread ends, however it ends.
struct Alive(Weak<Inbox>);

impl Drop for Alive {
    fn drop(&mut self) {
        if let Some(inbox) = self.0.upgrade() {
            inbox.alive.store(false, std::sync::atomic::Ordering::Release);
        }
    }
}

/// Handle to the release thread; the thread ends when the last handle is dropped.
#[derive(Clone)]
pub struct Releaser {
    inbox: Arc<Inbox>,
    priority: Arc<OnceLock<Priority>>,
}

impl Releaser {
    pub fn start(clock: Clock) -> std::io::Result<Self> {
        let inbox = Arc::new(Inbox {
            jobs: Mutex::new(Vec::with_capacity(1024)),
            thread: OnceLock::new(),
            alive: std::sync::atomic::AtomicBool::new(true),
        });
        let priority = Arc::new(OnceLock::new());
        let (set, weak) = (priority.clone(), Arc::downgrade(&inbox));
        let handle = std::thread::Builder::new().name("netem-release".into()).spawn(move || {
            let _alive = Alive(weak.clone());
            let _ = set.set(realtime::promote_current_thread("netem-release"));
            run(clock, weak)
        })?;
        let _ = inbox.thread.set(handle.thread().clone());
        Ok(Self { inbox, priority })
    }

    /// Runs `action` at `due_ns` on the clock (at once if that is past). Returns the action
    /// back if the thread is gone.
    pub fn schedule(&self, due_ns: u64, action: Action) -> Result<(), Action> {
        if !self.inbox.alive.load(std::sync::atomic::Ordering::Acquire) {
            return Err(action);
        }
        // A poisoned inbox only means a scheduler panicked while pushing: the jobs are whole.
        self.inbox.jobs.lock().unwrap_or_else(|e| e.into_inner()).push(Job { due_ns, action });
        if let Some(t) = self.inbox.thread.get() {
            t.unpark();
        }
        Ok(())
    }

    /// The scheduling the release thread obtained (`None` until it has started).
    pub fn priority(&self) -> Option<Priority> {
        self.priority.get().copied()
    }
}

/// Moves what the inbox holds into `queue` if no scheduler holds the inbox; true if it took
/// any. `spare` is swapped in, so the inbox's capacity is kept and nothing is allocated.
fn take_jobs(inbox: &Inbox, spare: &mut Vec<Job>, queue: &mut ReleaseQueue<Action>) -> bool {
    match inbox.jobs.try_lock() {
        Ok(mut jobs) => std::mem::swap(&mut *jobs, spare),
        Err(TryLockError::Poisoned(e)) => std::mem::swap(&mut *e.into_inner(), spare),
        // A scheduler is pushing: it unparks the thread when it is done.
        Err(TryLockError::WouldBlock) => return false,
    }
    let took = !spare.is_empty();
    for job in spare.drain(..) {
        queue.push(job.due_ns, job.action);
    }
    took
}

fn run(clock: Clock, inbox: Weak<Inbox>) {
    let mut queue: ReleaseQueue<Action> = ReleaseQueue::new();
    let mut spare: Vec<Job> = Vec::with_capacity(1024);
    let mut margin = SpinMargin::new();
    loop {
        // Netem is shutting down when the last handle is gone: what is held is dropped.
        let Some(inbox) = inbox.upgrade() else { return };
        let took = take_jobs(&inbox, &mut spare, &mut queue);
        while let Some((due, action)) = queue.pop_due(clock.now_ns()) {
            let error = clock.now_ns() as i64 - due as i64;
            action(error);
        }
        drop(inbox);
        if took {
            // Look again before sleeping: more may have come while these were released.
            continue;
        }
        match queue.next_release_ns() {
            None => std::thread::park(),
            Some(due) => {
                let now = clock.now_ns();
                match realtime::plan(now, due, margin.margin_ns()) {
                    Wait::Due => {}
                    // Read the clock again (no `spin_loop` hint: see `realtime::wait_until`).
                    Wait::Spin => {}
                    Wait::SleepUntil(t) => {
                        std::thread::park_timeout(std::time::Duration::from_nanos(t - now));
                        let woke = clock.now_ns();
                        // Woken before its time by a scheduler's unpark, not by the timer:
                        // that sleep says nothing of the machine.
                        if woke >= t {
                            margin.record(due, t, woke);
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn releases_run_in_due_order_never_before_their_time_whatever_order_they_were_scheduled_in() {
        let clock = Clock::new();
        let releaser = Releaser::start(clock).expect("thread");
        let (tx, rx) = std::sync::mpsc::channel();
        let now = clock.now_ns();
        // Scheduled latest first: each new job is due before those the thread already holds.
        for (k, offset_ms) in [(3u64, 30u64), (2, 20), (1, 10), (0, 0)] {
            let tx = tx.clone();
            let due = now + offset_ms * 1_000_000;
            let action: Action = Box::new(move |error_ns| {
                let _ = tx.send((k, error_ns, clock.now_ns() >= due));
            });
            assert!(releaser.schedule(due, action).is_ok());
        }
        let got: Vec<(u64, i64, bool)> = (0..4).map(|_| rx.recv().expect("released")).collect();
        assert_eq!(got.iter().map(|g| g.0).collect::<Vec<_>>(), [0, 1, 2, 3]);
        assert!(got.iter().all(|&(_, error_ns, on_or_after_due)| error_ns >= 0 && on_or_after_due));
        assert!(releaser.priority().is_some());
    }

    #[test]
    fn every_job_from_concurrent_schedulers_runs_once_at_or_after_its_time() {
        let clock = Clock::new();
        let releaser = Releaser::start(clock).expect("thread");
        let (tx, rx) = std::sync::mpsc::channel();
        let now = clock.now_ns();
        std::thread::scope(|s| {
            for t in 0..4u64 {
                let (releaser, tx) = (releaser.clone(), tx.clone());
                s.spawn(move || {
                    for k in 0..500u64 {
                        // Due within 20 ms, in no order, some already past.
                        let due = (now + (k * 7919 + t * 104_729) % 20_000_000).saturating_sub(1_000_000);
                        let tx = tx.clone();
                        let action: Action = Box::new(move |error_ns| {
                            let _ = tx.send((t, k, error_ns, clock.now_ns() >= due));
                        });
                        assert!(releaser.schedule(due, action).is_ok());
                    }
                });
            }
        });
        let mut seen: Vec<(u64, u64)> = (0..2000)
            .map(|_| {
                let (t, k, error_ns, on_time) = rx.recv().expect("released");
                assert!(error_ns >= 0 && on_time, "job {t}/{k} ran {error_ns} ns from its time");
                (t, k)
            })
            .collect();
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(seen.len(), 2000);
    }

    #[test]
    fn the_release_thread_ends_when_the_last_handle_is_dropped_and_drops_what_it_held() {
        let clock = Clock::new();
        let releaser = Releaser::start(clock).expect("thread");
        let held = Arc::new(());
        let witness = held.clone();
        let action: Action = Box::new(move |_| drop(witness));
        assert!(releaser.schedule(clock.now_ns() + 3_600_000_000_000, action).is_ok());
        let thread = releaser.inbox.thread.get().expect("started").clone();
        drop(releaser);
        // The hour-long job is dropped with the thread, its witness with it.
        for _ in 0..500 {
            if Arc::strong_count(&held) == 1 {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        assert_eq!(Arc::strong_count(&held), 1, "the release thread {:?} still holds its job", thread.name());
    }
}
