use super::*;

#[test]
fn clearance_is_horizontal_below_the_top_and_to_the_cap_above() {
    let c = Cylinder::new(0.0, 6.0, 1.5);
    assert!((c.clearance_m(0.0, 4.0, 1.0) - 0.5).abs() < 1e-15);
    assert!((c.clearance_m(0.0, 6.0, 1.0) + 1.5).abs() < 1e-15);
    assert!((c.clearance_m(0.0, 6.0, 12.0) - 2.0).abs() < 1e-15);
    assert!((c.clearance_m(3.5, 6.0, 13.0) - 2.0f64.hypot(3.0)).abs() < 1e-12);
}

#[test]
fn min_clearance_picks_the_nearest() {
    let obs = [Cylinder::new(3.5, 1.5, 0.25), Cylinder::new(2.8, 3.0, 0.4)];
    let (d, i) = min_clearance(&obs, 2.8, 2.0, 1.0);
    assert_eq!(i, Some(1));
    assert!((d - 0.6).abs() < 1e-12);
    assert_eq!(min_clearance(&[], 0.0, 0.0, 0.0), (f64::INFINITY, None));
}
