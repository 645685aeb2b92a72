//! An external controller under test (`hilbench run --controller-cmd`, `hilbench::external`):
//! the Python PD controller of examples/python-controller (grpcio, stubs generated from proto/
//! at its start, run by the test venv's interpreter) flown against a plant and netem started by
//! the bench, judged from the plant's truth; and controllers that fail.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use hilbench::drive::external::{
    ExternalDriver, ExternalFailure, ExternalRun, ExternalSettings, run_external,
};
use hilbench::scenario_file::ScenarioFile;
use hilbench_tests::TempDir;
use hilbench_tests::python::python;
use mav::TimeMode;

/// Longer than any run here takes: a hang is the failure these tests catch.
const PATIENCE: Duration = Duration::from_secs(120);

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path)
}

/// The Python controller's command line, under the test venv's interpreter.
fn python_controller() -> String {
    let controller = repo("examples/python-controller/controller.py");
    format!("'{}' '{}'", python().display(), controller.display())
}

fn open_field() -> mav::Scenario {
    ScenarioFile::load(&repo("examples/python-controller/open-field.toml")).expect("open-field.toml").scenario
}

/// `hilbench ARGS` to its end: exit code, stderr, and `OUT/summary.json`.
fn hilbench(args: &[&str], out: &Path) -> (Option<i32>, String, serde_json::Value) {
    let mut child = Command::new(hilbench_tests::service_binary("hilbench"))
        .args(args)
        .args(["--out", &out.display().to_string(), "--no-plots", "--quiet"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("hilbench starts");
    let started = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break status;
        }
        if started.elapsed() > PATIENCE {
            let _ = child.kill();
            panic!("hilbench {args:?} did not end within {PATIENCE:?}");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let mut stderr = String::new();
    if let Some(mut e) = child.stderr.take() {
        let _ = std::io::Read::read_to_string(&mut e, &mut stderr);
    }
    let summary = std::fs::read_to_string(out.join("summary.json"))
        .unwrap_or_else(|e| panic!("no summary.json ({e}); stderr:\n{stderr}"));
    (status.code(), stderr, serde_json::from_str(&summary).expect("summary.json is JSON"))
}

/// One run of `command` on `scenario` in lockstep, through the library (as `run_all` calls it).
fn fly(
    scenario: &mav::Scenario,
    command: &str,
    settings: ExternalSettings,
) -> Result<ExternalRun, ExternalFailure> {
    fly_in(TimeMode::Lockstep, scenario, command, settings)
}

fn fly_in(
    time_mode: TimeMode,
    scenario: &mav::Scenario,
    command: &str,
    settings: ExternalSettings,
) -> Result<ExternalRun, ExternalFailure> {
    let controller = ExternalDriver { time_mode, settings, plant: None, start_from_vehicle: false };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("a runtime");
    runtime.block_on(run_external(scenario, command, &controller))
}

#[test]
fn the_python_pd_controller_reaches_the_open_field_goal_in_lockstep_judged_from_the_plants_samples() {
    let out = TempDir::new("external-test-reach");
    let file = repo("examples/python-controller/open-field.toml").display().to_string();
    let (code, stderr, summary) = hilbench(&["run", &file, "--controller-cmd", &python_controller()], &out);
    assert_eq!(code, Some(0), "{stderr}");
    assert_eq!(summary["transport"], "external");
    assert_eq!(summary["time_mode"], "lockstep");
    let run = &summary["runs"][0];
    assert_eq!(run["controller"], "external");
    assert_eq!((run["reached"].as_bool(), run["end_reason"].as_str()), (Some(true), Some("reached")));
    assert_eq!(run["collided"], false);
    // The plant's truth: the last position is inside the goal's tolerance (0.15 m of [3, 4, 1]),
    // the path at least the straight line from the start (5.10 m), the time the plant's.
    let p: Vec<f64> =
        run["final_position_m"].as_array().expect("a position").iter().filter_map(|v| v.as_f64()).collect();
    let miss_m = ((p[0] - 3.0).powi(2) + (p[1] - 4.0).powi(2) + (p[2] - 1.0).powi(2)).sqrt();
    assert!(miss_m < 0.15, "{p:?}");
    let path_m = run["path_length_m"].as_f64().expect("a path length");
    assert!((26f64.sqrt()..8.0).contains(&path_m), "{path_m}");
    let time_s = run["time_to_goal_s"].as_f64().expect("a time to the goal");
    assert!(time_s > 0.0 && time_s < 30.0, "{time_s}");
    // Every command the plant applied is a row of the CSV, stamped with its round trip: the
    // paper's Gamma(12, 0.015) delays (mean 0.18 s) on commands, the controller's time none.
    let facts = &run["external_controller"];
    let cycles = run["cycles"].as_u64().expect("cycles");
    assert!(cycles > 10, "{cycles}");
    assert_eq!(facts["commands_applied"].as_u64(), Some(cycles));
    assert_eq!(facts["plant_steps_missed"], 0);
    assert_eq!(facts["exit"], "stopped by the bench");
    let latency_ms = run["end_to_end_latency_ms"]["median"].as_f64().expect("a latency");
    assert!((100.0..300.0).contains(&latency_ms), "{latency_ms}");
    let csv = std::fs::read_to_string(out.join("open-field-external.csv")).expect("the CSV");
    assert_eq!(csv.lines().count() as u64, cycles + 1);
}

#[test]
fn the_mcap_of_an_external_run_reads_back_in_python_with_a_pose_state_and_command_per_applied_command() {
    let out = TempDir::new("external-test-mcap");
    let file = repo("examples/python-controller/open-field.toml").display().to_string();
    let (code, stderr, summary) = hilbench(&["run", &file, "--controller-cmd", &python_controller()], &out);
    assert_eq!(code, Some(0), "{stderr}");
    let run = &summary["runs"][0];
    let cycles = run["cycles"].as_u64().expect("cycles");
    assert!(cycles > 10, "{cycles}");
    // Read by the Python `mcap` package, an implementation independent of the writer.
    let mcap = out.join("open-field-external.mcap");
    let read: serde_json::Value = serde_json::from_str(
        hilbench_tests::python::run_script("read_mcap.py", &[mcap.to_str().expect("utf-8")]).trim(),
    )
    .expect("the script's JSON");
    assert_eq!(read["metadata"]["hilbench"]["controller"], "external");
    assert_eq!(read["log_times_monotonic"], true);
    assert_eq!(read["messages"]["/scene"].as_u64(), Some(1));
    // One pose per command the plant applied (the CSV's rows), and the vehicle where it ended.
    assert_eq!(read["messages"]["/pose"].as_u64(), Some(cycles + 1));
    assert_eq!(read["messages"]["/tf"].as_u64(), Some(cycles + 1));
    for topic in ["/state", "/command"] {
        let seen: Vec<u64> = read["cycles"][topic]
            .as_array()
            .expect(topic)
            .iter()
            .filter_map(serde_json::Value::as_u64)
            .collect();
        assert_eq!(seen, (0..cycles).collect::<Vec<_>>(), "{topic}");
    }
    // No plan: the bench does not see an external controller's.
    assert!(read["messages"].get("/plan").is_none_or(|n| n == 0), "{}", read["messages"]);
    let last = read["last_pose"]["position"].as_array().expect("the last pose");
    let final_m = run["final_position_m"].as_array().expect("final_position_m");
    for k in 0..3 {
        let (a, b) = (last[k].as_f64().expect("x"), final_m[k].as_f64().expect("x"));
        assert_eq!(a.to_bits(), b.to_bits(), "axis {k}: {a} vs {b}");
    }
}

/// `hilbench run` of open-field with the example controller run by the test script `wrapper`
/// (tests/python/), into a new directory named `out`.
fn fly_wrapped(wrapper: &str, out: &str) -> (Option<i32>, String, serde_json::Value) {
    let out = TempDir::new(out);
    let file = repo("examples/python-controller/open-field.toml").display().to_string();
    let command = format!(
        "'{}' '{}' '{}'",
        python().display(),
        hilbench_tests::python::scripts_dir().join(wrapper).display(),
        repo("examples/python-controller/controller.py").display()
    );
    hilbench(&["run", &file, "--controller-cmd", &command], &out)
}

#[test]
fn a_controller_printing_bytes_that_are_not_utf8_keeps_its_output_pipes_and_reaches_the_goal() {
    // The controller under a wrapper that prints invalid UTF-8 to stdout and stderr every
    // 10 ms, and exits 41 when a write fails (the pipe closed).
    let (code, stderr, summary) = fly_wrapped("noisy_controller.py", "external-test-noisy");
    assert_eq!(code, Some(0), "{stderr}");
    let run = &summary["runs"][0];
    assert_eq!((run["reached"].as_bool(), run["end_reason"].as_str()), (Some(true), Some("reached")));
    assert_eq!(run["external_controller"]["exit"], "stopped by the bench");
}

/// summary.json's run counts the three commands netem refused and explains them.
fn assert_three_refusals_counted_and_explained(run: &serde_json::Value) {
    assert_eq!(run["external_controller"]["commands_refused"], 3, "{run:#}");
    let explanation = run["explanation"].as_array().expect("explanation");
    assert!(
        explanation
            .iter()
            .any(|e| e.as_str().is_some_and(|e| e.contains("netem refused 3 of the controller's commands"))),
        "{explanation:?}"
    );
}

#[test]
fn commands_refused_as_invalid_are_counted_in_the_summary_and_explained() {
    // Three NaN commands, each refused to the controller with INVALID_ARGUMENT, then the flight.
    let (code, stderr, summary) = fly_wrapped("invalid_first_controller.py", "external-test-invalid");
    assert_eq!(code, Some(0), "{stderr}");
    let run = &summary["runs"][0];
    assert_eq!(run["reached"], true, "{run:#}");
    assert_three_refusals_counted_and_explained(run);
}

#[test]
fn commands_refused_before_a_controller_gives_up_are_still_counted_in_the_failed_runs_summary() {
    // Three NaN commands refused, then the controller exits 5: the run ends in an error, and
    // its summary still says what netem refused (it said null before).
    let out = TempDir::new("external-test-invalid-exit");
    let file = repo("examples/python-controller/open-field.toml").display().to_string();
    let command = format!(
        "'{}' '{}' '{}' --then-exit",
        python().display(),
        hilbench_tests::python::scripts_dir().join("invalid_first_controller.py").display(),
        repo("examples/python-controller/controller.py").display()
    );
    let (code, stderr, summary) = hilbench(&["run", &file, "--controller-cmd", &command], &out);
    assert_ne!(code, Some(0), "a controller that gave up: {stderr}");
    let run = &summary["runs"][0];
    assert_eq!(run["end_reason"], "error", "{run:#}");
    assert_three_refusals_counted_and_explained(run);
}

#[test]
fn a_process_the_controller_started_outside_its_process_group_is_killed_at_the_end_and_said() {
    let out = TempDir::new("external-test-setsid");
    let pid_file = out.join("escaped.pid");
    let file = repo("examples/python-controller/open-field.toml").display().to_string();
    // A child in a session of its own (setsid): the process group's signals do not reach it.
    let command = format!(
        "setsid sh -c 'echo $$ > \"{}\"; exec sleep 300' & exec {}",
        pid_file.display(),
        python_controller()
    );
    let (code, stderr, summary) = hilbench(&["run", &file, "--controller-cmd", &command], &out);
    assert_eq!(code, Some(0), "{stderr}");
    let exit = summary["runs"][0]["external_controller"]["exit"].as_str().expect("exit").to_string();
    assert_eq!(
        exit,
        "stopped by the bench; 1 process(es) it started outside its process group (setsid) killed"
    );
    let pid = std::fs::read_to_string(&pid_file).expect("the escaped child's pid");
    let stat = PathBuf::from(format!("/proc/{}/stat", pid.trim()));
    let started = Instant::now();
    while std::fs::read_to_string(&stat).is_ok_and(|s| !s.contains(") Z ")) {
        assert!(started.elapsed() < Duration::from_secs(10), "pid {} still runs", pid.trim());
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_controller_that_exits_with_an_error_fails_the_run_naming_its_status_and_last_output() {
    let out = TempDir::new("external-test-exit");
    let file = repo("examples/python-controller/open-field.toml").display().to_string();
    let command = "echo starting; echo 'no route to the moon' >&2; exit 4";
    let (code, stderr, summary) = hilbench(&["run", &file, "--controller-cmd", command], &out);
    assert_eq!(code, Some(1), "{stderr}");
    for expected in ["exited (exit status: 4) before the run ended", "no route to the moon"] {
        assert!(stderr.contains(expected), "{expected:?} not in {stderr}");
    }
    let error = summary["error"].as_str().expect("the error in summary.json");
    assert!(error.contains("exit status: 4"), "{error}");
    // The failed run is kept as far as the plant flew it: not at all.
    assert_eq!(summary["runs"][0]["end_reason"], "error");
    assert_eq!(summary["runs"][0]["external_controller"]["commands_applied"], 0);
}

#[test]
fn a_controller_that_stops_stepping_fails_the_run_at_the_stall_timeout_and_is_killed() {
    let dir = TempDir::new("external-test-hang");
    let pid_file = dir.join("controller.pid");
    // It writes its pid and sleeps without ever calling Step: plant time stands still.
    let command = format!("echo $$ > '{}'; exec sleep 60", pid_file.display());
    let settings = ExternalSettings { stall_timeout: Duration::from_secs(2), ..ExternalSettings::default() };
    let failure = fly(&open_field(), &command, settings).expect_err("a controller that never steps");
    let error = format!("{failure}");
    assert!(error.contains("plant time has not moved for 2 s"), "{error}");
    assert!(error.contains("stopped calling Step"), "{error}");
    let partial = failure.partial.expect("the plant's first sample is kept");
    assert_eq!(partial.summary.end_reason, mpc::RunEnd::Error);
    assert_eq!(partial.final_sample.time_ns, 0);
    // Its process is gone (or a zombie its parent has not reaped yet), not left sleeping.
    let pid = std::fs::read_to_string(&pid_file).expect("the pid file");
    let stat = PathBuf::from(format!("/proc/{}/stat", pid.trim()));
    let started = Instant::now();
    while std::fs::read_to_string(&stat).is_ok_and(|s| !s.contains(") Z ")) {
        assert!(started.elapsed() < Duration::from_secs(10), "pid {} still runs", pid.trim());
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn the_python_controller_flying_straight_into_a_paper_1_cylinder_is_reported_collided_with_exit_3() {
    let out = TempDir::new("external-test-collide");
    let file = repo("scenarios/paper-1.toml").display().to_string();
    let (code, stderr, summary) = hilbench(&["run", &file, "--controller-cmd", &python_controller()], &out);
    assert_eq!(code, Some(3), "{stderr}");
    let run = &summary["runs"][0];
    assert_eq!((run["collided"].as_bool(), run["end_reason"].as_str()), (Some(true), Some("collided")));
    assert_eq!(run["reached"], false);
    assert_eq!(run["collisions"][0]["kind"], "cylinder");
    assert!(run["min_clearance_m"].as_f64().is_some_and(|c| c < 0.0), "{}", run["min_clearance_m"]);
}

/// `hilbench ARGS` (a sweep) writing into `out`, which must succeed: its `sweep.json`.
fn sweep_json(args: &[&str], out: &Path) -> serde_json::Value {
    let run = Command::new(hilbench_tests::service_binary("hilbench"))
        .args(args)
        .args(["--quiet", "--no-plots", "--out"])
        .arg(out)
        .stdin(Stdio::null())
        .output()
        .expect("hilbench runs");
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    serde_json::from_str(&std::fs::read_to_string(out.join("sweep.json")).expect("sweep.json")).expect("JSON")
}

/// Twenty delay seeds: the sweep of issue 21's example (a loop here; `hilbench sweep
/// --controller-cmd` once the sweep exists).
#[test]
fn a_sweep_of_the_python_controller_under_twenty_delay_processes_reaches_every_goal_and_claims_no_solve_time()
{
    let out = TempDir::new("external-test-sweep");
    let file = repo("examples/python-controller/open-field.toml");
    let controller = python_controller();
    let sweep = sweep_json(
        &["sweep", file.to_str().expect("utf-8"), "--controller-cmd", &controller, "--jobs", "2"],
        out.path(),
    );
    assert_eq!(sweep["runs"], 20, "the file's sweep.runs");
    assert_eq!((sweep["reached"].as_u64(), sweep["collided"].as_u64()), (Some(20), Some(0)), "{sweep}");
    for family in ["gamma", "uniform"] {
        assert_eq!(sweep["families"][family]["runs"], 10, "families in turn: {family}");
    }
    // The runs drew different delays, so the flights differ.
    let path_m = &sweep["path_length_m"];
    assert_ne!(path_m["p50"], path_m["p95"], "{path_m}");
    // The bench never sees the controller's solver: the report says so, not "0.0 s" and dashes.
    let report = std::fs::read_to_string(out.path().join("report.md")).expect("report.md");
    assert!(
        report.contains("Solve time: the external controller's own, not seen")
            && !report.contains("Solve time (ms"),
        "{report}"
    );
}

/// A sweep of the Python controller that collides (paper-1, straight into a cylinder): runs.csv
/// names the controller `external`, sweep.json its command, and each failure's trace (as flown,
/// and shrunk) replays the collision with the command its header names: it holds every delay
/// netem drew by the end, commands in flight included, so the replay never runs out first.
#[test]
fn an_external_controllers_sweep_failure_replays_as_written_shrunk_or_not_with_the_command_it_names() {
    let _turn = hilbench_tests::CPU_HEAVY.blocking_lock();
    let out = TempDir::new("external-test-sweep-replay");
    let paper_1 = std::fs::read_to_string(repo("scenarios/paper-1.toml")).expect("paper-1.toml");
    let file = out.join("paper-1-sweep.toml");
    // Delays long against the controller's 20 Hz: several commands are in flight at the end.
    let table = "\n[sweep]\nruns = 1\nseed = 3\nshrink_runs = 12\n\n[[sweep.families]]\nkind = \"uniform\"\n\
                 min_s = 0.05\nmax_s = 0.2\n";
    std::fs::write(&file, format!("{paper_1}{table}")).expect("write the file");
    let file = file.display().to_string();
    let controller = python_controller();
    for shrink in [false, true] {
        let dir = out.join(if shrink { "shrunk" } else { "flown" });
        let mut args = vec!["sweep", &file, "--controller-cmd", &controller, "--jobs", "1"];
        if shrink {
            args.push("--shrink");
        }
        let sweep = sweep_json(&args, &dir);
        assert_eq!(sweep["controllers"], serde_json::json!(["external"]), "{sweep}");
        assert_eq!(sweep["controller_cmd"].as_str(), Some(controller.as_str()));
        let csv = std::fs::read_to_string(dir.join("runs.csv")).expect("runs.csv");
        assert!(csv.lines().nth(1).is_some_and(|l| l.starts_with("0,external,")), "{csv}");
        let failure = &sweep["failures"][0];
        assert_eq!(failure["outcome"], "collided", "{sweep}");
        if shrink {
            assert!(failure["shrink"]["reruns"].as_u64().is_some_and(|r| r > 0), "{failure}");
            assert!(sweep["shrinking"]["reruns"].as_u64().is_some_and(|r| r > 0), "{sweep}");
        }
        let replayed = &failure["replay"];
        let trace = dir.join(failure["trace_file"].as_str().expect("a trace"));
        let text = std::fs::read_to_string(&trace).expect("the trace");
        let replay_line = text.lines().find(|l| l.starts_with("# replay:")).expect("a replay line");
        assert!(
            replay_line.contains("--controller-cmd") && replay_line.contains("controller.py"),
            "{replay_line}"
        );
        // The replay, as its header says: the same collision at the same plant time.
        let again = out.join(if shrink { "replay-shrunk" } else { "replay-flown" });
        let trace = trace.display().to_string();
        let (code, stderr, summary) =
            hilbench(&["run", &file, "--controller-cmd", &controller, "--delay-trace", &trace], &again);
        assert_eq!(code, Some(3), "the replay collides: {stderr}");
        let run = &summary["runs"][0];
        assert_eq!(run["end_reason"], "collided", "{run}");
        assert_eq!(run["collisions"][0]["time_s"], replayed["end_time_s"], "{run} against {replayed}");
        assert_eq!(run["min_clearance_m"], replayed["min_clearance_m"], "{run} against {replayed}");
        assert_eq!(run["cycles"], replayed["cycles"], "{run} against {replayed}");
    }
}

/// `hilbench falsify --controller-cmd`: every run of the search is the Python controller's,
/// scored from the plant's truth, and the worst run's trace names the command that replays it.
#[test]
fn a_falsification_of_the_python_controller_flies_and_scores_every_run_and_names_its_replay() {
    // Two controllers at once: not beside the real-time tests, which need the cores on time.
    let _turn = hilbench_tests::CPU_HEAVY.blocking_lock();
    let out = TempDir::new("external-test-falsify");
    let open_field =
        std::fs::read_to_string(repo("examples/python-controller/open-field.toml")).expect("open-field.toml");
    let file = out.join("open-field-falsify.toml");
    let table = "\n[falsify]\nbudget = 4\nseed = 2\nproperty = \"collision_or_miss\"\n\
                 [falsify.signal]\npoints = 2\nduration_s = 6.0\nmax_delay_s = 0.33\n";
    std::fs::write(&file, format!("{open_field}{table}")).expect("write the file");
    let controller = python_controller();
    let run = Command::new(hilbench_tests::service_binary("hilbench"))
        .args(["falsify", file.to_str().expect("utf-8"), "--space", "signal", "--whole-budget"])
        .args([
            "--controller-cmd",
            &controller,
            "--jobs",
            "2",
            "--no-shrink",
            "--quiet",
            "--no-plots",
            "--out",
        ])
        .arg(out.join("out"))
        .stdin(Stdio::null())
        .output()
        .expect("hilbench runs");
    assert!(matches!(run.status.code(), Some(0 | 3)), "{}", String::from_utf8_lossy(&run.stderr));
    let v: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("out").join("falsify.json")).expect("falsify.json"),
    )
    .expect("JSON");
    assert_eq!((v["controller"].as_str(), v["driver"].as_str()), (Some("external"), Some("external")), "{v}");
    let search = &v["searches"][0];
    assert_eq!((search["runs"].as_u64(), search["errors"].as_u64()), (Some(4), Some(0)), "{search}");
    // Reached in an open field: no obstacle, so an infinite clearance (null in JSON).
    assert!(
        ["reached", "missed", "collided"].contains(&search["best"]["outcome"].as_str().unwrap_or("")),
        "{search}"
    );
    let replay = search["worst_trace"]["replay_command"].as_str().expect("a replay command");
    assert!(replay.contains("--controller-cmd") && replay.contains("controller.py"), "{replay}");
}

#[test]
fn two_lockstep_runs_of_the_python_controller_with_one_seed_are_identical() {
    let scenario = open_field();
    let a = fly(&scenario, &python_controller(), ExternalSettings::default()).expect("first run");
    let b = fly(&scenario, &python_controller(), ExternalSettings::default()).expect("second run");
    assert!(a.summary.reached);
    let entry = |s| serde_json::to_value(hilbench::output::summary::run_entry(s)).expect("serialisable");
    assert_eq!(entry(&a.summary), entry(&b.summary));
    // Each reset starts a new flight id (from a random point per plant): all else is equal.
    let mut b_final = b.final_sample.clone();
    b_final.flight_id = a.final_sample.flight_id;
    assert_eq!(a.final_sample, b_final);
    // Row for row (the CSV's text: its NaN cells compare as text).
    assert_eq!(hilbench::output::cycle_log::to_csv(&a.rows), hilbench::output::cycle_log::to_csv(&b.rows));
    // Every fact, netem's count of the delays drawn among them: it counts the commands sent
    // before the end's plant time, not those the controller sends while the bench stops it.
    assert!(a.facts.commands_delayed.is_some_and(|n| n >= a.facts.commands_applied), "{:?}", a.facts);
    assert_eq!(a.facts, b.facts);
}

#[test]
fn in_real_time_the_python_controller_streams_and_reaches_the_open_field_goal() {
    let _turn = hilbench_tests::CPU_HEAVY.blocking_lock();
    let run = fly_in(TimeMode::RealTime, &open_field(), &python_controller(), ExternalSettings::default())
        .unwrap_or_else(|e| panic!("{e}"));
    let s = &run.summary;
    assert!(s.reached && !s.collided, "{} at {:?}", s.end_reason, s.final_position_m);
    // A command per streamed sample (20 Hz) over several seconds of plant time.
    assert!(run.facts.commands_applied > 20, "{:?}", run.facts);
    assert_eq!(run.facts.plant_steps_missed, 0);
    assert_eq!(run.facts.exit, "stopped by the bench");
}

#[test]
fn an_empty_controller_command_a_bad_stall_timeout_or_a_mode_beside_it_is_a_usage_error() {
    let file = repo("examples/python-controller/open-field.toml").display().to_string();
    // Each with the flag the error names.
    for (args, named) in [
        (vec!["--controller-cmd", " "], "--controller-cmd"),
        (vec!["--controller-cmd", "true", "--mode", "nmpc"], "--mode"),
        (vec!["--controller-cmd", "true", "--stall-timeout-s", "NaN"], "--stall-timeout-s"),
        (vec!["--stall-timeout-s", "5"], "--controller-cmd"),
    ] {
        let output = Command::new(hilbench_tests::service_binary("hilbench"))
            .args(["run", &file])
            .args(&args)
            .output()
            .expect("hilbench runs");
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(named), "{args:?}: {stderr}");
    }
}

/// `--plant` with a user's controller: a plant in the other time mode is refused before the
/// controller starts, naming both modes (a real-time plant never advances on Step).
#[test]
fn a_users_controller_on_a_plant_in_the_other_time_mode_is_refused_naming_both() {
    let addr = hilbench_tests::free_loopback_address();
    let _plant = hilbench_tests::Service::start(
        "plant",
        &["--listen", &addr, "--time-mode", "real-time", "--scenario", "paper-2"],
    );
    let out = TempDir::new("external-time-mode");
    let file = repo("examples/python-controller/open-field.toml").display().to_string();
    let run = Command::new(hilbench_tests::service_binary("hilbench"))
        .args(["run", &file, "--controller-cmd", &python_controller(), "--plant", &addr, "--quiet"])
        .args(["--no-plots", "--out", &out.path().display().to_string()])
        .stdin(Stdio::null())
        .output()
        .expect("hilbench runs");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("runs in RealTime, this run needs Lockstep"), "{stderr}");
}
