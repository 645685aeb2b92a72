//! The gateway package's binaries as a user starts them. (Being an integration test of this
//! package also makes `cargo test --workspace` link `gateway`, `mavsim` and `vehiclectl`, which
//! the end-to-end tests of `tests/` start.)

use std::process::Command;

fn help_of(binary: &str) -> String {
    let out = Command::new(binary).arg("--help").output().expect("the binary runs");
    assert!(out.status.success(), "{binary} --help: {out:?}");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn the_gateways_help_lists_its_trust_and_recording_flags() {
    let help = help_of(env!("CARGO_BIN_EXE_gateway"));
    for flag in [
        "--listen",
        "--mavlink",
        "--mavlink-signing-key",
        "--vehicle-sysid",
        "--allow-client",
        "--envelope-margin-m",
        "--max-speed-mps",
        "--record-link",
    ] {
        assert!(help.contains(flag), "{flag} missing from:\n{help}");
    }
}

#[test]
fn mavsim_and_vehiclectl_answer_help_naming_what_they_do() {
    assert!(help_of(env!("CARGO_BIN_EXE_mavsim")).contains("TIMESYNC"));
    let vehiclectl = help_of(env!("CARGO_BIN_EXE_vehiclectl"));
    for command in ["status", "arm", "offboard", "arm-offboard"] {
        assert!(vehiclectl.contains(command), "{command} missing from:\n{vehiclectl}");
    }
}

#[test]
fn an_unknown_flag_is_a_usage_error_naming_it() {
    let out = Command::new(env!("CARGO_BIN_EXE_gateway")).arg("--no-such-flag").output().expect("runs");
    assert_eq!(out.status.code(), Some(2), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("--no-such-flag"), "{out:?}");
}

/// A gateway on a free loopback port, with a MAVLink link nothing speaks on; killed on drop.
struct Gateway {
    child: std::process::Child,
    address: String,
}

impl Gateway {
    fn start() -> Self {
        let port =
            std::net::TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).expect("a port").port();
        let address = format!("127.0.0.1:{port}");
        let child = Command::new(env!("CARGO_BIN_EXE_gateway"))
            .args(["--listen", &address, "--mavlink", "udpin:127.0.0.1:0"])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("the gateway starts");
        let until = std::time::Instant::now() + std::time::Duration::from_secs(30);
        while std::net::TcpStream::connect(&address).is_err() {
            assert!(std::time::Instant::now() < until, "the gateway does not listen on {address}");
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
        Self { child, address }
    }
}

impl Drop for Gateway {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn vehiclectl_status_into_a_closed_pipe_ends_quietly_without_a_panic() {
    // `vehiclectl status | head -1`: the reader has gone when the status is printed.
    let gateway = Gateway::start();
    let mut child = Command::new(env!("CARGO_BIN_EXE_vehiclectl"))
        .args(["--gateway", &gateway.address, "status"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("vehiclectl starts");
    drop(child.stdout.take());
    let out = child.wait_with_output().expect("vehiclectl ends");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    // With a reader, the status is printed whole.
    let out = Command::new(env!("CARGO_BIN_EXE_vehiclectl"))
        .args(["--gateway", &gateway.address, "status"])
        .output()
        .expect("vehiclectl runs");
    assert!(out.status.success(), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("link_alive"), "{out:?}");
}
