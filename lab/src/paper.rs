//! Runs the paper scenarios in process with both controllers and prints a summary line per run
//! (`hilbench reproduce` is the product; this is for trying solver settings).
use mpc::{ClosedLoopSettings, ControllerMode, run_closed_loop};

use crate::settings::MpcFlags;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Built-in scenarios to run (default all three).
    #[arg(value_parser = crate::scenario)]
    scenarios: Vec<mav::Scenario>,
    /// Fly PANOC's plans alone (no safety layer).
    #[arg(long, env = "MPC_NO_SAFETY", value_parser = clap::builder::BoolishValueParser::new())]
    no_safety: bool,
    #[command(flatten)]
    mpc: MpcFlags,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let scenarios = match &args.scenarios[..] {
        [] => mav::Scenario::BUILT_IN.iter().map(|n| mav::Scenario::by_name(n)).collect::<Result<_, _>>()?,
        chosen => chosen.to_vec(),
    };
    for scenario in &scenarios {
        let name = &scenario.name;
        for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
            let t = std::time::Instant::now();
            let mut settings = ClosedLoopSettings::paper(mode);
            settings.episode.mpc = args.mpc.settings();
            if args.no_safety {
                settings.episode.safety = None;
            }
            match run_closed_loop(scenario, &settings) {
                Ok((s, _)) => println!(
                    "{name} {:10} reached={} t={:?} collided={} path={:.2} clear={:.3} cycles={} solve ms mean={:.3} med={:.3} p95={:.3} max={:.3} it_med={} limits={} fb={} end={:?} wall={:.1}s\n   collisions={:?}",
                    s.controller,
                    s.reached,
                    s.time_to_goal_s,
                    s.collided,
                    s.path_length_m,
                    s.min_clearance_m,
                    s.cycles,
                    s.solve_ms_mean,
                    s.solve_ms_median,
                    s.solve_ms_p95,
                    s.solve_ms_max,
                    s.iterations_median,
                    s.iteration_limits,
                    s.fallbacks,
                    s.final_position_m,
                    t.elapsed().as_secs_f64(),
                    s.collisions
                ),
                Err(e) => println!("{name} {mode:?} error: {e}"),
            }
        }
    }
    Ok(())
}
