//! One RK4 step of the rigid-body quadrotor (17 states), 1 ms step, and one simulation step
//! (the step, the quaternion's normalisation and the ground check).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use mav::rk4_step;
use nalgebra::{UnitQuaternion, Vector3};
use quad::model::MotorSpeeds;
use quad::{QuadModel, QuadParams, QuadSim, QuadState, SimSettings};
use std::hint::black_box;

fn flying() -> QuadState {
    let params = QuadParams::default();
    QuadState {
        velocity_mps: Vector3::new(0.3, -0.2, 0.1),
        attitude: UnitQuaternion::from_euler_angles(0.05, -0.04, 0.3),
        angular_velocity_rad_s: Vector3::new(0.2, -0.1, 0.05),
        ..QuadState::hovering_at(&params, Vector3::new(0.0, 0.0, 1.0))
    }
}

fn rk4(c: &mut Criterion) {
    let params = QuadParams::default();
    let Ok(model) = QuadModel::new(params) else { panic!("the default parameters are valid") };
    let commands = [0.6, 0.55, 0.58, 0.57];
    let u = model.commanded_speeds(&commands);
    let mut group = c.benchmark_group("quad");
    group.throughput(Throughput::Elements(1));
    group.bench_function("rk4_step", |b| {
        // Chained steps (each uses the previous result), like the simulation's loop.
        let mut x = flying().to_vector();
        b.iter(|| {
            x = rk4_step(black_box(&model), black_box(&x), black_box::<&MotorSpeeds>(&u), black_box(0.001));
        });
        black_box(x);
    });
    group.bench_function("sim_step", |b| {
        let Ok(mut sim) = QuadSim::new(params, SimSettings::default(), flying()) else {
            panic!("a valid simulation")
        };
        sim.set_commands([params.hover_command(); 4]);
        b.iter(|| sim.step());
        black_box(sim.state());
    });
    group.finish();
}

criterion_group!(benches, rk4);
criterion_main!(benches);
