//! Robustness survey: paper-2 with the multi-stage controller under many random delay traces
//! (uniform, Gamma, bursts in [0, 0.33] s), counting collisions and misses.
use mpc::{DelaySource, run_closed_loop};

use crate::settings::SurveyFlags;
use crate::traces::{self, TraceId};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Traces per kind.
    #[arg(long, env = "CASES", default_value_t = 20)]
    cases: u64,
    /// Run this trace alone (`kind:seed`) and print its cycles.
    #[arg(long, env = "ONLY")]
    only: Option<TraceId>,
    /// Also print, per run, how many cycles no candidate passed the checks in.
    #[arg(long, env = "VERBOSE", value_parser = clap::builder::BoolishValueParser::new())]
    verbose: bool,
    #[command(flatten)]
    pub(crate) survey: SurveyFlags,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let (scenario, mut settings) = args.survey.setup();
    let width = args.survey.width_s;
    for kind in traces::KINDS {
        let (mut collided, mut missed, mut fallbacks) = (0, 0, 0);
        // Cycles where no candidate passed the checks; worst clearance; sums for the means.
        let (mut unverified, mut worst, mut runs) = (0, f64::INFINITY, 0);
        let (mut time_s, mut path_m, mut reached_runs) = (0.0, 0.0, 0);
        for seed in 0..args.cases {
            // `--only kind:seed` runs one trace and prints its cycles (what the controller decided).
            if args.only.is_some_and(|o| o != TraceId { kind, seed }) {
                continue;
            }
            let trace = traces::trace(kind, seed, width);
            settings.delays = Some(DelaySource::Trace(trace));
            let (s, records) = run_closed_loop(&scenario, &settings)?;
            if args.only.is_some() {
                for r in &records {
                    let p = &r.record.state;
                    let reason = r.selection.as_ref().map(|s| s.reason()).unwrap_or_default();
                    println!(
                        "{:4} t={:6.2} p=[{:5.2},{:5.2},{:5.2}] d={:.3} {reason}",
                        r.record.cycle,
                        r.record.t_s(),
                        p[0],
                        p[1],
                        p[2],
                        r.delay_s
                    );
                }
            }
            if s.collided || !s.reached {
                let mean = trace_mean(settings.delays.as_ref());
                println!(
                    "  {kind} seed {seed}: collided {} reached {} clearance {:.3} mean delay {mean:.3}",
                    s.collided, s.reached, s.min_clearance_m
                );
            }
            collided += usize::from(s.collided);
            missed += usize::from(!s.reached);
            fallbacks += s.fallbacks;
            let run_unverified =
                records.iter().filter(|r| r.selection.is_some_and(|s| !s.verified_safe)).count();
            if args.verbose {
                // One line a run, to compare runs across settings (time, path, overrides).
                println!(
                    "  {kind} seed {seed}: time {} path {:.3} m, {} overrides, {run_unverified} unverified cycles",
                    s.time_to_goal_s.map_or("-".to_string(), |t| format!("{t:.3} s")),
                    s.path_length_m,
                    s.fallbacks,
                );
            }
            unverified += run_unverified;
            worst = worst.min(s.min_clearance_m);
            runs += 1;
            if let Some(t) = s.time_to_goal_s {
                time_s += t;
                path_m += s.path_length_m;
                reached_runs += 1;
            }
        }
        if runs == 0 {
            continue;
        }
        let reached_runs = f64::from(reached_runs);
        println!(
            "{kind}: {runs} traces, {collided} collided, {missed} missed the goal, {fallbacks} fallback cycles, \
             {unverified} unverified, worst clearance {worst:.3} m, mean time to goal {:.2} s, mean path {:.2} m",
            time_s / reached_runs,
            path_m / reached_runs
        );
    }
    Ok(())
}

fn trace_mean(d: Option<&DelaySource>) -> f64 {
    match d {
        Some(DelaySource::Trace(t)) => t.iter().sum::<f64>() / t.len() as f64,
        _ => f64::NAN,
    }
}
