//! Runs the three paper scenarios in process with both controllers and prints a summary line
//! per run (development aid; `hilbench reproduce` is the product).
use mpc::{ClosedLoopSettings, ControllerMode, run_closed_loop};

fn main() {
    let only: Vec<String> = std::env::args().skip(1).collect();
    for name in mav::Scenario::BUILT_IN {
        if !only.is_empty() && !only.iter().any(|o| o == name) {
            continue;
        }
        let scenario = mav::Scenario::by_name(name).expect("built in");
        for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
            let t = std::time::Instant::now();
            match run_closed_loop(&scenario, &ClosedLoopSettings::paper(mode)) {
                Ok((s, _)) => println!(
                    "{name} {:10} reached={} t={:?} collided={} path={:.2} clear={:.3} cycles={} solve ms mean={:.3} med={:.3} p95={:.3} max={:.3} it_med={} limits={} fb={} end={:?} wall={:.1}s\n   collisions={:?}",
                    s.controller,
                    s.reached,
                    s.time_to_goal_s,
                    s.collided,
                    s.path_length_m,
                    s.min_clearance_m,
                    s.cycles,
                    s.solve_ms_mean,
                    s.solve_ms_median,
                    s.solve_ms_p95,
                    s.solve_ms_max,
                    s.iterations_median,
                    s.iteration_limits,
                    s.fallbacks,
                    s.final_position_m,
                    t.elapsed().as_secs_f64(),
                    s.collisions
                ),
                Err(e) => println!("{name} {mode:?} error: {e}"),
            }
        }
    }
}
