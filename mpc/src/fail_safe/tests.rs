use super::*;
use mav::Scenario;

fn fail_safe(cylinders: Vec<Cylinder>) -> FailSafe {
    let p = ModelParams::default();
    FailSafe::new(BrakingCheck::default(), p, InputBounds::paper(p.gravity_mps2), cylinders, 1.0)
}

#[test]
fn hovering_in_the_open_is_safe_and_flying_at_a_wall_is_not() {
    let s = Scenario::paper_2();
    let fs = fail_safe(s.obstacles.clone());
    let hover = [9.81, 0.0, 0.0];
    let e = fs.envelope(&[3.2, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0], &hover, &hover);
    assert!(e.finite && (e.min_clearance_m - 1.28).abs() < 0.01, "{e:?}");
    assert!((e.min_altitude_m - 1.0).abs() < 1e-6, "{e:?}");
    // 2 m/s at the 0.4 m cylinder from 1 m away: braking cannot stop in time.
    let fast = [2.8, 1.6, 1.0, 0.0, 2.0, 0.0, 0.0, 0.0];
    let e = fs.envelope(&fast, &hover, &hover);
    assert!(e.min_clearance_m < 0.0, "{e:?}");
    // At 0.3 m/s it can.
    let slow = [2.8, 1.6, 1.0, 0.0, 0.3, 0.0, 0.0, 0.0];
    let e = fs.envelope(&slow, &hover, &hover);
    assert!(e.min_clearance_m > 0.3, "{e:?}");
}

#[test]
fn without_delay_real_time_and_lockstep_timing_agree() {
    let p = ModelParams::default();
    let check = BrakingCheck { max_delay_s: 0.0, ..BrakingCheck::default() };
    let s = Scenario::paper_2();
    let fs = FailSafe::new(check, p, InputBounds::paper(p.gravity_mps2), s.obstacles.clone(), 1.0);
    let x0 = [2.8, 1.2, 1.0, 0.0, 0.8, 0.0, 0.0, 0.0];
    let (hover, tilt) = ([9.81, 0.0, 0.0], [10.5, 0.05, -0.03]);
    let lockstep = fs.envelope(&x0, &hover, &tilt);
    let real_time = fs.envelope_real_time(&x0, &hover, &[], &tilt);
    assert!(
        (lockstep.min_clearance_m - real_time.min_clearance_m).abs() < 1e-9,
        "{lockstep:?} {real_time:?}"
    );
    assert!((lockstep.min_altitude_m - real_time.min_altitude_m).abs() < 1e-9, "{lockstep:?} {real_time:?}");
}

#[test]
fn commands_still_in_flight_are_flown_before_this_cycles() {
    let s = Scenario::paper_2();
    let fs = fail_safe(s.obstacles.clone());
    let hover = [9.81, 0.0, 0.0];
    // Slowly towards the 0.5 m cylinder at (4.3, 4.1), 0.8 m away; braking alone stops in
    // time.
    let x0 = [4.3, 2.8, 1.0, 0.0, 0.3, 0.0, 0.0, 0.0];
    let alone = fs.envelope_real_time(&x0, &hover, &[], &hover);
    assert!(alone.min_clearance_m > 0.2, "{alone:?}");
    // Three earlier commands rolling hard towards it (+y) are still on their way: they land
    // first, and the vehicle gets much closer.
    let push = [11.0, -0.17, 0.0];
    let in_flight: Vec<InFlight> =
        [0.15, 0.1, 0.05].iter().map(|&sent_ago_s| InFlight { sent_ago_s, command: push }).collect();
    let pushed = fs.envelope_real_time(&x0, &hover, &in_flight, &hover);
    assert!(pushed.min_clearance_m < alone.min_clearance_m - 0.2, "{alone:?} {pushed:?}");
}

#[test]
fn a_command_sent_in_the_future_counts_as_sent_now() {
    let s = Scenario::paper_2();
    let fs = fail_safe(s.obstacles.clone());
    let hover = [9.81, 0.0, 0.0];
    let x0 = [4.3, 2.8, 1.0, 0.0, 0.3, 0.0, 0.0, 0.0];
    let flight = |sent_ago_s| [InFlight { sent_ago_s, command: [11.0, -0.17, 0.0] }];
    let now = fs.envelope_real_time(&x0, &hover, &flight(0.0), &hover);
    for bad in [-1e9, f64::NEG_INFINITY, f64::NAN] {
        assert_eq!(fs.envelope_real_time(&x0, &hover, &flight(bad), &hover), now, "{bad}");
    }
}

#[test]
fn a_longer_delay_reaches_further() {
    let fs = |max_delay_s| {
        let p = ModelParams::default();
        let check = BrakingCheck { max_delay_s, ..BrakingCheck::default() };
        FailSafe::new(check, p, InputBounds::paper(p.gravity_mps2), vec![Cylinder::new(0.0, 3.0, 0.5)], 1.0)
    };
    let x0 = [0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0];
    let hover = [9.81, 0.0, 0.0];
    let near = fs(0.0).envelope(&x0, &hover, &hover).min_clearance_m;
    let far = fs(0.33).envelope(&x0, &hover, &hover).min_clearance_m;
    assert!(far < near - 0.2, "{near} {far}");
    let bad = BrakingCheck { delay_samples: 1, ..BrakingCheck::default() };
    assert!(bad.validate().is_err());
}

#[test]
fn the_check_widens_to_the_longest_delay_measured_never_narrows_below_the_tree_and_caps() {
    let base = BrakingCheck::default();
    assert_eq!(base.covering(0.33, None).max_delay_s, 0.33);
    assert_eq!(base.covering(0.33, Some(0.1)).max_delay_s, 0.33, "never below the tree's range");
    assert_eq!(base.covering(0.33, Some(1.2)).max_delay_s, 1.2, "a tail beyond it is covered");
    assert_eq!(base.covering(0.33, Some(60.0)).max_delay_s, MAX_COVERED_DELAY_S);
    assert_eq!(base.covering(0.33, Some(f64::NAN)).max_delay_s, 0.33);
    // Widening and narrowing again: the range follows the window, down to the tree's.
    let wide = base.covering(0.33, Some(1.2));
    assert_eq!(wide.covering(0.33, Some(0.2)).max_delay_s, 0.33);
}
