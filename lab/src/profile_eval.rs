//! Profiling target: the `cost_and_gradient` bench's loop (paper-2, DistanceAlm, c = 1e3, the
//! forward pass cached every other call, `mpc::fixtures::eval_case`), for callgrind's
//! instruction counts.
use mpc::fixtures::eval_case;
use mpc::{ControllerMode, OcpDefinition};
use std::hint::black_box;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// `nmpc` or `multistage`.
    #[arg(default_value = "multistage", value_parser = crate::mode)]
    mode: ControllerMode,
    /// Cost and gradient evaluations.
    #[arg(default_value_t = 10_000)]
    iterations: usize,
    /// Replace the sampling times by this many scenarios (0.05 s, 0.075 s, ...).
    scenarios: Option<usize>,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let (mode, iterations) = (args.mode, args.iterations);
    let scenario = mav::Scenario::paper_2();
    let mut def = OcpDefinition::from_scenario(&scenario, mode, 0.1, mpc::ObstacleFormulation::DistanceAlm);
    if let Some(m) = args.scenarios {
        def.sampling_times_s = (0..m).map(|i| 0.05 + 0.025 * i as f64).collect();
    }
    let (mut ev, mut z, y, mut grad) = eval_case(&def);
    let mut flip = 0.0;
    let start = std::time::Instant::now();
    let mut acc = 0.0;
    for _ in 0..iterations {
        flip = 1e-9 - flip;
        z[0] += flip;
        let cost = ev.cost(black_box(&z), 1e3, &y);
        ev.gradient(black_box(&z), 1e3, &y, &mut grad);
        acc += cost + grad[0];
    }
    println!(
        "{:.3} us per cost and gradient ({acc})",
        start.elapsed().as_secs_f64() * 1e6 / iterations as f64
    );
    Ok(())
}
