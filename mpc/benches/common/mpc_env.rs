//! Solver settings from the environment for the tuning aids (`examples/accuracy.rs`,
//! `fixed_instances.rs`, `paper.rs`, `budget_sweep.rs`), so that one set of variables configures
//! them all: MPC_TOL, MPC_AKKT, MPC_MEM (multi-stage), MPC_NMPC_TOL, MPC_NMPC_AKKT, MPC_NMPC_MEM
//! (standard NMPC), MPC_CTOL, MPC_C0, MPC_CMAX, MPC_OUTER, MPC_INNER, MPC_PSLACK (< 0: no
//! penalty preconditioner), MPC_PER_OUTER (0: no cap), MPC_YMAX, MPC_ELAPSED (1: NMPC warm
//! start shifted by the elapsed time; only where a closed loop runs, `accuracy` and `paper`),
//! MPC_INACTIVE (`measured`: `InactiveSetTolerances::MEASURED`; or `TOL,AKKT,GRAD`: the
//! multi-stage inactive-set tolerances); the defaults where unset.
use mpc::{InactiveSetTolerances, MpcSettings};

fn env(name: &str, default: f64) -> f64 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

pub fn settings_from_env() -> MpcSettings {
    let d = MpcSettings::default();
    MpcSettings {
        tolerance: env("MPC_TOL", d.tolerance),
        akkt_tolerance: env("MPC_AKKT", d.akkt_tolerance),
        single_scenario_tolerance: env("MPC_NMPC_TOL", d.single_scenario_tolerance),
        single_scenario_akkt_tolerance: env("MPC_NMPC_AKKT", d.single_scenario_akkt_tolerance),
        lbfgs_memory: env("MPC_MEM", d.lbfgs_memory as f64) as usize,
        single_scenario_lbfgs_memory: env("MPC_NMPC_MEM", d.single_scenario_lbfgs_memory as f64) as usize,
        constraint_tolerance: env("MPC_CTOL", d.constraint_tolerance),
        initial_penalty: env("MPC_C0", d.initial_penalty),
        max_penalty: env("MPC_CMAX", d.max_penalty),
        max_outer_iterations: env("MPC_OUTER", d.max_outer_iterations as f64) as usize,
        max_inner_iterations: env("MPC_INNER", d.max_inner_iterations as f64) as usize,
        penalty_preconditioner_slack_m: match env(
            "MPC_PSLACK",
            d.penalty_preconditioner_slack_m.unwrap_or(-1.0),
        ) {
            v if v < 0.0 => None,
            v => Some(v),
        },
        max_inner_iterations_per_outer: match env(
            "MPC_PER_OUTER",
            d.max_inner_iterations_per_outer.unwrap_or(0) as f64,
        ) as usize
        {
            0 => None,
            v => Some(v),
        },
        max_multiplier: env("MPC_YMAX", d.max_multiplier),
        warm_start_by_elapsed_time: env("MPC_ELAPSED", 0.0) > 0.0,
        inactive_set: std::env::var("MPC_INACTIVE").ok().map_or(d.inactive_set, |v| inactive_set(&v)),
        ..d
    }
}

fn inactive_set(value: &str) -> Option<InactiveSetTolerances> {
    if value == "measured" {
        return Some(InactiveSetTolerances::MEASURED);
    }
    let v: Vec<f64> = value.split(',').map(|x| x.trim().parse().expect("MPC_INACTIVE: numbers")).collect();
    match v[..] {
        [tolerance, akkt_tolerance, gradient_tolerance] => {
            Some(InactiveSetTolerances { tolerance, akkt_tolerance, gradient_tolerance })
        }
        _ => panic!("MPC_INACTIVE: `measured` or TOL,AKKT,GRAD"),
    }
}
