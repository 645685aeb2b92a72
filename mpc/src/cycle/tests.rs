use super::*;
use crate::problem::{ControllerMode, ObstacleFormulation};
use crate::safety::Decision;
use mav::Scenario;

const W5: [f64; 5] = [0.05, 0.15, 0.45, 0.30, 0.05];

fn controller(safety: Option<SafetySettings>) -> CycleController {
    let s = Scenario::paper_2();
    let def =
        OcpDefinition::from_scenario(&s, ControllerMode::Multistage, 0.1, ObstacleFormulation::DistanceAlm);
    CycleController::new(def, MpcSettings::default(), safety).expect("valid")
}

#[test]
fn a_good_panoc_plan_is_selected_and_sent() {
    let mut c = controller(Some(SafetySettings::default()));
    let s = Scenario::paper_2();
    let out = c.step(0, 0, &s.start, &[9.81, 0.0, 0.0], &W5, &SolveBudget::default()).expect("valid");
    let sel = out.selection.expect("layer on");
    assert_eq!(sel.decision, Decision::Panoc, "{}", sel.reason());
    assert_eq!(out.command, c.mpc().first_input());
    assert_eq!(c.plan(), c.mpc().solution());
    assert_eq!(c.predictions(), c.mpc().predictions());
}

#[test]
fn with_the_fail_safe_check_the_plans_coast_follows_the_delays_it_covers() {
    use crate::fail_safe::BrakingCheck;
    let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
    let check = BrakingCheck::default();
    let with = |check: BrakingCheck| SafetySettings { braking_check: Some(check), ..Default::default() };
    let mut c = controller(Some(with(check)));
    assert!(close(c.definition().coast_time_s, 0.96), "{}", c.definition().coast_time_s);
    c.cover_delays_up_to(Some(0.45));
    assert!(close(c.definition().coast_time_s, 1.2), "{}", c.definition().coast_time_s);
    c.cover_delays_up_to(Some(0.1));
    assert!(close(c.definition().coast_time_s, 0.96), "back with the range");
    // The plan check, no layer, or the check without a coast: the definition's (none).
    for c in [
        controller(Some(SafetySettings::default())),
        controller(None),
        controller(Some(with(BrakingCheck { plan_coast_s: None, ..check }))),
    ] {
        assert_eq!(c.definition().coast_time_s, 0.0);
    }
    // The penalty form has no coast: the check leaves it without one.
    let s = Scenario::paper_2();
    let def =
        OcpDefinition::from_scenario(&s, ControllerMode::Multistage, 0.1, ObstacleFormulation::PaperPenalty);
    let settings = MpcSettings { formulation: ObstacleFormulation::PaperPenalty, ..MpcSettings::default() };
    let mut paper = CycleController::new(def, settings, Some(with(check))).expect("valid");
    paper.cover_delays_up_to(Some(0.45));
    assert_eq!(paper.definition().coast_time_s, 0.0);
}

#[test]
fn forced_faults_hand_over_to_a_fallback_with_a_bounded_command() {
    for fault in [PanocFault::ZeroBudget, PanocFault::NanPlan] {
        let mut c = controller(Some(SafetySettings::default())).with_fault(Some(FaultInjection {
            fault,
            first_cycle: 1,
            cycles: 1,
        }));
        let s = Scenario::paper_2();
        let u = [9.81, 0.0, 0.0];
        let first = c.step(0, 0, &s.start, &u, &W5, &SolveBudget::default()).expect("valid");
        assert_eq!(first.fault, None);
        let out =
            c.step(1, 50_000_000, &s.start, &first.command, &W5, &SolveBudget::default()).expect("valid");
        assert_eq!(out.fault, Some(fault));
        let sel = out.selection.expect("layer on");
        assert!(sel.decision.is_fallback(), "{fault:?}: {}", sel.reason());
        assert!(sel.verified_safe, "{fault:?}: {}", sel.reason());
        let b = &s.bounds;
        assert!(
            out.command.iter().enumerate().all(|(k, v)| v.is_finite() && *v >= b.min[k] && *v <= b.max[k])
        );
        // PANOC's next warm start is the flown plan shifted.
        assert_eq!(&c.plan()[..3], &out.command[..]);
        // The predictions shown are the flown plan's, not PANOC's rejected one.
        let shown = c.predictions();
        assert_eq!(shown, c.mpc().predictions_of(c.plan()));
        assert_ne!(shown, c.mpc().predictions(), "{fault:?}");
        assert_eq!(shown.len(), 5);
        assert!(shown.iter().all(|t| t.len() == 41 && t[0] == s.start));
    }
}

#[test]
fn the_warm_start_follows_the_elapsed_time_for_nmpc_when_asked_and_one_step_otherwise() {
    // A zero budget on the second cycle returns the warm start as the plan.
    let s = Scenario::paper_2();
    let zero = Some(FaultInjection { fault: PanocFault::ZeroBudget, first_cycle: 1, cycles: 1 });
    let elapsed = MpcSettings { warm_start_by_elapsed_time: true, ..MpcSettings::default() };
    for (mode, weights, settings, expected_shift) in [
        (ControllerMode::Nmpc, &[1.0][..], elapsed, 4),
        (ControllerMode::Nmpc, &[1.0][..], MpcSettings::default(), 1),
        (ControllerMode::Multistage, &W5[..], elapsed, 1),
    ] {
        let def = OcpDefinition::from_scenario(&s, mode, 0.1, ObstacleFormulation::DistanceAlm);
        let mut c = CycleController::new(def, settings, None).expect("valid").with_fault(zero);
        let u = [9.81, 0.0, 0.0];
        c.step(0, 1_000_000_000, &s.start, &u, weights, &SolveBudget::default()).expect("valid");
        let first = c.plan().to_vec();
        // 0.2 s later: four of the NMPC's 0.05 s steps.
        let out = c.step(1, 1_200_000_000, &s.start, &u, weights, &SolveBudget::default()).expect("valid");
        assert_eq!(out.fault, Some(PanocFault::ZeroBudget));
        let n = first.len() / 3;
        for j in 0..n {
            let from = (j + expected_shift).min(n - 1);
            for k in 0..3 {
                let (got, want) = (c.plan()[3 * j + k], first[3 * from + k]);
                assert!(
                    (got - want).abs() < 1e-12,
                    "{mode:?} shift {expected_shift} step {j}: {got} vs {want}"
                );
            }
        }
    }
}

#[test]
fn without_the_layer_a_nan_plan_becomes_hover() {
    let mut c = controller(None).with_fault(Some(FaultInjection {
        fault: PanocFault::NanPlan,
        first_cycle: 0,
        cycles: 1,
    }));
    let s = Scenario::paper_2();
    let out = c.step(0, 0, &s.start, &[9.81, 0.0, 0.0], &W5, &SolveBudget::default()).expect("valid");
    assert_eq!(out.command, [9.81, 0.0, 0.0]);
    assert!(out.selection.is_none());
}
