//! Tuning aid: fast solves vs the reference on instances along the paper loops.
//! Usage: accuracy [stride] ; settings overrides from env MPC_TOL, MPC_AKKT, MPC_MEM, MPC_CTOL.
use mpc::{ControllerMode, MpcSettings, OcpDefinition, accuracy};

fn env(name: &str, default: f64) -> f64 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn main() {
    let stride: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(5);
    let d = MpcSettings::default();
    let fast = MpcSettings {
        tolerance: env("MPC_TOL", d.tolerance),
        akkt_tolerance: env("MPC_AKKT", d.akkt_tolerance),
        lbfgs_memory: env("MPC_MEM", d.lbfgs_memory as f64) as usize,
        constraint_tolerance: env("MPC_CTOL", d.constraint_tolerance),
        ..d
    };
    for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
        let mut gaps = Vec::new();
        let mut times = Vec::new();
        let mut iters = Vec::new();
        for name in mav::Scenario::BUILT_IN {
            let scenario = mav::Scenario::by_name(name).expect("built in");
            let def = OcpDefinition::from_scenario(&scenario, mode, fast.obstacle_margin_m, fast.formulation);
            let inst = accuracy::instances_along_loop(&scenario, mode, &MpcSettings::default(), stride)
                .expect("loop");
            for (idx, i) in inst.iter().enumerate() {
                // Reference costs are cached per instance (they do not depend on the fast settings).
                let path = format!("/tmp/mpc-ref-{}-{}-{stride}-{idx}.txt", mode.name(), name);
                let (report, sol) = accuracy::fast_solve(&def, &fast, i).expect("fast");
                let reference =
                    match std::fs::read_to_string(&path).ok().and_then(|s| s.trim().parse::<f64>().ok()) {
                        Some(r) => r,
                        None => {
                            let r = accuracy::reference_cost(
                                &def,
                                &MpcSettings::default(),
                                i,
                                &[&i.warm_start, &sol],
                            )
                            .expect("reference");
                            std::fs::write(&path, format!("{r}")).expect("cache");
                            r
                        }
                    };
                let gap = (report.cost - reference) / reference.abs().max(1e-12);
                let c = accuracy::Comparison { fast: report, reference_cost: reference, relative_gap: gap };
                gaps.push(c.relative_gap);
                times.push(c.fast.solve_time.as_secs_f64() * 1e3);
                iters.push(c.fast.iterations as f64);
                if c.relative_gap > 0.01 {
                    println!(
                        "{name} {} gap={:.3} fast={:.2} ref={:.2} it={} outer={} status={:?} viol={:.1e}",
                        mode.name(),
                        c.relative_gap,
                        c.fast.cost,
                        c.reference_cost,
                        c.fast.iterations,
                        c.fast.outer_iterations,
                        c.fast.status,
                        c.fast.constraint_violation
                    );
                }
            }
        }
        let within = gaps.iter().filter(|g| **g <= 0.01).count();
        let mut t = times.clone();
        let med = mpc::closed_loop::percentile(&mut t, 50.0);
        let p99 = mpc::closed_loop::percentile(&mut t, 99.0);
        let mut it = iters.clone();
        println!(
            "{}: {}/{} within 1% ; solve ms median {:.3} p99 {:.3} ; iterations median {}",
            mode.name(),
            within,
            gaps.len(),
            med,
            p99,
            mpc::closed_loop::percentile(&mut it, 50.0)
        );
    }
}
