use super::*;
use approx::assert_relative_eq;
use proptest::prelude::*;

fn mav() -> MavModel {
    MavModel::default()
}

fn integrate(
    step: fn(&MavModel, &State, &Input, f64) -> State,
    x0: State,
    u: Input,
    t_end: f64,
    n: usize,
) -> State {
    let dt = t_end / n as f64;
    let mut x = x0;
    for _ in 0..n {
        x = step(&mav(), &x, &u, dt);
    }
    x
}

#[test]
fn hover_is_an_equilibrium() {
    let m = mav();
    let x = State::from([1.0, -2.0, 3.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let u = m.params.hover_input();
    assert_eq!(m.derivative(&x, &u), State::zeros());
    assert_eq!(rk4_step(&m, &x, &u, 0.001), x);
    assert_eq!(euler_step(&m, &x, &u, 0.05), x);
}

#[test]
fn free_fall_with_zero_thrust_matches_the_drag_solution() {
    // vz' = -g - Az vz  =>  vz(t) = -(g/Az)(1 - e^{-Az t}),  z(t) = -(g/Az) t + (g/Az^2)(1 - e^{-Az t})
    let p = ModelParams::default();
    let (g, a) = (p.gravity_mps2, p.drag_z_per_s);
    let t = 2.0;
    let x = integrate(rk4_step, State::zeros(), Input::zeros(), t, 2000);
    let vz = -(g / a) * (1.0 - (-a * t).exp());
    let z = -(g / a) * t + (g / (a * a)) * (1.0 - (-a * t).exp());
    assert_relative_eq!(x[5], vz, max_relative = 1e-12);
    assert_relative_eq!(x[2], z, max_relative = 1e-12);
    assert_eq!(x[0], 0.0);
    assert_eq!(x[1], 0.0);
}

#[test]
fn attitude_follows_a_first_order_response() {
    let p = ModelParams::default();
    let u = Input::new(p.gravity_mps2, 0.1, -0.05);
    for &t in &[0.1, 0.5, 1.0, 3.0] {
        let x = integrate(rk4_step, State::zeros(), u, t, (t * 1000.0) as usize);
        let phi = 0.1 * (1.0 - (-t / p.tau_roll_s).exp());
        let theta = -0.05 * (1.0 - (-t / p.tau_pitch_s).exp());
        assert_relative_eq!(x[6], phi, max_relative = 1e-12);
        assert_relative_eq!(x[7], theta, max_relative = 1e-12);
    }
}

/// Observed order of convergence from errors at step h and h/2 against a fine reference.
fn observed_order(step: fn(&MavModel, &State, &Input, f64) -> State, n: usize) -> f64 {
    let x0 = State::from([0.0, 0.0, 1.0, 0.5, -0.3, 0.2, 0.1, -0.12]);
    let u = Input::new(12.0, -0.17, 0.17);
    let t = 1.0;
    let reference = integrate(rk4_step, x0, u, t, 100_000);
    let e1 = (integrate(step, x0, u, t, n) - reference).norm();
    let e2 = (integrate(step, x0, u, t, 2 * n) - reference).norm();
    (e1 / e2).log2()
}

#[test]
fn rk4_converges_at_fourth_order() {
    let order = observed_order(rk4_step, 20);
    assert!((order - 4.0).abs() < 0.15, "observed order {order}");
}

#[test]
fn euler_converges_at_first_order() {
    let order = observed_order(euler_step, 200);
    assert!((order - 1.0).abs() < 0.05, "observed order {order}");
}

/// A textbook system through the same generic integrators: x'' = -x, exact solution cos t.
struct Oscillator;
impl Dynamics<2, 1> for Oscillator {
    fn derivative(&self, x: &SVector<f64, 2>, _u: &SVector<f64, 1>) -> SVector<f64, 2> {
        SVector::<f64, 2>::new(x[1], -x[0])
    }
}

#[test]
fn integrators_solve_the_harmonic_oscillator() {
    let (n, t) = (1000, 1.0);
    let dt = t / n as f64;
    let (mut a, mut b) = (SVector::<f64, 2>::new(1.0, 0.0), SVector::<f64, 2>::new(1.0, 0.0));
    let u = SVector::<f64, 1>::zeros();
    for _ in 0..n {
        a = rk4_step(&Oscillator, &a, &u, dt);
        b = euler_step(&Oscillator, &b, &u, dt);
    }
    assert_relative_eq!(a[0], t.cos(), epsilon = 1e-12);
    assert_relative_eq!(b[0], t.cos(), epsilon = 1e-3);
}

#[test]
fn saturation_clips_to_the_box() {
    let b = InputBounds::paper(9.81);
    let (u, clipped) = b.saturate(&Input::new(30.0, -1.0, 0.1));
    assert!(clipped);
    assert_eq!(u, Input::new(19.62, -std::f64::consts::PI / 18.0, 0.1));
    let (_, clipped) = b.saturate(&Input::new(9.81, 0.0, 0.0));
    assert!(!clipped);
}

proptest! {
    #[test]
    fn steps_stay_finite_for_finite_states_and_bounded_inputs(
        p in prop::array::uniform3(-1e3f64..1e3),
        v in prop::array::uniform3(-50f64..50.0),
        att in prop::array::uniform2(-3.2f64..3.2),
        t in 0.0f64..19.62,
        phi_d in -0.1746f64..0.1746,
        theta_d in -0.1746f64..0.1746,
        dt in 1e-4f64..0.4,
    ) {
        let x = State::from([p[0], p[1], p[2], v[0], v[1], v[2], att[0], att[1]]);
        let u = Input::new(t, phi_d, theta_d);
        let a = rk4_step(&mav(), &x, &u, dt);
        let b = euler_step(&mav(), &x, &u, dt);
        prop_assert!(a.iter().all(|c| c.is_finite()));
        prop_assert!(b.iter().all(|c| c.is_finite()));
    }
}
