//! A run that went wrong says why where the user looks: the line printed per run, report.md,
//! summary.json and the per-cycle CSV's `decision` and `reason` columns.

use crate::common;

use std::path::Path;
use std::process::Command;

/// paper-2 with the multi-stage controller and OpEn's PANOC, started hovering 5 cm from its
/// first cylinder's surface with a 0.2 m margin: until it has moved away, no candidate passes
/// the safety layer's check, and it flies on best-effort commands. (Our PANOC finds a candidate
/// that passes from there: the accounting under test needs one that does not.)
fn tight_start(dir: &Path) -> std::path::PathBuf {
    common::paper_2_variant(
        dir,
        "tight",
        &[
            (
                "modes = [\"nmpc\", \"multistage\"]",
                "modes = [\"multistage\"]\nobstacle_margin_m = 0.2\nsolver = \"open\"",
            ),
            ("floor = false\n", ""),
            ("delay_compensation = false\n", ""),
            (
                "start = [3.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]",
                "start = [3.8, 1.5, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]",
            ),
            ("max_duration_s = 60.0", "max_duration_s = 10.0"),
        ],
    )
}

#[test]
fn best_effort_cycles_are_counted_and_explained_in_the_printout_report_summary_and_csv() {
    let dir = std::env::temp_dir().join(format!("hilbench-explanation-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary directory");
    let file = tight_start(&dir);
    let out = dir.join("out");
    let run = Command::new(env!("CARGO_BIN_EXE_hilbench"))
        .args(["run", file.to_str().expect("utf-8"), "--in-process", "--no-plots", "--out"])
        .arg(&out)
        .output()
        .expect("hilbench runs");
    assert!(run.status.success(), "{run:?}");
    let stdout = String::from_utf8_lossy(&run.stdout);

    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary.json"))
            .expect("JSON");
    let r = &summary["runs"][0];
    let best_effort = r["best_effort_cycles"].as_u64().expect("best_effort_cycles");
    assert!(best_effort > 0, "{r}");
    assert_eq!(r["decisions"]["best_effort"].as_u64(), Some(best_effort));
    assert!(r["fallbacks"].as_u64().expect("fallbacks") >= best_effort);
    let first = r["explanation"][0].as_str().expect("an explanation");
    assert!(first.starts_with(&format!("{best_effort} of ")), "{first}");

    assert!(stdout.contains(&format!("tight multistage: {first}")), "printed per run: {stdout}");
    let report = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    assert!(
        report.contains(&format!("tight with multistage reached its goal, but:\n\n- {first}")),
        "{report}"
    );

    let csv = std::fs::read_to_string(out.join("tight-multistage.csv")).expect("the per-cycle log");
    let header: Vec<&str> = csv.lines().next().expect("a header").split(',').collect();
    let decision = header.iter().position(|c| *c == "decision").expect("a decision column");
    assert_eq!(header.last(), Some(&"reason"));
    let rows: Vec<&str> =
        csv.lines().skip(1).filter(|l| l.split(',').nth(decision) == Some("best_effort")).collect();
    assert_eq!(rows.len() as u64, best_effort);
    assert!(rows.iter().all(|l| l.contains(" best effort (panoc: ")), "{rows:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
