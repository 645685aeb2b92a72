use super::*;

fn in_bounds(b: &InputBounds, u: [f64; 3]) -> bool {
    (0..3).all(|c| u[c].is_finite() && u[c] >= b.min[c] && u[c] <= b.max[c])
}

#[test]
fn braking_tilts_against_the_velocity() {
    let p = ModelParams::default();
    let b = InputBounds::paper(p.gravity_mps2);
    let u = braking_command(&p, &b, &[0.0, 0.0, 1.0, 2.0, -1.0, 0.5, 0.0, 0.0], 1.0);
    assert!(u[2] < 0.0, "pitch back against +vx: {u:?}");
    assert!(u[1] < 0.0, "roll against -vy (vy' = -T sin(phi)): {u:?}");
    assert!(u[0] < p.gravity_mps2 * 1.1 && in_bounds(&b, u));
    assert_eq!(braking_command(&p, &b, &[0.0; 8], 1.0), [p.gravity_mps2, 0.0, 0.0]);
    let nan = [f64::NAN; 8];
    assert_eq!(braking_command(&p, &b, &nan, 1.0), [p.gravity_mps2, 0.0, 0.0]);
}

#[test]
fn sanitize_replaces_non_finite_components_with_hover_clips_and_makes_zero_positive() {
    let p = ModelParams::default();
    let b = InputBounds::paper(p.gravity_mps2);
    let u = sanitize_command(&p, &b, [f64::NAN, 10.0, f64::NEG_INFINITY]);
    assert_eq!(u, [p.gravity_mps2, b.max[1], 0.0]);
    let u = sanitize_command(&p, &b, [p.gravity_mps2, -0.0, -0.0]);
    assert!(u[1].is_sign_positive() && u[2].is_sign_positive(), "{u:?}");
    let inside = [p.gravity_mps2, 0.1, -0.1];
    assert_eq!(sanitize_command(&p, &b, inside), inside);
}
