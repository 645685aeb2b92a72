//! Profiling target for the fail-safe check: the envelopes of `mpc/benches/cycle.rs`
//! (lockstep, and real time with three commands in flight), repeated, for instruction counts
//! under callgrind.
use mpc::{BrakingCheck, FailSafe, InFlight};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Repetitions.
    #[arg(default_value_t = 200)]
    repetitions: usize,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let reps = args.repetitions;
    let s = mav::Scenario::paper_2();
    let fs = FailSafe::new(BrakingCheck::default(), s.model, s.bounds, s.obstacles.clone(), 1.0);
    let x0 = [3.1, 1.2, 0.6, 0.1, 1.5, 0.2, 0.05, -0.02];
    let (u_prev, u) = ([10.5, 0.05, -0.02], [10.0, 0.1, 0.0]);
    let in_flight: Vec<InFlight> =
        [0.15, 0.1, 0.05].iter().map(|&sent_ago_s| InFlight { sent_ago_s, command: u_prev }).collect();
    let mut worst = f64::INFINITY;
    for _ in 0..reps {
        worst = worst.min(fs.envelope(std::hint::black_box(&x0), &u_prev, &u).min_clearance_m);
        worst = worst
            .min(fs.envelope_real_time(std::hint::black_box(&x0), &u_prev, &in_flight, &u).min_clearance_m);
    }
    println!("{reps} x 2 envelopes, worst clearance {worst:.4} m");
    Ok(())
}
