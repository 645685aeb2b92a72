//! Profiling target: a closed loop of paper-2 (run under callgrind), multi-stage unless the
//! first argument is `nmpc`.
use mpc::{ClosedLoopSettings, ControllerMode, run_closed_loop};
fn main() {
    let mode = match std::env::args().nth(1).as_deref() {
        Some("nmpc") => ControllerMode::Nmpc,
        _ => ControllerMode::Multistage,
    };
    let scenario = mav::Scenario::paper_2();
    let (s, _) = run_closed_loop(&scenario, &ClosedLoopSettings::paper(mode)).expect("run");
    println!("{} cycles", s.cycles);
}
