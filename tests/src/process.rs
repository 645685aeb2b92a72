//! Service binaries of this build run as a user runs them: child processes on loopback ports,
//! killed when dropped, and signalled (frozen, resumed, killed) by the fault tests.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};

/// A binary of this build (`target/<profile>/<name>`). Panics when it is not built: the tests
/// that use binaries need `cargo build --release -p plant -p netem -p controller -p hilbench`
/// (`cargo test --workspace` builds them).
pub fn service_binary(name: &str) -> PathBuf {
    // The tests run as target/<profile>/deps/<test>-<hash>.
    let exe = std::env::current_exe().expect("the test binary's path");
    let dir = exe.parent().and_then(std::path::Path::parent).expect("the target directory");
    let path = dir.join(name);
    assert!(path.exists(), "{} is not built: run the tests with `cargo test --workspace`", path.display());
    path
}

/// A loopback address that was free a moment ago, for a service to bind.
///
/// The port comes from below the kernel's ephemeral range (32768-60999 on Linux), taken in
/// turn from a counter: a port the kernel handed out for `bind(0)` and that the test released
/// could be handed to another test's connection or `bind(0)` before the service binds it
/// (seen as a failed test under parallel runs); ports outside that range are never handed out
/// by the kernel, and the counter never gives one twice within a test binary. The start
/// depends on the process id so that two test binaries running at once rarely meet; a port in
/// use is skipped.
pub fn free_loopback_address() -> String {
    use std::sync::atomic::{AtomicU32, Ordering};
    const FIRST: u32 = 20_000;
    const PORTS: u32 = 12_000;
    static NEXT: AtomicU32 = AtomicU32::new(u32::MAX);
    let _ = NEXT.compare_exchange(
        u32::MAX,
        (std::process::id() * 97) % PORTS,
        Ordering::SeqCst,
        Ordering::SeqCst,
    );
    for _ in 0..PORTS {
        let port = FIRST + NEXT.fetch_add(1, Ordering::SeqCst) % PORTS;
        let address = format!("127.0.0.1:{port}");
        // Free for TCP and UDP both: some services listen on one and the other.
        if std::net::TcpListener::bind(&address).is_ok() && std::net::UdpSocket::bind(&address).is_ok() {
            return address;
        }
    }
    panic!("no free loopback port in {FIRST}..{}", FIRST + PORTS)
}

/// A child process killed when dropped (a failing test leaves no service behind).
pub struct Service(pub Child);

impl Service {
    /// Starts `name` with `args`, its output discarded.
    pub fn start(name: &str, args: &[&str]) -> Self {
        Self::start_with(name, args, &[])
    }

    /// Starts `name` with `args` and the environment variables `env`, its output discarded.
    pub fn start_with(name: &str, args: &[&str], env: &[(&str, &str)]) -> Self {
        let child = Command::new(service_binary(name))
            .args(args)
            .envs(env.iter().copied())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        Self(child)
    }

    /// Starts `name` with `args`, its output (the log, on stdout) and errors written to `log`,
    /// for a test that asserts on what the service said.
    pub fn start_logged(name: &str, args: &[&str], log: &std::path::Path) -> Self {
        let file =
            std::fs::File::create(log).unwrap_or_else(|e| panic!("cannot create {}: {e}", log.display()));
        let errors = file.try_clone().unwrap_or_else(|e| panic!("{}: {e}", log.display()));
        let child = Command::new(service_binary(name))
            .args(args)
            .stdin(Stdio::null())
            .stdout(file)
            .stderr(errors)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        Self(child)
    }

    /// CPU time the process has used so far, user and system, all threads (`/proc/PID/stat`).
    pub fn cpu_time(&self) -> std::time::Duration {
        let pid = self.0.id();
        let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .unwrap_or_else(|e| panic!("/proc/{pid}/stat: {e}"));
        // Fields after the command name (which may hold spaces) in parentheses: utime and stime
        // are the 14th and 15th of the line, the 12th and 13th after the name.
        let after_name = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
        let ticks: u64 = after_name
            .split_whitespace()
            .skip(11)
            .take(2)
            .map(|f| f.parse::<u64>().unwrap_or_else(|e| panic!("/proc/{pid}/stat field {f:?}: {e}")))
            .sum();
        // The kernel reports them in USER_HZ ticks, 100 a second on every Linux ABI.
        std::time::Duration::from_millis(ticks * 10)
    }

    /// Sends `signal` (`STOP`, `CONT`, `KILL`, ...) with `kill(1)`.
    pub fn signal(&self, signal: &str) {
        let status = Command::new("kill")
            .args([format!("-{signal}"), self.0.id().to_string()])
            .status()
            .unwrap_or_else(|e| panic!("cannot run kill: {e}"));
        assert!(status.success(), "kill -{signal} {} failed", self.0.id());
    }
}

impl Drop for Service {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
