//! The `plant` binary as a user starts it.

use std::process::Command;

#[test]
fn help_lists_the_flags_a_user_starts_the_plant_with() {
    let out = Command::new(env!("CARGO_BIN_EXE_plant")).arg("--help").output().expect("plant runs");
    assert!(out.status.success(), "{out:?}");
    let help = String::from_utf8_lossy(&out.stdout);
    for flag in ["--listen", "--scenario", "--time-mode", "--max-streams"] {
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

#[test]
fn a_bad_scenario_file_is_refused_at_start_with_its_line_and_field() {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("plant-scenario-file");
    std::fs::create_dir_all(&dir).expect("a temporary directory");
    let good = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/slalom-4.toml"),
    )
    .expect("scenarios/slalom-4.toml");
    let bad = good.replace("radius_m = 0.35", "radius_m = -0.35");
    let file = dir.join("bad.toml");
    std::fs::write(&file, bad).expect("write the file");
    let out = Command::new(env!("CARGO_BIN_EXE_plant"))
        .args(["--listen", "127.0.0.1:0", "--scenario"])
        .arg(&file)
        .output()
        .expect("plant runs");
    assert!(!out.status.success(), "{out:?}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("bad.toml:") && stderr.contains("scenario.obstacles[0].radius_m"), "{stderr}");
}

#[test]
fn logs_written_to_a_pipe_carry_no_colour_codes() {
    use std::io::BufRead;
    let mut plant = Command::new(env!("CARGO_BIN_EXE_plant"))
        .args(["--listen", "127.0.0.1:0"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("plant starts");
    let mut first = String::new();
    let read = plant.stdout.take().map(|s| std::io::BufReader::new(s).read_line(&mut first));
    let _ = plant.kill();
    let _ = plant.wait();
    assert!(matches!(read, Some(Ok(n)) if n > 0), "no log line: {read:?}");
    assert!(!first.contains('\u{1b}'), "colour codes in {first:?}");
}

#[test]
fn max_streams_zero_is_refused_at_start_naming_the_flag() {
    let out = Command::new(env!("CARGO_BIN_EXE_plant"))
        .args(["--listen", "127.0.0.1:0", "--max-streams", "0"])
        .output()
        .expect("plant runs");
    assert!(!out.status.success(), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("--max-streams"), "{out:?}");
}
