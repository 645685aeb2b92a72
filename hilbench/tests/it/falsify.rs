//! `hilbench falsify` as a user runs it: a collision of the plan-check controller found within
//! a budget and its trace replayed by `hilbench run --delay-trace`; the same seed giving the
//! same search whatever `--jobs`; the stable keys of falsify.json; bad input refused before
//! anything flies.

use std::path::Path;
use std::process::Output;

use serde_json::Value;

use crate::common::{hilbench, json_of, out_dir, repo, s};

/// paper-2 with the plan-check controller: its `[falsify]` table searches a three-level signal
/// and the `[sweep]` families for a collision.
fn plan_check() -> String {
    repo("scenarios/sweeps/paper-2-delays-plan-check.toml")
}

/// `hilbench ARGS` run in `dir`.
fn hilbench_in(dir: &Path, args: &[&str]) -> Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_hilbench"))
        .current_dir(dir)
        .args(args)
        .output()
        .expect("hilbench runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// falsify.json without its wall-clock keys.
fn without_timing(mut v: Value) -> Value {
    fn strip(v: &mut Value) {
        match v {
            Value::Object(o) => {
                o.remove("timing");
                o.remove("wall_time_s");
                // Names the output directory's absolute path, which differs between the runs.
                o.remove("replay_command");
                o.values_mut().for_each(strip);
            }
            Value::Array(a) => a.iter_mut().for_each(strip),
            _ => {}
        }
    }
    strip(&mut v);
    v
}

#[test]
fn falsify_finds_a_collision_of_the_plan_check_controller_and_its_shrunk_trace_replays_it() {
    let out = out_dir("falsify-plan-check");
    let file = plan_check();
    // Run from the scenario's folder with a relative path, as a user does: the printed replay
    // must work from anywhere else.
    let folder = Path::new(&file).parent().expect("a folder").to_path_buf();
    let name = Path::new(&file).file_name().expect("a name").to_string_lossy().into_owned();
    let run = hilbench_in(
        &folder,
        &[
            "falsify",
            &name,
            "--space",
            "signal",
            "--method",
            "random",
            "--budget",
            "80",
            "--seed",
            "1",
            "--jobs",
            "2",
            "--shrink-runs",
            "12",
            "--no-plots",
            "--quiet",
            "--out",
            s(&out),
        ],
    );
    assert_eq!(run.status.code(), Some(3), "a failure found exits 3: {}", stderr(&run));
    let v = json_of(&out.join("falsify.json"));
    assert_eq!(v["schema"], "hilbench-falsify/1");
    assert_eq!((v["found"].as_bool(), v["property"].as_str()), (Some(true), Some("collision")), "{v}");
    let search = &v["searches"][0];
    assert_eq!((search["space"].as_str(), search["method"].as_str()), (Some("signal"), Some("random")));
    let first = search["first_failure_run"].as_u64().expect("a failure");
    assert_eq!(
        search["runs"].as_u64(),
        search["generations"].as_array().and_then(|g| g.last()).and_then(|g| g["runs"].as_u64()),
        "the last batch holds every run"
    );
    assert!(first <= search["runs"].as_u64().expect("runs"), "{search}");
    let best = search["best"]["score_m"].as_f64().expect("a best score");
    assert!(best < 0.0, "a collision scores below zero: {best}");
    assert_eq!(search["best"]["point"].as_object().map(|p| p.len()), Some(5), "3 levels and 2 switches");
    // The worst run's trace, shrunk, replays a collision with the numbers falsify.json gives.
    let worst = &search["worst_trace"];
    assert!(worst["shrink_reruns"].as_u64() > Some(0), "{worst}");
    let trace = out.join(worst["file"].as_str().expect("a trace file"));
    let header = std::fs::read_to_string(&trace).expect("the trace");
    // Smaller: fewer delays that are not zero than the run flew (zeros after them may be more).
    let delays = delay::parse_trace_file(&header).expect("a trace").delays_s;
    let nonzero = delays.iter().filter(|d| **d != 0.0).count() as u64;
    assert!(Some(nonzero) <= worst["original_delays"].as_u64(), "{nonzero} not zero: {worst}");
    assert!(header.contains("# replay: hilbench run"), "{header}");
    let replay = out_dir("falsify-plan-check-replay");
    let again = hilbench(&[
        "run",
        &file,
        "--in-process",
        "--mode",
        "multistage",
        "--no-plots",
        "--no-mcap",
        "--quiet",
        "--delay-trace",
        s(&trace),
        "--out",
        s(&replay),
    ]);
    assert_eq!(again.status.code(), Some(3), "a collision again: {}", stderr(&again));
    let r = &json_of(&replay.join("summary.json"))["runs"][0];
    for key in ["min_clearance_m", "cycles", "end_reason", "path_length_m"] {
        assert_eq!(r[key], worst["replay"][key], "{key} of {}", trace.display());
    }
    // The replay command as printed, pasted in another directory, flies the same run.
    let printed = worst["replay_command"].as_str().expect("a replay command");
    let words: Vec<&str> = printed.split_whitespace().collect();
    assert_eq!(words[..2], ["hilbench", "run"], "{printed}");
    let pasted = out_dir("falsify-plan-check-pasted");
    let elsewhere = std::env::temp_dir();
    let extra = ["--in-process", "--no-plots", "--no-mcap", "--quiet", "--out", s(&pasted)];
    let again = hilbench_in(&elsewhere, &[&words[1..], &extra[..]].concat());
    assert_eq!(again.status.code(), Some(3), "{printed}: {}", stderr(&again));
    let r = &json_of(&pasted.join("summary.json"))["runs"][0];
    assert_eq!(r["min_clearance_m"], worst["replay"]["min_clearance_m"], "{printed}");
    // Every run is a row of runs.csv.
    let csv = std::fs::read_to_string(out.join("runs.csv")).expect("runs.csv");
    assert_eq!(csv.lines().count() as u64 - 1, search["runs"].as_u64().expect("runs"));
    assert!(out.join("report.md").exists());
}

#[test]
fn the_same_seed_gives_the_same_cmaes_search_whatever_the_jobs() {
    let file = plan_check();
    let mut seen = Vec::new();
    for jobs in ["1", "2"] {
        let out = out_dir(&format!("falsify-determinism-{jobs}"));
        let run = hilbench(&[
            "falsify",
            &file,
            "--space",
            "gamma",
            "--budget",
            "14",
            "--seed",
            "7",
            "--jobs",
            jobs,
            "--whole-budget",
            "--no-shrink",
            "--quiet",
            "--out",
            s(&out),
        ]);
        assert!(matches!(run.status.code(), Some(0 | 3)), "{}", stderr(&run));
        let v = json_of(&out.join("falsify.json"));
        assert_eq!(v["searches"][0]["runs"], 14, "--whole-budget flies the budget: {v}");
        assert_eq!(v["searches"][0]["dims"][0]["name"], "shape");
        let csv = std::fs::read_to_string(out.join("runs.csv")).expect("runs.csv");
        // Without the wall-clock column.
        let csv: Vec<String> = csv
            .lines()
            .map(|l| {
                l.split(',')
                    .enumerate()
                    .filter(|(i, _)| *i != 8)
                    .map(|(_, c)| c)
                    .collect::<Vec<_>>()
                    .join(",")
            })
            .collect();
        assert!(out.join("plots/falsify-convergence-gamma.svg").exists(), "the convergence plot");
        seen.push((without_timing(v), csv));
    }
    assert_eq!(seen[0], seen[1], "--jobs 1 and --jobs 2 give one search");
}

#[test]
fn bad_flags_and_files_without_a_falsify_table_are_refused_before_anything_flies() {
    let out = out_dir("falsify-refused");
    let file = plan_check();
    let cases: [(&[&str], &str); 5] = [
        (&["falsify", &file, "--space", "nope"], "`nope` is none of the file's spaces"),
        (&["falsify", &repo("scenarios/paper-2.toml")], "no [falsify] table"),
        (&["falsify", &file, "--budget", "0"], "--budget"),
        (&["falsify", &file, "--mode", "both"], "one controller per falsification"),
        (&["falsify", &file, "--method", "annealing"], "--method"),
    ];
    for (args, want) in cases {
        let mut args = args.to_vec();
        args.extend(["--quiet", "--out", s(&out)]);
        let run = hilbench(&args);
        assert!(matches!(run.status.code(), Some(1 | 2)), "{args:?}: {run:?}");
        assert!(stderr(&run).contains(want), "{args:?}: {}", stderr(&run));
        assert!(!out.join("falsify.json").exists(), "{args:?} flew");
    }
}

#[test]
fn a_falsification_killed_mid_search_resumes_to_the_outputs_of_one_never_stopped() {
    let file = plan_check();
    let args = |dir: &Path| -> Vec<String> {
        [
            "falsify",
            &file,
            "--space",
            "gamma",
            "--budget",
            "14",
            "--seed",
            "7",
            "--jobs",
            "2",
            "--whole-budget",
            "--no-shrink",
            "--no-plots",
            "--quiet",
            "--out",
            s(dir),
        ]
        .map(String::from)
        .to_vec()
    };
    let whole = out_dir("falsify-never-stopped");
    let run = hilbench(&args(&whole).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(matches!(run.status.code(), Some(0 | 3)), "{}", stderr(&run));
    // kill -9 once a few runs are in the journal (a line each as they finish).
    let killed = out_dir("falsify-killed");
    let journal = killed.join(".falsify-journal.jsonl");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_hilbench"))
        .args(args(&killed))
        .spawn()
        .expect("starts");
    let started = std::time::Instant::now();
    while std::fs::read_to_string(&journal).map_or(0, |t| t.lines().count()) < 4 {
        assert!(started.elapsed().as_secs() < 120, "no runs in the journal");
        assert!(child.try_wait().expect("wait").is_none(), "the falsification ended before it was killed");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.kill().expect("kill -9");
    child.wait().expect("reaped");
    let kept = std::fs::read_to_string(&journal).expect("the journal is kept").lines().count() - 1;
    assert!((3..14).contains(&kept), "{kept} runs kept");
    assert!(!killed.join("falsify.json").exists());
    // The directory is refused to a new falsification, saying how to go on.
    let again = hilbench(&args(&killed).iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(again.status.code(), Some(1), "{again:?}");
    assert!(
        stderr(&again).contains("did not finish (killed)") && stderr(&again).contains("--resume"),
        "{again:?}"
    );
    // Resumed with another seed: refused, naming it; with the same flags: the runs it lacks.
    let mut other = args(&killed);
    let seed = other.iter().position(|a| a == "--seed").expect("--seed") + 1;
    other[seed] = "8".into();
    other.push("--resume".into());
    let refused = hilbench(&other.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(refused.status.code(), Some(1), "{refused:?}");
    assert!(stderr(&refused).contains("seed: 7 then, 8 now"), "{refused:?}");
    let mut resume = args(&killed);
    resume.push("--resume".into());
    let resumed = hilbench(&resume.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(resumed.status.code(), run.status.code(), "{}", stderr(&resumed));
    assert_eq!(
        without_timing(json_of(&killed.join("falsify.json"))),
        without_timing(json_of(&whole.join("falsify.json")))
    );
    // runs.csv without its wall-clock column; the worst run's trace as the never-stopped one's.
    let csv = |dir: &Path| -> Vec<String> {
        let text = std::fs::read_to_string(dir.join("runs.csv")).expect("runs.csv");
        text.lines()
            .map(|l| l.split(',').enumerate().filter(|(i, _)| *i != 8).map(|(_, c)| c).collect())
            .collect()
    };
    assert_eq!(csv(&killed), csv(&whole));
    let trace = json_of(&whole.join("falsify.json"))["searches"][0]["worst_trace"]["file"].clone();
    let trace = trace.as_str().expect("the worst run's trace file");
    let delays = |dir: &Path| {
        let text = std::fs::read_to_string(dir.join(trace)).expect("the trace");
        text.lines().filter(|l| !l.starts_with('#')).map(str::to_string).collect::<Vec<_>>()
    };
    assert_eq!(delays(&killed), delays(&whole));
    assert!(!journal.exists(), "the journal goes once the outputs are written");
}
