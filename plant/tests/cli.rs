//! The `plant` binary as a user starts it.

use std::process::Command;

#[test]
fn help_lists_the_flags_a_user_starts_the_plant_with() {
    let out = Command::new(env!("CARGO_BIN_EXE_plant")).arg("--help").output().expect("plant runs");
    assert!(out.status.success(), "{out:?}");
    let help = String::from_utf8_lossy(&out.stdout);
    for flag in ["--listen", "--scenario", "--time-mode"] {
        assert!(help.contains(flag), "{flag} missing from:\n{help}");
    }
}

#[test]
fn an_unknown_scenario_is_refused_at_start_with_its_name() {
    let out = Command::new(env!("CARGO_BIN_EXE_plant"))
        .args(["--listen", "127.0.0.1:0", "--scenario", "paper-9"])
        .output()
        .expect("plant runs");
    assert!(!out.status.success(), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("paper-9"), "{out:?}");
}
