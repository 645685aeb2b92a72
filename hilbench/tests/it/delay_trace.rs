//! `hilbench run --delay-trace`: a recorded trace replayed as a file's round trip, as a user
//! gives it on the command line.

use crate::common::csv_without_solve_times;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn hilbench(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hilbench")).args(args).output().expect("hilbench runs")
}

fn repo(path: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path).display().to_string()
}

fn out_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn a_delay_trace_replaces_the_files_delays_and_summary_json_and_the_report_name_it() {
    let out = out_dir("delay-trace-replaces");
    let (file, trace) = (repo("scenarios/slalom-4.toml"), repo("scenarios/wifi-trace.csv"));
    let args = [
        "run",
        &file,
        "--in-process",
        "--mode",
        "nmpc",
        "--no-plots",
        "--quiet",
        "--seed",
        "99",
        "--delay-trace",
        &trace,
    ];
    let run = hilbench(&[&args[..], &["--out", out.to_str().expect("utf-8")]].concat());
    assert!(run.status.success(), "{run:?}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary.json"))
            .expect("JSON");
    let profile = &summary["runs"][0]["delay_profile"];
    assert_eq!(profile["source"], "scenario", "{profile}");
    assert_eq!(profile["delays"]["kind"], "trace", "{profile}");
    assert_eq!(profile["delays"]["file"], trace.as_str(), "{profile}");
    let report = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    assert!(report.contains(&format!("delays: trace {trace} on commands, seed 99")), "{report}");
    // The CSV's measured delays are the trace's, line by line (cycle k measures cycle k-1's).
    let trace_delays =
        delay::parse_trace(&std::fs::read_to_string(&trace).expect("the trace")).expect("a trace");
    let csv = std::fs::read_to_string(out.join("slalom-4-nmpc.csv")).expect("the per-cycle CSV");
    let header: Vec<&str> = csv.lines().next().expect("a header").split(',').collect();
    let column = header.iter().position(|h| *h == "known_delay_s").expect("a known_delay_s column");
    let measured: Vec<f64> = csv
        .lines()
        .skip(2)
        .map(|l| l.split(',').nth(column).expect("a cell").parse().expect("a number"))
        .collect();
    assert!(measured.len() > 100, "{} cycles", measured.len());
    // The delay injected on cycle k's command is line k of the trace, to the nanosecond.
    let injected = header.iter().position(|h| *h == "injected_delay_s").expect("an injected_delay_s column");
    for (k, line) in csv.lines().skip(1).enumerate() {
        let cell: f64 = line.split(',').nth(injected).expect("a cell").parse().expect("a number");
        assert_eq!((cell * 1e9).round(), (trace_delays[k] * 1e9).round(), "cycle {k}: injected delay");
    }
    for (k, d) in measured.iter().enumerate() {
        assert!(
            (d - trace_delays[k]).abs() < 1e-9,
            "cycle {}: measured {d}, trace {}",
            k + 1,
            trace_delays[k]
        );
    }
}

#[test]
fn a_missing_or_bad_delay_trace_is_refused_naming_it() {
    let file = repo("scenarios/slalom-4.toml");
    let missing = hilbench(&["run", &file, "--in-process", "--quiet", "--delay-trace", "no-such-trace.csv"]);
    assert_eq!(missing.status.code(), Some(1), "{missing:?}");
    let stderr = String::from_utf8_lossy(&missing.stderr);
    assert!(stderr.contains("--delay-trace") && stderr.contains("no-such-trace.csv"), "{stderr}");
    let dir = out_dir("delay-trace-bad");
    std::fs::create_dir_all(&dir).expect("a temporary directory");
    let bad = dir.join("bad.csv");
    std::fs::write(&bad, "delay_s\n0.1\n-0.2\n").expect("write the trace");
    let run =
        hilbench(&["run", &file, "--in-process", "--quiet", "--delay-trace", bad.to_str().expect("utf-8")]);
    assert_eq!(run.status.code(), Some(1), "{run:?}");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("bad.csv") && stderr.contains("line 3"), "{stderr}");
}

#[test]
fn a_run_that_fails_still_writes_summary_json_with_the_error_and_exits_1() {
    let dir = out_dir("delay-trace-runs-out");
    std::fs::create_dir_all(&dir).expect("a temporary directory");
    let short = dir.join("short.csv");
    std::fs::write(&short, "delay_s\n0.1\n0.2\n0.05\n").expect("write the trace");
    let out = dir.join("out");
    let file = repo("scenarios/slalom-4.toml");
    // Over the services: netem refuses cycle 3's command, the controller ends its episode.
    let run = hilbench(&[
        "run",
        &file,
        "--mode",
        "nmpc",
        "--no-plots",
        "--quiet",
        "--delay-trace",
        short.to_str().expect("utf-8"),
        "--out",
        out.to_str().expect("utf-8"),
    ]);
    assert_eq!(run.status.code(), Some(1), "{run:?}");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("short.csv") && stderr.contains("summary.json"), "{stderr}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary.json"))
            .expect("JSON");
    let error = summary["error"].as_str().expect("an error key");
    assert!(error.contains("short.csv") && error.contains("message 3"), "{error}");
}

#[test]
fn the_scenario_written_beside_the_results_flies_the_same_run_again() {
    let first = out_dir("as-flown-first");
    let again = out_dir("as-flown-again");
    let file = repo("scenarios/wifi-trace.toml");
    let run = |file: &str, out: &Path, extra: &[&str]| {
        let args =
            ["run", file, "--in-process", "--no-plots", "--quiet", "--out", out.to_str().expect("utf-8")];
        let done = hilbench(&[&args[..], extra].concat());
        assert!(done.status.success(), "{done:?}");
    };
    run(&file, &first, &["--seed", "9", "--continue-after-collision"]);
    let written = first.join("slalom-4-wifi-trace.scenario.toml");
    let text = std::fs::read_to_string(&written).expect("the scenario as flown");
    assert!(text.contains("seed = 9") && text.contains("continue_after_collision = true"), "{text}");
    // Its trace is inline: the file flies from anywhere, without wifi-trace.csv beside it.
    run(written.to_str().expect("utf-8"), &again, &[]);
    for mode in ["nmpc", "multistage"] {
        let csv = format!("slalom-4-wifi-trace-{mode}.csv");
        assert_eq!(
            csv_without_solve_times(&first.join(&csv)),
            csv_without_solve_times(&again.join(&csv)),
            "{mode}"
        );
    }
}
