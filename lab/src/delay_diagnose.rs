//! Diagnosis of one delay trace of the survey (`delay-robustness`): per cycle, the plant's
//! smallest clearance between this cycle's start and the next (and which cylinder), what the
//! safety layer decided, and how far the plant ended from each scenario's prediction of the
//! selected plan. The survey's set-up and flags, plus the trace.
use mav::{CommandMeta, Input, PlantSim, SimSettings};
use mpc::{DelaySource, run_closed_loop};

use crate::settings::SurveyFlags;
use crate::traces::{self, TraceId};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The survey's trace, `kind:seed` (`uniform`, `gamma` or `bursts`).
    #[arg(long, env = "TRACE", default_value = "uniform:29")]
    trace: TraceId,
    #[command(flatten)]
    survey: SurveyFlags,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let trace = traces::trace(args.trace.kind, args.trace.seed, args.survey.width_s);
    let (scenario, mut settings) = args.survey.setup();
    settings.delays = Some(DelaySource::Trace(trace));
    settings.record_predictions = true;
    let (summary, records) = run_closed_loop(&scenario, &settings)?;
    println!("{summary:#?}");

    // Replay the plant with the recorded commands and delays, watching the clearance.
    let mut sim = PlantSim::new(&scenario, SimSettings::default())?;
    let dts = &scenario.sampling_times_s;
    for (k, r) in records.iter().enumerate() {
        let d_ns = mav::s_to_ns(r.delay_s).expect("delay");
        let next_ns = records
            .get(k + 1)
            .map(|n| mav::s_to_ns(n.record.t_s()).expect("t"))
            .unwrap_or(sim.time_ns() + d_ns);
        let mut worst = (f64::INFINITY, None, 0.0);
        let mut watch = |s: &PlantSim| {
            let x = s.state();
            let (c, i) = mav::geometry::min_clearance(s.obstacles(), x[0], x[1], x[2]);
            if c < worst.0 {
                worst = (c, i, mav::ns_to_s(s.time_ns()));
            }
        };
        sim.advance(d_ns, &mut watch);
        sim.apply(
            Input::from(r.record.command),
            CommandMeta { command_seq: k as u64 + 1, ..Default::default() },
        )
        .expect("apply");
        sim.advance_to(next_ns, &mut watch);
        let x = r.record.state;
        let speed = (x[3] * x[3] + x[4] * x[4] + x[5] * x[5]).sqrt();
        let sel = r.selection.as_ref().map(|s| s.reason()).unwrap_or_default();
        // The scenario nearest to the cycle's delay and its prediction at the next sample.
        let dt_next = mav::ns_to_s(next_ns) - r.record.t_s();
        let miss: Vec<String> = r
            .record
            .predictions
            .iter()
            .zip(dts)
            .map(|(p, dt)| {
                let p = &p.positions_m;
                // Prediction at time dt_next (linear interpolation between points).
                let s = dt_next / dt;
                let j = (s.floor() as usize).min(p.len() - 2);
                let f = s - j as f64;
                let at: Vec<f64> = (0..3).map(|c| p[j][c] + f * (p[j + 1][c] - p[j][c])).collect();
                let y = sim.state();
                format!("{:.2}", ((at[0] - y[0]).powi(2) + (at[1] - y[1]).powi(2)).sqrt())
            })
            .collect();
        println!(
            "{:3} t={:5.2} p=[{:4.2},{:4.2},{:4.2}] |v|={:4.2} d={:.3} plant {:+.3} (cyl {:?} at {:.2}) err [{}] {sel}",
            r.record.cycle,
            r.record.t_s(),
            x[0],
            x[1],
            x[2],
            speed,
            r.delay_s,
            worst.0,
            worst.1,
            worst.2,
            miss.join(" ")
        );
    }
    Ok(())
}
