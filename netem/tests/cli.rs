//! The `netem` binary as a user starts it.

use std::process::Command;

#[test]
fn help_lists_the_flags_a_user_starts_netem_with() {
    let out = Command::new(env!("CARGO_BIN_EXE_netem")).arg("--help").output().expect("netem runs");
    assert!(out.status.success(), "{out:?}");
    let help = String::from_utf8_lossy(&out.stdout);
    for flag in ["--listen", "--profile", "--seed", "--time-mode", "--max-streams"] {
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

/// netem with a profile file, told to listen on an address already taken: it reads its profile
/// and then fails to listen (so that a valid file ends the process too).
fn netem_with_profile_file(text: &str) -> std::process::Output {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("bind a loopback port");
    let listen = taken.local_addr().expect("address").to_string();
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("netem-profile-file");
    std::fs::create_dir_all(&dir).expect("a temporary directory");
    let file = dir
        .join(format!("profile-{:x}.toml", text.len() * 31 + text.bytes().map(usize::from).sum::<usize>()));
    std::fs::write(&file, text).expect("write the profile file");
    Command::new(env!("CARGO_BIN_EXE_netem"))
        .args(["--listen", &listen, "--plant", "127.0.0.1:1"])
        .arg("--profile-file")
        .arg(&file)
        .output()
        .expect("netem runs")
}

#[test]
fn a_bad_profile_file_is_refused_at_start_naming_the_file_and_the_key() {
    for (text, key) in [
        ("kind = \"lognormal\"\nmean_s = 0.1\nstd_s = -0.02\n", "std_s"),
        ("kind = \"regime\"\n[[states]]\nkind = \"constant\"\ndelay_s = 0.1\n", "states[0].mean_dwell_s"),
        ("[to_plant]\nkind = \"trace\"\nfile = \"missing.csv\"\n", "to_plant.file"),
        ("kind = \"gamma\"\nshape = 2.0\nscale = 0.1\n", "scale"),
    ] {
        let out = netem_with_profile_file(text);
        assert!(!out.status.success(), "{text}: {out:?}");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains("--profile-file") && stderr.contains(key), "{key}: {stderr}");
    }
}

#[test]
fn a_valid_profile_file_gets_as_far_as_listening() {
    let out = netem_with_profile_file(
        "[to_plant]\nkind = \"regime\"\n[[to_plant.states]]\nkind = \"constant\"\ndelay_s = 0.02\nmean_dwell_messages = 10.0\n[[to_plant.states]]\nkind = \"pareto\"\nscale_s = 0.05\nshape = 2.5\nmean_dwell_s = 1.0\n[to_controller]\nkind = \"normal\"\nmean_s = 0.01\nstd_s = 0.002\n",
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("--profile-file"), "{stderr}");
    assert!(stderr.contains("--listen") && stderr.contains("cannot listen"), "{stderr}");
}

#[test]
fn max_streams_zero_is_refused_at_start_naming_the_flag() {
    let out = Command::new(env!("CARGO_BIN_EXE_netem"))
        .args(["--listen", "127.0.0.1:0", "--max-streams", "0"])
        .output()
        .expect("netem runs");
    assert!(!out.status.success(), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("--max-streams"), "{out:?}");
}
