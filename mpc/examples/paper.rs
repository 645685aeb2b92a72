//! Runs the three paper scenarios in process with both controllers and prints a summary line
//! per run (development aid; `hilbench reproduce` is the product). Solver settings from the
//! `MPC_*` environment variables of `benches/common/mpc_env.rs`; `MPC_NO_SAFETY=1` flies PANOC's
//! plans alone (no safety layer).
use mpc::{ClosedLoopSettings, ControllerMode, run_closed_loop};

#[path = "../benches/common/mpc_env.rs"]
mod mpc_env;

fn main() {
    let only: Vec<String> = std::env::args().skip(1).collect();
    for name in mav::Scenario::BUILT_IN {
        if !only.is_empty() && !only.iter().any(|o| o == name) {
            continue;
        }
        let scenario = mav::Scenario::by_name(name).expect("built in");
        for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
            let t = std::time::Instant::now();
            let mut settings = ClosedLoopSettings::paper(mode);
            settings.mpc = mpc_env::settings_from_env();
            if std::env::var("MPC_NO_SAFETY").is_ok_and(|v| v == "1") {
                settings.safety = None;
            }
            match run_closed_loop(&scenario, &settings) {
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
