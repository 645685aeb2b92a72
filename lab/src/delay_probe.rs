//! paper-2 under a constant round-trip delay or a trace, both controllers, with and without
//! the safety layer: where each run went and what the layer decided.
use anyhow::Context;
use mpc::{ControllerMode, DelaySource, run_closed_loop};

use crate::fmt::fixed;
use crate::settings::ScenarioFlags;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// A constant delay in seconds, or a trace file (one delay per line).
    #[arg(default_value = "0.33")]
    delay: String,
    /// Print every cycle.
    #[arg(long, env = "VERBOSE", value_parser = clap::builder::BoolishValueParser::new())]
    verbose: bool,
    #[command(flatten)]
    scenario: ScenarioFlags,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let trace = match args.delay.parse::<f64>() {
        Ok(d) => vec![d],
        Err(_) => {
            let text = std::fs::read_to_string(&args.delay)
                .with_context(|| format!("cannot read {}", args.delay))?;
            delay::parse_trace(&text).with_context(|| args.delay.clone())?
        }
    };
    for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
        for safety in [false, true] {
            let (scenario, mut settings) = args.scenario.setup(mode);
            settings.delays = Some(DelaySource::Trace(trace.clone()));
            if !safety {
                settings.episode.safety = None;
            }
            let (s, records) = run_closed_loop(&scenario, &settings)?;
            println!(
                "{} safety={safety}: reached={} collided={} clearance={:.3} path={:.2} cycles={} fallbacks={} decisions={:?}",
                mode.name(),
                s.reached,
                s.collided,
                s.min_clearance_m,
                s.path_length_m,
                s.cycles,
                s.fallbacks,
                s.decisions
            );
            if args.verbose {
                for r in &records {
                    println!(
                        "  {:3} t={:5.2} p=[{}] v=[{}] w={:?} pred_clear={:.3} {}",
                        r.record.cycle,
                        r.record.t_s(),
                        fixed(&r.record.state[..3], 5, ","),
                        fixed(&r.record.state[3..6], 5, ","),
                        r.record.weights.iter().map(|w| (w * 100.0).round() / 100.0).collect::<Vec<_>>(),
                        r.report.min_clearance_m,
                        r.selection.as_ref().map(|s| s.reason()).unwrap_or_default()
                    );
                }
            }
        }
    }
    Ok(())
}
