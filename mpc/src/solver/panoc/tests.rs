use super::*;

/// `ψ(z) = z'Qz / 2 - b'z` with `Q` tridiagonal (4 on the diagonal, -1 beside), counting
/// gradient evaluations.
struct Quadratic {
    b: Vec<f64>,
    gradients: usize,
}

impl Quadratic {
    fn q_times(z: &[f64], out: &mut [f64]) {
        let n = z.len();
        for k in 0..n {
            let mut v = 4.0 * z[k];
            if k > 0 {
                v -= z[k - 1];
            }
            if k + 1 < n {
                v -= z[k + 1];
            }
            out[k] = v;
        }
    }
}

impl SmoothCost for Quadratic {
    fn cost(&mut self, z: &[f64]) -> f64 {
        let mut qz = vec![0.0; z.len()];
        Self::q_times(z, &mut qz);
        0.5 * dot(z, &qz) - dot(&self.b, z)
    }

    fn cost_and_gradient(&mut self, z: &[f64], grad: &mut [f64]) -> f64 {
        self.gradients += 1;
        Self::q_times(z, grad);
        let f = 0.5 * dot(z, grad) - dot(&self.b, z);
        for k in 0..z.len() {
            grad[k] -= self.b[k];
        }
        f
    }
}

/// A box QP whose solution is known by construction: `z*` has its first two coordinates at the
/// upper bound 1 (with the gradient pushing outwards) and the rest inside; `b = Q z* + λ` with
/// `λ` positive on the active coordinates (the KKT conditions), zero elsewhere.
fn box_qp() -> (Quadratic, Vec<f64>, Vec<f64>, Vec<f64>) {
    let n = 12;
    let z_star: Vec<f64> = (0..n).map(|k| if k < 2 { 1.0 } else { 0.5 - 0.07 * k as f64 }).collect();
    let mut b = vec![0.0; n];
    Quadratic::q_times(&z_star, &mut b);
    b[0] += 3.0;
    b[1] += 0.5;
    (Quadratic { b, gradients: 0 }, z_star, vec![-1.0; n], vec![1.0; n])
}

#[test]
fn a_box_qp_converges_to_its_known_solution() {
    let (mut qp, z_star, lo, hi) = box_qp();
    let mut panoc = Panoc::new(z_star.len(), 5);
    let mut z = vec![0.0; z_star.len()];
    let exit = panoc.solve(&mut qp, &mut z, &lo, &hi, 1e-16, 500, None);
    assert_eq!(exit.status, PanocStatus::Converged, "{exit:?}");
    for (k, (a, b)) in z.iter().zip(&z_star).enumerate() {
        assert!((a - b).abs() < 1e-7, "z[{k}] = {a}, expected {b}");
    }
    assert!(z[0] == 1.0 && z[1] == 1.0, "the active bounds are met exactly (projection)");
}

/// `sum_k 100 (z_{k+1} - z_k²)² + (1 - z_k)²` (the chained Rosenbrock function), minimum 0 at
/// all ones, on the box `[-2, 2]`.
struct Rosenbrock;

impl SmoothCost for Rosenbrock {
    fn cost(&mut self, z: &[f64]) -> f64 {
        (0..z.len() - 1).map(|k| 100.0 * (z[k + 1] - z[k] * z[k]).powi(2) + (1.0 - z[k]).powi(2)).sum()
    }

    fn cost_and_gradient(&mut self, z: &[f64], grad: &mut [f64]) -> f64 {
        grad.iter_mut().for_each(|g| *g = 0.0);
        for k in 0..z.len() - 1 {
            let t = z[k + 1] - z[k] * z[k];
            grad[k] += -400.0 * t * z[k] - 2.0 * (1.0 - z[k]);
            grad[k + 1] += 200.0 * t;
        }
        self.cost(z)
    }
}

#[test]
fn the_rosenbrock_valley_is_followed_to_its_minimum() {
    let n = 6;
    let mut panoc = Panoc::new(n, 8);
    let mut z = vec![-1.2, 1.0, -1.2, 1.0, -1.2, 1.0];
    // The minimum is 0, so the relative test needs the absolute cost to fall with it: a tight
    // tolerance stops on the residual floor of the iteration budget instead.
    let exit = panoc.solve(&mut Rosenbrock, &mut z, &[-2.0; 6], &[2.0; 6], 1e-12, 5000, None);
    assert_ne!(exit.status, PanocStatus::NotFinite);
    for (k, v) in z.iter().enumerate() {
        assert!((v - 1.0).abs() < 1e-4, "z[{k}] = {v} ({exit:?})");
    }
}

#[test]
fn a_bound_that_cuts_the_rosenbrock_valley_holds_the_solution_on_it() {
    // Upper bound 0.5 on z_0: the minimum over z_0 <= 0.5 in 2-D is at z_0 = 0.5, z_1 = 0.25
    // (there the valley's floor z_1 = z_0² is reached and 1 - z_0 pulls z_0 up to the bound).
    let mut panoc = Panoc::new(2, 5);
    let mut z = vec![-1.0, 2.0];
    let exit = panoc.solve(&mut Rosenbrock, &mut z, &[-2.0, -2.0], &[0.5, 2.0], 1e-14, 2000, None);
    assert_eq!(exit.status, PanocStatus::Converged, "{exit:?}");
    assert_eq!(z[0], 0.5);
    assert!((z[1] - 0.25).abs() < 1e-6, "{z:?}");
}

#[test]
fn the_lipschitz_estimate_is_carried_to_the_next_call_without_a_finite_difference() {
    let (mut qp, z_star, lo, hi) = box_qp();
    let mut panoc = Panoc::new(z_star.len(), 5);
    let mut z = vec![0.0; z_star.len()];
    panoc.solve(&mut qp, &mut z, &lo, &hi, 1e-16, 500, None);
    // Q's largest eigenvalue is below 6: the estimate stays within a factor 2 of it (doubling).
    assert!(panoc.lipschitz() > 2.0 && panoc.lipschitz() < 12.0, "{}", panoc.lipschitz());
    // A call at the solution: one gradient at the start, none for an estimate, and converged
    // at once.
    qp.gradients = 0;
    let exit = panoc.solve(&mut qp, &mut z, &lo, &hi, 1e-16, 500, None);
    assert_eq!((exit.status, exit.iterations, qp.gradients), (PanocStatus::Converged, 0, 1));
    // Forgotten, the estimate costs a second gradient.
    panoc.forget_lipschitz();
    qp.gradients = 0;
    panoc.solve(&mut qp, &mut z, &lo, &hi, 1e-16, 500, None);
    assert_eq!(qp.gradients, 2);
}

#[test]
fn a_large_carried_lipschitz_estimate_does_not_loosen_the_stopping_test() {
    // OpEn's test `γ |R| < ε` is met at once when `γ = 0.95 / L` is tiny; the test on `R`
    // alone still needs the solution. Carried `L` 1e6 against the QP's true 6:
    let (mut qp, z_star, lo, hi) = box_qp();
    let tolerance = 1e-10;
    let mut panoc = Panoc::new(z_star.len(), 5);
    panoc.lipschitz = 1e6;
    let mut z = vec![0.0; z_star.len()];
    let exit = panoc.solve(&mut qp, &mut z, &lo, &hi, tolerance, 10_000, None);
    assert_eq!(exit.status, PanocStatus::Converged, "{exit:?}");
    assert!(0.5 * exit.residual * exit.residual <= tolerance * exit.cost.abs());
    let gap = z.iter().zip(&z_star).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    assert!(gap < 1e-4, "{z:?}");
}

#[test]
fn the_same_inputs_give_the_same_bits() {
    let solve = || {
        let mut panoc = Panoc::new(6, 4);
        let mut z = vec![-1.2, 1.0, -1.2, 1.0, -1.2, 1.0];
        let exit = panoc.solve(&mut Rosenbrock, &mut z, &[-2.0; 6], &[2.0; 6], 1e-10, 300, None);
        (exit.iterations, exit.cost.to_bits(), z.iter().map(|v| v.to_bits()).collect::<Vec<_>>())
    };
    assert_eq!(solve(), solve());
}

#[test]
fn the_iteration_limit_returns_the_best_half_step_inside_the_box() {
    let mut panoc = Panoc::new(6, 4);
    let mut z = vec![-1.2, 1.0, -1.2, 1.0, -1.2, 1.0];
    let exit = panoc.solve(&mut Rosenbrock, &mut z, &[-2.0; 6], &[0.9; 6], 1e-30, 3, None);
    assert_eq!((exit.status, exit.iterations), (PanocStatus::IterationLimit, 3));
    assert!(z.iter().all(|v| (-2.0..=0.9).contains(v)), "{z:?}");
    assert_eq!(Rosenbrock.cost(&z), exit.cost);
}
