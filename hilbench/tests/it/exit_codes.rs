//! `hilbench`'s exit codes, as a script sees them: 0 no collision, 1 an error, 2 a usage error,
//! 3 a run collided.

use crate::common;

use std::path::Path;
use std::process::{Command, Output};

fn hilbench(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hilbench")).args(args).output().expect("hilbench runs")
}

/// paper-2 with the vehicle launched at 12 m/s straight at a cylinder 1.5 m ahead it cannot stop in front of
/// (tilt limited to 10 degrees), for 2 s of plant time.
fn colliding_scenario(dir: &Path) -> std::path::PathBuf {
    common::paper_2_variant(
        dir,
        "launched",
        &[
            (
                "start = [3.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]",
                "start = [3.5, 0.0, 1.0, 0.0, 12.0, 0.0, 0.0, 0.0]",
            ),
            ("max_duration_s = 60.0", "max_duration_s = 2.0"),
        ],
    )
}

#[test]
fn a_usage_error_exits_2_and_a_collision_exits_3() {
    let usage = hilbench(&["run", "scenarios/slalom-4.toml", "--mode", "Both"]);
    assert_eq!(usage.status.code(), Some(2), "{usage:?}");

    let dir = std::env::temp_dir().join(format!("hilbench-exit-codes-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary directory");
    let file = colliding_scenario(&dir);
    let out = dir.join("out");
    let args =
        ["run", file.to_str().expect("utf-8"), "--in-process", "--mode", "nmpc", "--no-plots", "--quiet"];
    let collided = hilbench(&[&args[..], &["--out", out.to_str().expect("utf-8")]].concat());
    assert_eq!(collided.status.code(), Some(3), "{collided:?}");
    let summary = std::fs::read_to_string(out.join("summary.json")).expect("summary.json");
    assert!(summary.contains("\"collided\": true"), "{summary}");
    // report.md names the collision: what was hit, how deep, when and where.
    let report = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    assert!(report.contains("launched with nmpc collided:\n\n- cylinder "), "{report}");
    assert!(report.contains(" mm deep, at ") && report.contains(" s, at ["), "{report}");

    let missing = hilbench(&["run", dir.join("nothing.toml").to_str().expect("utf-8"), "--in-process"]);
    assert_eq!(missing.status.code(), Some(1), "{missing:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_run_ends_at_its_first_collision_unless_asked_to_continue() {
    let dir = std::env::temp_dir().join(format!("hilbench-first-collision-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary directory");
    let file = colliding_scenario(&dir);
    let run = |extra: &[&str], out: &str| -> serde_json::Value {
        let out = dir.join(out);
        let args =
            ["run", file.to_str().expect("utf-8"), "--in-process", "--mode", "nmpc", "--no-plots", "--quiet"];
        let done = hilbench(&[&args[..], extra, &["--out", out.to_str().expect("utf-8")]].concat());
        assert_eq!(done.status.code(), Some(3), "{done:?}");
        let text = std::fs::read_to_string(out.join("summary.json")).expect("summary.json");
        serde_json::from_str::<serde_json::Value>(&text).expect("JSON")["runs"][0].clone()
    };
    let ended = run(&[], "ended");
    let went_on = run(&["--continue-after-collision"], "went-on");
    assert_eq!(ended["end_reason"], "collided", "{ended}");
    assert_eq!(went_on["end_reason"], "time_limit", "{went_on}");
    let cycles = |v: &serde_json::Value| v["cycles"].as_u64().expect("cycles");
    assert!(cycles(&ended) < cycles(&went_on), "{} cycles against {}", cycles(&ended), cycles(&went_on));
    // The run stopped at the first cycle whose sample shows the collision.
    let first = ended["collisions"][0]["time_s"].as_f64().expect("a collision time");
    let csv = std::fs::read_to_string(dir.join("ended/launched-nmpc.csv")).expect("the per-cycle CSV");
    let last_t: f64 =
        csv.lines().last().and_then(|l| l.split(',').nth(1)).expect("t_s").parse().expect("a number");
    assert!(last_t < first, "last cycle at {last_t} s, collision at {first} s");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_run_into_a_directory_that_holds_files_is_refused_leaving_them_and_runs_without_out_get_a_directory_each()
{
    let dir = common::out_dir("exit-codes-not-empty");
    std::fs::create_dir_all(&dir).expect("dir");
    std::fs::write(dir.join("notes.md"), "the user's").expect("write");
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/paper-2.toml");
    let run = hilbench(&["run", common::s(&file), "--in-process", "--quiet", "--out", common::s(&dir)]);
    assert_eq!(run.status.code(), Some(1), "{run:?}");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("holds 1 file(s) hilbench did not write (notes.md)"), "{stderr}");
    // Nothing written into it.
    let names: Vec<_> =
        std::fs::read_dir(&dir).expect("dir").map(|e| e.expect("entry").file_name()).collect();
    assert_eq!(names, ["notes.md"]);
    // Without --out, two runs in the same second get a directory each.
    let cwd = common::out_dir("exit-codes-default-dirs");
    std::fs::create_dir_all(&cwd).expect("dir");
    let twice: Vec<_> = (0..2)
        .map(|_| {
            Command::new(env!("CARGO_BIN_EXE_hilbench"))
                .args(["run", common::s(&file), "--in-process", "--quiet", "--no-plots", "--mode", "nmpc"])
                .current_dir(&cwd)
                .spawn()
                .expect("starts")
        })
        .collect();
    for child in twice {
        assert!(child.wait_with_output().expect("ends").status.success());
    }
    let dirs = std::fs::read_dir(cwd.join("runs")).expect("runs/").count();
    assert_eq!(dirs, 2);
}

#[test]
fn a_plant_address_where_nothing_listens_is_said_to_be_waited_for_then_refused_naming_it() {
    let dir = common::out_dir("exit-codes-no-plant");
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/paper-2.toml");
    // Port 1 on loopback: nothing listens there (it is privileged and unused).
    let run = hilbench(&[
        "run",
        common::s(&file),
        "--mode",
        "nmpc",
        "--plant",
        "127.0.0.1:1",
        "--no-plots",
        "--out",
        common::s(&dir),
    ]);
    assert_eq!(run.status.code(), Some(1), "{run:?}");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("waiting for 127.0.0.1:1 ("), "{stderr}");
    assert!(stderr.contains("cannot connect to 127.0.0.1:1 (tried for 30 s)"), "{stderr}");
    assert!(stderr.contains("Connection refused"), "{stderr}");
}

#[test]
fn a_file_without_the_nmpc_tuning_is_refused_to_the_benchs_controllers_naming_the_keys_before_any_flight() {
    let dir = std::env::temp_dir().join(format!("hilbench-no-tuning-{}", std::process::id()));
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/python-controller/open-field.toml");
    let file = file.to_str().expect("utf-8");
    let out = dir.join("out");
    let out = out.to_str().expect("utf-8");
    for args in [
        &["run", file, "--in-process", "--no-plots", "--out", out][..],
        &["sweep", file, "--runs", "2", "--out", out],
    ] {
        let refused = hilbench(args);
        let stderr = String::from_utf8_lossy(&refused.stderr);
        assert_eq!(refused.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(
            stderr.contains("leaves out `q_x`, `q_u`, `q_du`, `horizon`")
                && stderr.contains("--controller-cmd"),
            "{args:?}: {stderr}"
        );
        assert!(!dir.exists(), "{args:?}: nothing written");
    }
}
