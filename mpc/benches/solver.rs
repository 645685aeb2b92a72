//! Hot paths of the controller: cost + gradient, and warm-started solves from states along the
//! paper closed loops (targets in BENCHMARKS.md).
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use mpc::{ControllerMode, Mpc, MpcSettings, OcpDefinition, PanocSolver, SolveBudget, accuracy};
use std::hint::black_box;

use mpc::fixtures::eval_case;

fn cost_and_gradient(c: &mut Criterion) {
    let scenario = mav::Scenario::paper_2();
    // And the multi-stage problem with the fail-safe check's coast (0.96 s over 0.33 s): every
    // point's constraint along its coast.
    let cases = [
        (ControllerMode::Nmpc, 0.0, ""),
        (ControllerMode::Multistage, 0.0, ""),
        (ControllerMode::Multistage, 0.96, "_coast"),
    ];
    for (mode, coast_time_s, suffix) in cases {
        let mut def =
            OcpDefinition::from_scenario(&scenario, mode, 0.1, mpc::ObstacleFormulation::DistanceAlm);
        def.coast_time_s = coast_time_s;
        let (mut ev, mut z, y, mut grad) = eval_case(&def);
        let mut flip = 0.0;
        c.bench_function(&format!("cost_and_gradient/{}{suffix}", mode.name()), |b| {
            b.iter(|| {
                // Perturb so the forward cache cannot serve the call.
                flip = 1e-9 - flip;
                z[0] += flip;
                let cost = ev.cost(black_box(&z), 1e3, &y);
                ev.gradient(black_box(&z), 1e3, &y, &mut grad);
                black_box((cost, grad[0]))
            })
        });
    }
}

fn warm_started_solves(c: &mut Criterion) {
    let mut group = c.benchmark_group("solve_warm");
    group.sample_size(10);
    // OpEn's PANOC (the paper's, `reproduce`'s) and ours (scenario files'), each along its
    // own loops.
    for (mode, solver) in [ControllerMode::Nmpc, ControllerMode::Multistage]
        .into_iter()
        .flat_map(|m| [PanocSolver::OpEn, PanocSolver::Own].map(|s| (m, s)))
    {
        for name in mav::Scenario::BUILT_IN {
            let scenario = mav::Scenario::by_name(name).expect("built in");
            let settings = MpcSettings { solver, ..MpcSettings::default() };
            // The loop's own warm-started solves; cycle 0 is a cold start.
            let solves = accuracy::loop_solves(&scenario, mode, &settings).expect("runs");
            let instances: Vec<accuracy::Instance> = solves.into_iter().skip(1).map(|s| s.instance).collect();
            let def = OcpDefinition::from_scenario(
                &scenario,
                mode,
                settings.obstacle_margin_m,
                settings.formulation,
            );
            let mut mpc = Mpc::new(def, settings).expect("valid");
            let id = BenchmarkId::new(format!("{}/{}", mode.name(), solver.name()), &scenario.name);
            group.bench_with_input(id, &instances, |b, inst| {
                b.iter(|| {
                    for i in inst {
                        mpc.set_warm_start(&i.warm_start).expect("valid");
                        black_box(
                            mpc.solve(&i.x0, &i.u_prev, &i.weights, &SolveBudget::default()).expect("valid"),
                        );
                    }
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, cost_and_gradient, warm_started_solves);
criterion_main!(benches);
