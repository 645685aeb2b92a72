//! The robustness campaigns of docs/robustness.md as fixed-seed property tests: on every field
//! of `scenarios/fields/` (obstacle fields the controller was not tuned on, and paper-1/2 with
//! the bench's defaults), under every delay process of their `[sweep]` table (Gamma with shapes
//! 2-30, lognormal with 6-19 % of delays beyond the largest sampling time, Pareto tails, a
//! regime switching between about 0.05 and 0.3 s, uniform over [0, 0.33] s), ten runs each, the
//! multi-stage controller with a scenario file's defaults (our PANOC, the fail-safe check, the plant's
//! braking watchdog) reaches the goal without touching a cylinder or the ground. The recorded
//! campaigns (50 runs per field and process) are in docs/robustness.md.

use std::path::Path;
use std::process::Command;

/// Runs per field: ten per delay family (the files pick families in turn).
const RUNS: u64 = 50;

/// Sweeps `field` and checks its counts: at most `max_collisions` runs collided, every other
/// run reached the goal.
fn campaign(field: &str, max_collisions: u64) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let file = root.join("scenarios/fields").join(format!("{field}.toml"));
    let out = std::env::temp_dir().join(format!("hilbench-campaign-{field}-{}", std::process::id()));
    let run = Command::new(env!("CARGO_BIN_EXE_hilbench"))
        .args(["sweep", file.to_str().expect("utf-8"), "--runs", &RUNS.to_string(), "--quiet", "--no-plots"])
        .arg("--out")
        .arg(&out)
        .output()
        .expect("hilbench runs");
    assert!(run.status.success(), "{run:?}");
    let text = std::fs::read_to_string(out.join("sweep.json")).expect("sweep.json");
    let sweep: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    let families = sweep["families"].as_object().expect("families by name");
    assert_eq!(families.len(), 5, "{field}: five delay processes");
    for (name, f) in families {
        assert_eq!(f["runs"], RUNS / 5, "{field} {name}: runs per process");
    }
    assert_eq!(sweep["runs"], RUNS);
    let collided = sweep["collided"].as_u64().expect("collided");
    assert!(collided <= max_collisions, "{field}: {collided} collisions; failures: {}", sweep["failures"]);
    assert_eq!(
        sweep["reached"].as_u64(),
        Some(RUNS - collided),
        "{field}: every run that did not collide reaches the goal; failures: {}",
        sweep["failures"]
    );
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn the_multistage_controller_reaches_the_goal_clear_on_a_staggered_slalom_under_every_delay_process() {
    campaign("staggered-slalom", 0);
}

#[test]
fn the_multistage_controller_reaches_the_goal_clear_through_a_narrow_gap_under_every_delay_process() {
    campaign("narrow-gap", 0);
}

#[test]
fn the_multistage_controller_reaches_the_goal_clear_past_an_asymmetric_cylinder_under_every_delay_process() {
    campaign("asymmetric-single", 0);
}

#[test]
fn the_multistage_controller_reaches_the_goal_clear_on_paper_1_under_every_delay_process() {
    campaign("paper-1-field", 0);
}

#[test]
fn the_multistage_controller_reaches_the_goal_clear_on_paper_2_under_every_delay_process() {
    campaign("paper-2-field", 0);
}
