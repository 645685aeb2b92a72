//! Decide what the network does to a few messages: delays drawn from the paper's Gamma, then a
//! recorded trace replayed, on a seeded `DelayLine` (the same line netem holds messages with).
//!
//! `cargo run --release -p delay --example delay_line`
use delay::{DelayLine, Direction, DirectionProfile, Distribution, Trace, parse_trace};

/// Sends a message every 50 ms on `line` and prints when each copy leaves it (in order: the
/// default FIFO ordering holds a message until the ones before it have left).
fn send_some(line: &mut DelayLine, messages: u64) {
    for k in 0..messages {
        let decision = line.send(k * 50_000_000);
        let releases: Vec<String> =
            decision.releases().map(|r| format!("{:.1} ms", r.release_time_ns as f64 / 1e6)).collect();
        println!(
            "  message {k}: sent at {} ms, drawn delay {:.1} ms, released at [{}]",
            k * 50,
            decision.sampled_delay_s * 1e3,
            releases.join(", ")
        );
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // docs/spec.md's paper mode: round-trip delays Gamma(shape 12, scale 0.015 s), seed 42.
    // The same seed and send times give the same decisions, bit for bit.
    let gamma = Distribution::Gamma { shape: 12.0, scale_s: 0.015 };
    let mut line = DelayLine::new(Direction::ControllerToPlant, DirectionProfile::with_delay(gamma, 42))?;
    println!("Gamma(12, 0.015 s), seed 42:");
    send_some(&mut line, 5);

    // A trace file's text (one delay in seconds per line), replayed in order and looped.
    let delays_s = parse_trace("0.020\n0.180\n# a burst\n0.330\n0.040\n")?;
    let trace = Distribution::Trace(Trace::looping(delays_s));
    let mut line = DelayLine::new(Direction::ControllerToPlant, DirectionProfile::with_delay(trace, 0))?;
    println!("trace of 4 delays, looping:");
    send_some(&mut line, 6);
    Ok(())
}
