//! Solve the paper-2 problem once with the multi-stage NMPC and print the report.
//!
//! `cargo run --release -p mpc --example solve_once`
use mpc::{ControllerMode, Mpc, MpcSettings, OcpDefinition, SolveBudget};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // The problem: paper-2's model, bounds, cylinders, goal and weights, with one scenario per
    // sampling time of the multi-stage tree (M = 5, N = 40), the default obstacle margin.
    let scenario = mav::Scenario::paper_2();
    let settings = MpcSettings::default();
    let def = OcpDefinition::from_scenario(
        &scenario,
        ControllerMode::Multistage,
        settings.obstacle_margin_m,
        settings.formulation,
    );
    let mut mpc = Mpc::new(def, settings)?;

    // One instance: the measured state, the input in force (hover) and the scenarios'
    // probabilities (here equal; the controller takes them from its delay window's Gamma fit).
    let m = scenario.sampling_times_s.len();
    let weights = vec![1.0 / m as f64; m];
    let hover = [scenario.model.gravity_mps2, 0.0, 0.0];
    // A cold start (no previous plan): in a loop each solve warm-starts from the last plan.
    let report = mpc.solve(&scenario.start, &hover, &weights, &SolveBudget::default())?;

    println!(
        "status {:?} after {} PANOC iterations ({} outer)",
        report.status, report.iterations, report.outer_iterations
    );
    println!("cost {:.3}, constraint violation {:.2e}", report.cost, report.constraint_violation);
    println!("smallest predicted clearance {:.3} m", report.min_clearance_m);
    println!("evaluator passes: {} forward, {} adjoint", report.passes.forward, report.passes.adjoint);
    println!("solve time {:.3} ms", report.solve_time.as_secs_f64() * 1e3);
    // The plan: N inputs [thrust m/s², roll rad, pitch rad]; the first is the command to send.
    let u0 = &mpc.solution()[..3];
    println!("first input: thrust {:.3} m/s², roll {:.4} rad, pitch {:.4} rad", u0[0], u0[1], u0[2]);
    Ok(())
}
