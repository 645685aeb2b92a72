//! Points flown in process: the score's sign on real runs, and a search over real runs
//! repeated bit for bit.

use falsify::in_process::{evaluate, par_map};
use falsify::{Interpolation, Method, Property, SearchSettings, SignalTable, Space, search};
use mav::Scenario;
use mpc::ControllerMode;

fn signal() -> Space {
    Space::signal(&SignalTable {
        points: 2,
        interpolation: Interpolation::Constant,
        duration_s: 10.0,
        min_delay_s: 0.0,
        max_delay_s: 0.33,
        free_times: true,
    })
}

#[test]
fn a_clear_run_scores_its_clearance_and_a_missed_goal_fails_collision_or_miss_only() {
    let scenario = Scenario::paper_2();
    let point = [0.18, 0.1, 5.0];
    let e = evaluate(&signal(), &scenario, ControllerMode::Multistage, Property::CollisionOrMiss, &point)
        .expect("a run");
    assert!(e.summary.reached && !e.summary.collided, "{:?}", e.summary.end_reason);
    assert!(
        e.score > 0.0 && e.score == e.summary.min_clearance_m,
        "{} vs {}",
        e.score,
        e.summary.min_clearance_m
    );
    assert_eq!(e.scenario.delays.as_ref().and_then(|d| d.delays_s.as_ref()).map(|d| d[0]), Some(0.18));
    // Two seconds are too short to reach the goal: a miss, scored minus the distance left.
    let short = Scenario { max_duration_s: 2.0, ..scenario };
    let e = evaluate(&signal(), &short, ControllerMode::Multistage, Property::CollisionOrMiss, &point)
        .expect("a run");
    assert!(!e.summary.reached && !e.summary.collided);
    assert!(e.score < -1.0 && (e.score + e.facts.distance_to_goal_m).abs() < 1e-12, "{}", e.score);
    assert!(Property::Collision.robustness(&e.facts) > 0.0, "not a collision");
}

#[test]
fn a_search_over_real_runs_repeats_bit_for_bit_whatever_the_threads() {
    let scenario = Scenario::paper_2();
    let space = signal();
    let run = |jobs: usize| {
        let settings = SearchSettings {
            population: Some(3),
            stop_at_failure: false,
            ..SearchSettings::new(Method::Cmaes, 6, 4)
        };
        search(
            &space.dims,
            &settings,
            |batch| {
                par_map(batch, jobs, |p| {
                    evaluate(&space, &scenario, ControllerMode::Nmpc, Property::Collision, p)
                        .map_or(f64::NAN, |e| e.score)
                })
            },
            |_| {},
        )
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a.runs, 6);
    assert_eq!(a, b);
    assert!(a.generations.iter().all(|g| g.best.is_finite()));
}
