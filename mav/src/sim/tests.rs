use super::*;
use crate::model::rk4_step;

fn sim(s: &Scenario) -> PlantSim {
    PlantSim::new(s, SimSettings::default()).expect("valid settings")
}

#[test]
fn advancing_matches_plain_rk4_and_is_split_invariant_on_the_grid() {
    let s = Scenario::paper_1();
    let u = Input::new(10.5, 0.05, -0.03);
    let mut a = sim(&s);
    a.apply(u, CommandMeta::default()).expect("finite");
    a.advance(250_000_000, |_| {});
    let mut b = sim(&s);
    b.apply(u, CommandMeta::default()).expect("finite");
    for _ in 0..25 {
        b.advance(10_000_000, |_| {});
    }
    let mut x = s.start_state();
    for _ in 0..250 {
        x = rk4_step(&MavModel::default(), &x, &u, 0.001);
    }
    assert_eq!(a.state(), &x);
    assert_eq!(b.state(), &x);
    assert_eq!(a.time_ns(), 250_000_000);
}

#[test]
fn off_grid_stops_add_a_partial_step_and_realign() {
    let s = Scenario::paper_1();
    let mut a = sim(&s);
    let mut steps = Vec::new();
    a.advance(2_500_000, |p| steps.push(p.time_ns()));
    a.advance(1_000_000, |p| steps.push(p.time_ns()));
    assert_eq!(steps, vec![1_000_000, 2_000_000, 2_500_000, 3_000_000, 3_500_000]);
}

#[test]
fn commands_are_saturated_and_non_finite_ones_change_nothing() {
    let s = Scenario::paper_1();
    let mut a = sim(&s);
    let applied = a.apply(Input::new(100.0, 0.0, 0.0), CommandMeta { command_seq: 7, ..Default::default() });
    let applied = applied.expect("finite");
    assert!(applied.saturated);
    assert_eq!(applied.input[0], 2.0 * 9.81);
    let before = a.peek();
    assert_eq!(
        a.apply(Input::new(f64::NAN, 0.0, 0.0), CommandMeta::default()),
        Err(SimError::Invalid { field: "thrust_mps2", reason: "must be finite" })
    );
    assert_eq!(a.peek(), before);
}

#[test]
fn flying_into_a_cylinder_is_reported_once_with_time_and_position() {
    let s = Scenario::paper_1();
    let mut a = sim(&s);
    a.reset(State::from([0.0, 4.0, 1.0, 0.0, 3.0, 0.0, 0.0, 0.0])).expect("finite");
    a.advance(1_000_000_000, |_| {});
    let cyl: Vec<_> = a.collisions().iter().filter(|c| c.kind == CollisionKind::Cylinder).collect();
    assert_eq!(cyl.len(), 1);
    let e = cyl[0];
    assert_eq!(e.obstacle_index, 0);
    assert!((e.position_m[1] - 4.5).abs() < 0.01, "entered at {:?}", e.position_m);
    assert!(a.min_clearance_m() < 0.0);
}

#[test]
fn falling_below_the_ground_is_a_collision() {
    let s = Scenario::paper_1();
    let mut a = sim(&s);
    a.apply(Input::new(12.0, 0.0, 0.0), CommandMeta::default()).expect("finite");
    a.advance(500_000_000, |_| {});
    assert!(!a.collided());
    a.apply(Input::new(0.0, 0.0, 0.0), CommandMeta::default()).expect("finite");
    a.advance(2_000_000_000, |_| {});
    assert_eq!(a.collisions().len(), 1);
    assert_eq!(a.collisions()[0].kind, CollisionKind::Ground);
    // Resting on the ground at hover thrust is not a collision.
    let mut b = sim(&s);
    b.advance(1_000_000_000, |_| {});
    assert!(!b.collided());
}

#[test]
fn watchdog_holds_hover_until_the_next_command() {
    let s = Scenario::paper_1();
    let settings = SimSettings {
        watchdog_timeout_ns: Some(100_000_000),
        watchdog_action: WatchdogAction::Hover,
        ..Default::default()
    };
    let mut a = PlantSim::new(&s, settings).expect("valid");
    a.apply(Input::new(12.0, 0.1, 0.0), CommandMeta::default()).expect("finite");
    a.advance(99_000_000, |_| {});
    assert!(!a.watchdog_hover());
    a.advance(1_000_000, |_| {});
    assert!(a.watchdog_hover());
    assert_eq!(a.effective_input(), &Input::new(9.81, 0.0, 0.0));
    // Hover since 100 ms: 50 ms of it after 50 ms more.
    assert_eq!(a.watchdog_hover_ns(), 0);
    a.advance(50_000_000, |_| {});
    assert_eq!(a.sample().watchdog_hover_ns, 50_000_000);
    a.apply(Input::new(11.0, 0.0, 0.0), CommandMeta::default()).expect("finite");
    assert!(!a.watchdog_hover());
    a.advance(20_000_000, |_| {});
    assert_eq!(a.watchdog_hover_ns(), 50_000_000, "counted after the next command");
    a.reset(s.start_state()).expect("finite");
    assert_eq!(a.watchdog_hover_ns(), 0);
}

#[test]
fn the_braking_watchdog_applies_the_braking_law_every_20_ms_until_the_vehicle_stands_still() {
    let s = Scenario::paper_2();
    let mut a = PlantSim::new(&s, SimSettings::default()).expect("valid");
    a.reset(State::from([0.0, 0.0, 1.0, 1.5, -0.5, 0.0, 0.0, 0.0])).expect("finite");
    a.apply(Input::new(9.81, 0.0, 0.0), CommandMeta::default()).expect("finite");
    let brake = |a: &PlantSim| {
        Input::from(crate::command::braking_command(
            &s.model,
            &s.bounds,
            &(*a.state()).into(),
            crate::command::DEFAULT_BRAKE_GAIN_PER_S,
        ))
    };
    a.advance(DEFAULT_WATCHDOG_TIMEOUT_NS - 1_000_000, |_| {});
    assert!(!a.watchdog_hover());
    a.advance(1_000_000, |_| {});
    assert!(a.watchdog_hover());
    assert_eq!(a.effective_input(), &brake(&a), "the law from the state when it fired");
    // Recomputed on the 20 ms grid of plant time, held in between.
    let held = *a.effective_input();
    a.advance(WATCHDOG_BRAKE_PERIOD_NS - 1_000_000, |_| {});
    assert_eq!(a.effective_input(), &held);
    a.advance(1_000_000, |_| {});
    assert!(a.time_ns().is_multiple_of(WATCHDOG_BRAKE_PERIOD_NS));
    assert_eq!(a.effective_input(), &brake(&a));
    // From 1.58 m/s the law stops the vehicle: after 15 s it stands still.
    a.advance(15_000_000_000, |_| {});
    let speed = (a.state()[3].powi(2) + a.state()[4].powi(2) + a.state()[5].powi(2)).sqrt();
    assert!(speed < 0.01, "speed {speed} m/s");
    assert!(!a.collided());
}

#[test]
fn a_collision_records_its_deepest_penetration_while_inside() {
    let s = Scenario::paper_1();
    let c = s.obstacles[0];
    let mut a = sim(&s);
    // Straight at the cylinder's axis at 1 m/s from 5 cm outside: in 55 ms it is 5 cm deep.
    let start = State::from([c.x_m - c.radius_m - 0.05, c.y_m, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0]);
    a.reset(start).expect("finite");
    a.advance(100_000_000, |_| {});
    let hit = a.sample().collisions[0];
    assert_eq!(hit.kind, CollisionKind::Cylinder);
    assert!(hit.penetration_m < 0.002, "entry {}", hit.penetration_m);
    let depth = -a.sample().min_clearance_m;
    assert!(hit.depth_m > 0.03 && (hit.depth_m - depth).abs() < 1e-12, "{} vs {depth}", hit.depth_m);
}

#[test]
fn path_length_integrates_speed() {
    let s = Scenario::paper_1();
    // Without a watchdog: the vehicle coasts at hover (drag alone slows it).
    let mut a =
        PlantSim::new(&s, SimSettings { watchdog_timeout_ns: None, ..Default::default() }).expect("valid");
    a.reset(State::from([0.0, -5.0, 1.0, 0.0, 2.0, 0.0, 0.0, 0.0])).expect("finite");
    a.advance(1_000_000_000, |_| {});
    // vy(t) = 2 e^{-0.1 t}  =>  distance = 20 (1 - e^{-0.1})
    let expected = 20.0 * (1.0 - (-0.1f64).exp());
    assert!((a.path_length_m() - expected).abs() < 1e-6, "{}", a.path_length_m());
}
