//! Fly the plant simulation of paper-2 for a second: a command applied at a plant time, the
//! RK4 integration advanced in plant time, the state, path length and clearance read back.
//!
//! `cargo run --release -p mav --example hover_step`
use mav::{CommandMeta, Input, PlantSim, Scenario, SimSettings};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let scenario = Scenario::paper_2();
    // RK4 at 1 kHz, the plant's default; time is integer nanoseconds and moves only when asked.
    let mut sim = PlantSim::new(&scenario, SimSettings::default())?;

    // A little more thrust than hover and a small pitch: climb and move forward.
    let hover = scenario.model.hover_input();
    sim.apply(hover + Input::new(0.5, 0.0, 0.05), CommandMeta { command_seq: 1, ..Default::default() })?;

    // Advance 1 s of plant time in steps of 0.25 s (the observer sees every RK4 step; unused).
    for _ in 0..4 {
        sim.advance(250_000_000, |_| {});
        let x = sim.state();
        println!(
            "t = {:.2} s: position [{:.3}, {:.3}, {:.3}] m, velocity [{:.3}, {:.3}, {:.3}] m/s",
            sim.time_ns() as f64 / 1e9,
            x[0],
            x[1],
            x[2],
            x[3],
            x[4],
            x[5]
        );
    }
    println!(
        "path length {:.3} m, smallest clearance to a cylinder {:.3} m, collided {}",
        sim.path_length_m(),
        sim.min_clearance_m(),
        sim.collided()
    );
    Ok(())
}
