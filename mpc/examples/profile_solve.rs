//! Profiling target: the multi-stage closed loop of paper-2 (run under callgrind).
use mpc::{ClosedLoopSettings, ControllerMode, run_closed_loop};
fn main() {
    let scenario = mav::Scenario::paper_2();
    let (s, _) =
        run_closed_loop(&scenario, &ClosedLoopSettings::paper(ControllerMode::Multistage)).expect("run");
    println!("{} cycles", s.cycles);
}
