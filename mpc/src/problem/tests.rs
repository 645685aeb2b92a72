use super::constraints::{any_penalty_term, constraint, floor_constraint};
use super::euler::sin_cos_small;
use super::*;
use mav::{Dynamics, MavModel, Scenario, euler_step};
use proptest::prelude::*;

fn evaluator(
    mode: ControllerMode,
    formulation: ObstacleFormulation,
    x0: [f64; 8],
    weights: &[f64],
) -> Evaluator {
    coasting_evaluator(mode, formulation, 0.0, x0, weights)
}

fn coasting_evaluator(
    mode: ControllerMode,
    formulation: ObstacleFormulation,
    coast_time_s: f64,
    x0: [f64; 8],
    weights: &[f64],
) -> Evaluator {
    let mut def = OcpDefinition::from_scenario(&Scenario::paper_2(), mode, 0.1, formulation);
    def.coast_time_s = coast_time_s;
    let mut ev = Evaluator::new(&def);
    ev.set_instance(&x0, &[9.81, 0.01, -0.02], weights);
    ev
}

#[test]
fn forward_pass_is_the_euler_model_of_mav() {
    let x0 = [3.0, 0.5, 0.7, 0.2, 1.1, -0.3, 0.05, -0.08];
    let mut ev = evaluator(ControllerMode::Multistage, ObstacleFormulation::DistanceAlm, x0, &[0.2; 5]);
    let n = ev.num_variables();
    let z: Vec<f64> = (0..n).map(|k| ((k % 7) as f64 - 3.0) * 0.3).collect();
    ev.objective(&z);
    let u = ev.inputs().to_vec();
    let model = MavModel::default();
    for (i, &dt) in [0.05, 0.07, 0.1, 0.2, 0.33].iter().enumerate() {
        let mut x = mav::State::from(x0);
        for j in 0..ev.horizon() {
            let uj = mav::Input::new(u[3 * j], u[3 * j + 1], u[3 * j + 2]);
            x = euler_step(&model, &x, &uj, dt);
            let p = ev.predicted_states(i)[j + 1];
            for k in 0..8 {
                assert!((p[k] - x[k]).abs() <= 1e-9 * (1.0 + x[k].abs()), "scenario {i} step {j} state {k}");
            }
        }
    }
    // and the derivative used is the model's
    let d = model.derivative(&mav::State::from(x0), &mav::Input::new(9.81, 0.0, 0.0));
    assert!(d.iter().all(|v| v.is_finite()));
}

fn arb_z(n: usize) -> impl Strategy<Value = Vec<f64>> {
    prop::collection::vec(-1.0f64..1.0, n)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    #[test]
    fn gradient_matches_finite_differences_single_scenario(
        z in arb_z(120), px in 2.5f64..3.8, py in 0.5f64..4.5, vy in 0.0f64..2.0,
        c in prop::sample::select(vec![0.0, 1e2, 1e4]),
        y_scale in 0.0f64..50.0,
        paper_form in any::<bool>(),
        coast_s in prop::sample::select(vec![0.0, 0.7]),
    ) {
        let form = if paper_form { ObstacleFormulation::PaperPenalty } else { ObstacleFormulation::DistanceAlm };
        let coast_s = if paper_form { 0.0 } else { coast_s };
        let x0 = [px, py, 0.8, 0.1, vy, 0.0, 0.02, -0.03];
        let mut ev = coasting_evaluator(ControllerMode::Nmpc, form, coast_s, x0, &[1.0]);
        let nc = 40 * 3;
        let y: Vec<f64> = if paper_form { Vec::new() } else { (0..nc).map(|k| y_scale * ((k % 5) as f64) / 5.0).collect() };
        prop_assert!(check_gradient(&mut ev, &z, c, &y).is_ok(), "{:?}", check_gradient(&mut ev, &z, c, &y));
    }

    #[test]
    fn gradient_matches_finite_differences_five_scenarios(
        z in arb_z(120), px in 2.5f64..3.8, py in 0.5f64..4.5, vy in 0.0f64..2.0,
        w in prop::collection::vec(0.0f64..1.0, 5),
        c in prop::sample::select(vec![0.0, 1e2, 1e4]),
        y_scale in 0.0f64..50.0,
        paper_form in any::<bool>(),
        coast_s in prop::sample::select(vec![0.0, 0.7]),
    ) {
        let form = if paper_form { ObstacleFormulation::PaperPenalty } else { ObstacleFormulation::DistanceAlm };
        let coast_s = if paper_form { 0.0 } else { coast_s };
        let mut w = w;
        w[2] += 0.1;
        let x0 = [px, py, 0.8, 0.1, vy, 0.0, 0.02, -0.03];
        let mut ev = coasting_evaluator(ControllerMode::Multistage, form, coast_s, x0, &w);
        let nc = 5 * 40 * 3;
        let y: Vec<f64> = if paper_form { Vec::new() } else { (0..nc).map(|k| y_scale * ((k % 5) as f64) / 5.0).collect() };
        prop_assert!(check_gradient(&mut ev, &z, c, &y).is_ok(), "{:?}", check_gradient(&mut ev, &z, c, &y));
    }
}

#[test]
fn obstacles_are_active_in_the_gradient_tests() {
    // A state heading straight at the 0.4 m cylinder: some predicted point is inside, for
    // one scenario and for five, both forms, with and without ALM multipliers.
    let x0 = [2.8, 2.0, 0.8, 0.0, 1.5, 0.0, 0.0, 0.0];
    for (mode, weights) in [(ControllerMode::Nmpc, vec![1.0]), (ControllerMode::Multistage, vec![0.2; 5])] {
        for form in [ObstacleFormulation::PaperPenalty, ObstacleFormulation::DistanceAlm] {
            let mut ev = evaluator(mode, form, x0, &weights);
            let z = vec![0.0; 120];
            let with = ev.cost(&z, 1e3, &[]);
            let without = ev.cost(&z, 0.0, &[]);
            assert!(with > without, "{mode:?} {form:?}: penalty must be active");
            assert!(check_gradient(&mut ev, &z, 1e3, &[]).is_ok(), "{mode:?} {form:?}");
            if form == ObstacleFormulation::DistanceAlm {
                let nc = weights.len() * 40 * 3;
                let y: Vec<f64> = (0..nc).map(|k| 20.0 * ((k % 5) as f64)).collect();
                assert!(ev.cost(&z, 1e3, &y) > with, "{mode:?}: multipliers add terms");
                assert!(check_gradient(&mut ev, &z, 1e3, &y).is_ok(), "{mode:?} with multipliers");
            }
        }
    }
    // Far from every cylinder nothing is active: the penalty adds nothing, and the gradient
    // is the objective's.
    let far = [8.0, -6.0, 0.8, 0.0, -0.5, 0.0, 0.0, 0.0];
    for (mode, weights) in [(ControllerMode::Nmpc, vec![1.0]), (ControllerMode::Multistage, vec![0.2; 5])] {
        let mut ev = evaluator(mode, ObstacleFormulation::DistanceAlm, far, &weights);
        let z = vec![0.0; 120];
        assert_eq!(ev.cost(&z, 1e3, &[]), ev.cost(&z, 0.0, &[]), "{mode:?}");
        assert!(check_gradient(&mut ev, &z, 1e3, &[]).is_ok(), "{mode:?}");
    }
}

/// The coast's closest point to an axis, against the geometry worked by hand.
#[test]
fn a_coast_comes_closest_where_it_heads_for_the_axis_and_nowhere_else() {
    use super::constraints::closest_coast_point;
    // 2 m east of the axis, 1 m/s west: 0.7 s of coasting ends 1.3 m from it.
    assert_eq!(closest_coast_point(2.0, 0.0, -1.0, 0.0, 0.7), (1.3, 0.0, 0.7));
    // Past the axis within the coast: the closest point is abeam of it (its offset 0.5 m).
    let (qx, qy, s) = closest_coast_point(1.0, 0.5, -2.0, 0.0, 0.7);
    assert!((qx.abs() < 1e-12) && (qy - 0.5).abs() < 1e-12 && (s - 0.5).abs() < 1e-12);
    // Moving away, or along the surface, or hovering: the point itself.
    assert_eq!(closest_coast_point(2.0, 0.0, 1.0, 0.0, 0.7), (2.0, 0.0, 0.0));
    assert_eq!(closest_coast_point(2.0, 0.0, 0.0, 1.0, 0.7), (2.0, 0.0, 0.0));
    assert_eq!(closest_coast_point(2.0, 0.0, 0.0, 0.0, 0.7), (2.0, 0.0, 0.0));
    // No coast: the point itself whatever the velocity.
    assert_eq!(closest_coast_point(2.0, 0.0, -1.0, 0.0, 0.0), (2.0, 0.0, 0.0));
}

/// A point clear of the inflated cylinder but heading for it fast enough to reach it within
/// the coast is a violation with a coast and none without, and the coast's gradient (checked
/// against finite differences) pulls the velocity away from the cylinder.
#[test]
fn a_coast_makes_a_point_heading_for_a_cylinder_a_violation_one_passing_it_none_and_one_through_its_axis_turn_aside()
 {
    let def = OcpDefinition::from_scenario(
        &Scenario::paper_2(),
        ControllerMode::Nmpc,
        0.1,
        ObstacleFormulation::DistanceAlm,
    );
    let cyl = def.obstacles[0];
    let r = cyl.radius_m + 0.1;
    // 0.3 m outside the inflated radius, west of the axis, below the top.
    let (px, py, pz) = (cyl.x_m - r - 0.3, cyl.y_m, 0.5 * cyl.height_m);
    let ob = super::constraints::ObstacleTerm { xo: cyl.x_m, yo: cyl.y_m, r2: r * r, zo: cyl.height_m, r };
    let toward = [px, py, pz, 1.0, 0.0, 0.0, 0.0, 0.0];
    let past = [px, py, pz, 0.0, 1.0, 0.0, 0.0, 0.0];
    let g = |coast_s: f64, x: &[f64; 8]| constraint(ObstacleFormulation::DistanceAlm, &ob, coast_s, x);
    assert!((g(0.0, &toward).0 + 0.3).abs() < 1e-12, "no coast: 0.3 m clear");
    assert!((g(0.5, &toward).0 - (0.5 - 0.3)).abs() < 1e-12, "0.5 m of coast at 1 m/s: 0.2 m inside");
    assert!((g(2.0, &toward).0 - r).abs() < 1e-6, "a coast through the axis: the whole radius");
    assert_eq!(g(0.7, &past).0, g(0.0, &past).0, "passing it: the point alone");
    let (_, dg) = g(0.5, &toward);
    assert!(dg[3] > 0.0 && dg[4] == 0.0, "more speed toward it, more violation: {dg:?}");
    // Straight at the axis, the coast through it: a unit normal to one side (the left of the
    // velocity), not the zero that `q / |q|` with `|q|` at rounding level would give.
    let (_, dg) = g(2.0, &toward);
    assert!((dg[0].hypot(dg[1]) - 1.0).abs() < 1e-12, "a unit normal: {dg:?}");
    assert!(dg[0].abs() < 1e-12 && dg[1] < 0.0, "sideways, the left of +x pushed out: {dg:?}");
    let s = r + 0.3;
    assert!(
        (dg[3] - s * dg[0]).abs() < 1e-9 && (dg[4] - s * dg[1]).abs() < 1e-9,
        "in v, s times that: {dg:?}"
    );
    // The gradient against central differences in (px, py, vx, vy), heading for the cylinder
    // at an angle (the closest point then moves with every component).
    let angled = [px, py - 0.2, pz, 1.0, 0.4, 0.0, 0.0, 0.0];
    let (_, dg) = g(0.7, &angled);
    for k in [0usize, 1, 3, 4] {
        let h = 1e-6;
        let (mut a, mut b) = (angled, angled);
        a[k] += h;
        b[k] -= h;
        let fd = (g(0.7, &a).0 - g(0.7, &b).0) / (2.0 * h);
        assert!((fd - dg[k]).abs() < 1e-6, "component {k}: {fd} against {}", dg[k]);
    }
}

#[test]
fn a_penalty_term_is_active_where_c_g_plus_y_is_positive() {
    assert!(!any_penalty_term(&[-0.1, -0.2], &[], 1e3));
    assert!(any_penalty_term(&[-0.1, 0.001], &[], 1e3));
    // A multiplier keeps a satisfied constraint in the augmented Lagrangian...
    assert!(any_penalty_term(&[-0.1, -0.2], &[101.0, 0.0], 1e3));
    // ...until the constraint is satisfied by more than y / c.
    assert!(!any_penalty_term(&[-0.1, -0.2], &[99.0, 0.0], 1e3));
}

#[test]
fn small_angle_sin_cos_matches_libm() {
    for k in -1000..=1000 {
        let x = k as f64 * 0.6e-3;
        let (s, c) = sin_cos_small(x);
        assert!((s - x.sin()).abs() <= 2e-16, "sin({x})");
        assert!((c - x.cos()).abs() <= 2e-16, "cos({x})");
    }
    assert_eq!(sin_cos_small(2.0), 2.0f64.sin_cos());
}

#[test]
fn the_penalty_preconditioner_adds_curvature_only_for_active_constraints() {
    // Far from every cylinder: nothing active, the hover scaling is unchanged.
    let x0 = [0.0, 8.0, 1.5, 0.0, 0.0, 0.0, 0.0, 0.0];
    let mut ev = evaluator(ControllerMode::Multistage, ObstacleFormulation::DistanceAlm, x0, &[0.2; 5]);
    let hover = ev.scaling.scale.clone();
    let u: Vec<f64> = (0..120).map(|k| [9.81, 0.0, 0.0][k % 3]).collect();
    ev.objective_at_inputs(&u);
    ev.update_scaling_with_penalty(1e3, &[], 0.0);
    assert_eq!(ev.scaling.scale, hover);
    // Heading into the 0.4 m cylinder: the inputs before an active point get stiffer.
    let x0 = [2.8, 2.0, 0.8, 0.0, 1.5, 0.0, 0.0, 0.0];
    let mut ev = evaluator(ControllerMode::Multistage, ObstacleFormulation::DistanceAlm, x0, &[0.2; 5]);
    let hover = ev.scaling.scale.clone();
    ev.objective_at_inputs(&u);
    assert!(ev.constraint_values().iter().any(|g| *g > 0.0));
    ev.update_scaling_with_penalty(1e3, &[], 0.0);
    assert!(ev.scaling.scale.iter().zip(&hover).all(|(a, b)| a <= b));
    assert!(ev.scaling.scale.iter().zip(&hover).any(|(a, b)| a < b));
}

#[test]
fn scaling_round_trips_and_maps_the_box() {
    let ev = evaluator(ControllerMode::Multistage, ObstacleFormulation::DistanceAlm, [0.0; 8], &[0.2; 5]);
    let u: Vec<f64> = (0..120).map(|k| [12.0, 0.1, -0.1][k % 3]).collect();
    let mut z = vec![0.0; 120];
    let mut back = vec![0.0; 120];
    ev.to_scaled(&u, &mut z);
    ev.to_inputs(&z, &mut back);
    for (a, b) in u.iter().zip(&back) {
        assert!((a - b).abs() < 1e-12);
    }
    let (mut lo, mut hi) = (vec![0.0; 120], vec![0.0; 120]);
    ev.scaled_bounds(&mav::InputBounds::paper(9.81), &mut lo, &mut hi);
    let mut u_lo = vec![0.0; 120];
    ev.to_inputs(&lo, &mut u_lo);
    assert!((u_lo[0] - 0.0).abs() < 1e-12 && (u_lo[1] + std::f64::consts::PI / 18.0).abs() < 1e-12);
}

/// The evaluator's passes one scenario at a time, as they were before the lane-parallel
/// ones (the oracle of `lane_parallel_passes_are_bit_identical_to_one_scenario_at_a_time`):
/// `(cost, gradient in z, constraint values, predicted states)` at inputs `ev.u`.
fn scalar_reference(ev: &Evaluator, c: f64, y: &[f64]) -> (f64, Vec<f64>, Vec<f64>, Vec<[f64; 8]>) {
    let (m, n, n_con) = (ev.m, ev.n, ev.n_con);
    let e = crate::qp::EulerCoeffs::new(&ev.params);
    let (kr, kp) = (e.kr, e.kp);
    let n_obs = ev.obstacles.len();
    let mut states = vec![[0.0; 8]; m * (n + 1)];
    let mut trig = vec![[0.0; 4]; m * n];
    let mut con = vec![0.0; m * n * n_con];
    // Forward pass.
    let mut objective = 0.0;
    for i in 0..m {
        let dt = ev.dts[i];
        let states = &mut states[i * (n + 1)..(i + 1) * (n + 1)];
        let trig = &mut trig[i * n..(i + 1) * n];
        let con = &mut con[i * n * n_con..(i + 1) * n * n_con];
        let mut x = ev.x0s[i];
        states[0] = x;
        let mut state_cost = 0.0;
        for (j, u) in ev.u.chunks_exact(3).enumerate() {
            let (sr, cr) = sin_cos_small(x[6]);
            let (sp, cp) = sin_cos_small(x[7]);
            trig[j] = [sr, cr, sp, cp];
            x = e.step(&x, u, dt, [sr, cr, sp, cp]);
            states[j + 1] = x;
            for ((xk, rk), qk) in x.iter().zip(&ev.x_ref).zip(&ev.q_x) {
                let e = xk - rk;
                state_cost += qk * e * e;
            }
            for (ob, c) in ev.obstacles.iter().zip(&mut con[j * n_con..j * n_con + n_obs]) {
                *c = constraint(ev.formulation, ob, ev.coast_s, &x).0;
            }
            if let Some(floor) = ev.min_altitude_m {
                con[j * n_con + n_obs] = floor_constraint(ev.formulation, floor, &x).0;
            }
        }
        objective += ev.weights[i] * state_cost;
    }
    objective += ev.weight_sum * ev.input_cost();
    let mut penalty = 0.0;
    if c > 0.0 {
        for (k, g) in con.iter().enumerate() {
            let v = g + y.get(k).map_or(0.0, |y| y / c);
            if v > 0.0 {
                penalty += v * v;
            }
        }
        penalty *= 0.5 * c;
    }
    // Adjoint pass.
    let w2 = 2.0 * ev.weight_sum;
    let mut grad_u = vec![0.0; 3 * n];
    for j in 0..n {
        for ch in 0..3 {
            let k = 3 * j + ch;
            let u = ev.u[k];
            let prev = if j == 0 { ev.u_prev[ch] } else { ev.u[k - 3] };
            let mut gk = ev.q_u[ch] * (u - ev.u_ref[ch]) + ev.q_du[ch] * (u - prev);
            if j + 1 < n {
                gk -= ev.q_du[ch] * (ev.u[k + 3] - u);
            }
            grad_u[k] = w2 * gk;
        }
    }
    for i in 0..m {
        let dt = ev.dts[i];
        let w2 = 2.0 * ev.weights[i];
        let wq: [f64; 8] = std::array::from_fn(|k| w2 * ev.q_x[k]);
        let states = &states[i * (n + 1) + 1..(i + 1) * (n + 1)];
        let con = &con[i * n * n_con..(i + 1) * n * n_con];
        let y = y.get(i * n * n_con..(i + 1) * n * n_con).unwrap_or(&[]);
        let mut l = [0.0f64; 8];
        for j in (0..n).rev() {
            let x = &states[j];
            for k in 0..8 {
                l[k] += wq[k] * (x[k] - ev.x_ref[k]);
            }
            if c > 0.0 {
                for o in j * n_con..(j + 1) * n_con {
                    let v = c * con[o] + y.get(o).copied().unwrap_or(0.0);
                    if v > 0.0 {
                        let dg = ev.constraint_gradient(o - j * n_con, x);
                        l[0] += v * dg[0];
                        l[1] += v * dg[1];
                        l[2] += v * dg[2];
                        l[3] += v * dg[3];
                        l[4] += v * dg[4];
                    }
                }
            }
            let [sr, cr, sp, cp] = trig[i * n + j];
            let t = ev.u[3 * j];
            grad_u[3 * j] += dt * (cr * sp * l[3] - sr * l[4] + cr * cp * l[5]);
            grad_u[3 * j + 1] += dt * kr * l[6];
            grad_u[3 * j + 2] += dt * kp * l[7];
            e.adjoint_step(&mut l, dt, t, [sr, cr, sp, cp]);
        }
    }
    let grad = grad_u.iter().zip(&ev.scaling.scale).map(|(g, s)| g * s).collect();
    (objective + penalty, grad, con, states)
}

/// Every scenario count from 1 to past a group (`MAX_LANES`), both formulations, with and
/// without the floor, dead-time compensation and multipliers, attitudes in and out of the
/// series' range, and active constraints: the same bits as one scenario at a time.
#[test]
fn lane_parallel_passes_are_bit_identical_to_one_scenario_at_a_time() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    for m in [1usize, 2, 3, 4, 5, 7, 8, 9, 13] {
        for (form, floor, compensation, coast_s) in [
            (ObstacleFormulation::DistanceAlm, None, false, 0.0),
            (ObstacleFormulation::DistanceAlm, Some(0.4), true, 0.0),
            (ObstacleFormulation::DistanceAlm, Some(0.4), true, 0.6),
            (ObstacleFormulation::PaperPenalty, None, true, 0.0),
            (ObstacleFormulation::PaperPenalty, Some(0.4), false, 0.0),
        ] {
            let mut def =
                OcpDefinition::from_scenario(&Scenario::paper_2(), ControllerMode::Multistage, 0.1, form);
            def.sampling_times_s = (0..m).map(|i| 0.05 + 0.025 * i as f64).collect();
            def.min_altitude_m = floor;
            def.delay_compensation = compensation;
            def.coast_time_s = coast_s;
            let mut ev = Evaluator::new(&def);
            let n = ev.num_variables();
            for point in 0..4 {
                // Heading at the cylinders (active constraints); attitudes beyond 0.5 rad
                // (libm's sin and cos) in every other point.
                let angle = if point % 2 == 1 { 0.8 } else { 0.1 };
                let x0 = [
                    rng.random_range(2.6..3.4),
                    rng.random_range(1.0..3.0),
                    rng.random_range(0.3..1.0),
                    0.0,
                    rng.random_range(0.5..1.5),
                    0.0,
                    rng.random_range(-angle..angle),
                    rng.random_range(-angle..angle),
                ];
                let weights: Vec<f64> = (0..m).map(|_| rng.random_range(0.0..1.0)).collect();
                ev.set_instance(&x0, &[9.81, 0.01, -0.02], &weights);
                let z: Vec<f64> = (0..n).map(|_| rng.random_range(-3.0..3.0)).collect();
                let y: Vec<f64> = match point {
                    0 => Vec::new(),
                    _ => (0..def.num_constraints()).map(|_| rng.random_range(0.0..20.0)).collect(),
                };
                for c in [0.0, 1e3] {
                    let mut grad = vec![0.0; n];
                    let mut con = vec![0.0; def.num_constraints()];
                    let cost = ev.cost(&z, c, &y);
                    ev.gradient(&z, c, &y, &mut grad);
                    ev.constraints(&z, &mut con);
                    let (ref_cost, ref_grad, ref_con, ref_states) = scalar_reference(&ev, c, &y);
                    let case = format!(
                        "M = {m}, {form:?}, floor {floor:?}, compensation {compensation}, coast {coast_s} s, point {point}, c = {c}"
                    );
                    assert_eq!(cost.to_bits(), ref_cost.to_bits(), "cost: {case}");
                    assert_eq!(bits(&grad), bits(&ref_grad), "gradient: {case}");
                    assert_eq!(bits(&con), bits(&ref_con), "constraints: {case}");
                    for i in 0..m {
                        let states = &ref_states[i * (n / 3 + 1)..(i + 1) * (n / 3 + 1)];
                        let state_bits =
                            |s: &[[f64; 8]]| s.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
                        assert_eq!(
                            state_bits(ev.predicted_states(i)),
                            state_bits(states),
                            "states of scenario {i}: {case}"
                        );
                    }
                    if point == 2 && c > 0.0 && m == 5 {
                        assert!(con.iter().any(|g| *g > 0.0), "some constraint active: {case}");
                    }
                }
            }
        }
    }
}
