//! A panic in any task of a run ends the run with an error naming it, rather than leaving the
//! run waiting on a service whose task died (tokio catches a task's panic and serves on).
//!
//! [`watch`] installs, once per process, a panic hook that keeps the default hook's message and
//! publishes the panic's text and place when it happened on a thread of a run's runtime (named
//! [`RUN_THREAD`]: `run_all`'s workers and blocking threads, where the in-process services and
//! the driver run). Panics elsewhere (a test harness's own, proptest's shrinking) are not a
//! run's.

use std::sync::OnceLock;

use tokio::sync::watch;

/// The thread name of a run's runtime.
pub const RUN_THREAD: &str = "hilbench-run";

fn channel() -> &'static watch::Sender<Option<String>> {
    static PANICS: OnceLock<watch::Sender<Option<String>>> = OnceLock::new();
    PANICS.get_or_init(|| {
        let default_hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if std::thread::current().name() != Some(RUN_THREAD) {
                default_hook(info);
                return;
            }
            // One line, no backtrace: a task that panics on every call (a service handler the
            // controller retries) would otherwise print a symbolised backtrace per retry, each
            // holding stderr for seconds, and keep the run's own error from being printed.
            let place = info.location().map(|l| format!(" at {}:{}", l.file(), l.line())).unwrap_or_default();
            let text = format!("{}{place}", hilbench_svc::panic_text(info.payload()));
            eprintln!("a task of the run panicked: {text}");
            channel().send_replace(Some(text));
        }));
        watch::channel(None).0
    })
}

/// A receiver that changes at the next panic on a run's thread (the text and place of the
/// panic); the hook is installed at the first call.
pub fn watch() -> watch::Receiver<Option<String>> {
    channel().subscribe()
}
