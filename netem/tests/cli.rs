//! The `netem` binary as a user starts it.

use std::process::Command;

#[test]
fn help_lists_the_flags_a_user_starts_netem_with() {
    let out = Command::new(env!("CARGO_BIN_EXE_netem")).arg("--help").output().expect("netem runs");
    assert!(out.status.success(), "{out:?}");
    let help = String::from_utf8_lossy(&out.stdout);
    for flag in ["--listen", "--profile", "--seed", "--time-mode"] {
        assert!(help.contains(flag), "{flag} missing from:\n{help}");
    }
}

#[test]
fn an_unknown_profile_is_refused_at_start_with_its_name() {
    let out = Command::new(env!("CARGO_BIN_EXE_netem"))
        .args(["--listen", "127.0.0.1:0", "--upstream", "127.0.0.1:1", "--profile", "no-such-profile"])
        .output()
        .expect("netem runs");
    assert!(!out.status.success(), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("no-such-profile"), "{out:?}");
}
