//! `controller solve` as a user runs it: the built binary, problems from a file, from stdin and
//! from `-`, one JSON answer per line on stdout, exit status 0 with bad lines among good ones.

use std::io::Write;
use std::process::{Command, Output, Stdio};

const GOOD: &str = r#"{"scenario":"paper-2","x0":[3.2,0,0,0,0,0,0,0],"u_prev":[9.81,0,0],"weights":[0.05,0.15,0.45,0.3,0.05]}"#;
const BAD: &str =
    r#"{"scenario":"paper-2","x0":[3.2,0,0],"u_prev":[9.81,0,0],"weights":[0.05,0.15,0.45,0.3,0.05]}"#;

fn controller() -> Command {
    Command::new(env!("CARGO_BIN_EXE_controller"))
}

fn answers(out: &Output) -> Vec<serde_json::Value> {
    assert!(out.status.success(), "exit {:?}: {}", out.status, String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| match serde_json::from_str(l) {
            Ok(v) => v,
            Err(e) => panic!("not a JSON line ({e}): {l}"),
        })
        .collect()
}

fn check(answers: &[serde_json::Value]) {
    assert_eq!(answers.len(), 2, "{answers:?}");
    assert_eq!(answers[0]["line"], 1);
    for key in ["status", "iterations", "solve_ms", "cost", "u", "min_clearance_m"] {
        assert!(!answers[0][key].is_null(), "missing {key}: {}", answers[0]);
    }
    assert_eq!(answers[1]["line"], 2);
    assert_eq!(answers[1]["field"], "x0");
}

fn with_stdin(mut cmd: Command, input: &str) -> Output {
    let mut child = match cmd.stdin(Stdio::piped()).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn() {
        Ok(c) => c,
        Err(e) => panic!("cannot start the controller binary: {e}"),
    };
    if let Some(mut stdin) = child.stdin.take() {
        stdin.write_all(input.as_bytes()).expect("write stdin");
    }
    child.wait_with_output().expect("controller output")
}

#[test]
fn solve_reads_a_file_stdin_or_dash_and_answers_every_line() {
    let input = format!("{GOOD}\n{BAD}\n");
    let path = std::env::temp_dir().join(format!("hilbench-solve-cli-{}.jsonl", std::process::id()));
    std::fs::write(&path, &input).expect("write the problem file");
    let from_file = controller().arg("solve").arg(&path).output().expect("controller runs");
    let _ = std::fs::remove_file(&path);
    let file_answers = answers(&from_file);
    check(&file_answers);

    let mut stdin = controller();
    stdin.arg("solve");
    let stdin_answers = answers(&with_stdin(stdin, &input));
    check(&stdin_answers);
    let mut dash = controller();
    dash.args(["solve", "-"]);
    check(&answers(&with_stdin(dash, &input)));
    // The same problem gives the same plan, whichever way it came in.
    assert_eq!(file_answers[0]["u"], stdin_answers[0]["u"]);

    let missing = controller().args(["solve", "/nonexistent/problems.jsonl"]).output().expect("runs");
    assert!(!missing.status.success());
    assert!(String::from_utf8_lossy(&missing.stderr).contains("cannot open"));
}

#[test]
fn solve_refuses_a_file_that_is_not_a_regular_file_naming_it() {
    let out = controller().args(["solve", "/dev/zero"]).output().expect("controller runs");
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("/dev/zero: not a regular file"), "{stderr}");
    assert!(out.stdout.is_empty());
}
