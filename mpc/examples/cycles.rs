//! Per-cycle solver statistics of one paper run and what the safety layer chose (development
//! aid). Usage: cycles SCENARIO MODE; solver settings from the `MPC_*` environment variables
//! of `benches/common/mpc_env.rs`.
use mpc::{ClosedLoopSettings, ControllerMode, run_closed_loop};

#[path = "../benches/common/mpc_env.rs"]
mod mpc_env;

#[path = "../benches/common/fmt.rs"]
mod fmt;
use fmt::fixed;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let scenario = mav::Scenario::by_name(&args[1]).expect("scenario");
    let mode = ControllerMode::parse(&args[2]).expect("mode");
    let mut settings = ClosedLoopSettings::paper(mode);
    settings.mpc = mpc_env::settings_from_env();
    let (s, records) = run_closed_loop(&scenario, &settings).expect("run");
    for r in &records {
        println!(
            "{:3} t={:6.2} p=[{}] v=[{}] u=[{:6.2} {:6.3} {:6.3}] d={:.3} {:?} it={} outer={} c={:.0e} viol={:.2e} clr={:.3} ms={:.2} cost={:.1} w={:.2?} {}",
            r.record.cycle,
            r.record.t_s(),
            fixed(&r.record.state[..3], 6, " "),
            fixed(&r.record.state[3..6], 5, " "),
            r.record.command[0],
            r.record.command[1],
            r.record.command[2],
            r.delay_s,
            r.report.status,
            r.report.iterations,
            r.report.outer_iterations,
            r.report.penalty_parameter,
            r.report.constraint_violation,
            r.report.min_clearance_m,
            r.report.solve_time.as_secs_f64() * 1e3,
            r.report.cost,
            r.record.weights,
            r.selection.as_ref().map_or(String::new(), |sel| sel.reason())
        );
    }
    println!("{s:?}");
}
