//! The optimisers on functions with known optima, and the search's determinism.

use falsify::{Dim, Method, SearchSettings, search};

fn unit_dims(n: usize) -> Vec<Dim> {
    (0..n).map(|i| Dim::new(format!("x[{i}]"), 0.0, 1.0)).collect()
}

/// Runs CMA-ES on `f` over `dims` until `f < target` (a "failure" of `f - target`); returns the
/// runs it took and the best value.
fn minimise(
    dims: &[Dim],
    f: impl Fn(&[f64]) -> f64,
    target: f64,
    budget: u64,
    seed: u64,
) -> (Option<u64>, f64) {
    // Tolerances far below the targets: a restart only when a run has converged.
    let settings =
        SearchSettings { tol_x: 1e-12, tol_fun: 1e-14, ..SearchSettings::new(Method::Cmaes, budget, seed) };
    let r = search(dims, &settings, |batch| batch.iter().map(|x| f(x) - target).collect(), |_| {});
    (r.runs_to_failure(), r.best.map_or(f64::INFINITY, |b| b.score + target))
}

fn sphere(centre: f64) -> impl Fn(&[f64]) -> f64 {
    move |x: &[f64]| x.iter().map(|v| (v - centre).powi(2)).sum()
}

fn rosenbrock(x: &[f64]) -> f64 {
    x.windows(2).map(|w| 100.0 * (w[1] - w[0] * w[0]).powi(2) + (1.0 - w[0]).powi(2)).sum()
}

#[test]
fn cmaes_reaches_the_sphere_minimum_to_1e_10_within_2500_runs_in_8_dimensions() {
    for seed in 1..=5 {
        let (runs, best) = minimise(&unit_dims(8), sphere(0.37), 1e-10, 2500, seed);
        assert!(runs.is_some(), "seed {seed}: best {best:e} after 2500 runs");
    }
}

#[test]
fn cmaes_with_restarts_reaches_the_rosenbrock_minimum_in_4_dimensions() {
    // x in [-2, 2]^4 (the cube scaled), minimum 0 at (1, 1, 1, 1).
    let dims: Vec<Dim> = (0..4).map(|i| Dim::new(format!("x[{i}]"), -2.0, 2.0)).collect();
    for seed in 1..=5 {
        let (runs, best) = minimise(&dims, rosenbrock, 1e-8, 20_000, seed);
        assert!(runs.is_some(), "seed {seed}: best {best:e} after 20000 runs");
    }
}

#[test]
fn cmaes_finds_a_minimum_on_the_boundary() {
    // The sphere's centre outside the box: the minimum is the face's point (1, ..., 1), 3 x 0.09.
    for seed in 1..=5 {
        let (runs, best) = minimise(&unit_dims(3), sphere(1.3), 0.27 + 1e-9, 3000, seed);
        assert!(runs.is_some(), "seed {seed}: best {best} after 3000 runs");
    }
    // A corner: the sum's minimum 0 at the origin.
    let (runs, best) = minimise(&unit_dims(5), |x| x.iter().sum(), 1e-6, 3000, 1);
    assert!(runs.is_some(), "best {best} after 3000 runs");
}

#[test]
fn random_search_stays_in_the_box_and_cmaes_beats_it_on_the_sphere() {
    let dims = vec![Dim::new("a", -1.0, 3.0), Dim::new("b", 10.0, 10.5)];
    let settings = SearchSettings { stop_at_failure: false, ..SearchSettings::new(Method::Random, 500, 3) };
    let mut seen = 0;
    let r = search(
        &dims,
        &settings,
        |batch| {
            for p in batch {
                assert!((-1.0..=3.0).contains(&p[0]) && (10.0..=10.5).contains(&p[1]), "{p:?}");
            }
            seen += batch.len();
            batch.iter().map(|p| (p[0] - 1.0).powi(2) + (p[1] - 10.2).powi(2)).collect()
        },
        |_| {},
    );
    assert_eq!((seen, r.runs), (500, 500));
    let (_, cmaes_best) = minimise(&dims, |p| (p[0] - 1.0).powi(2) + (p[1] - 10.2).powi(2), -1.0, 500, 3);
    let random_best = r.best.expect("a best").score;
    assert!(cmaes_best < random_best * 1e-3, "cmaes {cmaes_best:e}, random {random_best:e}");
}

/// The points of every batch of a search whose scores are `f` of the points.
fn trail(method: Method, seed: u64, population: Option<usize>) -> Vec<Vec<f64>> {
    let settings =
        SearchSettings { population, stop_at_failure: false, ..SearchSettings::new(method, 200, seed) };
    let mut points = Vec::new();
    search(
        &unit_dims(3),
        &settings,
        |batch| {
            points.extend(batch.iter().cloned());
            batch.iter().map(|x| rosenbrock(x)).collect()
        },
        |_| {},
    );
    points
}

#[test]
fn the_same_seed_gives_the_same_search_bit_for_bit_and_another_seed_another() {
    for method in [Method::Cmaes, Method::Random] {
        let a = trail(method, 11, None);
        assert_eq!(a.len(), 200, "{method:?}: the budget is flown exactly");
        let bits = |p: &Vec<Vec<f64>>| p.iter().flatten().map(|v| v.to_bits()).collect::<Vec<u64>>();
        assert_eq!(bits(&a), bits(&trail(method, 11, None)), "{method:?}");
        assert_ne!(bits(&a), bits(&trail(method, 12, None)), "{method:?}");
    }
    // Random search's point i does not depend on the batch size (the parallelism).
    assert_eq!(trail(Method::Random, 5, Some(3)), trail(Method::Random, 5, Some(64)));
}

#[test]
fn a_search_stops_at_its_first_failure_and_reports_the_run() {
    // Fails (score < 0) once x0 > 0.9.
    let settings = SearchSettings::new(Method::Random, 1000, 2);
    let mut progress = Vec::new();
    let r = search(
        &unit_dims(2),
        &settings,
        |b| b.iter().map(|x| 0.9 - x[0]).collect(),
        |g| progress.push(g.clone()),
    );
    let first = r.first_failure.clone().expect("a failure");
    assert!(first.point[0] > 0.9 && first.score < 0.0);
    // The batch holding it is the last one flown; the best so far never rises.
    let batch = progress[0].runs;
    assert!(first.run <= r.runs && r.runs - first.run < batch, "{} of {}", first.run, r.runs);
    assert!(progress.windows(2).all(|w| w[1].best <= w[0].best && w[1].runs > w[0].runs));
    assert_eq!(r.runs_to_failure(), Some(first.run));
    assert_eq!(progress.last().map(|g| g.best), r.best.map(|b| b.score));
}

#[test]
fn a_warmed_up_cmaes_flies_random_searchs_first_points_then_refines_the_best_of_them() {
    let dims = unit_dims(3);
    let points = |method: Method, warmup: usize| {
        let settings = SearchSettings {
            stop_at_failure: false,
            warmup,
            tol_x: 1e-12,
            tol_fun: 1e-14,
            ..SearchSettings::new(method, 400, 9)
        };
        let mut seen = Vec::new();
        let r = search(
            &dims,
            &settings,
            |batch| {
                seen.extend(batch.iter().cloned());
                batch.iter().map(|x| sphere(0.8)(x)).collect()
            },
            |_| {},
        );
        (seen, r.best.expect("a best").score)
    };
    let (random, _) = points(Method::Random, 0);
    let (warm, best) = points(Method::Cmaes, 40);
    assert_eq!(warm[..40], random[..40], "the warm-up is random search's first 40 points");
    assert_ne!(warm[40..80], random[40..80], "then CMA-ES");
    // From the best warm-up point CMA-ES converges on the sphere's minimum.
    assert!(best < 1e-6, "{best}");
    assert_eq!(points(Method::Cmaes, 40).0, warm, "deterministic");
}
