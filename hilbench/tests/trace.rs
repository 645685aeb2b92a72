//! `hilbench trace import|stats|fit` on a real ping recording (linkfit/tests/data): the lost
//! probes become `lost` lines, the statistics count them, the fit's tables load as a scenario
//! file's, and a bad line is refused with its number.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn hilbench(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hilbench")).args(args).output().expect("hilbench runs")
}

fn fixture(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../linkfit/tests/data").join(name).display().to_string()
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("hilbench-trace-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temp dir");
    dir
}

#[test]
fn a_ping_recording_imports_with_its_losses_and_fits_into_tables_the_loader_takes() {
    let dir = temp("ping");
    let trace = dir.join("link.csv");
    let out = hilbench(&[
        "trace",
        "import",
        "--format",
        "ping",
        &fixture("ping-linux-loopback.txt"),
        "--out",
        &trace.display().to_string(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(&trace).expect("the trace");
    assert_eq!(text.lines().filter(|l| *l == "lost").count(), 8, "{text}");
    assert!(text.contains("# tool: ping"), "{text}");

    let out = hilbench(&["trace", "stats", &trace.display().to_string(), "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stats: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!((stats["count"].as_u64(), stats["losses"].as_u64()), (Some(200), Some(8)));

    let out = hilbench(&["trace", "fit", &trace.display().to_string(), "--seed", "1"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let tables = String::from_utf8(out.stdout).expect("UTF-8");
    let delays = tables.split("[[sweep.families]]").next().expect("the scenario table").to_string();
    // The [scenario.delays] table in a scenario file: the loader takes it.
    let paper_2 =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/paper-2.toml"))
            .expect("paper-2");
    let start = paper_2.find("[scenario.delays]").expect("paper-2's delays");
    let end = paper_2[start + 1..].find("\n[").map_or(paper_2.len(), |i| start + 1 + i);
    let file = dir.join("fitted.toml");
    let text = format!("{}{}{}", &paper_2[..start], delays, &paper_2[end..])
        .replace("name = \"paper-2\"", "name = \"fitted-link\"");
    std::fs::write(&file, text).expect("write");
    hilbench::scenario_file::ScenarioFile::load(&file).unwrap_or_else(|e| panic!("{e}\n{delays}"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_bad_line_is_refused_with_its_number_or_skipped_and_counted() {
    let dir = temp("bad");
    let csv = dir.join("rtt.csv");
    std::fs::write(&csv, "rtt_ms\n12.5\n13\nfast\n14\n").expect("write");
    let out_file = dir.join("out.csv").display().to_string();
    let args = ["trace", "import", "--format", "csv", csv.to_str().expect("UTF-8"), "--out", &out_file];
    let out = hilbench(&args);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("line 4"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = hilbench(&[&args[..], &["--skip-bad"]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(&out_file).expect("the trace");
    assert_eq!(text.lines().filter(|l| !l.starts_with('#') && *l != "delay_s").count(), 3, "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}
