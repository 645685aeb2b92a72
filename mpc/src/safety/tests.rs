use super::*;
use crate::command::braking_command;
use crate::fail_safe::BrakingCheck;
use crate::problem::{ControllerMode, ObstacleFormulation};
use crate::qp::{QpSettings, QpStatus};
use crate::solver::{MpcSettings, SolveBudget};
use mav::{CommandMeta, Input, PlantSim, Scenario, SimSettings, State, WatchdogAction};
use proptest::prelude::*;

const W5: [f64; 5] = [0.05, 0.15, 0.45, 0.30, 0.05];
const HOVER: [f64; 3] = [9.81, 0.0, 0.0];

fn def_of(s: &Scenario, mode: ControllerMode) -> OcpDefinition {
    OcpDefinition::from_scenario(s, mode, 0.1, ObstacleFormulation::DistanceAlm)
}

fn in_bounds(b: &InputBounds, u: [f64; 3]) -> bool {
    (0..3).all(|c| u[c].is_finite() && u[c] >= b.min[c] && u[c] <= b.max[c])
}

/// Smallest true clearance and altitude of `plan` re-simulated with `mav`'s Euler step,
/// independently of the evaluator.
fn resimulate(def: &OcpDefinition, x0: &[f64; 8], plan: &[f64]) -> (f64, f64) {
    let model = mav::MavModel::new(def.model);
    let (mut clearance, mut altitude) = (f64::INFINITY, f64::INFINITY);
    for &dt in &def.sampling_times_s {
        let mut x = mav::State::from(*x0);
        for j in 0..def.horizon {
            let u = mav::Input::new(plan[3 * j], plan[3 * j + 1], plan[3 * j + 2]);
            x = mav::euler_step(&model, &x, &u, dt);
            let (c, _) = mav::geometry::min_clearance(&def.obstacles, x[0], x[1], x[2]);
            clearance = clearance.min(c);
            altitude = altitude.min(x[2]);
        }
    }
    (clearance, altitude)
}

#[test]
fn a_converged_safe_panoc_plan_is_selected_and_the_qp_cross_checks_it() {
    let s = Scenario::paper_2();
    let def = def_of(&s, ControllerMode::Multistage);
    let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
    let mut layer = SafetyLayer::new(&def, SafetySettings::default()).expect("valid");
    let r = mpc.solve(&s.start, &HOVER, &W5, &SolveBudget::default()).expect("valid");
    let sel = layer.select(&s.start, &HOVER, &W5, &mpc, &r);
    assert_eq!(sel.decision, Decision::Panoc, "{}", sel.reason());
    assert_eq!(sel.command, mpc.first_input());
    assert!(sel.verified_safe && sel.panoc.min_clearance_m >= 0.0);
    assert!(sel.qp_report.is_some(), "the first cycle is always cross-checked");
    assert!(sel.reason().starts_with("panoc"));
    assert_eq!(layer.plan(), Some(mpc.solution()));
}

#[test]
fn panoc_forced_to_fail_hands_over_to_the_qp() {
    let s = Scenario::paper_2();
    let def = def_of(&s, ControllerMode::Multistage);
    let settings = MpcSettings { max_outer_iterations: 1, ..Default::default() };
    let mut mpc = Mpc::new(def.clone(), settings).expect("valid");
    let safety = SafetySettings { accept_iteration_limit: false, ..Default::default() };
    let mut layer = SafetyLayer::new(&def, safety).expect("valid");
    let budget = SolveBudget { max_inner_iterations: Some(1), deadline: None };
    let r = mpc.solve(&s.start, &HOVER, &W5, &budget).expect("valid");
    // One iteration from hover leaves the long scenarios' plans inside the cylinders.
    assert_eq!(r.status, SolveStatus::InfeasibleAtLimit, "{r:?}");
    let sel = layer.select(&s.start, &HOVER, &W5, &mpc, &r);
    assert_eq!(sel.decision, Decision::Qp, "{}", sel.reason());
    assert!(matches!(sel.panoc.rejection, Some(Rejection::PanocStatus { .. })));
    assert!(sel.verified_safe && sel.qp.min_clearance_m >= 0.0);
    assert!(in_bounds(&def.bounds, sel.command));
    let plan = layer.plan().expect("plan");
    let (clearance, _) = resimulate(&def, &s.start, plan);
    assert!(clearance >= 0.0, "{clearance}");
}

#[test]
fn a_colliding_converged_plan_is_rejected() {
    // Drifting at the 0.4 m cylinder; "PANOC" claims convergence on the hover plan.
    let s = Scenario::paper_2();
    let def = def_of(&s, ControllerMode::Nmpc);
    let x0 = [2.8, 1.8, 0.8, 0.0, 1.0, 0.0, 0.0, 0.0];
    let hover_plan: Vec<f64> = (0..def.num_variables()).map(|k| HOVER[k % 3]).collect();
    let mut layer = SafetyLayer::new(&def, SafetySettings::default()).expect("valid");
    let sel = layer.select_plan(&x0, &HOVER, &[1.0], Ok((&hover_plan, SolveStatus::Converged)));
    assert!(
        matches!(sel.panoc.rejection, Some(Rejection::Collision { min_clearance_m }) if min_clearance_m < 0.0)
    );
    assert_ne!(sel.decision, Decision::Panoc);
    assert!(in_bounds(&def.bounds, sel.command));
    if sel.verified_safe {
        let (clearance, _) = resimulate(&def, &x0, layer.plan().expect("plan"));
        assert!(clearance >= 0.0);
    }
}

/// paper-2's standard NMPC definition, a layer with the default fail-safe check for a plant
/// without a watchdog (commands held until the next lands, delays up to 0.33 s), the check
/// alone, and a plan that hovers throughout.
fn fail_safe_fixture() -> (OcpDefinition, SafetyLayer, FailSafe, Vec<f64>) {
    let def = def_of(&Scenario::paper_2(), ControllerMode::Nmpc);
    let check = BrakingCheck { plant_watchdog_s: None, ..BrakingCheck::default() };
    let settings = SafetySettings { braking_check: Some(check), ..Default::default() };
    let layer = SafetyLayer::new(&def, settings).expect("valid");
    let gain = settings.brake_gain_per_s;
    let fail_safe = FailSafe::new(check, def.model, def.bounds, def.obstacles.clone(), gain);
    let hover_plan: Vec<f64> = (0..def.num_variables()).map(|k| HOVER[k % 3]).collect();
    (def, layer, fail_safe, hover_plan)
}

#[test]
fn the_fail_safe_check_judges_the_first_input_followed_by_braking_under_every_delay() {
    let (def, mut layer, fail_safe, hover_plan) = fail_safe_fixture();
    let mut plan_layer = SafetyLayer::new(&def, SafetySettings::default()).expect("valid");
    let hover = Ok((&hover_plan[..], SolveStatus::Converged));
    // 0.8 m/s at the 0.4 m cylinder from 1.2 m. Drifting on at hover for the whole plan
    // (2 s) hits it, so the plan check rejects the plan; but only its first input is
    // sent, and braking from the next cycle on stops in time under every delay.
    let x0 = [2.8, 1.4, 1.0, 0.0, 0.8, 0.0, 0.0, 0.0];
    let sel = plan_layer.select_plan(&x0, &HOVER, &[1.0], hover);
    assert!(matches!(sel.panoc.rejection, Some(Rejection::Collision { .. })), "{}", sel.reason());
    let sel = layer.select_plan(&x0, &HOVER, &[1.0], hover);
    assert_eq!(sel.decision, Decision::Panoc, "{}", sel.reason());
    assert!(sel.verified_safe && sel.panoc.min_clearance_m >= 0.0);
    let e = fail_safe.envelope(&x0, &HOVER, &HOVER);
    assert_eq!(e.min_clearance_m, sel.panoc.min_clearance_m);
    // At 1 m/s it does not (the previous command may stay on for 0.33 s, the next one may
    // land 0.33 s after its sample): nothing passes, and the layer says so.
    let x0 = [2.8, 1.4, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0];
    let sel = layer.select_plan(&x0, &HOVER, &[1.0], hover);
    assert!(matches!(sel.panoc.rejection, Some(Rejection::Collision { .. })), "{}", sel.reason());
    assert!(!sel.verified_safe, "{}", sel.reason());
    assert!(in_bounds(&def.bounds, sel.command));
}

#[test]
fn without_a_floor_the_fail_safe_check_still_keeps_the_vehicle_above_the_ground() {
    // Paper mode has no floor. 0.3 m up, sinking at 0.5 m/s, a plan of zero thrust: its
    // first input, held up to 0.38 s before braking lands, takes the vehicle into the
    // ground, which the fail-safe check sees unless it is told there is no ground.
    let def = def_of(&Scenario::paper_2(), ControllerMode::Nmpc);
    assert_eq!(def.min_altitude_m, None);
    let falling = vec![0.0; def.num_variables()];
    let x0 = [3.2, 0.0, 0.3, 0.0, 0.0, -0.5, 0.0, 0.0];
    for ground_z_m in [Some(0.0), None] {
        let check = BrakingCheck { ground_z_m, ..BrakingCheck::default() };
        let settings = SafetySettings { braking_check: Some(check), ..Default::default() };
        let mut layer = SafetyLayer::new(&def, settings).expect("valid");
        let sel = layer.select_plan(&x0, &HOVER, &[1.0], Ok((&falling[..], SolveStatus::Converged)));
        match ground_z_m {
            Some(_) => {
                assert!(
                    matches!(sel.panoc.rejection, Some(Rejection::BelowFloor { min_altitude_m }) if min_altitude_m < 0.0),
                    "{}",
                    sel.reason()
                );
                assert_ne!(sel.decision, Decision::Panoc);
            }
            None => assert_eq!(sel.decision, Decision::Panoc, "{}", sel.reason()),
        }
    }
    let bad = BrakingCheck { ground_z_m: Some(f64::NAN), ..BrakingCheck::default() };
    assert!(bad.validate().is_err());
}

#[test]
fn in_real_time_the_fail_safe_check_flies_the_commands_in_flight_first() {
    let (_, mut layer, fail_safe, hover_plan) = fail_safe_fixture();
    let hover = Ok((&hover_plan[..], SolveStatus::Converged));
    // 0.8 m/s at the 0.4 m cylinder from 1.2 m: hover then braking passes (test above).
    let x0 = [2.8, 1.4, 1.0, 0.0, 0.8, 0.0, 0.0, 0.0];
    layer.set_in_flight(Some(&[]));
    let sel = layer.select_plan(&x0, &HOVER, &[1.0], hover);
    assert_eq!(sel.decision, Decision::Panoc, "{}", sel.reason());
    let e = fail_safe.envelope_real_time(&x0, &HOVER, &[], &HOVER);
    assert_eq!(e.min_clearance_m, sel.panoc.min_clearance_m);
    // Two earlier commands rolling towards it (+y) are still on their way: the same plan
    // no longer passes.
    let push = InFlight { sent_ago_s: 0.05, command: [11.0, -0.17, 0.0] };
    layer.set_in_flight(Some(&[InFlight { sent_ago_s: 0.1, ..push }, push]));
    let sel = layer.select_plan(&x0, &HOVER, &[1.0], hover);
    assert!(matches!(sel.panoc.rejection, Some(Rejection::Collision { .. })), "{}", sel.reason());
    // Back to lockstep timing: it passes again.
    layer.set_in_flight(None);
    let sel = layer.select_plan(&x0, &HOVER, &[1.0], hover);
    assert_eq!(sel.decision, Decision::Panoc, "{}", sel.reason());
}

#[test]
fn a_missed_deadline_reuses_the_previous_plan_shifted() {
    let s = Scenario::paper_3();
    let def = def_of(&s, ControllerMode::Nmpc);
    let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
    let mut layer = SafetyLayer::new(&def, SafetySettings::default()).expect("valid");
    let r = mpc.solve(&s.start, &HOVER, &[1.0], &SolveBudget::default()).expect("valid");
    let first = layer.select(&s.start, &HOVER, &[1.0], &mpc, &r);
    assert_eq!(first.decision, Decision::Panoc);
    let plan = mpc.solution().to_vec();
    // Next cycle: PANOC errs and the QP runs out of its budget.
    layer.set_qp_budget(QpBudget { max_iterations: Some(1), deadline: None });
    let x1 = s.start;
    let sel = layer.select_without_panoc(&x1, &first.command, &[1.0]);
    assert_eq!(sel.decision, Decision::ShiftedPlan, "{}", sel.reason());
    assert_eq!(sel.panoc.rejection, Some(Rejection::PanocError));
    assert_eq!(sel.qp.rejection, Some(Rejection::QpStatus { status: QpStatus::IterationLimit }));
    assert_eq!(sel.command, [plan[3], plan[4], plan[5]]);
    // and only max_plan_shifts times in a row, then brake.
    let mut last = sel;
    for _ in 1..layer.settings().max_plan_shifts {
        last = layer.select_without_panoc(&x1, &last.command, &[1.0]);
        assert_eq!(last.decision, Decision::ShiftedPlan);
    }
    let sel = layer.select_without_panoc(&x1, &last.command, &[1.0]);
    assert_eq!(sel.decision, Decision::Brake);
    assert_eq!(sel.shifted.rejection, Some(Rejection::NoPlan));
}

#[test]
fn non_finite_and_absurd_states_brake_with_a_finite_command() {
    let s = Scenario::paper_1();
    let def = def_of(&s, ControllerMode::Multistage);
    let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
    let mut layer = SafetyLayer::new(&def, SafetySettings::default()).expect("valid");
    // NaN state: PANOC refuses it; nothing can be checked.
    let mut x0 = s.start;
    x0[3] = f64::NAN;
    assert!(mpc.solve(&x0, &HOVER, &W5, &SolveBudget::default()).is_err());
    let sel = layer.select_without_panoc(&x0, &HOVER, &W5);
    assert_eq!(sel.decision, Decision::Brake);
    assert!(!sel.verified_safe);
    assert!(in_bounds(&def.bounds, sel.command));
    // Finite but absurd: PANOC fails numerically; every candidate is rejected as not finite.
    let x0 = [0.0, 0.0, 1.0, 1e200, -1e200, 1e200, 0.0, 0.0];
    let r = mpc.solve(&x0, &HOVER, &W5, &SolveBudget::default()).expect("valid input");
    assert_eq!(r.status, SolveStatus::NumericalFailure);
    let sel = layer.select(&x0, &HOVER, &W5, &mpc, &r);
    assert_eq!(sel.decision, Decision::Brake, "{}", sel.reason());
    assert!(in_bounds(&def.bounds, sel.command));
}

#[test]
fn the_qp_runs_on_schedule_and_whenever_panoc_is_rejected() {
    assert!((0..10).all(|k| QpSchedule::EveryCycle.due(k)));
    assert_eq!((0..10).filter(|&k| QpSchedule::EveryNth(5).due(k)).collect::<Vec<_>>(), vec![0, 5]);
    assert!((0..10).all(|k| !QpSchedule::WhenNeeded.due(k)));
    let bad = SafetySettings { qp_schedule: QpSchedule::EveryNth(0), ..Default::default() };
    assert!(bad.validate().is_err());

    let s = Scenario::paper_3();
    let def = def_of(&s, ControllerMode::Nmpc);
    let settings = SafetySettings { qp_schedule: QpSchedule::WhenNeeded, ..Default::default() };
    let mut layer = SafetyLayer::new(&def, settings).expect("valid");
    let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
    let r = mpc.solve(&s.start, &HOVER, &[1.0], &SolveBudget::default()).expect("valid");
    let sel = layer.select(&s.start, &HOVER, &[1.0], &mpc, &r);
    assert_eq!(sel.decision, Decision::Panoc);
    assert!(sel.qp_report.is_none() && sel.cost_gap.is_none());
    let sel = layer.select_without_panoc(&s.start, &HOVER, &[1.0]);
    assert!(sel.qp_report.is_some(), "a rejected PANOC plan always brings the QP in");
}

fn arb_case() -> impl Strategy<Value = (OcpDefinition, [f64; 8], Vec<f64>)> {
    (
        2usize..=20,
        prop::collection::vec(0.03f64..0.35, 1..=5),
        prop::collection::vec((0.0f64..6.0, 0.0f64..6.0, 0.1f64..0.8), 0..=3),
        (0.0f64..6.0, 0.0f64..6.0, 0.3f64..3.0),
        (-2.0f64..2.0, -2.0f64..2.0, -1.0f64..1.0, -0.17f64..0.17, -0.17f64..0.17),
        prop::collection::vec(0.0f64..1.0, 5),
    )
        .prop_map(|(n, dts, obs, p, v, w)| {
            let mut def = def_of(&Scenario::paper_2(), ControllerMode::Multistage);
            def.horizon = n;
            def.sampling_times_s = dts;
            def.obstacles = obs.into_iter().map(|(x, y, r)| mav::Cylinder::new(x, y, r)).collect();
            let mut w: Vec<f64> = w[..def.num_scenarios()].to_vec();
            w[0] += 0.05;
            (def, [p.0, p.1, p.2, v.0, v.1, v.2, v.3, v.4], w)
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(40))]

    /// Whatever PANOC does: the command is finite and inside the bounds, and a plan
    /// reported safe keeps non-negative clearance (and the floor) on the nonlinear model,
    /// re-simulated independently.
    #[test]
    fn the_selected_command_is_bounded_and_a_safe_plan_is_clear(
        (def, x0, w) in arb_case(),
        inner in prop::sample::select(vec![1usize, 20, 200]),
        floor in prop::option::of(0.0f64..0.3),
    ) {
        let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
        let qp = QpSettings { min_altitude_m: floor, ..Default::default() };
        let mut layer = SafetyLayer::new(&def, SafetySettings { qp, ..Default::default() }).expect("valid");
        let mut u_prev = HOVER;
        let mut x = x0;
        let model = mav::MavModel::new(def.model);
        // Two cycles, so that the shifted plan and the QP's nominal come into play.
        for _ in 0..2 {
            let budget = SolveBudget { max_inner_iterations: Some(inner), deadline: None };
            let r = mpc.solve(&x, &u_prev, &w, &budget).expect("valid");
            let sel = layer.select(&x, &u_prev, &w, &mpc, &r);
            prop_assert!(in_bounds(&def.bounds, sel.command), "{:?}", sel.command);
            if sel.decision == Decision::Panoc {
                prop_assert!(r.status != SolveStatus::NumericalFailure);
            }
            if sel.verified_safe {
                let (clearance, altitude) = resimulate(&def, &x, layer.plan().expect("plan"));
                prop_assert!(clearance >= -1e-9, "{}: clearance {clearance}", sel.reason());
                // A vehicle already below the floor may not sink further (it cannot be above
                // the floor at once): the layer's rule, `scoring.rs`.
                if let Some(f) = floor {
                    let lowest = f.min(x[2]);
                    prop_assert!(altitude >= lowest - 1e-6, "{}: altitude {altitude} < {lowest}", sel.reason());
                }
            }
            if let Some(q) = sel.qp_report.filter(|q| q.status.has_solution()) {
                let allowed = if q.status == QpStatus::SolvedElastic { q.elastic_violation_m } else { 0.0 };
                prop_assert!(q.linear_violation <= allowed + 1e-6, "{q:?}");
            }
            let xs = mav::euler_step(&model, &mav::State::from(x), &mav::Input::from(sel.command), def.sampling_times_s[0]);
            x = std::array::from_fn(|k| xs[k]);
            u_prev = sel.command;
        }
    }
}

/// The truth of one cycle on paper-2's plant: `u_prev` on at the sample, `command` landing
/// `d_s` later, and from the next sample on the controller's braking landing `d_next_s` after
/// each sample (every `max(0.05, d_next_s)`), for 15 s; the smallest clearance to a cylinder.
fn flown_clearance_m(
    x0: [f64; 8],
    command: [f64; 3],
    d_s: f64,
    d_next_s: f64,
    action: WatchdogAction,
) -> f64 {
    let scenario = Scenario::paper_2();
    let settings = SimSettings { watchdog_action: action, ..SimSettings::default() };
    let mut sim = PlantSim::new(&scenario, settings).expect("valid");
    sim.reset(State::from(x0)).expect("finite");
    sim.apply(Input::from(HOVER), CommandMeta::default()).expect("finite");
    let ns = |s: f64| (s * 1e9).round() as u64;
    let mut landings = vec![(ns(d_s), command)];
    let period_s = 0.05f64.max(d_next_s);
    let mut sample_s = 0.05f64.max(d_s);
    let mut next = 0;
    while sim.time_ns() < ns(15.0) {
        // The next event: a landing, or a sample that computes a brake.
        let landing = landings.get(next).map(|(t, _)| *t).filter(|t| *t <= ns(sample_s));
        match landing {
            Some(t) => {
                sim.advance_to(t, |_| {});
                sim.apply(Input::from(landings[next].1), CommandMeta::default()).expect("finite");
                next += 1;
            }
            None => {
                sim.advance_to(ns(sample_s), |_| {});
                let brake = braking_command(&scenario.model, &scenario.bounds, &(*sim.state()).into(), 1.0);
                landings.push((ns(sample_s + d_next_s), brake));
                sample_s += period_s;
            }
        }
    }
    sim.min_clearance_m()
}

#[test]
fn with_the_plants_braking_watchdog_a_command_that_passes_stays_clear_however_late_the_next_lands() {
    let def = def_of(&Scenario::paper_2(), ControllerMode::Nmpc);
    let check = BrakingCheck::default();
    assert_eq!(check.plant_watchdog_s, Some(0.5), "the bench's plants brake after 500 ms");
    let fail_safe = FailSafe::new(check, def.model, def.bounds, def.obstacles.clone(), 1.0);
    // Towards the 0.4 m cylinder from 1.2 m at 0.6 m/s, hovering: passes the check.
    let x0 = [2.8, 1.4, 1.0, 0.0, 0.6, 0.0, 0.0, 0.0];
    let envelope = fail_safe.envelope(&x0, &HOVER, &HOVER);
    assert!(envelope.min_clearance_m > 0.0, "{envelope:?}");
    // The truth: whatever the delays, up to 10 s, the plant's watchdog brakes once a command
    // is 0.5 s old, and the vehicle stays clear.
    for d_s in [0.0, 0.2, 0.5, 1.0] {
        for d_next_s in [0.0, 0.33, 0.5, 0.7, 1.5, 3.0, 10.0] {
            let clearance = flown_clearance_m(x0, HOVER, d_s, d_next_s, WatchdogAction::Brake);
            assert!(clearance > 0.0, "d {d_s} s, d' {d_next_s} s: clearance {clearance} m");
        }
    }
    // A plant whose watchdog only levels the vehicle lets it coast into the cylinder when the
    // next command is late enough: the check's promise rests on the braking watchdog.
    assert!(flown_clearance_m(x0, HOVER, 0.0, 10.0, WatchdogAction::Hover) < 0.0);
}
