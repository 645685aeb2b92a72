//! Diagnosis of one delay trace of the survey (`delay_robustness`): per cycle, the plant's
//! smallest clearance between this cycle's start and the next (and which cylinder), what the
//! safety layer decided, and how far the plant ended from each scenario's prediction of the
//! selected plan. Same environment as the survey (COMP, FLOOR, MARGIN), plus TRACE=kind:seed.
use mav::{CommandMeta, Input, PlantSim, SimSettings};
use mpc::{ClosedLoopSettings, ControllerMode, DelaySource, run_closed_loop};

#[path = "../benches/common/delay_traces.rs"]
mod traces;

fn main() {
    let spec = std::env::var("TRACE").unwrap_or_else(|_| "uniform:29".into());
    let (kind, seed) = spec.split_once(':').expect("TRACE=kind:seed");
    let seed: u64 = seed.parse().expect("seed");
    let trace = traces::trace(kind, seed, 0.33);
    let mut scenario = mav::Scenario::paper_2();
    scenario.delay_compensation = std::env::var("COMP").is_ok();
    scenario.min_altitude_m = std::env::var("FLOOR").ok().and_then(|z| z.parse().ok());
    let mut settings = ClosedLoopSettings::paper(ControllerMode::Multistage);
    if let Some(m) = std::env::var("MARGIN").ok().and_then(|m| m.parse().ok()) {
        settings.mpc.obstacle_margin_m = m;
    }
    // FAILSAFE=1: the safety layer's fail-safe check (first input, then braking, under every
    // delay up to DMAX s, SAMPLES delays per cycle).
    if std::env::var("FAILSAFE").is_ok()
        && let Some(safety) = settings.safety.as_mut()
    {
        let mut check = mpc::BrakingCheck::default();
        if let Some(d) = std::env::var("DMAX").ok().and_then(|d| d.parse().ok()) {
            check.max_delay_s = d;
        }
        if let Some(n) = std::env::var("SAMPLES").ok().and_then(|n| n.parse().ok()) {
            check.delay_samples = n;
        }
        safety.braking_check = Some(check);
    }
    settings.delays = Some(DelaySource::Trace(trace));
    settings.record_predictions = true;
    let (summary, records) = run_closed_loop(&scenario, &settings).expect("run");
    println!("{summary:#?}");

    // Replay the plant with the recorded commands and delays, watching the clearance.
    let mut sim = PlantSim::new(&scenario, SimSettings::default()).expect("sim");
    let dts = &scenario.sampling_times_s;
    for (k, r) in records.iter().enumerate() {
        let d_ns = mav::s_to_ns(r.delay_s).expect("delay");
        let next_ns =
            records.get(k + 1).map(|n| mav::s_to_ns(n.t_s).expect("t")).unwrap_or(sim.time_ns() + d_ns);
        let mut worst = (f64::INFINITY, None, 0.0);
        let mut watch = |s: &PlantSim| {
            let x = s.state();
            let (c, i) = mav::geometry::min_clearance(s.obstacles(), x[0], x[1], x[2]);
            if c < worst.0 {
                worst = (c, i, mav::ns_to_s(s.time_ns()));
            }
        };
        sim.advance(d_ns, &mut watch);
        sim.apply(Input::from(r.command), CommandMeta { command_seq: k as u64 + 1, ..Default::default() })
            .expect("apply");
        sim.advance_to(next_ns, &mut watch);
        let x = r.state;
        let speed = (x[3] * x[3] + x[4] * x[4] + x[5] * x[5]).sqrt();
        let sel = r.selection.as_ref().map(|s| s.reason()).unwrap_or_default();
        // The scenario nearest to the cycle's delay and its prediction at the next sample.
        let dt_next = mav::ns_to_s(next_ns) - r.t_s;
        let miss: Vec<String> = r
            .predictions
            .iter()
            .zip(dts)
            .map(|(p, dt)| {
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
            r.cycle,
            r.t_s,
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
}
