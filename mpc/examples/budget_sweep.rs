//! Tuning aid: how cost, violation and clearance of chosen loop solves evolve with the budget.
//! Usage: budget_sweep SCENARIO MODE CYCLE...
use mpc::{ControllerMode, MpcSettings, OcpDefinition, accuracy};

#[path = "../benches/common/mpc_env.rs"]
mod mpc_env;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let scenario = mav::Scenario::by_name(&args[1]).expect("scenario");
    let mode = ControllerMode::parse(&args[2]).expect("mode");
    let s = mpc_env::settings_from_env();
    let loop_settings = MpcSettings::default();
    let solves = accuracy::loop_solves(&scenario, mode, &loop_settings).expect("loop");
    let def = OcpDefinition::from_scenario(&scenario, mode, s.obstacle_margin_m, s.formulation);
    for k in args[3..].iter().map(|a| a.parse::<usize>().expect("cycle")) {
        let ls = &solves[k];
        let reference =
            accuracy::reference_cost(&def, &s, &ls.instance, &[&ls.instance.warm_start, &ls.plan])
                .expect("reference");
        println!("cycle {k}: reference {reference:.4}");
        for budget in [5, 10, 20, 40, 80, 160, 320, 640, 2000] {
            let budgeted = MpcSettings { max_inner_iterations: budget, ..s };
            let (r, _) = accuracy::fast_solve(&def, &budgeted, &ls.instance).expect("solve");
            println!(
                "  budget {budget:5}: it={:4} outer={} c={:.0e} cost={:.4} gap={:+.4} viol={:.2e} clear={:.3} {:?}",
                r.iterations,
                r.outer_iterations,
                r.penalty_parameter,
                r.cost,
                (r.cost - reference) / reference,
                r.constraint_violation,
                r.min_clearance_m,
                r.status
            );
        }
    }
}
