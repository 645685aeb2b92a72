//! The slowest solves of the paper closed loops, with their ALM statistics.
use mpc::{ControllerMode, MpcSettings, accuracy};

pub fn run() -> anyhow::Result<()> {
    let s = MpcSettings::default();
    for name in mav::Scenario::BUILT_IN {
        let scenario = mav::Scenario::by_name(name)?;
        let solves = accuracy::loop_solves(&scenario, ControllerMode::Multistage, &s)?;
        for (k, ls) in solves.iter().enumerate() {
            let r = &ls.report;
            if r.iterations > 100 {
                println!(
                    "{name} cycle {k}: it={} outer={} c={:.0e} viol={:.3e} status={:?} clear={:.3} ms={:.2} p=[{:.2},{:.2},{:.2}]",
                    r.iterations,
                    r.outer_iterations,
                    r.penalty_parameter,
                    r.constraint_violation,
                    r.status,
                    r.min_clearance_m,
                    r.solve_time.as_secs_f64() * 1e3,
                    ls.instance.x0[0],
                    ls.instance.x0[1],
                    ls.instance.x0[2]
                );
            }
        }
    }
    Ok(())
}
