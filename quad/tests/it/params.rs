//! Parameters and settings: derived quantities, and every refusal names its field.

use approx::assert_relative_eq;
use nalgebra::Vector3;
use quad::{QuadModel, QuadParams, QuadSim, QuadState, SimError, SimSettings};

#[test]
fn default_is_a_450_mm_class_quad_hovering_near_58_percent_with_thrust_to_weight_3() {
    let p = QuadParams::default();
    assert!(p.validate().is_ok());
    assert!((0.5..=1.2).contains(&p.mass_kg));
    assert!((0.125..=0.225).contains(&p.arm_length_m));
    let twr = p.thrust_to_weight();
    assert!((2.0..=4.0).contains(&twr), "{twr}");
    assert_relative_eq!(p.hover_command(), 1.0 / twr.sqrt(), max_relative = 1e-12);
    assert!((0.57..0.58).contains(&p.hover_command()), "{}", p.hover_command());
    // At the hover command the four motors carry the weight.
    let Ok(model) = QuadModel::new(p) else { panic!("valid") };
    let speeds = model.commanded_speeds(&[p.hover_command(); 4]);
    let (thrust, torque) = model.thrust_and_torque(&speeds.into());
    assert_relative_eq!(thrust, p.weight_n(), max_relative = 1e-14);
    assert_eq!(torque, Vector3::zeros());
}

fn field_of(e: impl std::fmt::Display) -> String {
    let text = e.to_string();
    text.split('`').nth(1).unwrap_or_default().to_string()
}

#[test]
fn every_bad_parameter_is_refused_naming_its_field() {
    type Set = fn(&mut QuadParams, f64);
    let fields: [(&str, Set, f64); 10] = [
        ("mass_kg", |p, v| p.mass_kg = v, 0.0),
        ("arm_length_m", |p, v| p.arm_length_m = v, -0.1),
        ("inertia_kg_m2", |p, v| p.inertia_kg_m2[1] = v, 0.0),
        ("thrust_coefficient_n_per_rad2_s2", |p, v| p.thrust_coefficient_n_per_rad2_s2 = v, 0.0),
        ("torque_coefficient_n_m_per_rad2_s2", |p, v| p.torque_coefficient_n_m_per_rad2_s2 = v, -1e-9),
        ("motor_time_constant_s", |p, v| p.motor_time_constant_s = v, 0.0),
        ("max_motor_speed_rad_s", |p, v| p.max_motor_speed_rad_s = v, -1.0),
        ("drag_coefficient_n_s_per_m", |p, v| p.drag_coefficient_n_s_per_m = v, -0.1),
        ("rotational_drag_n_m_s_per_rad", |p, v| p.rotational_drag_n_m_s_per_rad = v, -0.1),
        ("gravity_mps2", |p, v| p.gravity_mps2 = v, 0.0),
    ];
    for (field, set, bad) in fields {
        for value in [bad, f64::NAN, f64::INFINITY] {
            let mut p = QuadParams::default();
            set(&mut p, value);
            let Err(e) = p.validate() else { panic!("{field} = {value} accepted") };
            assert_eq!(field_of(&e), field, "{e}");
            let Err(e) = QuadSim::new(p, SimSettings::default(), QuadState::resting_at(0.0, 0.0)) else {
                panic!("{field} = {value} accepted by the simulation")
            };
            assert_eq!(field_of(&e), field, "{e}");
        }
    }
    let flat = QuadParams { inertia_kg_m2: [0.01, 0.01, 0.03], ..QuadParams::default() };
    let Err(e) = flat.validate() else { panic!("an impossible inertia accepted") };
    assert!(e.to_string().contains("`inertia_kg_m2`") && e.to_string().contains("triangle"), "{e}");
}

#[test]
fn steps_out_of_range_or_too_long_for_the_motors_are_refused_naming_step_ns() {
    let p = QuadParams::default();
    for step_ns in [0, 999, 1_000_001, 2_000_000] {
        let Err(e) = SimSettings { step_ns }.validate(&p) else { panic!("{step_ns} accepted") };
        assert_eq!(field_of(&e), "step_ns", "{e}");
    }
    let fast_motors = QuadParams { motor_time_constant_s: 0.002, ..p };
    let Err(e) = SimSettings::default().validate(&fast_motors) else { panic!("accepted") };
    assert!(e.to_string().contains("quarter of motor_time_constant_s"), "{e}");
    assert!(SimSettings { step_ns: 250_000 }.validate(&fast_motors).is_ok());
}

#[test]
fn bad_initial_states_are_refused_naming_the_field() {
    let p = QuadParams::default();
    let below = QuadState { position_m: Vector3::new(0.0, 0.0, -0.01), ..QuadState::resting_at(0.0, 0.0) };
    let nan = QuadState { velocity_mps: Vector3::new(f64::NAN, 0.0, 0.0), ..QuadState::resting_at(0.0, 0.0) };
    let fast = QuadState { motor_speed_rad_s: [0.0, 0.0, 0.0, 1e4], ..QuadState::resting_at(0.0, 0.0) };
    for (state, field) in
        [(below, "initial.position_m"), (nan, "initial"), (fast, "initial.motor_speed_rad_s")]
    {
        let Err(e) = QuadSim::new(p, SimSettings::default(), state) else { panic!("{field} accepted") };
        assert_eq!(field_of(&e), field, "{e}");
        assert!(matches!(e, SimError::Invalid { .. }));
    }
}
