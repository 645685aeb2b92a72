//! Hot paths of the controller: cost + gradient, and warm-started solves from states along the
//! paper closed loops (targets in BENCHMARKS.md).
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use mpc::{
    ClosedLoopSettings, ControllerMode, Mpc, MpcSettings, OcpDefinition, SolveBudget, run_closed_loop,
};
use std::hint::black_box;

#[path = "common/eval_case.rs"]
mod eval_case;
use eval_case::eval_case;

fn cost_and_gradient(c: &mut Criterion) {
    let scenario = mav::Scenario::paper_2();
    for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
        let def = OcpDefinition::from_scenario(&scenario, mode, 0.1, mpc::ObstacleFormulation::DistanceAlm);
        let (mut ev, mut z, y, mut grad) = eval_case(&def);
        let mut flip = 0.0;
        c.bench_function(&format!("cost_and_gradient/{}", mode.name()), |b| {
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

/// Problem instances along the paper closed loops: (x0, u_prev, weights, warm start).
type Instance = ([f64; 8], [f64; 3], Vec<f64>, Vec<f64>);

pub fn instances(mode: ControllerMode) -> Vec<(mav::Scenario, Vec<Instance>)> {
    mav::Scenario::BUILT_IN
        .iter()
        .map(|name| {
            let scenario = mav::Scenario::by_name(name).expect("built in");
            let (_, records) = run_closed_loop(&scenario, &ClosedLoopSettings::paper(mode)).expect("runs");
            let mut out = Vec::new();
            let g = scenario.model.gravity_mps2;
            for k in 1..records.len() {
                let prev = &records[k - 1];
                let mut warm = prev.plan[3..].to_vec();
                warm.extend_from_slice(&prev.plan[prev.plan.len() - 3..]);
                let u_prev = if k == 0 { [g, 0.0, 0.0] } else { prev.command };
                out.push((records[k].state, u_prev, records[k].weights.clone(), warm));
            }
            (scenario, out)
        })
        .collect()
}

fn warm_started_solves(c: &mut Criterion) {
    let mut group = c.benchmark_group("solve_warm");
    group.sample_size(10);
    for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
        for (scenario, instances) in instances(mode) {
            let settings = MpcSettings::default();
            let def = OcpDefinition::from_scenario(
                &scenario,
                mode,
                settings.obstacle_margin_m,
                settings.formulation,
            );
            let mut mpc = Mpc::new(def, settings).expect("valid");
            group.bench_with_input(BenchmarkId::new(mode.name(), &scenario.name), &instances, |b, inst| {
                b.iter(|| {
                    for (x0, u_prev, w, warm) in inst {
                        mpc.set_warm_start(warm).expect("valid");
                        black_box(mpc.solve(x0, u_prev, w, &SolveBudget::default()).expect("valid"));
                    }
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, cost_and_gradient, warm_started_solves);
criterion_main!(benches);
