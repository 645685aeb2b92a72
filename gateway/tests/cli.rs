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
