//! Bit-level fingerprint of the evaluator and the closed loops (development aid for changes to
//! `problem.rs` that must not change any result bit): prints the bits of `Evaluator::cost`,
//! `objective`, `constraints` and `gradient` at seeded random points over scenario counts,
//! formulations, floors and dead-time compensation, then the path length, final position and
//! every command of the paper closed loops. Run before and after a change and `diff` the output.
//!
//! `cargo run --release -p lab -- eval-bits [evaluator|closed-loop]`
use mpc::{
    ClosedLoopSettings, ControllerMode, Evaluator, ObstacleFormulation, OcpDefinition, run_closed_loop,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// FNV-1a over the bits of a sequence of floats.
fn hash(values: impl IntoIterator<Item = f64>) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for v in values {
        for b in v.to_bits().to_le_bytes() {
            h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

fn evaluator_points() {
    let mut rng = ChaCha8Rng::seed_from_u64(20_240_601);
    let base = mav::Scenario::paper_2();
    let all_dts = [0.05, 0.07, 0.1, 0.2, 0.33, 0.04, 0.12, 0.25, 0.09, 0.15, 0.3, 0.06, 0.08];
    for m in [1usize, 2, 3, 4, 5, 6, 7, 8, 9, 13] {
        for formulation in [ObstacleFormulation::DistanceAlm, ObstacleFormulation::PaperPenalty] {
            for (floor, compensation) in [(None, false), (Some(0.4), true), (Some(0.4), false), (None, true)]
            {
                let mut def =
                    OcpDefinition::from_scenario(&base, ControllerMode::Multistage, 0.1, formulation);
                def.sampling_times_s = all_dts[..m].to_vec();
                def.min_altitude_m = floor;
                def.delay_compensation = compensation;
                let mut ev = Evaluator::new(&def);
                let n = ev.num_variables();
                let mut grad = vec![0.0; n];
                let mut con = vec![0.0; def.num_constraints()];
                for point in 0..12 {
                    let mut x0 = [0.0f64; 8];
                    x0[0] = rng.random_range(2.0..4.0);
                    x0[1] = rng.random_range(0.0..5.0);
                    x0[2] = rng.random_range(0.2..1.2);
                    for v in &mut x0[3..6] {
                        *v = rng.random_range(-1.5..1.5);
                    }
                    // Now and then attitudes beyond the small-angle series' range.
                    let angle = if point % 4 == 3 { 0.8 } else { 0.15 };
                    for v in &mut x0[6..8] {
                        *v = rng.random_range(-angle..angle);
                    }
                    let u_prev = [
                        rng.random_range(5.0..15.0),
                        rng.random_range(-0.1..0.1),
                        rng.random_range(-0.1..0.1),
                    ];
                    let weights: Vec<f64> = (0..m).map(|_| rng.random_range(0.0..1.0)).collect();
                    ev.set_instance(&x0, &u_prev, &weights);
                    let spread = if point % 3 == 2 { 40.0 } else { 2.0 };
                    let z: Vec<f64> = (0..n).map(|_| rng.random_range(-spread..spread)).collect();
                    let y: Vec<f64> = if point % 2 == 0 {
                        Vec::new()
                    } else {
                        (0..def.num_constraints()).map(|_| rng.random_range(0.0..20.0)).collect()
                    };
                    for c in [0.0, 1e2, 1e4] {
                        let cost = ev.cost(&z, c, &y);
                        let objective = ev.objective(&z);
                        ev.gradient(&z, c, &y, &mut grad);
                        ev.constraints(&z, &mut con);
                        let states = (0..m).flat_map(|i| {
                            ev.predicted_states(i).iter().flatten().copied().collect::<Vec<_>>()
                        });
                        println!(
                            "M={m} {formulation:?} floor={floor:?} comp={compensation} p={point} c={c}: cost={:016x} obj={:016x} grad={:016x} con={:016x} states={:016x}",
                            cost.to_bits(),
                            objective.to_bits(),
                            hash(grad.iter().copied()),
                            hash(con.iter().copied()),
                            hash(states),
                        );
                    }
                }
            }
        }
    }
}

fn closed_loops() {
    let mut scenarios: Vec<mav::Scenario> =
        mav::Scenario::BUILT_IN.iter().map(|name| mav::Scenario::by_name(name).expect("built in")).collect();
    // The paper scenarios have neither a floor nor dead-time compensation: one run with both.
    let mut variant = mav::Scenario::paper_2();
    variant.name = "paper-2+floor+compensation".into();
    variant.min_altitude_m = Some(0.3);
    variant.delay_compensation = true;
    scenarios.push(variant);
    for scenario in &scenarios {
        for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
            match run_closed_loop(scenario, &ClosedLoopSettings::paper(mode)) {
                Ok((s, records)) => {
                    println!(
                        "{} {}: cycles={} path={:016x} final={:?} reached={} commands={:016x} plans={:016x}",
                        scenario.name,
                        mode.name(),
                        s.cycles,
                        s.path_length_m.to_bits(),
                        s.final_position_m.map(f64::to_bits),
                        s.reached,
                        hash(records.iter().flat_map(|r| r.record.command)),
                        hash(records.iter().flat_map(|r| r.plan.iter().copied())),
                    );
                    for r in &records {
                        println!("  {} {:?}", r.record.cycle, r.record.command.map(f64::to_bits));
                    }
                }
                Err(e) => println!("{} {}: error {e}", scenario.name, mode.name()),
            }
        }
    }
}

/// What to fingerprint.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Part {
    Evaluator,
    ClosedLoop,
}

#[derive(Debug, clap::Args)]
pub struct Args {
    /// One part alone (default both).
    part: Option<Part>,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    if args.part != Some(Part::ClosedLoop) {
        evaluator_points();
    }
    if args.part != Some(Part::Evaluator) {
        closed_loops();
    }
    Ok(())
}
