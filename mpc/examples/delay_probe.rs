//! Diagnosis aid: paper-2 under a constant round-trip delay, with and without the safety layer;
//! prints where the run went and what the layer decided.
use mpc::{ClosedLoopSettings, ControllerMode, DelaySource, run_closed_loop};

#[path = "../benches/common/fmt.rs"]
mod fmt;
use fmt::fixed;

fn main() {
    // A constant delay in seconds, or a trace file (one delay per line).
    let arg = std::env::args().nth(1).unwrap_or_else(|| "0.33".into());
    let trace = match arg.parse::<f64>() {
        Ok(d) => vec![d],
        Err(_) => delay::parse_trace(&std::fs::read_to_string(&arg).expect("trace file")).expect("trace"),
    };
    let mut scenario = mav::Scenario::paper_2();
    scenario.delay_compensation = std::env::var("COMP").is_ok();
    scenario.min_altitude_m = std::env::var("FLOOR").ok().and_then(|z| z.parse().ok());
    for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
        for safety in [false, true] {
            let mut settings = ClosedLoopSettings::paper(mode);
            if let Some(m) = std::env::var("MARGIN").ok().and_then(|m| m.parse().ok()) {
                settings.mpc.obstacle_margin_m = m;
            }
            settings.delays = Some(DelaySource::Trace(trace.clone()));
            if !safety {
                settings.safety = None;
            }
            let (s, records) = run_closed_loop(&scenario, &settings).expect("run");
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
            if std::env::var("VERBOSE").is_ok() {
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
}
