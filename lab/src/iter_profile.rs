//! What one PANOC iteration costs in the multi-stage paper loops, for the solves
//! that stop at the iteration budget and for the others. First the loops' own solves (OpEn's
//! timer), then the same instances solved again in order on one `Mpc` (multipliers and penalty
//! carried over), with the evaluator's forward and adjoint passes per iteration
//! (deterministic) and the wall time per iteration (not).
use mpc::{ControllerMode, Mpc, MpcSettings, OcpDefinition, SolveBudget, SolveStatus, accuracy};

/// One solve: whether it stopped at the budget, iterations, outer iterations, forward and
/// adjoint passes (counted in the replay only), wall time and OpEn's time (µs).
struct Row {
    at_budget: bool,
    iterations: usize,
    outer: usize,
    passes: Option<(u64, u64)>,
    wall_us: f64,
    open_us: f64,
}

pub fn run() -> anyhow::Result<()> {
    let s = MpcSettings::default();
    let mode = ControllerMode::Multistage;
    let (mut in_loop, mut replayed) = (Vec::new(), Vec::new());
    for name in mav::Scenario::BUILT_IN {
        let scenario = mav::Scenario::by_name(name)?;
        let def = OcpDefinition::from_scenario(&scenario, mode, s.obstacle_margin_m, s.formulation);
        let solves = accuracy::loop_solves(&scenario, mode, &s)?;
        let mut mpc = Mpc::new(def, s)?;
        for ls in &solves[1..] {
            let r = &ls.report;
            let open_us = r.solve_time.as_secs_f64() * 1e6;
            let at_budget = r.status == SolveStatus::IterationLimit;
            in_loop.push(Row {
                at_budget,
                iterations: r.iterations,
                outer: r.outer_iterations,
                passes: None,
                wall_us: open_us,
                open_us,
            });
            let i = &ls.instance;
            mpc.set_warm_start(&i.warm_start)?;
            let t = std::time::Instant::now();
            let r = mpc.solve(&i.x0, &i.u_prev, &i.weights, &SolveBudget::default())?;
            let wall_us = t.elapsed().as_secs_f64() * 1e6;
            replayed.push(Row {
                at_budget: r.status == SolveStatus::IterationLimit,
                iterations: r.iterations,
                outer: r.outer_iterations,
                passes: Some((r.passes.forward, r.passes.adjoint)),
                wall_us,
                open_us: r.solve_time.as_secs_f64() * 1e6,
            });
        }
    }
    for (what, rows) in [("in the loops", &in_loop), ("replayed", &replayed)] {
        for at_budget in [true, false] {
            let sel: Vec<&Row> = rows.iter().filter(|r| r.at_budget == at_budget).collect();
            let it = sel.iter().map(|r| r.iterations).sum::<usize>().max(1) as f64;
            let sum = |f: &dyn Fn(&Row) -> f64| sel.iter().map(|r| f(r)).sum::<f64>();
            let passes = match sel.iter().map(|r| r.passes).collect::<Option<Vec<_>>>() {
                Some(p) => format!(
                    "forward {:.2} adjoint {:.2} passes, ",
                    p.iter().map(|p| p.0 as f64).sum::<f64>() / it,
                    p.iter().map(|p| p.1 as f64).sum::<f64>() / it
                ),
                None => String::new(),
            };
            println!(
                "{what}, {}: {} solves, {it} iterations, {:.2} outer per solve, per iteration: {passes}wall {:.2} µs, OpEn {:.2} µs",
                if at_budget { "at the budget" } else { "the others" },
                sel.len(),
                sum(&|r| r.outer as f64) / sel.len().max(1) as f64,
                sum(&|r| r.wall_us) / it,
                sum(&|r| r.open_us) / it,
            );
        }
    }
    Ok(())
}
