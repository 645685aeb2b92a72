//! Real-time releases: one OS thread holds every scheduled copy in a [`ReleaseQueue`] and runs
//! its release action at the scheduled time.
//!
//! A thread rather than a tokio timer: tokio's timer wheel has a 1 ms resolution, which alone
//! would eat the whole 1 ms release-error budget. The thread sleeps in a channel receive with
//! a timeout (futex, tens of microseconds of slack) until shortly before the next release, and
//! yields in a loop for the last [`SPIN_NS`]. On Linux it asks for a higher priority
//! ([`RELEASE_THREAD_NICE`]) so that it is not kept waiting behind busy threads.

use std::sync::mpsc;

use delay::ReleaseQueue;

use crate::clock::Clock;

/// How long before a release the thread stops sleeping and polls, ns.
pub const SPIN_NS: u64 = 150_000;

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
}

impl Releaser {
    pub fn start(clock: Clock) -> std::io::Result<Self> {
        let (tx, rx) = mpsc::channel::<Job>();
        std::thread::Builder::new().name("netem-release".into()).spawn(move || run(clock, rx))?;
        Ok(Self { tx })
    }

    /// Runs `action` at `due_ns` on the clock (at once if that is past). Returns the action
    /// back if the thread is gone.
    pub fn schedule(&self, due_ns: u64, action: Action) -> Result<(), Action> {
        self.tx.send(Job { due_ns, action }).map_err(|e| e.0.action)
    }
}

/// Nice value asked for the release thread (Linux; needs the privilege to lower it, and is
/// skipped with a debug log without it): a woken release thread then preempts busy threads.
pub const RELEASE_THREAD_NICE: i32 = -10;

fn raise_priority() {
    #[cfg(target_os = "linux")]
    match rustix::process::setpriority_process(Some(rustix::thread::gettid()), RELEASE_THREAD_NICE) {
        Ok(()) => tracing::debug!(nice = RELEASE_THREAD_NICE, "release thread priority raised"),
        Err(e) => tracing::debug!("release thread keeps its priority: {e}"),
    }
}

fn run(clock: Clock, rx: mpsc::Receiver<Job>) {
    raise_priority();
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
                let wait = due.saturating_sub(now);
                if wait > SPIN_NS {
                    rx.recv_timeout(std::time::Duration::from_nanos(wait - SPIN_NS))
                } else {
                    match rx.try_recv() {
                        Ok(j) => Ok(j),
                        Err(mpsc::TryRecvError::Empty) => {
                            std::thread::yield_now();
                            Err(mpsc::RecvTimeoutError::Timeout)
                        }
                        Err(mpsc::TryRecvError::Disconnected) => Err(mpsc::RecvTimeoutError::Disconnected),
                    }
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
