//! Real-time releases: one OS thread holds every scheduled copy in a [`ReleaseQueue`] and runs
//! its release action at the scheduled time.
//!
//! A thread rather than a tokio timer: tokio's timer wheel has a 1 ms resolution, twenty times
//! the 50 µs release-error target. The thread is made real time by
//! [`hilbench_svc::realtime::promote_current_thread`] (`SCHED_FIFO` when permitted, a timer
//! slack of 1 ns) and waits for the next release as every real-time thread of the bench does
//! ([`hilbench_svc::realtime::plan`]): it sleeps in the job channel's receive with a timeout
//! (a futex, woken at once by a new job, which may be due earlier) until [`SPIN_NS`] before
//! the release, then spins reading the clock, still taking new jobs, until the release is due.
//!
//! ## What a release costs
//! The release actions run on this thread one after the other, so they must be short (a
//! channel send, a push into a stream's buffer, a datagram's `send_to`): the release error of
//! a copy includes the actions of the copies due before it. They should not take netem's lock
//! either: a task holding it may be preempted, and the thread would wait for it (the UDP path
//! did, p99 in milliseconds under load, until its copies were counted by a task instead).

use std::sync::mpsc;
use std::sync::{Arc, OnceLock};

use delay::ReleaseQueue;
use hilbench_svc::realtime::{self, Priority, Wait};

use crate::clock::Clock;

pub use realtime::SPIN_NS;

/// A release action; it gets the release error (actual minus scheduled time), ns.
pub type Action = Box<dyn FnOnce(i64) + Send>;

struct Job {
    due_ns: u64,
    action: Action,
}

/// Handle to the release thread; the thread ends when the last handle is dropped.
#[derive(Clone)]
pub struct Releaser {
    tx: mpsc::Sender<Job>,
    priority: Arc<OnceLock<Priority>>,
}

impl Releaser {
    pub fn start(clock: Clock) -> std::io::Result<Self> {
        let (tx, rx) = mpsc::channel::<Job>();
        let priority = Arc::new(OnceLock::new());
        let set = priority.clone();
        std::thread::Builder::new().name("netem-release".into()).spawn(move || {
            let _ = set.set(realtime::promote_current_thread("netem-release"));
            run(clock, rx)
        })?;
        Ok(Self { tx, priority })
    }

    /// Runs `action` at `due_ns` on the clock (at once if that is past). Returns the action
    /// back if the thread is gone.
    pub fn schedule(&self, due_ns: u64, action: Action) -> Result<(), Action> {
        self.tx.send(Job { due_ns, action }).map_err(|e| e.0.action)
    }

    /// The scheduling the release thread obtained (`None` until it has started).
    pub fn priority(&self) -> Option<Priority> {
        self.priority.get().copied()
    }
}

fn run(clock: Clock, rx: mpsc::Receiver<Job>) {
    let mut queue: ReleaseQueue<Action> = ReleaseQueue::new();
    loop {
        while let Some((due, action)) = queue.pop_due(clock.now_ns()) {
            let error = clock.now_ns() as i64 - due as i64;
            action(error);
        }
        let next = match queue.next_release_ns() {
            None => rx.recv().map_err(|_| mpsc::RecvTimeoutError::Disconnected),
            Some(due) => {
                let now = clock.now_ns();
                match realtime::plan(now, due, SPIN_NS) {
                    Wait::Due => continue,
                    Wait::SleepUntil(t) => rx.recv_timeout(std::time::Duration::from_nanos(t - now)),
                    Wait::Spin => match rx.try_recv() {
                        Ok(j) => Ok(j),
                        // Read the clock again (no `spin_loop` hint: see `realtime::wait_until`).
                        Err(mpsc::TryRecvError::Empty) => Err(mpsc::RecvTimeoutError::Timeout),
                        Err(mpsc::TryRecvError::Disconnected) => Err(mpsc::RecvTimeoutError::Disconnected),
                    },
                }
            }
        };
        match next {
            Ok(job) => queue.push(job.due_ns, job.action),
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            // Netem is shutting down: what is still held is dropped with it.
            Err(mpsc::RecvTimeoutError::Disconnected) => return,
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
        let (tx, rx) = mpsc::channel();
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
}
