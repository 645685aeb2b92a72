//! What `hilbench` prints while it runs when stderr is not a terminal (a log file, CI).

use std::path::Path;
use std::process::Command;

#[test]
fn without_a_terminal_each_finished_run_prints_a_plain_line_on_stderr() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/slalom-4.toml");
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("progress-lines");
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
        .arg(&out)
        .output()
        .expect("hilbench runs");
    assert!(quiet.stderr.is_empty(), "{}", String::from_utf8_lossy(&quiet.stderr));
}
