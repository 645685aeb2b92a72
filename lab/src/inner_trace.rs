//! PANOC's progress on one inner (fixed penalty, zero multipliers) problem of a loop solve,
//! against the iteration budget.
use std::cell::RefCell;

use mpc::{Evaluator, MpcSettings, OcpDefinition, accuracy};
use optimization_engine::constraints::Rectangle;
use optimization_engine::panoc::{PANOCCache, PANOCOptimizer};
use optimization_engine::{Problem, SolverError};

use crate::settings::LoopArgs;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    run: LoopArgs,
    /// The loop's cycle.
    cycle: usize,
    /// The penalty parameter.
    penalty: f64,
    /// PANOC's tolerance (default: the loop's own for the mode).
    tolerance: Option<f64>,
    /// L-BFGS memory (default: the loop's own for the mode).
    lbfgs_memory: Option<usize>,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let (scenario, mode, k, c) = (&args.run.scenario, args.run.mode, args.cycle, args.penalty);
    let s = MpcSettings::default();
    let solves = accuracy::loop_solves(scenario, mode, &s)?;
    let def = OcpDefinition::from_scenario(scenario, mode, s.obstacle_margin_m, s.formulation);
    // By default the tolerance and memory the loop's PANOC used for this kind of problem.
    let (default_tol, _, default_mem) = s.panoc_for(def.num_scenarios());
    let tol = args.tolerance.unwrap_or(default_tol);
    let mem = args.lbfgs_memory.unwrap_or(default_mem);
    let inst =
        &solves.get(k).ok_or_else(|| anyhow::anyhow!("cycle {k}: the loop has {}", solves.len()))?.instance;
    let ev = RefCell::new(Evaluator::new(&def));
    let n = def.num_variables();
    let (mut lo, mut hi, mut z0) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    {
        let mut e = ev.borrow_mut();
        e.set_instance(&inst.x0, &inst.u_prev, &inst.weights);
        e.scaled_bounds(&def.bounds, &mut lo, &mut hi);
        e.to_scaled(&inst.warm_start, &mut z0);
    }
    let cost = |z: &[f64], v: &mut f64| -> Result<(), SolverError> {
        *v = ev.borrow_mut().cost(z, c, &[]);
        Ok(())
    };
    let grad = |z: &[f64], g: &mut [f64]| -> Result<(), SolverError> {
        ev.borrow_mut().gradient(z, c, &[], g);
        Ok(())
    };
    for iters in [1, 2, 3, 5, 8, 12, 20, 30, 50, 80, 120, 200, 400, 1000] {
        let mut cache = PANOCCache::new(n, tol, mem);
        let rect = Rectangle::new(Some(&lo), Some(&hi));
        let problem = Problem::new(&rect, grad, cost);
        let mut z = z0.clone();
        let st = PANOCOptimizer::new(problem, &mut cache)
            .with_max_iter(iters)
            .solve(&mut z)
            .map_err(|e| anyhow::anyhow!("PANOC: {e:?}"))?;
        let obj = ev.borrow_mut().objective(&z);
        let psi = ev.borrow_mut().cost(&z, c, &[]);
        let viol: f64 =
            ev.borrow().constraint_values().iter().map(|g| g.max(0.0).powi(2)).sum::<f64>().sqrt();
        println!(
            "max {iters:5}: it={:4} fpr={:.2e} psi={psi:.4} objective={obj:.4} viol={viol:.3e} {:?}",
            st.iterations(),
            st.norm_fpr(),
            st.exit_status()
        );
        if st.iterations() < iters {
            break;
        }
    }
    Ok(())
}
