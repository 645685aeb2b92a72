//! What `hilbench` prints while it runs when stderr is not a terminal (a log file, CI).

use std::path::Path;
use std::process::Command;

#[test]
fn without_a_terminal_each_finished_run_prints_a_plain_line_on_stderr() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/slalom-4.toml");
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("progress-lines");
    let quiet_out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("progress-lines-quiet");
    for dir in [&out, &quiet_out] {
        let _ = std::fs::remove_dir_all(dir);
    }
    let run = Command::new(env!("CARGO_BIN_EXE_hilbench"))
        .args(["run", file.to_str().expect("utf-8"), "--in-process", "--no-plots", "--out"])
        .arg(&out)
        .output()
        .expect("hilbench runs");
    assert!(run.status.success(), "{run:?}");
    let stderr = String::from_utf8_lossy(&run.stderr);
    for mode in ["nmpc", "multistage"] {
        assert!(
            stderr.lines().any(|l| l.contains("slalom-4") && l.contains(mode) && l.contains("done (")),
            "no line for {mode} in:\n{stderr}"
        );
    }
    assert!(!stderr.contains('\u{1b}'), "escape codes in:\n{stderr}");
    let quiet = Command::new(env!("CARGO_BIN_EXE_hilbench"))
        .args(["run", file.to_str().expect("utf-8"), "--in-process", "--no-plots", "--quiet", "--out"])
        .arg(&quiet_out)
        .output()
        .expect("hilbench runs");
    assert!(quiet.stderr.is_empty(), "{}", String::from_utf8_lossy(&quiet.stderr));
}

#[test]
fn ctrl_c_writes_what_finished_marks_the_summary_interrupted_and_exits_130() {
    use std::io::BufRead;
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("interrupted");
    let _ = std::fs::remove_dir_all(&out);
    let mut child = Command::new(env!("CARGO_BIN_EXE_hilbench"))
        .args(["reproduce", "--no-plots", "--out"])
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("hilbench starts");
    let stderr = child.stderr.take().expect("stderr");
    let mut lines = std::io::BufReader::new(stderr).lines();
    // The first finished run (of six), then Ctrl-C.
    let first = lines.by_ref().map_while(Result::ok).find(|l| l.contains("done ("));
    assert!(first.is_some(), "no run finished");
    let signal = Command::new("kill").args(["-INT", &child.id().to_string()]).status().expect("kill runs");
    assert!(signal.success());
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    let status = child.wait().expect("hilbench ends");
    assert_eq!(status.code(), Some(130), "{rest:?}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary.json"))
            .expect("JSON");
    assert_eq!(summary["interrupted"], true);
    let runs = summary["runs"].as_array().expect("runs").len();
    assert!((1..6).contains(&runs), "{runs} runs written");
    assert!(rest.iter().any(|l| l.contains("interrupted")), "{rest:?}");
}

#[test]
fn without_a_terminal_a_real_time_run_says_every_few_seconds_that_it_is_flying() {
    // paper-2 without its cylinders and with its goal out of reach: the run flies to its time
    // limit, 7 s of plant time, which in real time is 7 s of wall time on any machine (the
    // heartbeat comes every 5 s).
    let paper_2 =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/paper-2.toml"))
            .expect("paper-2.toml");
    let (head, obstacles) = paper_2.split_once("[[scenario.obstacles]]").expect("paper-2's cylinders");
    let (_, network) = obstacles.split_once("[scenario.delays]").expect("paper-2's delays");
    let text = format!("{head}[scenario.delays]{network}")
        .replace("name = \"paper-2\"", "name = \"far-goal\"")
        .replace("goal_m = [3.2, 5.0, 1.0]", "goal_m = [3.2, 60.0, 1.0]")
        .replace("max_duration_s = 60.0", "max_duration_s = 7.0");
    assert!(text.contains("far-goal") && text.contains("60.0, 1.0") && text.contains("= 7.0"), "{text}");
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("progress-heartbeat");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("a directory");
    let file = dir.join("far-goal.toml");
    std::fs::write(&file, text).expect("write the scenario");
    let out = dir.join("out");
    let run = Command::new(env!("CARGO_BIN_EXE_hilbench"))
        .args(["run", file.to_str().expect("utf-8"), "--mode", "nmpc", "--time-mode", "real-time"])
        .args(["--no-plots", "--out"])
        .arg(&out)
        .output()
        .expect("hilbench runs");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{run:?}");
    assert!(
        stderr.lines().any(|l| l.contains("far-goal") && l.contains("nmpc") && l.contains("flying (")),
        "no heartbeat line in:\n{stderr}"
    );
    assert!(stderr.lines().any(|l| l.contains("done (")), "no line for the finished run in:\n{stderr}");
}
