#![allow(clippy::needless_range_loop)]

use super::settings::ELASTIC_TOLERANCE_M;
use super::*;
use crate::problem::{ControllerMode, ObstacleFormulation};
use crate::solver::{Mpc, MpcSettings, SolveBudget};
use mav::Scenario;
use proptest::prelude::*;

const W5: [f64; 5] = [0.05, 0.15, 0.45, 0.30, 0.05];
const HOVER: [f64; 3] = [9.81, 0.0, 0.0];

fn paper_def(scenario: &Scenario, mode: ControllerMode) -> OcpDefinition {
    OcpDefinition::from_scenario(scenario, mode, 0.1, ObstacleFormulation::DistanceAlm)
}

/// paper-3 without cylinders, goal 1 m up: a problem that stays near hover.
fn free_space_def() -> OcpDefinition {
    let mut def = paper_def(&Scenario::paper_3(), ControllerMode::Multistage);
    def.obstacles.clear();
    def
}

/// A small problem for brute-force checks.
fn small_def() -> OcpDefinition {
    let mut def = paper_def(&Scenario::paper_2(), ControllerMode::Multistage);
    def.horizon = 6;
    def.sampling_times_s = vec![0.05, 0.2];
    def
}

fn states_of(def: &OcpDefinition, x0: &[f64; 8], u: &[f64], dt: f64) -> Vec<[f64; 8]> {
    let model = mav::MavModel::new(def.model);
    let mut x = mav::State::from(*x0);
    let mut out = Vec::new();
    for j in 0..def.horizon {
        x = mav::euler_step(&model, &x, &mav::Input::new(u[3 * j], u[3 * j + 1], u[3 * j + 2]), dt);
        out.push(std::array::from_fn(|k| x[k]));
    }
    out
}

#[test]
fn hessian_and_gradient_match_brute_force_gauss_newton() {
    let def = small_def();
    let x0 = [3.0, 1.0, 0.5, 0.3, 0.8, -0.2, 0.05, -0.04];
    let u_prev = [10.0, 0.01, -0.02];
    let w = [0.3, 0.7];
    let nv = def.num_variables();
    let nominal: Vec<f64> = (0..nv).map(|k| [10.5, 0.05, -0.08][k % 3] + 0.004 * (k as f64)).collect();
    assert!(nominal.iter().enumerate().all(|(k, v)| *v <= def.bounds.max[k % 3]), "inside the bounds");
    let mut qp = QpFallback::new(&def, QpSettings::default()).expect("valid");
    qp.solve(&x0, &u_prev, &w, Some(&nominal), &QpBudget::default()).expect("valid");
    // Brute force: Jacobians by central differences, H = sum_i 2 w_i J_i^T Q J_i + input terms.
    let mut h = vec![0.0; nv * nv];
    for (i, &dt) in def.sampling_times_s.iter().enumerate() {
        let mut jac = vec![vec![[0.0; 8]; def.horizon]; nv];
        for v in 0..nv {
            let (mut up, mut um) = (nominal.clone(), nominal.clone());
            up[v] += 1e-6;
            um[v] -= 1e-6;
            let (xp, xm) = (states_of(&def, &x0, &up, dt), states_of(&def, &x0, &um, dt));
            for k in 0..def.horizon {
                for s in 0..8 {
                    jac[v][k][s] = (xp[k][s] - xm[k][s]) / 2e-6;
                }
                for s in 0..3 {
                    let got = qp.sens[(i * def.horizon + k) * nv + v][s];
                    assert!((got - jac[v][k][s]).abs() < 1e-6, "sensitivity {i} {k} {v} {s}: {got}");
                }
            }
        }
        for a in 0..nv {
            for b in 0..nv {
                let mut acc = 0.0;
                for k in 0..def.horizon {
                    for s in 0..8 {
                        acc += 2.0 * w[i] * def.q_x[s] * jac[a][k][s] * jac[b][k][s];
                    }
                }
                h[a * nv + b] += acc;
            }
        }
    }
    let wsum: f64 = w.iter().sum();
    for k in 0..nv {
        let c = k % 3;
        h[k * nv + k] += 2.0 * wsum * (def.q_u[c] + def.q_du[c] * if k + 3 < nv { 2.0 } else { 1.0 });
        if k + 3 < nv {
            h[k * nv + k + 3] -= 2.0 * wsum * def.q_du[c];
            h[(k + 3) * nv + k] -= 2.0 * wsum * def.q_du[c];
        }
    }
    let scale = h.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for k in 0..nv * nv {
        assert!(
            (qp.hess[k] - h[k]).abs() < 1e-5 * scale,
            "H[{}][{}]: {} vs {}",
            k / nv,
            k % nv,
            qp.hess[k],
            h[k]
        );
    }
    // Gradient at the nominal against finite differences of the nonlinear objective.
    let mut ev = Evaluator::new(&def);
    ev.set_instance(&x0, &u_prev, &w);
    for v in 0..nv {
        let (mut up, mut um) = (nominal.clone(), nominal.clone());
        up[v] += 1e-6;
        um[v] -= 1e-6;
        let fd = (ev.objective_at_inputs(&up) - ev.objective_at_inputs(&um)) / 2e-6;
        assert!((fd - qp.grad[v]).abs() < 1e-4 * (1.0 + fd.abs()), "gradient {v}: {} vs {fd}", qp.grad[v]);
    }
}

#[test]
fn without_obstacles_near_hover_the_qp_agrees_with_panoc() {
    let def = free_space_def();
    let mut x0 = [0.0; 8];
    x0[..3].copy_from_slice(&[3.0, 4.6, 0.7]);
    let settings = MpcSettings { tolerance: 1e-7, max_inner_iterations: 3000, ..Default::default() };
    let mut mpc = Mpc::new(def.clone(), settings).expect("valid");
    let r = mpc.solve(&x0, &HOVER, &W5, &SolveBudget::default()).expect("valid");
    let range = [2.0 * 9.81, std::f64::consts::PI / 9.0, std::f64::consts::PI / 9.0];
    // The full QP (no move blocking) agrees closely; the default, move-blocked QP is a
    // restriction of it: its first inputs (the ones applied) and its cost stay close.
    let full = QpSettings { sqp_rounds: 2, block_steps: 1, ..Default::default() };
    let blocked = QpSettings { sqp_rounds: 2, ..Default::default() };
    for (settings, first_steps, input_tol, cost_tol) in [(full, 40, 0.01, 1e-3), (blocked, 6, 0.02, 5e-3)] {
        let mut qp = QpFallback::new(&def, settings).expect("valid");
        let q = qp.solve(&x0, &HOVER, &W5, None, &QpBudget::default()).expect("valid");
        assert_eq!(q.status, QpStatus::Solved);
        assert_eq!(q.num_half_planes, 0);
        let u = qp.solution().expect("solved");
        let mut worst = 0.0f64;
        for (k, (a, b)) in u.iter().zip(mpc.solution()).enumerate().take(3 * first_steps) {
            worst = worst.max((a - b).abs() / range[k % 3]);
        }
        assert!(
            worst < input_tol,
            "block_steps {}: input difference {worst} of the range",
            settings.block_steps
        );
        assert!(
            (q.cost - r.cost).abs() <= cost_tol * r.cost,
            "block_steps {}: QP cost {} vs PANOC cost {}",
            settings.block_steps,
            q.cost,
            r.cost
        );
    }
}

/// paper-2, standard NMPC, heading between the cylinders: many half-planes.
fn between_cylinders() -> (OcpDefinition, [f64; 8]) {
    let def = paper_def(&Scenario::paper_2(), ControllerMode::Nmpc);
    (def, [3.3, 2.2, 0.9, 0.0, 0.6, 0.1, 0.0, 0.0])
}

#[test]
fn lazy_rows_give_the_solution_of_the_qp_with_every_row() {
    let (def, x0) = between_cylinders();
    let eager = QpSettings { lazy_slack_m: f64::INFINITY, ..Default::default() };
    let mut qp = QpFallback::new(&def, eager).expect("valid");
    let r_all = qp.solve(&x0, &HOVER, &[1.0], None, &QpBudget::default()).expect("valid");
    assert_eq!(r_all.status, QpStatus::Solved);
    assert_eq!(r_all.clarabel_solves, 1);
    assert_eq!(
        r_all.num_clarabel_rows,
        2 * qp.num_qp_variables() + r_all.num_constraints - 2 * qp.num_variables()
    );
    let u_all = qp.solution().expect("solved").to_vec();
    // The default (rows with a large nominal slack start outside), no rows at first at all
    // (every row that matters must be found by the re-solves), and every row a candidate,
    // screened to each run's closest points (fewer rows in the end than every row).
    let none_first =
        QpSettings { lazy_slack_m: f64::NEG_INFINITY, max_lazy_rounds: 10, ..Default::default() };
    let screened = QpSettings { lazy_slack_m: 2.0, max_lazy_rounds: 10, ..Default::default() };
    for settings in [QpSettings::default(), none_first, screened] {
        let mut qp = QpFallback::new(&def, settings).expect("valid");
        let r = qp.solve(&x0, &HOVER, &[1.0], None, &QpBudget::default()).expect("valid");
        assert_eq!(r.status, QpStatus::Solved);
        assert_eq!(r.num_constraints, r_all.num_constraints);
        assert!(r.num_clarabel_rows < r_all.num_clarabel_rows, "rows {}", r.num_clarabel_rows);
        assert!(r.linear_violation <= 1e-6, "violation {}", r.linear_violation);
        if settings.lazy_slack_m == f64::NEG_INFINITY {
            assert!(r.clarabel_solves >= 2, "solves {}", r.clarabel_solves);
        }
        let u = qp.solution().expect("solved");
        let worst = u.iter().zip(&u_all).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst < 1e-4, "{settings:?}: largest input difference {worst}");
        assert!((r.cost - r_all.cost).abs() <= 1e-6 * r_all.cost, "cost {} vs {}", r.cost, r_all.cost);
    }
}

#[test]
fn a_run_ends_at_a_gap_and_at_the_end_of_a_scenario() {
    let mut runs = RowRuns { prev: Vec::new(), next: Vec::new(), last: vec![None; 2], owner: Vec::new() };
    // Scenario 0: constraint 0 at points 1, 2, then 4 (a gap); constraint 1 at 2, 3.
    // Scenario 1: constraint 0 at 5, 6 (right after scenario 0's point 4), constraint 1 at 4.
    let rows = [(0, 0, 1), (0, 0, 2), (0, 1, 2), (0, 1, 3), (0, 0, 4), (1, 0, 5), (1, 1, 4), (1, 0, 6)];
    for (r, &(i, c, k)) in rows.iter().enumerate() {
        if r > 0 && rows[r - 1].0 != i {
            runs.start_scenario();
        }
        runs.link(i, c, r, k);
    }
    assert_eq!(runs.prev, [None, Some(0), None, Some(2), None, None, None, Some(5)]);
    assert_eq!(runs.next, [Some(1), None, Some(3), None, None, Some(7), None, None]);
}

#[test]
fn runs_link_consecutive_points_of_one_scenario_and_constraint_only() {
    // paper-2 multi-stage between the cylinders, with the floor: rows of five scenarios,
    // three cylinders and the floor; a short activation distance, so that runs also end
    // and start again.
    let (_, x0) = between_cylinders();
    let s = Scenario::paper_2();
    let def = paper_def(&s, ControllerMode::Multistage);
    let settings = QpSettings { min_altitude_m: Some(0.0), activation_distance_m: 0.3, ..Default::default() };
    let mut qp = QpFallback::new(&def, settings).expect("valid");
    let w = [0.05, 0.15, 0.45, 0.30, 0.05];
    qp.solve(&x0, &HOVER, &w, None, &QpBudget::default()).expect("valid");
    let runs = &qp.runs;
    assert_eq!(runs.owner.len(), qp.b.len());
    let scenarios: std::collections::BTreeSet<usize> = runs.owner.iter().map(|o| o[0]).collect();
    assert!(scenarios.len() > 1, "rows of several scenarios: {scenarios:?}");
    let (mut linked, mut starts) = (0, 0);
    for (r, &[i, c, k]) in runs.owner.iter().enumerate() {
        let before = runs.owner.iter().position(|o| *o == [i, c, k - 1]);
        assert_eq!(runs.prev[r], before, "row {r} {:?}", runs.owner[r]);
        let after = runs.owner.iter().position(|o| *o == [i, c, k + 1]);
        assert_eq!(runs.next[r], after, "row {r} {:?}", runs.owner[r]);
        if before.is_some() {
            linked += 1;
        } else {
            starts += 1;
        }
    }
    assert!(linked > 0 && starts > 0, "{linked} linked, {starts} run starts");
}

#[test]
fn blocked_corrections_are_constant_over_each_block() {
    let (def, x0) = between_cylinders();
    let settings = QpSettings::default();
    let mut qp = QpFallback::new(&def, settings).expect("valid");
    // 6 free steps, then ceil(34 / 6) = 6 blocks.
    assert_eq!(qp.num_qp_variables(), 3 * 12);
    let nominal: Vec<f64> =
        (0..qp.num_variables()).map(|k| HOVER[k % 3] + 0.01 * ((k * 7) % 5) as f64).collect();
    let r = qp.solve(&x0, &HOVER, &[1.0], Some(&nominal), &QpBudget::default()).expect("valid");
    assert_eq!(r.status, QpStatus::Solved);
    let u = qp.solution().expect("solved");
    let d = |j: usize, c: usize| u[3 * j + c] - nominal[3 * j + c];
    let mut moved = 0.0f64;
    for j in 0..def.horizon {
        for c in 0..3 {
            moved = moved.max(d(j, c).abs());
            let first = if j < 6 { j } else { 6 + (j - 6) / 6 * 6 };
            assert!((d(j, c) - d(first, c)).abs() < 1e-12, "step {j} channel {c}");
        }
    }
    assert!(moved > 1e-3, "the QP moved the inputs by {moved}");
}

#[test]
fn the_qp_solution_satisfies_its_own_linear_constraints() {
    let s = Scenario::paper_2();
    // Standard NMPC: from this state the multi-stage problem has points of the 0.2 s and
    // 0.33 s scenarios that no input keeps outside the inflated cylinder (infeasible).
    let def = paper_def(&s, ControllerMode::Nmpc);
    // Heading at the 0.4 m cylinder at (2.8, 3.0).
    let x0 = [2.9, 1.6, 0.8, 0.0, 0.6, 0.0, 0.0, 0.0];
    let settings = QpSettings { min_altitude_m: Some(0.2), ..Default::default() };
    let mut qp = QpFallback::new(&def, settings).expect("valid");
    let r = qp.solve(&x0, &HOVER, &[1.0], None, &QpBudget::default()).expect("valid");
    assert_eq!(r.status, QpStatus::Solved);
    assert!(r.num_half_planes > 50, "half-planes: {}", r.num_half_planes);
    assert!(r.linear_violation <= 1e-6, "violation {}", r.linear_violation);
    let u = qp.solution().expect("solved");
    for (k, v) in u.iter().enumerate() {
        assert!(*v >= def.bounds.min[k % 3] && *v <= def.bounds.max[k % 3]);
    }
    assert!(r.cost.is_finite() && r.min_clearance_m.is_finite() && r.min_altitude_m.is_finite());
}

#[test]
fn a_floor_above_reach_is_infeasible_never_a_solution() {
    let def = paper_def(&Scenario::paper_2(), ControllerMode::Multistage);
    let settings =
        QpSettings { min_altitude_m: Some(500.0), elastic_penalty_per_m: None, ..Default::default() };
    let mut qp = QpFallback::new(&def, settings).expect("valid");
    let r = qp.solve(&Scenario::paper_2().start, &HOVER, &W5, None, &QpBudget::default()).expect("valid");
    assert_eq!(r.status, QpStatus::Infeasible);
    assert!(qp.solution().is_none() && qp.first_input().is_none());
    assert!(r.cost.is_nan());
    // Elastic (the default): the best climb there is, and the status says it is not enough.
    let mut qp =
        QpFallback::new(&def, QpSettings { elastic_penalty_per_m: Some(1e5), ..settings }).expect("valid");
    let r = qp.solve(&Scenario::paper_2().start, &HOVER, &W5, None, &QpBudget::default()).expect("valid");
    assert_eq!(r.status, QpStatus::SolvedElastic);
    assert!(r.elastic_violation_m > 400.0, "{r:?}");
}

#[test]
fn contradictory_half_planes_are_infeasible_or_elastic_never_solved() {
    // The nominal (hover, drifting at 1.5 m/s) flies straight through the cylinder and a
    // tiny trust region forbids turning away: the half-planes contradict the box.
    let def = paper_def(&Scenario::paper_2(), ControllerMode::Nmpc);
    let x0 = [2.8, 2.0, 0.8, 0.0, 1.5, 0.0, 0.0, 0.0];
    let tr = [1e-3, 1e-4, 1e-4];
    let hard = QpSettings { trust_region: Some(tr), elastic_penalty_per_m: None, ..Default::default() };
    let mut qp = QpFallback::new(&def, hard).expect("valid");
    let r = qp.solve(&x0, &HOVER, &[1.0], None, &QpBudget::default()).expect("valid");
    assert_eq!(r.status, QpStatus::Infeasible);
    assert!(qp.solution().is_none() && r.elastic_violation_m.is_nan());
    // Elastic: a solution that says how far it stays inside, never "solved"; it keeps the
    // box and trust region, and leaves no point deeper than the nominal put it.
    let elastic =
        QpSettings { trust_region: Some(tr), elastic_penalty_per_m: Some(1e5), ..Default::default() };
    let mut qp = QpFallback::new(&def, elastic).expect("valid");
    let r = qp.solve(&x0, &HOVER, &[1.0], None, &QpBudget::default()).expect("valid");
    assert_eq!(r.status, QpStatus::SolvedElastic);
    assert!(r.num_elastic_rows > 0 && r.elastic_violation_m > 1e-3, "{r:?}");
    assert!(r.linear_violation <= r.elastic_violation_m + 1e-6, "{r:?}");
    let u = qp.solution().expect("elastic solution").to_vec();
    let nominal = qp.nominal().to_vec();
    for (k, (v, nom)) in u.iter().zip(&nominal).enumerate() {
        assert!((v - nom).abs() <= tr[k % 3] + 1e-7, "input {k}: {v} vs nominal {nom}");
    }
    let nv = u.len();
    for ((row, b), slack) in qp.rows.chunks_exact(nv).zip(&qp.b).zip(&qp.slack) {
        let excess = row.iter().zip(&u).map(|(a, x)| a * x).sum::<f64>() - b;
        assert!(excess <= (-slack).max(0.0) + 1e-6, "a row went deeper: {excess} > {}", -slack);
    }
}

#[test]
fn elastic_rows_change_nothing_when_the_hard_qp_is_feasible() {
    // Paper-1 from a state on its way (in front of the cylinder), linearized around
    // PANOC's plan shifted as in the loop: PANOC's plans cut into the inflated cylinder by
    // up to its constraint tolerance, so some half-planes start violated, yet the inputs
    // can satisfy them all.
    let scenario = Scenario::paper_1();
    let def = paper_def(&scenario, ControllerMode::Multistage);
    let hard = QpSettings { elastic_penalty_per_m: None, ..Default::default() };
    let mut qp_hard = QpFallback::new(&def, hard).expect("valid");
    let elastic = QpSettings { elastic_penalty_per_m: Some(1e5), ..Default::default() };
    let mut qp_elastic = QpFallback::new(&def, elastic).expect("valid");
    let x0 = [0.2, 0.9, 0.45, 0.17, 1.6, 0.57, -0.16, -0.01];
    let mut mpc = Mpc::new(def.clone(), MpcSettings::default()).expect("valid");
    mpc.solve(&x0, &HOVER, &W5, &SolveBudget::default()).expect("valid");
    let plan = mpc.solution();
    let mut nominal = plan[3..].to_vec();
    nominal.extend_from_slice(&plan[plan.len() - 3..]);
    let nominal = Some(&nominal[..]);
    let rh = qp_hard.solve(&x0, &HOVER, &W5, nominal, &QpBudget::default()).expect("valid");
    let re = qp_elastic.solve(&x0, &HOVER, &W5, nominal, &QpBudget::default()).expect("valid");
    assert_eq!(rh.status, QpStatus::Solved, "{rh:?}");
    assert_eq!(re.status, QpStatus::Solved, "{re:?}");
    assert!(re.num_elastic_rows > 0, "the case must have violated rows: {re:?}");
    assert!(re.elastic_violation_m <= ELASTIC_TOLERANCE_M);
    let (uh, ue) = (qp_hard.solution().expect("solved"), qp_elastic.solution().expect("solved"));
    let worst = uh.iter().zip(ue).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(worst < 1e-4, "largest input difference {worst}");
    assert!((rh.cost - re.cost).abs() <= 1e-6 * rh.cost.abs(), "cost {} vs {}", rh.cost, re.cost);
}

#[test]
fn bad_input_and_settings_are_refused_naming_the_field() {
    let def = small_def();
    assert!(matches!(
        QpFallback::new(&def, QpSettings { sqp_rounds: 0, ..Default::default() }),
        Err(MpcError::InvalidSetting { field: "sqp_rounds", .. })
    ));
    assert!(matches!(
        QpFallback::new(&def, QpSettings { block_steps: 0, ..Default::default() }),
        Err(MpcError::InvalidSetting { field: "block_steps", .. })
    ));
    assert!(matches!(
        QpFallback::new(&def, QpSettings { lazy_slack_m: f64::NAN, ..Default::default() }),
        Err(MpcError::InvalidSetting { field: "lazy_slack_m", .. })
    ));
    let mut qp = QpFallback::new(&def, QpSettings::default()).expect("valid");
    let mut x0 = [0.0; 8];
    x0[3] = f64::NAN;
    let e = qp.solve(&x0, &HOVER, &[0.5, 0.5], None, &QpBudget::default());
    assert!(matches!(e, Err(MpcError::InvalidInput { field, .. }) if field == "x0[3]"));
    let e = qp.solve(&[0.0; 8], &HOVER, &[1.0], None, &QpBudget::default());
    assert!(matches!(e, Err(MpcError::InvalidInput { field, .. }) if field == "weights"));
    let e = qp.solve(&[0.0; 8], &HOVER, &[0.5, 0.5], Some(&[1.0; 5]), &QpBudget::default());
    assert!(matches!(e, Err(MpcError::InvalidInput { field, .. }) if field == "nominal"));
}

fn arb_def() -> impl Strategy<Value = OcpDefinition> {
    (
        2usize..=25,
        prop::collection::vec(0.03f64..0.35, 1..=5),
        prop::collection::vec((0.5f64..6.0, 0.5f64..6.0, 0.1f64..0.8), 0..=3),
    )
        .prop_map(|(n, dts, obs)| {
            let mut def = paper_def(&Scenario::paper_2(), ControllerMode::Multistage);
            def.horizon = n;
            def.sampling_times_s = dts;
            def.obstacles = obs.into_iter().map(|(x, y, r)| mav::Cylinder::new(x, y, r)).collect();
            def
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// A solution is a solution of the QP, and an infeasible floor is never "solved".
    #[test]
    fn the_qp_never_reports_success_on_an_infeasible_problem(
        def in arb_def(),
        p in (0.0f64..6.0, 0.0f64..6.0, 0.0f64..3.0),
        v in (-2.0f64..2.0, -2.0f64..2.0, -1.0f64..1.0),
        att in (-0.17f64..0.17, -0.17f64..0.17),
        w in prop::collection::vec(0.01f64..1.0, 5),
        floor_above in 40.0f64..200.0,
    ) {
        let x0 = [p.0, p.1, p.2, v.0, v.1, v.2, att.0, att.1];
        let w = &w[..def.num_scenarios()];
        let mut qp = QpFallback::new(&def, QpSettings::default()).expect("valid");
        let r = qp.solve(&x0, &HOVER, w, None, &QpBudget::default()).expect("valid");
        if r.status.has_solution() {
            // Elastic rows may stay violated, by what the report says and only then.
            let allowed = if r.status == QpStatus::SolvedElastic { r.elastic_violation_m } else { 0.0 };
            prop_assert!(r.linear_violation <= allowed + 1e-6, "violation {} ({:?})", r.linear_violation, r.status);
            prop_assert!(r.status == QpStatus::SolvedElastic || r.elastic_violation_m <= ELASTIC_TOLERANCE_M);
            let u = qp.solution().expect("solution");
            prop_assert!(u.iter().all(|v| v.is_finite()));
            prop_assert!(r.cost.is_finite());
        } else {
            prop_assert!(qp.solution().is_none());
        }
        // A floor far above anything reachable within the horizon (at most 2g up).
        let horizon_s = def.horizon as f64 * def.sampling_times_s.iter().fold(0.0f64, |a, b| a.max(*b));
        let reach = p.2 + v.2.abs() * horizon_s + 0.5 * 9.81 * horizon_s * horizon_s;
        let settings = QpSettings {
            min_altitude_m: Some(reach + floor_above),
            elastic_penalty_per_m: None,
            ..Default::default()
        };
        let mut qp = QpFallback::new(&def, settings).expect("valid");
        let r = qp.solve(&x0, &HOVER, w, None, &QpBudget::default()).expect("valid");
        prop_assert!(!r.status.has_solution(), "status {:?} on an infeasible floor", r.status);
        prop_assert!(qp.solution().is_none());
        // Elastic: never "solved" either.
        let mut qp = QpFallback::new(&def, QpSettings { elastic_penalty_per_m: Some(1e5), ..settings }).expect("valid");
        let r = qp.solve(&x0, &HOVER, w, None, &QpBudget::default()).expect("valid");
        prop_assert!(r.status != QpStatus::Solved && r.status != QpStatus::SolvedReducedAccuracy, "{:?}", r.status);
    }
}
