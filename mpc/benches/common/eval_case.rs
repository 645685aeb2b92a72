//! The `cost_and_gradient` bench's instance, shared by `benches/solver.rs` and
//! `examples/profile_eval.rs`: a state between paper-2's cylinders at 1.5 m/s, equal scenario
//! weights, hover as the last input, fixed scaled inputs and no multipliers.
use mpc::{Evaluator, OcpDefinition};

/// The evaluator with the instance set, the scaled inputs `z`, the multipliers `y` and a
/// gradient buffer.
pub fn eval_case(def: &OcpDefinition) -> (Evaluator, Vec<f64>, Vec<f64>, Vec<f64>) {
    let mut ev = Evaluator::new(def);
    let m = def.num_scenarios();
    let weights = vec![1.0 / m as f64; m];
    let mut x0 = [0.0; 8];
    x0[..3].copy_from_slice(&[3.1, 1.2, 0.6]);
    x0[4] = 1.5;
    ev.set_instance(&x0, &[9.81, 0.0, 0.0], &weights);
    let n = ev.num_variables();
    let z: Vec<f64> = (0..n).map(|k| ((k * 7919) % 13) as f64 * 0.05 - 0.3).collect();
    let y = vec![0.0; def.num_constraints()];
    (ev, z, y, vec![0.0; n])
}
