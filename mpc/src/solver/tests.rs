use std::time::Duration;

use optimization_engine::FunctionCallResult;
use optimization_engine::alm::{AlmOptimizer, AlmProblem};
use optimization_engine::constraints::Rectangle;

use super::alm::{is_open_time_up_before_first_solve, projected_gradient_norm};
use super::*;
use crate::error::invalid_input;
use crate::problem::{ControllerMode, MAX_COAST_TIME_S};
use mav::Scenario;

fn mpc_for(scenario: &Scenario, mode: ControllerMode, settings: MpcSettings) -> Mpc {
    let def = OcpDefinition::from_scenario(scenario, mode, settings.obstacle_margin_m, settings.formulation);
    Mpc::new(def, settings).expect("valid settings")
}

const W5: [f64; 5] = [0.05, 0.15, 0.45, 0.30, 0.05];

#[test]
fn solves_the_paper_start_safely_within_bounds() {
    for formulation in [ObstacleFormulation::DistanceAlm, ObstacleFormulation::PaperPenalty] {
        let s = Scenario::paper_2();
        let mut mpc =
            mpc_for(&s, ControllerMode::Multistage, MpcSettings { formulation, ..Default::default() });
        let r = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &SolveBudget::default()).expect("valid");
        assert_ne!(r.status, SolveStatus::NumericalFailure);
        assert!(r.cost.is_finite() && r.cost > 0.0);
        assert!(r.min_clearance_m >= 0.0, "{formulation:?}: predicted clearance {}", r.min_clearance_m);
        let u = mpc.first_input();
        assert!(s.bounds.contains(&mav::Input::from(u)));
        assert!(u[0] > 9.81, "climbs towards the goal 1 m up: {u:?}");
    }
}

#[test]
fn a_warm_started_second_solve_is_cheaper() {
    let s = Scenario::paper_3();
    let mut mpc = mpc_for(&s, ControllerMode::Nmpc, MpcSettings::default());
    let first = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &[1.0], &SolveBudget::default()).expect("valid");
    let second = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &[1.0], &SolveBudget::default()).expect("valid");
    assert!(second.iterations <= first.iterations, "{} > {}", second.iterations, first.iterations);
}

#[test]
fn the_warm_start_advances_by_whole_steps_repeating_the_last_input() {
    let s = Scenario::paper_2();
    let mut mpc = mpc_for(&s, ControllerMode::Nmpc, MpcSettings::default());
    let n = s.horizon;
    let plan: Vec<f64> = (0..3 * n).map(|k| [9.0, 0.01, -0.01][k % 3] + 0.001 * (k / 3) as f64).collect();
    let zero = SolveBudget { max_inner_iterations: Some(0), deadline: None };
    for steps in [0, 1, 3, n - 1, n + 5] {
        mpc.set_warm_start(&plan).expect("valid");
        mpc.advance_warm_start(steps);
        // A zero budget returns the warm start as the solution (through the scaling: to
        // rounding).
        mpc.solve(&s.start, &[9.81, 0.0, 0.0], &[1.0], &zero).expect("valid");
        let got = mpc.solution();
        let shift = steps.min(n - 1);
        for j in 0..3 * n {
            let from = 3 * (j / 3 + shift).min(n - 1) + j % 3;
            assert!(
                (got[j] - plan[from]).abs() < 1e-12,
                "steps {steps}, value {j}: {} vs {}",
                got[j],
                plan[from]
            );
        }
    }
}

#[test]
fn advancing_the_warm_start_shifts_each_scenarios_multipliers_by_points() {
    let s = Scenario::paper_2();
    let mut mpc = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
    let (n, nc, m) = (s.horizon, mpc.def.constraints_per_point(), mpc.def.num_scenarios());
    assert_eq!(mpc.warm_multipliers.len(), m * n * nc);
    let value = |i: usize, j: usize, c: usize| (1000 * i + 10 * j + c) as f64;
    for i in 0..m {
        for j in 0..n {
            for c in 0..nc {
                mpc.warm_multipliers[(i * n + j) * nc + c] = value(i, j, c);
            }
        }
    }
    mpc.advance_warm_start(3);
    for i in 0..m {
        for j in 0..n {
            for c in 0..nc {
                let from = (j + 3).min(n - 1);
                assert_eq!(mpc.warm_multipliers[(i * n + j) * nc + c], value(i, from, c), "{i} {j} {c}");
            }
        }
    }
}

#[test]
fn the_iteration_budget_is_respected_and_reported() {
    let s = Scenario::paper_1();
    let settings = MpcSettings { max_outer_iterations: 1, ..Default::default() };
    let mut mpc = mpc_for(&s, ControllerMode::Multistage, settings);
    let budget = SolveBudget { max_inner_iterations: Some(2), deadline: None };
    let r = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &budget).expect("valid");
    // Two iterations from hover: the long scenarios' plans still cross paper-1's cylinder, and
    // the status says so.
    assert_eq!(r.status, SolveStatus::InfeasibleAtLimit, "{r:?}");
    assert!(r.depth_m() > 0.0 && r.depth_m() == -r.min_clearance_m, "{r:?}");
    assert!(r.iterations <= 2);
    assert!(s.bounds.contains(&mav::Input::from(mpc.first_input())));
}

#[test]
fn a_budget_of_zero_runs_no_iteration_not_even_the_restoration_from_a_plan_inside() {
    let s = Scenario::paper_1();
    // Our PANOC (the restoration is its), the paper's exact problem.
    let settings = MpcSettings { solver: PanocSolver::Own, obstacle_margin_m: 0.0, ..Default::default() };
    assert!(settings.restoration_iterations > 0);
    // A plan inside paper-1's cylinder: two iterations from hover, without the restoration.
    let inside = {
        let unrestored = MpcSettings { restoration_iterations: 0, ..settings };
        let mut mpc = mpc_for(&s, ControllerMode::Multistage, unrestored);
        let two = SolveBudget { max_inner_iterations: Some(2), deadline: None };
        let r = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &two).expect("valid");
        assert_eq!(r.status, SolveStatus::InfeasibleAtLimit, "the warm start must be inside: {r:?}");
        mpc.solution().to_vec()
    };
    let mut mpc = mpc_for(&s, ControllerMode::Multistage, settings);
    mpc.set_warm_start(&inside).expect("valid");
    let zero = SolveBudget { max_inner_iterations: Some(0), deadline: None };
    let r = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &zero).expect("valid");
    assert_eq!(r.iterations, 0, "{r:?}");
    assert_eq!(r.status, SolveStatus::InfeasibleAtLimit, "{r:?}");
    for (got, want) in mpc.solution().iter().zip(&inside) {
        assert!((got - want).abs() < 1e-12, "{got} vs {want}");
    }
}

#[test]
fn each_solve_reports_its_own_passes_and_an_identical_solve_reports_the_same() {
    // Two workspaces solving the same instance: per-evaluator counts, so neither sees the
    // other's passes (a process-global counter would count both).
    let s = Scenario::paper_1();
    let mut a = mpc_for(&s, ControllerMode::Nmpc, MpcSettings::default());
    let mut b = mpc_for(&s, ControllerMode::Nmpc, MpcSettings::default());
    let hover = [9.81, 0.0, 0.0];
    let ra = a.solve(&s.start, &hover, &[1.0], &SolveBudget::default()).expect("valid");
    let rb = b.solve(&s.start, &hover, &[1.0], &SolveBudget::default()).expect("valid");
    assert_eq!(ra.passes, rb.passes);
    // At least one forward pass per PANOC iteration and the final evaluation; one adjoint
    // pass per gradient.
    assert!(ra.passes.forward > ra.iterations as u64, "{ra:?}");
    assert!(ra.passes.adjoint >= ra.iterations as u64, "{ra:?}");
}

#[test]
fn a_wall_clock_deadline_stops_the_solve_with_its_best_iterate_inside_the_bounds() {
    // Real time: a deadline too short for even one PANOC iteration of the paper-1 start
    // (a hard solve: 200 iterations without one) ends the solve with `Deadline`.
    let s = Scenario::paper_1();
    let mut mpc = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
    let budget = SolveBudget { max_inner_iterations: None, deadline: Some(Duration::from_nanos(1)) };
    let r = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &budget).expect("valid");
    assert_eq!(r.status, SolveStatus::Deadline, "{r:?}");
    assert!(r.iterations < MpcSettings::default().max_inner_iterations, "{r:?}");
    assert!(mpc.solution().iter().all(|u| u.is_finite()));
    for u in mpc.solution().chunks(3) {
        assert!(s.bounds.contains(&mav::Input::new(u[0], u[1], u[2])), "{u:?}");
    }
    assert!(r.cost.is_finite() && r.min_clearance_m.is_finite(), "{r:?}");
    // Deadlines that run out inside the solve, one outer iteration or another: a status,
    // never a panic, and a plan inside the bounds.
    for micros in [20, 21, 30, 50, 100, 300, 1000, 3000] {
        let budget =
            SolveBudget { max_inner_iterations: None, deadline: Some(Duration::from_micros(micros)) };
        let r = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &budget).expect("valid");
        assert_ne!(r.status, SolveStatus::NumericalFailure, "{micros} us: {r:?}");
        assert!(mpc.solution().iter().all(|u| u.is_finite()));
    }
    // A generous deadline changes nothing against no deadline (lockstep's iteration budget).
    let mut timed = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
    let mut counted = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
    let long = SolveBudget { max_inner_iterations: None, deadline: Some(Duration::from_secs(3600)) };
    let a = timed.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &long).expect("valid");
    let b = counted.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &SolveBudget::default()).expect("valid");
    assert_eq!((a.status, a.iterations), (b.status, b.iterations));
    assert_eq!(timed.solution(), counted.solution());
}

#[test]
fn the_panic_of_an_open_call_out_of_time_before_its_first_solve_is_recognized() {
    // OpEn's own panic, reproduced on a fresh cache with no time at all: the solver turns
    // exactly this one into `Deadline` (and lets any other panic unwind).
    let cache = AlmCache::new(PANOCCache::new(2, 1e-5, 3), 0, 0);
    let (lo, hi) = ([-1.0, -1.0], [1.0, 1.0]);
    let cost = |u: &[f64], _: &[f64], c: &mut f64| -> FunctionCallResult {
        *c = u[0] * u[0] + u[1] * u[1];
        Ok(())
    };
    let grad = |u: &[f64], _: &[f64], g: &mut [f64]| -> FunctionCallResult {
        g[0] = 2.0 * u[0];
        g[1] = 2.0 * u[1];
        Ok(())
    };
    type NoMapping = fn(&[f64], &mut [f64]) -> FunctionCallResult;
    let problem = AlmProblem::new(
        Rectangle::new(Some(&lo), Some(&hi)),
        None::<Rectangle>,
        None::<Rectangle>,
        cost,
        grad,
        None::<NoMapping>,
        None::<NoMapping>,
        0,
        0,
    );
    let mut cache = cache;
    let mut u = [0.5, 0.5];
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        AlmOptimizer::new(&mut cache, problem).with_max_duration(Duration::ZERO).solve(&mut u)
    }));
    match outcome {
        Err(payload) => assert!(is_open_time_up_before_first_solve(payload.as_ref())),
        Ok(r) => panic!("OpEn no longer panics out of time (the guard can go): {r:?}"),
    }
    assert!(!is_open_time_up_before_first_solve(&"index out of bounds"));
    assert!(!is_open_time_up_before_first_solve(&String::from("already borrowed")));
}

#[test]
fn bad_input_is_refused_naming_the_field_and_changes_nothing() {
    let s = Scenario::paper_1();
    let mut mpc = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
    let before = mpc.solution().to_vec();
    let mut x0 = s.start;
    x0[4] = f64::NAN;
    let e = mpc.solve(&x0, &[9.81, 0.0, 0.0], &W5, &SolveBudget::default());
    assert_eq!(e, Err(invalid_input("x0[4]", "must be finite")));
    let e = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &[1.0], &SolveBudget::default());
    assert!(matches!(e, Err(MpcError::InvalidInput { field, .. }) if field == "weights"));
    let e = mpc.solve(&s.start, &[9.81, f64::INFINITY, 0.0], &W5, &SolveBudget::default());
    assert!(matches!(e, Err(MpcError::InvalidInput { field, .. }) if field == "u_prev[1]"));
    let e = mpc.set_warm_start(&[1.0; 7]);
    assert!(matches!(e, Err(MpcError::InvalidInput { field, .. }) if field == "warm_start"));
    assert_eq!(mpc.solution(), &before[..]);
    assert!(matches!(
        MpcSettings { penalty_update_factor: 1.0, ..Default::default() }.validate(),
        Err(MpcError::InvalidSetting { field: "penalty_update_factor", .. })
    ));
}

#[test]
fn standard_nmpc_has_its_own_panoc_tolerances_and_memory() {
    let s = MpcSettings {
        tolerance: 1e-3,
        akkt_tolerance: 1e-2,
        lbfgs_memory: 10,
        single_scenario_tolerance: 3e-2,
        single_scenario_akkt_tolerance: 1e-1,
        single_scenario_lbfgs_memory: 7,
        ..Default::default()
    };
    assert_eq!(s.panoc_for(1), (3e-2, 1e-1, 7));
    assert_eq!(s.panoc_for(5), (1e-3, 1e-2, 10));
    for (bad, field) in [
        (MpcSettings { single_scenario_tolerance: f64::NAN, ..s }, "single_scenario_tolerance"),
        (MpcSettings { single_scenario_akkt_tolerance: 0.0, ..s }, "single_scenario_akkt_tolerance"),
        (MpcSettings { single_scenario_lbfgs_memory: 0, ..s }, "single_scenario_lbfgs_memory"),
    ] {
        assert!(matches!(bad.validate(), Err(MpcError::InvalidSetting { field: f, .. }) if f == field));
    }
    // A tighter NMPC tolerance costs iterations on the same problem: the setting is used.
    let scenario = Scenario::paper_1();
    let x0 = [0.2, 3.0, 0.9, 0.1, 1.2, 0.05, 0.02, -0.01];
    let iterations = |settings: MpcSettings| {
        let mut mpc = mpc_for(&scenario, ControllerMode::Nmpc, settings);
        mpc.solve(&x0, &[9.81, 0.0, 0.0], &[1.0], &SolveBudget::default()).expect("valid").iterations
    };
    let tight = MpcSettings { single_scenario_tolerance: 1e-6, single_scenario_akkt_tolerance: 1e-5, ..s };
    assert!(iterations(tight) > iterations(s), "{} vs {}", iterations(tight), iterations(s));
}

#[test]
fn inactive_set_tolerances_are_validated_naming_the_field() {
    let t = InactiveSetTolerances::MEASURED;
    let with = |t: InactiveSetTolerances| MpcSettings { inactive_set: Some(t), ..Default::default() };
    assert_eq!(with(t).validate(), Ok(()));
    for (bad, field) in [
        (InactiveSetTolerances { tolerance: f64::NAN, ..t }, "inactive_set.tolerance"),
        (InactiveSetTolerances { akkt_tolerance: 0.0, ..t }, "inactive_set.akkt_tolerance"),
        (InactiveSetTolerances { gradient_tolerance: f64::INFINITY, ..t }, "inactive_set.gradient_tolerance"),
    ] {
        assert!(matches!(with(bad).validate(), Err(MpcError::InvalidSetting { field: f, .. }) if f == field));
    }
}

/// Paper-2 with its cylinders moved 20 m away, out of reach whatever the inputs do: no
/// constraint term ever.
fn open_space() -> Scenario {
    let mut s = Scenario::paper_2();
    for c in &mut s.obstacles {
        c.x_m += 20.0;
    }
    s
}

/// Report and solution bits of one solve from a fresh workspace.
fn solve_bits(
    scenario: &Scenario,
    mode: ControllerMode,
    settings: MpcSettings,
    x0: &[f64; 8],
    weights: &[f64],
) -> (SolveReport, Vec<u64>) {
    let mut mpc = mpc_for(scenario, mode, settings);
    let r = mpc.solve(x0, &[9.81, 0.0, 0.0], weights, &SolveBudget::default()).expect("valid");
    (r, mpc.solution().iter().map(|v| v.to_bits()).collect())
}

#[test]
fn inactive_set_tolerances_apply_where_no_constraint_term_is_active() {
    let loose = MpcSettings { inactive_set: Some(InactiveSetTolerances::MEASURED), ..Default::default() };
    let open_space = open_space();
    let x0 = [3.1, 1.2, 0.6, 0.1, 1.4, 0.2, 0.05, -0.02];
    let (tight_report, _) =
        solve_bits(&open_space, ControllerMode::Multistage, MpcSettings::default(), &x0, &W5);
    let (loose_report, _) = solve_bits(&open_space, ControllerMode::Multistage, loose, &x0, &W5);
    assert_eq!(loose_report.status, SolveStatus::Converged);
    assert!(
        loose_report.iterations < tight_report.iterations,
        "{} vs {} iterations",
        loose_report.iterations,
        tight_report.iterations
    );
    // The looser test still stops close to the optimum on this smooth problem.
    let gap = (loose_report.cost - tight_report.cost) / tight_report.cost;
    assert!(gap.abs() < 1e-2, "cost gap {gap}");

    // Inside the inflated radius of a cylinder, moving towards it: the first predicted points
    // cannot leave it, so a term is active at every outer iteration and the solve is the
    // one of the default settings, bit for bit.
    let scenario = Scenario::paper_2();
    let c = scenario.obstacles[1];
    let x0 = [c.x_m + c.radius_m + 0.05, c.y_m, 1.0, -0.5, 0.0, 0.0, 0.0, 0.0];
    let (a, a_bits) = solve_bits(&scenario, ControllerMode::Multistage, MpcSettings::default(), &x0, &W5);
    let (b, b_bits) = solve_bits(&scenario, ControllerMode::Multistage, loose, &x0, &W5);
    assert!(a.constraint_violation > 0.0, "a term must be active");
    assert_eq!((a.iterations, a.cost.to_bits(), a_bits), (b.iterations, b.cost.to_bits(), b_bits));

    // Standard NMPC ignores the option (it has its own tolerances).
    let x0 = [3.1, 1.2, 0.6, 0.1, 1.4, 0.2, 0.05, -0.02];
    let (a, a_bits) = solve_bits(&open_space, ControllerMode::Nmpc, MpcSettings::default(), &x0, &[1.0]);
    let (b, b_bits) = solve_bits(&open_space, ControllerMode::Nmpc, loose, &x0, &[1.0]);
    assert_eq!((a.iterations, a.cost.to_bits(), a_bits), (b.iterations, b.cost.to_bits(), b_bits));
}

#[test]
fn an_inactive_set_result_must_have_a_small_projected_gradient() {
    // A gradient tolerance no result can meet: every inactive-set outer iteration is
    // handed on, so the solve runs all its outer iterations and never reports convergence.
    let open_space = open_space();
    let unreachable = InactiveSetTolerances { gradient_tolerance: 1e-300, ..InactiveSetTolerances::MEASURED };
    let s = MpcSettings { inactive_set: Some(unreachable), ..Default::default() };
    let x0 = [3.1, 1.2, 0.6, 0.1, 1.4, 0.2, 0.05, -0.02];
    let (r, _) = solve_bits(&open_space, ControllerMode::Multistage, s, &x0, &W5);
    assert_eq!(r.status, SolveStatus::IterationLimit);
    assert_eq!(r.outer_iterations, s.max_outer_iterations);
}

#[test]
fn projected_gradient_norm_is_the_unit_step_residual_on_the_box() {
    let (lo, hi) = ([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]);
    // Interior: the gradient itself; at a bound, only the part pointing into the box.
    assert_eq!(projected_gradient_norm(&[0.0, 0.0, 0.0], &[0.3, 0.0, -0.4], &lo, &hi), 0.5);
    assert_eq!(projected_gradient_norm(&[1.0, -1.0, 0.0], &[-2.0, -5.0, 0.0], &lo, &hi), 2.0);
    assert_eq!(projected_gradient_norm(&[0.5, 0.0, 0.0], &[-3.0, 0.0, 0.0], &lo, &hi), 0.5);
}

#[test]
fn solves_are_deterministic() {
    let s = Scenario::paper_2();
    let x0 = [3.1, 1.2, 0.6, 0.1, 1.4, 0.2, 0.05, -0.02];
    let run = || {
        let mut mpc = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
        let r = mpc.solve(&x0, &[10.0, 0.01, 0.0], &W5, &SolveBudget::default()).expect("valid");
        (r.cost.to_bits(), r.iterations, mpc.solution().iter().map(|v| v.to_bits()).collect::<Vec<_>>())
    };
    assert_eq!(run(), run());
}

#[test]
fn a_numerical_failure_returns_the_warm_start_inside_the_bounds() {
    let s = Scenario::paper_1();
    let mut mpc = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
    // Finite but absurd: the predicted cost overflows to infinity.
    let x0 = [0.0, 0.0, 0.0, 1e200, 1e200, 1e200, 0.0, 0.0];
    let r = mpc.solve(&x0, &[9.81, 0.0, 0.0], &W5, &SolveBudget::default()).expect("valid input");
    assert_eq!(r.status, SolveStatus::NumericalFailure);
    assert_eq!(mpc.first_input(), [9.81, 0.0, 0.0]);
}

#[test]
fn our_panoc_solves_the_paper_start_safely_and_deterministically_with_its_estimate_carried() {
    let s = Scenario::paper_2();
    let own = MpcSettings { solver: PanocSolver::Own, ..MpcSettings::default() };
    let run = || {
        let mut mpc = mpc_for(&s, ControllerMode::Multistage, own);
        let first = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &SolveBudget::default()).expect("valid");
        assert!(mpc.panoc.lipschitz() > 0.0, "the estimate is kept for the next solve");
        let u = mpc.first_input();
        let second = mpc.solve(&s.start, &u, &W5, &SolveBudget::default()).expect("valid");
        for r in [&first, &second] {
            assert_ne!(r.status, SolveStatus::NumericalFailure);
            assert!(r.min_clearance_m >= 0.0, "predicted clearance {}", r.min_clearance_m);
        }
        assert!(s.bounds.contains(&mav::Input::from(u)));
        assert!(u[0] > 9.81, "climbs towards the goal 1 m up: {u:?}");
        (
            second.cost.to_bits(),
            second.iterations,
            mpc.solution().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        )
    };
    assert_eq!(run(), run());
}

#[test]
fn a_reset_forgets_our_panocs_lipschitz_estimate() {
    let s = Scenario::paper_3();
    let own = MpcSettings { solver: PanocSolver::Own, ..MpcSettings::default() };
    let mut mpc = mpc_for(&s, ControllerMode::Nmpc, own);
    mpc.solve(&s.start, &[9.81, 0.0, 0.0], &[1.0], &SolveBudget::default()).expect("valid");
    assert!(mpc.panoc.lipschitz() > 0.0);
    mpc.reset_warm_start();
    assert_eq!(mpc.panoc.lipschitz(), 0.0);
}

#[test]
fn each_panoc_stops_at_its_own_default_budget_on_a_state_that_needs_more() {
    // paper-2's start under the paper's prior weights is one of the states no budget from 100
    // to 5,000 iterations converges on (BENCHMARKS.md "The solver"): both solvers spend their
    // whole budget, which is what bounds the solve time.
    let s = Scenario::paper_2();
    let weights = [0.0, 0.003, 0.036, 0.640, 0.313];
    for (solver, budget) in [(PanocSolver::Own, 100), (PanocSolver::OpEn, 200)] {
        let settings = MpcSettings { solver, ..MpcSettings::default() };
        assert_eq!(settings.inner_budget(), budget, "{solver:?}");
        let mut mpc = mpc_for(&s, ControllerMode::Multistage, settings);
        let r = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &weights, &SolveBudget::default()).expect("valid");
        assert_eq!((r.status, r.iterations), (SolveStatus::IterationLimit, budget), "{solver:?}");
        // A budget given with the solve overrides the default.
        let mut mpc = mpc_for(&s, ControllerMode::Multistage, settings);
        let given = SolveBudget { max_inner_iterations: Some(7), deadline: None };
        let r = mpc.solve(&s.start, &[9.81, 0.0, 0.0], &weights, &given).expect("valid");
        assert!(r.iterations <= 7, "{solver:?}: {r:?}");
    }
}

#[test]
fn an_answer_whose_plan_is_inside_a_cylinder_says_so_and_never_converged_or_iteration_limit() {
    // The paper's exact problem (no margin) from hover at paper-1's start and from a paper-2
    // state flying at the first cylinder, at budgets from 1 to the default: every answer's
    // plan is predicted clear, or its status is `InfeasibleAtLimit` with the depth.
    let p1 = Scenario::paper_1();
    let p2 = Scenario::paper_2();
    let moving = [3.3, 0.6, 0.6, 0.0, 0.9, 0.3, 0.0, 0.05];
    let mut seen_inside = 0;
    for solver in [PanocSolver::OpEn, PanocSolver::Own] {
        let settings = MpcSettings { solver, obstacle_margin_m: 0.0, ..MpcSettings::default() };
        for (s, x0) in [(&p1, p1.start), (&p2, moving)] {
            for budget in [1, 2, 5, 20, 60, settings.inner_budget()] {
                let mut mpc = mpc_for(s, ControllerMode::Multistage, settings);
                let b = SolveBudget { max_inner_iterations: Some(budget), deadline: None };
                let r = mpc.solve(&x0, &[9.81, 0.0, 0.0], &W5, &b).expect("valid");
                let deepest = mpc
                    .predictions()
                    .iter()
                    .flat_map(|p| p[1..].to_vec())
                    .map(|x| mav::geometry::min_clearance(&s.obstacles, x[0], x[1], x[2]).0)
                    .fold(f64::INFINITY, f64::min);
                assert_eq!(deepest.to_bits(), r.min_clearance_m.to_bits(), "{solver:?} {budget}");
                let inside = deepest < -INSIDE_TOLERANCE_M;
                assert_eq!(r.status == SolveStatus::InfeasibleAtLimit, inside, "{solver:?} {budget}: {r:?}");
                if inside {
                    seen_inside += 1;
                    assert!(r.depth_m() > INSIDE_TOLERANCE_M, "{r:?}");
                    assert!(r.status.at_iteration_limit());
                } else {
                    assert_eq!(r.depth_m(), 0.0, "{r:?}");
                }
            }
        }
    }
    assert!(seen_inside > 0, "the sample must hold plans inside a cylinder");
}

#[test]
fn only_an_iteration_limit_on_a_plan_inside_becomes_infeasible_at_limit() {
    let inside = -0.05;
    assert_eq!(SolveStatus::IterationLimit.with_clearance(inside), SolveStatus::InfeasibleAtLimit);
    assert_eq!(SolveStatus::IterationLimit.with_clearance(0.3), SolveStatus::IterationLimit);
    assert_eq!(
        SolveStatus::IterationLimit.with_clearance(-0.5 * INSIDE_TOLERANCE_M),
        SolveStatus::IterationLimit
    );
    assert_eq!(SolveStatus::IterationLimit.with_clearance(f64::INFINITY), SolveStatus::IterationLimit);
    for s in [SolveStatus::Converged, SolveStatus::Deadline, SolveStatus::NumericalFailure] {
        assert_eq!(s.with_clearance(inside), s);
    }
    let names: Vec<&str> = SolveStatus::ALL.iter().map(|s| s.name()).collect();
    assert_eq!(
        names,
        ["converged", "iteration_limit", "infeasible_at_limit", "deadline", "numerical_failure"]
    );
    assert!(
        SolveStatus::InfeasibleAtLimit.at_iteration_limit()
            && SolveStatus::IterationLimit.at_iteration_limit()
    );
    assert!(!SolveStatus::Converged.at_iteration_limit() && !SolveStatus::Deadline.at_iteration_limit());
}

#[test]
fn a_converged_answer_is_clear_even_without_a_margin() {
    // With no margin the constraint tolerance alone would let a converged plan sit up to 2 cm
    // inside a cylinder; such a plan is not a solution and the solve goes on.
    let s = Scenario::paper_2();
    let moving = [3.3, 0.6, 0.6, 0.0, 0.9, 0.3, 0.0, 0.05];
    for solver in [PanocSolver::OpEn, PanocSolver::Own] {
        let settings = MpcSettings { solver, obstacle_margin_m: 0.0, ..MpcSettings::default() };
        let mut mpc = mpc_for(&s, ControllerMode::Multistage, settings);
        let b = SolveBudget { max_inner_iterations: Some(100_000), deadline: None };
        let r = mpc.solve(&moving, &[9.81, 0.0, 0.0], &W5, &b).expect("valid");
        if r.status == SolveStatus::Converged {
            assert!(r.min_clearance_m >= -INSIDE_TOLERANCE_M, "{solver:?}: {r:?}");
        } else {
            assert_eq!(r.status, SolveStatus::InfeasibleAtLimit, "{solver:?}: {r:?}");
        }
    }
}

#[test]
fn our_restoration_phase_clears_a_plan_the_budget_left_inside_a_cylinder() {
    // paper-1's start, the paper's exact problem (no margin), a cold solve: our PANOC's 100
    // iterations leave the long scenarios' plans inside the cylinder; the restoration phase
    // takes them out, and a restoration that cannot is not kept.
    let s = Scenario::paper_1();
    let base = MpcSettings { solver: PanocSolver::Own, obstacle_margin_m: 0.0, ..MpcSettings::default() };
    let solve = |settings: MpcSettings| {
        let mut mpc = mpc_for(&s, ControllerMode::Multistage, settings);
        mpc.solve(&s.start, &[9.81, 0.0, 0.0], &W5, &SolveBudget::default()).expect("valid")
    };
    let without = solve(MpcSettings { restoration_iterations: 0, ..base });
    assert_eq!(without.status, SolveStatus::InfeasibleAtLimit, "{without:?}");
    let with = solve(base);
    assert_eq!(with.status, SolveStatus::IterationLimit, "{with:?}");
    assert!(with.min_clearance_m >= 0.0, "{with:?}");
    assert!(with.iterations > without.iterations && with.iterations <= 100 + base.restoration_iterations);
    // One restoration iteration cannot clear it: the plan the budget reached comes back.
    let short = solve(MpcSettings { restoration_iterations: 1, ..base });
    assert_eq!(short.status, SolveStatus::InfeasibleAtLimit, "{short:?}");
    assert_eq!(short.cost.to_bits(), without.cost.to_bits());
}

#[test]
fn a_second_restoration_further_out_clears_a_plan_the_first_left_inside() {
    // Cycle 12 of OpEn's paper-1 multi-stage loop, solved cold by ours with no margin: the
    // budget and the first restoration (3 mm out) leave the plan 6 cm inside the cylinder;
    // the second, 2 cm out from the first's result, takes it out. Without the second phase
    // the answer says so.
    let scenario = Scenario::paper_1();
    let mode = ControllerMode::Multistage;
    let logged =
        crate::accuracy::loop_solves(&scenario, mode, &MpcSettings::default()).expect("the loop flies");
    let i = &logged[12].instance;
    let mut cold_scenario = scenario.clone();
    cold_scenario.obstacle_margin_m = Some(0.0);
    let base = MpcSettings { solver: PanocSolver::Own, obstacle_margin_m: 0.0, ..MpcSettings::default() };
    let solve = |settings: MpcSettings| {
        let mut mpc = mpc_for(&cold_scenario, mode, settings);
        mpc.set_warm_start(&i.warm_start).expect("the logged warm start fits");
        mpc.solve(&i.x0, &i.u_prev, &i.weights, &SolveBudget::default()).expect("valid")
    };
    let once = solve(MpcSettings { restoration_retry_shift_m: 0.0, ..base });
    assert_eq!(once.status, SolveStatus::InfeasibleAtLimit, "{once:?}");
    assert!(once.min_clearance_m < -0.01, "{once:?}");
    let twice = solve(base);
    assert_eq!(twice.status, SolveStatus::IterationLimit, "{twice:?}");
    assert!(twice.min_clearance_m >= 0.0, "{twice:?}");
    assert!(twice.iterations > once.iterations, "{twice:?} against {once:?}");
    assert!(twice.iterations <= base.own_max_inner_iterations + 2 * base.restoration_iterations, "{twice:?}");
    for bad in [-0.01, f64::NAN, f64::INFINITY] {
        assert!(matches!(
            MpcSettings { restoration_retry_shift_m: bad, ..base }.validate(),
            Err(MpcError::InvalidSetting { field: "restoration_retry_shift_m", .. })
        ));
    }
}

#[test]
fn a_coast_time_out_of_range_or_with_the_penalty_form_is_refused_and_changes_nothing() {
    let s = Scenario::paper_2();
    let mut mpc = mpc_for(&s, ControllerMode::Multistage, MpcSettings::default());
    for bad in [-0.1, f64::NAN, f64::INFINITY, MAX_COAST_TIME_S + 0.1] {
        assert!(mpc.set_coast_time(bad).is_err(), "{bad}");
        assert_eq!(mpc.definition().coast_time_s, 0.0, "unchanged after {bad}");
    }
    mpc.set_coast_time(1.0).expect("in range");
    assert_eq!(mpc.definition().coast_time_s, 1.0);
    let penalty = MpcSettings { formulation: ObstacleFormulation::PaperPenalty, ..Default::default() };
    let mut paper = mpc_for(&s, ControllerMode::Multistage, penalty);
    let err = paper.set_coast_time(0.5).expect_err("the penalty form has no coast");
    assert!(err.to_string().contains("coast_time_s"), "{err}");
    paper.set_coast_time(0.0).expect("no coast is every form's");
    let mut def =
        OcpDefinition::from_scenario(&s, ControllerMode::Multistage, 0.1, ObstacleFormulation::DistanceAlm);
    def.coast_time_s = 6.0;
    let err = Mpc::new(def, MpcSettings::default()).err().expect("refused at construction too");
    assert!(err.to_string().contains("coast_time_s"), "{err}");
}

/// Deepest violation over the predicted points of every scenario of the coast `p + s v`, `s`
/// in `[0, coast_s]`, against the cylinders inflated by `margin_m`, m: sampled along the coast
/// (an implementation of its own, not the evaluator's closed form).
fn deepest_coast_violation_m(
    states: &[Vec<[f64; 8]>],
    cylinders: &[mav::Cylinder],
    margin_m: f64,
    coast_s: f64,
) -> f64 {
    let mut worst = f64::NEG_INFINITY;
    for x in states.iter().flat_map(|p| p.iter().skip(1)) {
        for c in cylinders {
            if x[2] >= c.height_m {
                continue;
            }
            for k in 0..=400 {
                let s = coast_s * k as f64 / 400.0;
                let d = (x[0] + s * x[3] - c.x_m).hypot(x[1] + s * x[4] - c.y_m);
                worst = worst.max(c.radius_m + margin_m - d);
            }
        }
    }
    worst
}

/// Standard NMPC (one scenario, whose solves come close to an optimum) from a state heading
/// north at 1 m/s toward paper-2's first cylinder, just right of the straight line to the
/// goal: without a coast the plan's coasts cut 7-8 cm into the inflated cylinder (it turns
/// late); with one, about 1.6 cm (both solvers, at their iteration limits).
#[test]
fn a_plan_solved_with_a_coast_keeps_its_coast_nearly_clear_where_the_plan_without_one_does_not() {
    let s = Scenario::paper_2();
    let x0 = [3.2, 0.3, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0];
    let coast_s = 0.96;
    for solver in [PanocSolver::OpEn, PanocSolver::Own] {
        let violation = |coast: f64| {
            let mut mpc = mpc_for(&s, ControllerMode::Nmpc, MpcSettings { solver, ..MpcSettings::default() });
            mpc.set_coast_time(coast).expect("in range");
            let r = mpc.solve(&x0, &[9.81, 0.0, 0.0], &[1.0], &SolveBudget::default()).expect("valid");
            assert!(r.min_clearance_m > 0.0, "{solver:?}, coast {coast}: the plan is clear");
            deepest_coast_violation_m(&mpc.predictions(), &s.obstacles, 0.1, coast_s)
        };
        let (without, with) = (violation(0.0), violation(coast_s));
        assert!(without > 0.05, "{solver:?}: without a coast {without:.4} m");
        assert!(with < 0.3 * without, "{solver:?}: with a coast {with:.4} m, without {without:.4} m");
    }
}
