//! `hilbench sweep`, `hilbench sweep-merge` and `hilbench run --sweep-run` as a user runs them:
//! the outputs and their keys, run i flown again alone, a failure's trace replayed (shrunk or
//! not), shards merged, the services' numbers, bad input refused before anything runs.

use std::path::Path;
use std::process::Command;

use hilbench::sweep::stats::{RunRow, from_csv};
use serde_json::Value;

use crate::common::{hilbench, json_of, out_dir, repo, s};

/// Long delays: the paper's controller collides within a few cycles (runs 0, 1, 3) or misses
/// the goal (run 2).
fn long_delays() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sweep-long-delays.toml").display().to_string()
}

/// `hilbench run FILE --in-process --no-plots --quiet ARGS --out OUT` to its end: a sweep's run
/// alone (`--sweep-run I`) or a failure's replay (`--delay-trace`).
fn run_alone(file: &str, args: &[&str], out: &Path) -> std::process::Output {
    hilbench(
        &[&["run", file, "--in-process", "--no-plots", "--quiet"][..], args, &["--out", s(out)]].concat(),
    )
}

fn rows_of(dir: &Path) -> Vec<RunRow> {
    from_csv(&std::fs::read_to_string(dir.join("runs.csv")).expect("runs.csv")).expect("a sweep's runs.csv")
}

/// A row without its wall-clock numbers.
fn deterministic(r: &RunRow) -> RunRow {
    RunRow {
        solve_ms_p50: None,
        solve_ms_p99: None,
        solve_ms_max: None,
        solver_s: None,
        wall_s: 0.0,
        ..r.clone()
    }
}

/// `sweep.json` without the wall-clock keys (`timing`, `solve_ms` at every level) and `shard`.
fn without_timing(mut v: Value) -> Value {
    fn strip(v: &mut Value) {
        if let Some(o) = v.as_object_mut() {
            o.remove("solve_ms");
            o.remove("timing");
            o.remove("shard");
            for (_, x) in o.iter_mut() {
                strip(x);
            }
        }
    }
    strip(&mut v);
    v
}

#[test]
fn a_sweep_writes_its_outputs_with_the_stable_keys_and_run_i_flies_again_alone_bit_for_bit() {
    let out = out_dir("sweep-outputs");
    let file = repo("scenarios/sweeps/paper-2-delays.toml");
    let sweep = hilbench(&["sweep", &file, "--runs", "6", "--jobs", "2", "--quiet", "--out", s(&out)]);
    assert!(sweep.status.success(), "{sweep:?}");
    let v = json_of(&out.join("sweep.json"));
    for key in [
        "runs",
        "reached",
        "collided",
        "collided_ground",
        "missed",
        "best_effort_cycles",
        "families",
        "failures",
    ] {
        assert!(v.get(key).is_some(), "sweep.json without {key}: {v}");
    }
    for (key, sub) in [
        ("min_clearance_m", &["p1", "p5", "p50"][..]),
        ("path_length_m", &["p50", "p95"]),
        ("time_to_goal_s", &["p50", "p95"]),
        ("solve_ms", &["p50", "p99", "max"]),
    ] {
        for p in sub {
            assert!(v[key].get(*p).is_some(), "sweep.json without {key}.{p}");
        }
    }
    assert_eq!(v["runs"], 6);
    let counted: u64 =
        ["reached", "collided", "missed", "errors"].iter().map(|k| v[*k].as_u64().expect("a count")).sum();
    assert_eq!(counted, 6, "every run counted once: {v}");
    let families: u64 = ["uniform", "gamma", "bursts"]
        .iter()
        .map(|f| v["families"][*f]["runs"].as_u64().expect("a family"))
        .sum();
    assert_eq!(families, 6);
    let rows = rows_of(&out);
    assert_eq!(rows.iter().map(|r| r.run).collect::<Vec<_>>(), (0..6).collect::<Vec<_>>());
    assert!(out.join("report.md").exists());
    for plot in ["sweep-clearance-cdf", "sweep-path-length", "sweep-failures-top"] {
        assert!(out.join("plots").join(format!("{plot}.png")).exists(), "{plot}");
    }
    // Run i alone, by index: the same flight, to the bit.
    for row in [&rows[1], &rows[4]] {
        let i = row.run.to_string();
        let alone = out_dir(&format!("sweep-run-{i}"));
        let run = run_alone(&file, &["--sweep-run", &i], &alone);
        assert!(run.status.code() == Some(0) || run.status.code() == Some(3), "{run:?}");
        let r = &json_of(&alone.join("summary.json"))["runs"][0];
        assert_eq!(r["min_clearance_m"].as_f64(), row.min_clearance_m, "run {i}");
        assert_eq!(r["path_length_m"].as_f64(), row.path_length_m, "run {i}");
        assert_eq!(r["cycles"].as_u64(), Some(row.cycles), "run {i}");
        assert_eq!(r["time_to_goal_s"].as_f64(), row.time_to_goal_s, "run {i}");
    }
}

#[test]
fn a_failures_trace_replays_it_bit_for_bit_shrunk_or_not() {
    let file = long_delays();
    for shrink in [false, true] {
        let out = out_dir(&format!("sweep-failures-{shrink}"));
        let mut args = vec!["sweep", &file, "--runs", "2", "--no-plots", "--quiet", "--out", s(&out)];
        if shrink {
            args.push("--shrink");
        }
        let sweep = hilbench(&args);
        assert!(sweep.status.success(), "{sweep:?}");
        let v = json_of(&out.join("sweep.json"));
        assert_eq!(v["collided"], 2, "the paper's controller collides under 0.31-0.33 s delays: {v}");
        for failure in v["failures"].as_array().expect("failures") {
            let trace = out.join(failure["trace_file"].as_str().expect("a trace file"));
            let (kept, flown) = (failure["trace_delays"].as_u64(), failure["flown_delays"].as_u64());
            if shrink {
                assert!(failure["shrink"]["reruns"].as_u64() > Some(0), "{failure}");
                // Smaller: fewer delays that are not zero (the zeros after them may be more:
                // a run with smaller delays can fail later).
                let text = std::fs::read_to_string(&trace).expect("the trace");
                let delays = delay::parse_trace_file(&text).expect("a trace").delays_s;
                assert_eq!(delays.len() as u64, kept.expect("trace_delays"), "{failure}");
                let nonzero = delays.iter().filter(|d| **d != 0.0).count() as u64;
                assert!(nonzero < flown.expect("flown_delays"), "{nonzero} not zero: {failure}");
            } else {
                assert_eq!(kept, flown, "{failure}");
            }
            let replay = out_dir(&format!("sweep-replay-{shrink}-{}", failure["run"]));
            let run = run_alone(&file, &["--mode", "multistage", "--delay-trace", s(&trace)], &replay);
            assert_eq!(run.status.code(), Some(3), "a collision again: {run:?}");
            let r = &json_of(&replay.join("summary.json"))["runs"][0];
            let want = &failure["replay"];
            for key in ["min_clearance_m", "path_length_m", "cycles", "end_reason"] {
                assert_eq!(r[key], want[key], "{key} of {}", trace.display());
            }
        }
    }
}

#[test]
fn a_spent_shrink_wall_budget_starts_no_rerun_and_each_failure_says_its_line() {
    let file = long_delays();
    let out = out_dir("sweep-shrink-wall");
    // A nanosecond of wall time: spent before the first rerun could start.
    let args = [
        "sweep",
        &file,
        "--runs",
        "2",
        "--no-plots",
        "--out",
        s(&out),
        "--shrink",
        "--shrink-wall-s",
        "1e-9",
    ];
    let sweep = hilbench(&args);
    let stderr = String::from_utf8_lossy(&sweep.stderr);
    assert!(sweep.status.success(), "{stderr}");
    let v = json_of(&out.join("sweep.json"));
    assert_eq!(v["collided"], 2, "{v}");
    assert_eq!(v["shrinking"]["reruns"], 0, "{v}");
    for failure in v["failures"].as_array().expect("failures") {
        assert_eq!(failure["shrink"]["complete"], false, "{failure}");
        assert_eq!(failure["trace_delays"], failure["flown_delays"], "nothing shrunk: {failure}");
    }
    // Not a terminal here: the lines are printed all the same.
    assert!(stderr.contains("stopping after") && stderr.contains("shrunk 1 of 2: run "), "{stderr}");
    assert!(stderr.contains("shrunk 2 of 2: run ") && stderr.contains("in 0 reruns (its budget"), "{stderr}");
}

/// The variables `--shard auto` reads.
const SCHEDULER_VARS: [&str; 7] = [
    "SLURM_ARRAY_TASK_ID",
    "SLURM_ARRAY_TASK_COUNT",
    "SLURM_ARRAY_TASK_MIN",
    "SLURM_ARRAY_TASK_MAX",
    "SLURM_ARRAY_TASK_STEP",
    "JOB_COMPLETION_INDEX",
    "HILBENCH_SHARD_COUNT",
];

/// `hilbench ARGS` with the scheduler's variables `vars` (and no others of theirs).
fn hilbench_under(vars: &[(&str, &str)], args: &[&str]) -> std::process::Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_hilbench"));
    for var in SCHEDULER_VARS {
        command.env_remove(var);
    }
    command.envs(vars.iter().copied()).args(args).output().expect("hilbench runs")
}

#[test]
fn two_shards_merged_equal_the_unsharded_sweep() {
    let file = long_delays();
    let whole = out_dir("sweep-whole");
    let run = |vars: &[(&str, &str)], extra: &[&str], dir: &Path| {
        let out = hilbench_under(
            vars,
            &[
                &["sweep", &file, "--runs", "4", "--jobs", "2", "--no-plots", "--quiet", "--out", s(dir)],
                extra,
            ]
            .concat(),
        );
        assert!(out.status.success(), "{out:?}");
    };
    run(&[], &[], &whole);
    let (a, b) = (out_dir("sweep-shard-0"), out_dir("sweep-shard-1"));
    // Shard 0 as a Kubernetes Indexed Job's pod runs it, shard 1 as a Slurm array's task
    // (--array=1-2: index = ID - MIN).
    run(&[("JOB_COMPLETION_INDEX", "0"), ("HILBENCH_SHARD_COUNT", "2")], &["--shard", "auto"], &a);
    let slurm = [
        ("SLURM_ARRAY_TASK_ID", "2"),
        ("SLURM_ARRAY_TASK_COUNT", "2"),
        ("SLURM_ARRAY_TASK_MIN", "1"),
        ("SLURM_ARRAY_TASK_MAX", "2"),
    ];
    run(&slurm, &["--shard", "auto/2"], &b);
    for (dir, shard, from) in [(&a, "0/2", "kubernetes"), (&b, "1/2", "slurm")] {
        let v = json_of(&dir.join("sweep.json"));
        assert_eq!((v["shard"].as_str(), v["shard_from"].as_str()), (Some(shard), Some(from)), "{v}");
    }
    assert_eq!(rows_of(&a).len() + rows_of(&b).len(), 4);
    assert_eq!(rows_of(&a).iter().map(|r| r.run).collect::<Vec<_>>(), [0, 1]);
    let merged = out_dir("sweep-merged");
    let merge = hilbench(&["sweep-merge", s(&b), s(&a), "--out", s(&merged), "--no-plots", "--quiet"]);
    assert!(merge.status.success(), "{merge:?}");
    assert_eq!(
        without_timing(json_of(&merged.join("sweep.json"))),
        without_timing(json_of(&whole.join("sweep.json")))
    );
    let strip = |rows: Vec<RunRow>| rows.iter().map(deterministic).collect::<Vec<_>>();
    assert_eq!(strip(rows_of(&merged)), strip(rows_of(&whole)));
    for f in json_of(&merged.join("sweep.json"))["failures"].as_array().expect("failures") {
        let trace = f["trace_file"].as_str().expect("a trace");
        assert_eq!(
            std::fs::read_to_string(merged.join(trace)).expect("merged trace"),
            std::fs::read_to_string(whole.join(trace)).expect("whole trace")
        );
    }
    // A shard merged twice is refused.
    let twice = hilbench(&["sweep-merge", s(&a), s(&a), "--out", s(&out_dir("sweep-twice")), "--quiet"]);
    assert_eq!(twice.status.code(), Some(1), "{twice:?}");
    assert!(String::from_utf8_lossy(&twice.stderr).contains("in two shards"), "{twice:?}");
    // A shard left out is refused, naming the runs it held.
    let half = hilbench(&["sweep-merge", s(&a), "--out", s(&out_dir("sweep-half")), "--quiet"]);
    assert_eq!(half.status.code(), Some(1), "{half:?}");
    let stderr = String::from_utf8_lossy(&half.stderr);
    assert!(stderr.contains("2 of the sweep's 4 runs with multistage are in no shard: runs 2-3"), "{stderr}");
}

#[test]
fn shard_auto_without_a_schedulers_variables_is_refused_naming_them_before_anything_runs() {
    let out = out_dir("sweep-auto-refused");
    for (vars, says) in [
        (&[][..], "SLURM_ARRAY_TASK_ID"),
        (&[("JOB_COMPLETION_INDEX", "1")][..], "HILBENCH_SHARD_COUNT"),
        (&[("SLURM_ARRAY_TASK_ID", "5"), ("SLURM_ARRAY_TASK_COUNT", "4")][..], "below"),
    ] {
        let run = hilbench_under(vars, &["sweep", &long_delays(), "--shard", "auto", "--out", s(&out)]);
        assert_eq!(run.status.code(), Some(1), "{vars:?}: {run:?}");
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(stderr.contains("--shard auto") && stderr.contains(says), "{vars:?}: {stderr}");
        assert!(!out.exists(), "{vars:?}: something ran");
    }
}

#[test]
fn a_sweep_over_grpc_gives_the_numbers_of_the_sweep_in_process() {
    let file = long_delays();
    let (local, grpc) = (out_dir("sweep-local"), out_dir("sweep-grpc"));
    for (dir, extra) in [(&local, None), (&grpc, Some("--grpc"))] {
        let mut args =
            vec!["sweep", &file, "--runs", "2", "--jobs", "1", "--no-plots", "--quiet", "--out", s(dir)];
        args.extend(extra);
        let out = hilbench(&args);
        assert!(out.status.success(), "{out:?}");
    }
    let strip = |rows: Vec<RunRow>| rows.iter().map(deterministic).collect::<Vec<_>>();
    let rows = strip(rows_of(&local));
    assert_eq!(rows.len(), 2);
    assert_eq!(strip(rows_of(&grpc)), rows);
    assert_eq!(json_of(&grpc.join("sweep.json"))["transport"], "grpc");
}

#[test]
fn a_run_past_the_time_limit_is_a_failure_with_its_reason_and_the_sweep_goes_on() {
    let out = out_dir("sweep-timeout");
    let sweep = hilbench(&[
        "sweep",
        &long_delays(),
        "--runs",
        "3",
        "--run-timeout-s",
        "0.001",
        "--no-plots",
        "--quiet",
        "--out",
        s(&out),
    ]);
    assert!(sweep.status.success(), "{sweep:?}");
    let v = json_of(&out.join("sweep.json"));
    assert_eq!(
        (v["runs"].as_u64(), v["timeouts"].as_u64(), v["errors"].as_u64()),
        (Some(3), Some(3), Some(3)),
        "{v}"
    );
    let rows = rows_of(&out);
    assert!(rows.iter().all(|r| r.outcome.name() == "timeout" && r.what.contains("time limit")), "{rows:?}");
}

#[test]
fn bad_flags_and_sweep_tables_are_refused_before_anything_runs() {
    let file = long_delays();
    for (args, flag) in [
        (vec!["--runs", "0"], "--runs"),
        (vec!["--shard", "3/2"], "--shard"),
        (vec!["--shard", "1"], "--shard"),
        (vec!["--jobs", "0"], "--jobs"),
        (vec!["--run-timeout-s", "nan"], "--run-timeout-s"),
    ] {
        let out = out_dir("sweep-refused");
        let run = hilbench(&[&["sweep", &file, "--out", s(&out)], &args[..]].concat());
        assert_eq!(run.status.code(), Some(2), "{args:?}: {run:?}");
        assert!(String::from_utf8_lossy(&run.stderr).contains(flag), "{args:?}: {run:?}");
        assert!(!out.exists(), "{args:?}: something ran");
    }
    let dir = out_dir("sweep-bad-table");
    std::fs::create_dir_all(&dir).expect("a directory");
    let text = std::fs::read_to_string(&file).expect("the test file");
    let bad = text.replace("delay_s = [0.31, 0.33]", "delay_s = [0.33, 0.31]");
    let line = bad.lines().position(|l| l.contains("[0.33, 0.31]")).expect("the line") + 1;
    let path = dir.join("bad.toml");
    std::fs::write(&path, bad).expect("write");
    let run = hilbench(&["sweep", s(&path), "--out", s(&dir.join("out"))]);
    assert_eq!(run.status.code(), Some(1), "{run:?}");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains(&format!("bad.toml:{line}: field `sweep.families[0].delay_s`")), "{stderr}");
    assert!(!dir.join("out").exists());
    // No [sweep] table, no --runs: each named.
    let none = hilbench(&["sweep", &repo("scenarios/paper-2.toml"), "--out", s(&dir.join("out"))]);
    assert_eq!(none.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&none.stderr).contains("no [sweep] table"), "{none:?}");
}

#[test]
fn a_sweep_of_more_runs_than_one_process_holds_is_refused_naming_runs_before_allocating_them() {
    // `--runs 100000000` aborted allocating 50 GB (exit 134). Refused at once, with the way out.
    let out = out_dir("sweep-too-many-runs");
    let started = std::time::Instant::now();
    let run = hilbench(&["sweep", &long_delays(), "--out", s(&out), "--runs", "100000000"]);
    assert_eq!(run.status.code(), Some(1), "{run:?}");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("--runs 100000000") && stderr.contains("--shard"), "{stderr}");
    assert!(!out.exists(), "something ran");
    assert!(started.elapsed() < std::time::Duration::from_secs(30), "{:?}", started.elapsed());
}

#[test]
fn ctrl_c_writes_the_runs_that_finished_marks_the_sweep_interrupted_and_exits_130() {
    let out = out_dir("sweep-interrupted");
    let mut child = Command::new(env!("CARGO_BIN_EXE_hilbench"))
        .args(["sweep", &long_delays(), "--runs", "5000", "--no-plots", "--quiet", "--out", s(&out)])
        .spawn()
        .expect("hilbench starts");
    // Ctrl-C once a run has finished (runs.csv is appended as runs finish: its header and a
    // row), far too early for 5000 runs, whatever the machine's speed.
    let started = std::time::Instant::now();
    while std::fs::read_to_string(out.join("runs.csv")).map_or(0, |t| t.lines().count()) < 2 {
        assert!(started.elapsed().as_secs() < 120, "no run in runs.csv");
        assert!(child.try_wait().expect("wait").is_none(), "the sweep ended before Ctrl-C");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let signal = Command::new("kill").args(["-INT", &child.id().to_string()]).status().expect("kill runs");
    assert!(signal.success());
    let status = child.wait_with_output().expect("hilbench ends").status;
    assert_eq!(status.code(), Some(130));
    let v = json_of(&out.join("sweep.json"));
    assert_eq!(v["interrupted"], true);
    let runs = v["runs"].as_u64().expect("runs");
    assert!((1..5000).contains(&runs), "{runs} runs");
    assert_eq!(rows_of(&out).len() as u64, runs);
}

#[test]
fn a_sweep_killed_mid_way_resumes_to_the_outputs_of_one_never_stopped_and_its_directory_is_refused_meanwhile()
{
    let file = repo("scenarios/sweeps/paper-2-delays.toml");
    let args = |dir: &Path| -> Vec<String> {
        ["sweep", &file, "--runs", "12", "--jobs", "2", "--no-plots", "--quiet", "--out", s(dir)]
            .map(String::from)
            .to_vec()
    };
    let whole = out_dir("sweep-never-stopped");
    let run = hilbench(&args(&whole).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(run.status.success(), "{run:?}");
    // kill -9 once a few runs are in runs.csv (appended as they finish).
    let killed = out_dir("sweep-killed");
    let mut child = Command::new(env!("CARGO_BIN_EXE_hilbench")).args(args(&killed)).spawn().expect("starts");
    let started = std::time::Instant::now();
    while std::fs::read_to_string(killed.join("runs.csv")).map_or(0, |t| t.lines().count()) < 4 {
        assert!(started.elapsed().as_secs() < 120, "no runs in runs.csv");
        assert!(child.try_wait().expect("wait").is_none(), "the sweep ended before it was killed");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.kill().expect("kill -9");
    child.wait().expect("reaped");
    let kept = rows_of(&killed);
    assert!(kept.len() >= 3 && kept.len() < 12, "{} rows kept", kept.len());
    assert!(!killed.join("sweep.json").exists());
    // The directory is refused to a new sweep and to a merge, saying how to go on.
    let again = hilbench(&args(&killed).iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(again.status.code(), Some(1), "{again:?}");
    assert!(String::from_utf8_lossy(&again.stderr).contains("did not finish (killed)"), "{again:?}");
    let merge = hilbench(&["sweep-merge", s(&killed), "--out", s(&out_dir("sweep-killed-merge")), "--quiet"]);
    assert_eq!(merge.status.code(), Some(1), "{merge:?}");
    assert!(String::from_utf8_lossy(&merge.stderr).contains("--resume"), "{merge:?}");
    // Resumed with another seed: refused, naming it; with the same flags: the runs it lacks.
    let mut other: Vec<String> = args(&killed);
    other.extend(["--seed".into(), "99".into(), "--resume".into()]);
    let refused = hilbench(&other.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(refused.status.code(), Some(1), "{refused:?}");
    assert!(String::from_utf8_lossy(&refused.stderr).contains("seed:"), "{refused:?}");
    let mut resume = args(&killed);
    resume.push("--resume".into());
    let resumed = hilbench(&resume.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(resumed.status.success(), "{resumed:?}");
    let strip = |rows: Vec<RunRow>| rows.iter().map(deterministic).collect::<Vec<_>>();
    assert_eq!(strip(rows_of(&killed)), strip(rows_of(&whole)));
    assert_eq!(
        without_timing(json_of(&killed.join("sweep.json"))),
        without_timing(json_of(&whole.join("sweep.json")))
    );
    // Finished: the outputs and their list are left, no journal, no marker.
    let mut names: Vec<String> = std::fs::read_dir(&killed)
        .expect("dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert!(names.iter().all(|n| !n.starts_with('.') || n == ".hilbench-outputs"), "{names:?}");
}

/// The long-delays file with only its short family (the paper's controller reaches the goal).
fn short_delays(dir: &Path) -> String {
    let text = std::fs::read_to_string(long_delays()).expect("the file");
    let text = text
        .replace("name = \"long\"\n", "name = \"long\"\nweight = 0.0\n")
        .replace("name = \"short\"\nweight = 0.0\n", "name = \"short\"\n");
    std::fs::create_dir_all(dir).expect("a dir");
    let path = dir.join("short.toml");
    std::fs::write(&path, text).expect("write");
    s(&path).to_string()
}

#[test]
fn until_bound_per_family_waits_for_each_familys_own_bound() {
    let dir = out_dir("until-bound-per-family");
    // Two short-delay families, drawn in turn: run i flies family i mod 2.
    let text = std::fs::read_to_string(long_delays()).expect("the file");
    let text = text
        .replace("[sweep]\n", "[sweep]\nfamily_choice = \"in_turn\"\n")
        .replace(
            "name = \"long\"\nkind = \"constant\"\ndelay_s = [0.31, 0.33]",
            "name = \"near\"\nkind = \"constant\"\ndelay_s = [0.0, 0.02]",
        )
        .replace("name = \"short\"\nweight = 0.0\n", "name = \"short\"\n");
    std::fs::create_dir_all(&dir).expect("a dir");
    let file = dir.join("two.toml");
    std::fs::write(&file, text).expect("write");
    let out = dir.join("out");
    let run = hilbench(&[
        "sweep",
        s(&file),
        "--until-bound",
        "0.3",
        "--per-family",
        "--jobs",
        "2",
        "--no-plots",
        "--out",
        s(&out),
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    // 11 runs without a failure put a family's bound below 0.3 (pooled, 11 runs in all would
    // have done): 22 in turn, 11 of each.
    let v = json_of(&out.join("sweep.json"));
    assert_eq!(
        (v["until_bound"]["stopped"].as_str(), v["until_bound"]["runs"].as_u64()),
        (Some("below"), Some(22)),
        "{v}"
    );
    for family in ["near", "short"] {
        assert_eq!(v["families"][family]["runs"], 11, "{family}: {v}");
        let upper = v["until_bound"]["by_family"][family]["multistage"]["upper"].as_f64().expect("a bound");
        assert!(upper < 0.3, "{family}: {upper}");
    }
    assert!(
        stderr.contains("below 30.000 % for each family") && stderr.contains("by family: near multistage"),
        "{stderr}"
    );
    // Without --until-bound the flag is refused.
    let refused = hilbench(&["sweep", s(&file), "--per-family", "--no-plots", "--out", s(&dir.join("x"))]);
    assert_eq!(refused.status.code(), Some(2), "{refused:?}");
}

#[test]
fn until_bound_stops_at_the_first_run_count_that_decides_whatever_the_jobs() {
    let dir = out_dir("until-bound");
    let file = short_delays(&dir);
    // 0 failures in n runs: the 95 % upper bound 1 - 0.025^(1/n) is below 0.3 from n = 11.
    let mut sweeps = Vec::new();
    for jobs in ["1", "3"] {
        let out = dir.join(format!("jobs-{jobs}"));
        let run = hilbench(&[
            "sweep",
            &file,
            "--until-bound",
            "0.3",
            "--jobs",
            jobs,
            "--no-plots",
            "--out",
            s(&out),
        ]);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(run.status.success(), "{stderr}");
        assert!(
            stderr.contains(
                "until-bound: after 11 runs without a failure the failure probability is below 30.000 %"
            ),
            "{stderr}"
        );
        let v = json_of(&out.join("sweep.json"));
        assert_eq!(v["until_bound"]["stopped"], "below", "{v}");
        assert_eq!(
            (v["until_bound"]["runs"].as_u64(), v["runs"].as_u64(), v["runs_planned"].as_u64()),
            (Some(11), Some(11), Some(11))
        );
        assert!(v["failure_probability"]["any"]["upper"].as_f64().expect("upper") < 0.3);
        assert_eq!(rows_of(&out).iter().map(|r| r.run).collect::<Vec<_>>(), (0..11).collect::<Vec<_>>());
        sweeps.push(v);
    }
    let strip = |v: &Value| {
        let mut v = without_timing(v.clone());
        v["until_bound"]["runs_left_out"] = Value::Null;
        v
    };
    assert_eq!(strip(&sweeps[0]), strip(&sweeps[1]), "the same sweep with 1 and 3 jobs");

    // A failing run stops it: the long delays' run 0 collides.
    let out = dir.join("failing");
    let run = hilbench(&[
        "sweep",
        &long_delays(),
        "--until-bound",
        "0.3",
        "--jobs",
        "2",
        "--no-plots",
        "--out",
        s(&out),
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let v = json_of(&out.join("sweep.json"));
    assert_eq!(
        (v["until_bound"]["stopped"].as_str(), v["until_bound"]["failed_run"].as_u64()),
        (Some("failure"), Some(0)),
        "{v}"
    );
    assert_eq!(rows_of(&out).len(), 1);

    // A cap the bound cannot be reached within is refused before anything flies, and before
    // --out is claimed: the command set right flies there, no --resume asked for.
    let out = dir.join("capped");
    let run = hilbench(&["sweep", &file, "--until-bound", "0.01", "--runs", "100", "--out", s(&out)]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("only after 368 runs, more than the cap of 100"), "{stderr}");
    assert!(!out.exists(), "the refused sweep claimed {}", out.display());
    let refused = hilbench(&["sweep", &file, "--until-bound", "1.5", "--out", s(&out)]);
    assert_eq!(refused.status.code(), Some(2));
    let right = hilbench(&["sweep", &file, "--until-bound", "0.3", "--out", s(&out)]);
    assert_eq!(right.status.code(), Some(0), "{}", String::from_utf8_lossy(&right.stderr));
}

#[test]
fn a_sweep_of_two_controllers_reports_each_apart_in_the_table_the_report_and_the_plots() {
    // Two runs, each flown by both controllers: 4 flights, but 2 runs, and every number per
    // controller (they were pooled: "4 of 2 runs", one row per family).
    let out = out_dir("sweep-two-controllers");
    let sweep = hilbench(&["sweep", &long_delays(), "--runs", "2", "--mode", "both", "--out", s(&out)]);
    assert!(sweep.status.success(), "{sweep:?}");
    let v = json_of(&out.join("sweep.json"));
    assert_eq!(v["runs"], 4, "sweep.json's runs counts flights: {v}");
    let report = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    assert!(
        report
            .contains(", 2 of 2 runs, seed 3, each flown by every controller (nmpc, multistage: 4 flights)"),
        "{report}"
    );
    for (label, c) in [("standard NMPC", "nmpc"), ("multi-stage NMPC", "multistage")] {
        let a = &v["by_controller"][c];
        assert_eq!(a["runs"], 2, "{c}: {v}");
        let heading = format!(
            "## {label} (`{c}`): 2 runs, {} reached, {} collided, {} missed, {} errors",
            a["reached"], a["collided"], a["missed"], a["errors"]
        );
        assert!(report.contains(&heading), "{heading:?} not in:\n{report}");
        // Its own table: the family's row counts this controller's runs only.
        let section = report.split(&heading).nth(1).expect("the section");
        let long = section.lines().find(|l| l.starts_with("| long |")).expect("the family's row");
        assert!(long.starts_with(&format!("| long | 2 | {} | {} |", a["reached"], a["collided"])), "{long}");
    }
    // The terminal table: a row per controller and family, and a count line per controller.
    let stdout = String::from_utf8_lossy(&sweep.stdout);
    assert!(stdout.contains("2 runs of paper-2-long-delays"), "{stdout}");
    for c in ["nmpc", "multistage"] {
        let a = &v["by_controller"][c];
        assert!(stdout.lines().any(|l| l.split_whitespace().take(3).eq([c, "long", "2"])), "{c}: {stdout}");
        assert!(
            stdout.contains(&format!("  {c}: {} reached, {} collided", a["reached"], a["collided"])),
            "{stdout}"
        );
    }
    for plot in ["sweep-clearance-cdf", "sweep-path-length", "sweep-failures-top"] {
        assert!(out.join("plots").join(format!("{plot}.png")).exists(), "{plot}");
    }
    let top = std::fs::read_to_string(out.join("plots/sweep-failures-top.svg")).expect("the top view");
    assert!(
        top.contains("standard NMPC (2 runs)") && top.contains("multi-stage NMPC (2 runs)"),
        "a panel each"
    );

    // One controller: no sections, the runs counted as before.
    let one = out_dir("sweep-one-controller");
    let sweep =
        hilbench(&["sweep", &long_delays(), "--runs", "2", "--no-plots", "--quiet", "--out", s(&one)]);
    assert!(sweep.status.success(), "{sweep:?}");
    let report = std::fs::read_to_string(one.join("report.md")).expect("report.md");
    assert!(report.contains(", 2 of 2 runs, seed 3, controller multistage,"), "{report}");
    assert!(!report.contains("(`multistage`)"), "{report}");
}

#[test]
fn sweep_merge_reads_only_regular_files_naming_the_shards_file() {
    let shard = out_dir("sweep-merge-not-a-file");
    std::fs::create_dir_all(shard.join("sweep.json")).expect("a folder where sweep.json should be");
    let merge =
        hilbench(&["sweep-merge", s(&shard), "--out", s(&out_dir("sweep-merge-not-a-file-out")), "--quiet"]);
    assert_eq!(merge.status.code(), Some(1), "{merge:?}");
    let stderr = String::from_utf8_lossy(&merge.stderr);
    assert!(stderr.contains("sweep.json: a directory; only a regular file is read"), "{stderr}");
}

#[test]
fn a_familys_loss_is_drawn_per_run_recorded_flown_as_lost_commands_and_kept_in_the_failure_trace() {
    let dir = out_dir("sweep-loss");
    // The short family (the controller reaches the goal) losing 20 to 30 % of its commands.
    let text = std::fs::read_to_string(short_delays(&dir)).expect("the file");
    let lossy = dir.join("lossy.toml");
    std::fs::write(&lossy, text.replace("max_s = 0.05\n", "max_s = 0.05\nloss = [0.2, 0.3]\n"))
        .expect("write");
    let out = dir.join("sweep");
    let sweep = hilbench(&["sweep", s(&lossy), "--runs", "2", "--no-plots", "--quiet", "--out", s(&out)]);
    assert!(sweep.status.success(), "{sweep:?}");
    let rows = rows_of(&out);
    assert_eq!(rows.len(), 2);
    for row in &rows {
        // The drawn loss, with the run's other drawn parameters.
        let loss: f64 = row
            .params
            .split(';')
            .find_map(|p| p.strip_prefix("loss="))
            .unwrap_or_else(|| panic!("no loss in {:?}", row.params))
            .parse()
            .expect("a number");
        assert!((0.2..=0.3).contains(&loss), "{loss}");
        // Flown alone, the run loses that share of its commands: the per-cycle CSV's lost
        // commands (an empty injected_delay_s) within 5 standard deviations of the binomial.
        let alone = dir.join(format!("run-{}", row.run));
        let i = row.run.to_string();
        let run = run_alone(s(&lossy), &["--sweep-run", &i], &alone);
        assert!(run.status.code() == Some(0) || run.status.code() == Some(3), "{run:?}");
        let csv = std::fs::read_to_string(alone.join(format!("paper-2-long-delays-{}.csv", row.controller)))
            .expect("the per-cycle CSV");
        let header: Vec<&str> = csv.lines().next().expect("a header").split(',').collect();
        let column = header.iter().position(|h| *h == "injected_delay_s").expect("injected_delay_s");
        let cells: Vec<&str> =
            csv.lines().skip(1).map(|l| l.split(',').nth(column).expect("a cell")).collect();
        let n = cells.len() as f64;
        let lost = cells.iter().filter(|c| c.is_empty()).count() as f64;
        assert_eq!(Some(row.cycles), Some(cells.len() as u64), "one line a cycle");
        let sd = (n * loss * (1.0 - loss)).sqrt();
        assert!(
            n > 50.0 && (lost - n * loss).abs() < 5.0 * sd,
            "run {i}: {lost} of {n} commands lost, p = {loss}"
        );
    }

    // A failing run's trace keeps its lost commands, and replays to the same end.
    let text = std::fs::read_to_string(long_delays()).expect("the file");
    let long_lossy = dir.join("long-lossy.toml");
    std::fs::write(
        &long_lossy,
        text.replace("delay_s = [0.31, 0.33]\n", "delay_s = [0.31, 0.33]\nloss = 0.5\n"),
    )
    .expect("write");
    let out = dir.join("failures");
    let sweep =
        hilbench(&["sweep", s(&long_lossy), "--runs", "1", "--no-plots", "--quiet", "--out", s(&out)]);
    assert!(sweep.status.success(), "{sweep:?}");
    let v = json_of(&out.join("sweep.json"));
    let failure = &v["failures"][0];
    let trace = out.join(failure["trace_file"].as_str().expect("a failure's trace"));
    let text = std::fs::read_to_string(&trace).expect("the trace");
    let entries = delay::parse_trace(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
    assert!(entries.iter().any(|d| delay::is_lost(*d)), "no lost command in\n{text}");
    let replay = dir.join("replay");
    let run = run_alone(s(&long_lossy), &["--delay-trace", s(&trace)], &replay);
    assert!(run.status.code() == Some(0) || run.status.code() == Some(3), "{run:?}");
    let r = &json_of(&replay.join("summary.json"))["runs"][0];
    for key in ["min_clearance_m", "path_length_m", "cycles", "end_reason"] {
        assert_eq!(r[key], failure["replay"][key], "{key} of {}", trace.display());
    }
}

/// Every file below `dir` with its contents, for "left as it was".
fn snapshot(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).expect("a directory") {
            let path = entry.expect("an entry").path();
            if path.is_dir() {
                stack.push(path);
            } else {
                out.push((path.display().to_string(), std::fs::read(&path).expect("a file")));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn a_merge_into_one_of_its_shards_or_of_shards_that_disagree_is_refused_leaving_every_directory_as_it_was() {
    let base = out_dir("sweep-merge-refused");
    std::fs::create_dir_all(&base).expect("dir");
    let file = long_delays();
    let shard = |i: usize, file: &str| {
        let dir = base.join(format!("sh{i}"));
        let shard = format!("{i}/2");
        let out = hilbench(&[
            "sweep",
            file,
            "--runs",
            "4",
            "--shard",
            &shard,
            "--no-plots",
            "--quiet",
            "--out",
            s(&dir),
        ]);
        assert!(out.status.success(), "{out:?}");
        dir
    };
    let (a, b) = (shard(0, &file), shard(1, &file));
    let before = (snapshot(&a), snapshot(&b));
    let refused = |dirs: &[&Path], out: &Path, says: &str| {
        let args: Vec<&str> = [
            &["sweep-merge"][..],
            &dirs.iter().map(|d| s(d)).collect::<Vec<_>>(),
            &["--out", s(out), "--quiet"],
        ]
        .concat();
        let merge = hilbench(&args);
        assert_eq!(merge.status.code(), Some(1), "{merge:?}");
        let stderr = String::from_utf8_lossy(&merge.stderr);
        assert!(stderr.contains(says), "{says:?} not in {stderr}");
    };
    // --out naming a shard, the folder that holds them, a folder inside one.
    refused(&[&a, &b], &a, "is the shard");
    refused(&[&a, &b], &base, "holds the shard");
    refused(&[&a, &b], &b.join("merged"), "lies inside the shard");
    assert_eq!((snapshot(&a), snapshot(&b)), before, "a refused merge touched a shard");
    // A shard flown from an edited file (an obstacle moved 0.5 m): refused, naming the fingerprint.
    let text = std::fs::read_to_string(&file).expect("the file");
    let edited_file = base.join("edited.toml");
    let moved = edited_file_with_an_obstacle_moved(&text);
    std::fs::write(&edited_file, moved).expect("write");
    let c = {
        let dir = base.join("sh1-edited");
        let out = hilbench(&[
            "sweep",
            s(&edited_file),
            "--runs",
            "4",
            "--shard",
            "1/2",
            "--no-plots",
            "--quiet",
            "--out",
            s(&dir),
        ]);
        assert!(out.status.success(), "{out:?}");
        dir
    };
    let merged = base.join("merged");
    refused(&[&a, &c], &merged, "flew another scenario than");
    // Nothing claimed by a refused merge: the right one then goes into the same --out.
    assert!(!merged.join(".hilbench-in-progress").exists());
    // A runs.csv edited from collided to reached while sweep.json lists the failure.
    let csv = std::fs::read_to_string(b.join("runs.csv")).expect("runs.csv");
    std::fs::write(b.join("runs.csv"), csv.replacen(",collided,", ",reached,", 1)).expect("write");
    refused(&[&a, &b], &merged, "runs.csv and sweep.json disagree");
    std::fs::write(b.join("runs.csv"), csv).expect("write back");
    let merge = hilbench(&["sweep-merge", s(&a), s(&b), "--out", s(&merged), "--no-plots", "--quiet"]);
    assert!(merge.status.success(), "{merge:?}");
}

/// The scenario file `text` with its first obstacle moved 0.5 m (x 3.5 -> 4.0).
fn edited_file_with_an_obstacle_moved(text: &str) -> String {
    assert!(text.contains("x_m = 3.5\n"), "the test file's first obstacle moved");
    text.replacen("x_m = 3.5\n", "x_m = 4.0\n", 1)
}
