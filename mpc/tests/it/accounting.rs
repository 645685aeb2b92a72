//! The run summary tells the truth about the safety layer: a cycle that sent a command no
//! check verified is counted as `best_effort` (and as a fallback), and a run that goes wrong
//! says why in words.

use mav::Scenario;
use mpc::{ClosedLoopSettings, ControllerMode, run_closed_loop};

/// paper-2 with the start moved to `gap_m` from the surface of its first cylinder, 1 m up.
fn start_near_a_cylinder(gap_m: f64) -> Scenario {
    let mut scenario = Scenario::paper_2();
    let c = scenario.obstacles[0];
    scenario.start = [c.x_m + c.radius_m + gap_m, c.y_m, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    scenario.max_duration_s = 3.0;
    scenario
}

#[test]
fn cycles_that_sent_an_unverified_command_are_counted_as_best_effort_fallbacks_and_explained() {
    let mut settings = ClosedLoopSettings::paper(ControllerMode::Multistage);
    // The check asks for more clearance than the start has: nothing passes it at first.
    let safety = settings.episode.safety.as_mut().expect("paper mode has the safety layer");
    safety.required_clearance_m = 0.2;
    let (summary, traces) = run_closed_loop(&start_near_a_cylinder(0.05), &settings).expect("valid run");
    let unverified = traces.iter().filter(|t| t.selection.is_some_and(|s| !s.verified_safe)).count() as u64;
    assert!(unverified > 0, "the set-up must force best-effort cycles: {:?}", summary.decisions);
    assert_eq!(summary.best_effort_cycles, unverified);
    assert_eq!(summary.decisions["best_effort"], unverified);
    assert_eq!(summary.decisions.values().sum::<u64>(), summary.cycles, "every cycle has one label");
    assert!(summary.fallbacks >= unverified, "a best-effort cycle is a fallback");
    for t in &traces {
        let label = t.record.decision_label();
        assert_eq!(label == "best_effort", t.record.best_effort, "cycle {}", t.record.cycle);
        if t.record.best_effort {
            assert!(t.record.reason.contains("best effort"), "{}", t.record.reason);
        }
    }
    let explanation = summary.explanation.join("\n");
    assert!(
        explanation
            .contains(&format!("{unverified} of {} cycles sent a command that failed", summary.cycles)),
        "{explanation}"
    );
}

#[test]
fn a_clean_run_has_no_best_effort_cycle_and_no_explanation() {
    let settings = ClosedLoopSettings::paper(ControllerMode::Multistage);
    let (summary, _) = run_closed_loop(&Scenario::paper_2(), &settings).expect("valid run");
    assert!(summary.reached && !summary.collided);
    assert_eq!(summary.best_effort_cycles, 0);
    assert_eq!(summary.decisions["best_effort"], 0);
    assert!(summary.explanation.is_empty(), "{:?}", summary.explanation);
}
