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

/// A loopback address that was free a moment ago (the service binds it).
pub fn free_loopback_address() -> String {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind a loopback port");
    listener.local_addr().expect("address").to_string()
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
