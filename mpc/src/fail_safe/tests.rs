use super::*;
use mav::Scenario;
use proptest::prelude::*;

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
fn a_cycle_too_short_to_move_time_neither_passes_validation_nor_spins_the_check() {
    // 1e-300 s: `t + min_cycle_s == t`, and the braking loops used to spin for ever (the
    // controller sat at cycle 1 ignoring SIGTERM); 1e-6 s: 5 million cycles per flight.
    for min_cycle_s in [1e-300, 1e-6] {
        let check = BrakingCheck {
            min_cycle_s,
            max_delay_s: 0.0,
            stop_speed_mps: 0.0,
            plant_watchdog_s: None,
            ..BrakingCheck::default()
        };
        assert!(check.validate().is_err(), "{min_cycle_s}");
        let p = ModelParams::default();
        let fs = FailSafe::new(check, p, InputBounds::paper(p.gravity_mps2), vec![], 1.0);
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let x0 = [0.0, 0.0, 1.0, 0.0, 2.0, 0.0, 0.0, 0.0];
            let hover = [9.81, 0.0, 0.0];
            let lockstep = fs.envelope(&x0, &hover, &hover);
            let real_time = fs.envelope_real_time(&x0, &hover, &[], &hover);
            let _ = tx.send((lockstep, real_time));
        });
        let done = rx.recv_timeout(std::time::Duration::from_secs(60));
        assert!(done.is_ok(), "min_cycle_s = {min_cycle_s:e}: the check did not finish in 60 s");
    }
    let shortest = BrakingCheck { min_cycle_s: mav::MIN_CYCLE_S, ..BrakingCheck::default() };
    assert_eq!(shortest.validate(), Ok(()));
    let long = BrakingCheck { horizon_s: 1e9, ..BrakingCheck::default() };
    assert!(long.validate().is_err());
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

#[test]
fn the_plans_coast_is_twice_the_longest_delay_up_to_the_watchdog_plus_plan_coast_s() {
    let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
    // The defaults: delays up to 0.33 s, the plant's watchdog at 0.5 s, 0.3 s more.
    let base = BrakingCheck::default();
    assert_eq!(base.plan_coast_s, Some(0.3));
    assert!(close(base.plan_coast_time_s(), 0.96), "{}", base.plan_coast_time_s());
    assert!(close(base.covering(0.33, Some(0.4)).plan_coast_time_s(), 1.1), "a longer delay measured");
    assert!(
        close(base.covering(0.33, Some(1.2)).plan_coast_time_s(), 1.3),
        "past the watchdog the plant brakes"
    );
    let no_watchdog = BrakingCheck { plant_watchdog_s: None, ..base };
    assert!(close(no_watchdog.covering(0.33, Some(1.2)).plan_coast_time_s(), 2.7));
    assert_eq!(no_watchdog.covering(0.33, Some(3.0)).plan_coast_time_s(), crate::MAX_COAST_TIME_S, "capped");
    assert_eq!(BrakingCheck { plan_coast_s: None, ..base }.plan_coast_time_s(), 0.0, "off");
    for bad in [-0.1, f64::NAN, f64::INFINITY, 5.5] {
        let err = BrakingCheck { plan_coast_s: Some(bad), ..base }.validate().expect_err("refused");
        assert!(err.to_string().contains("braking_check.plan_coast_s"), "{bad}: {err}");
    }
}

/// The pair-by-pair flights the check made before it shared the prefix of each `d`
/// (`FailSafe::worst_over_delays`): every pair `(d, d')` flown whole from `x0`. The
/// yardstick of the shared flights, bit for bit.
mod pair_by_pair {
    use super::*;

    fn worst_over_delays(
        fs: &FailSafe,
        x0: &[f64; 8],
        mut fly: impl FnMut(f64, f64, &mut Envelope),
    ) -> Envelope {
        let mut out =
            Envelope { min_clearance_m: f64::INFINITY, min_altitude_m: f64::INFINITY, finite: true };
        fs.observe(&State::from(*x0), &mut out);
        for d in fs.check.delays() {
            for d_next in fs.check.delays() {
                fly(d, d_next, &mut out);
                if !out.finite {
                    return out;
                }
            }
        }
        out
    }

    pub(super) fn envelope(fs: &FailSafe, x0: &[f64; 8], u_prev: &[f64; 3], command: &[f64; 3]) -> Envelope {
        worst_over_delays(fs, x0, |d, d_next, out| fly(fs, x0, u_prev, command, d, d_next, out))
    }

    pub(super) fn envelope_real_time(
        fs: &FailSafe,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        in_flight: &[InFlight],
        command: &[f64; 3],
    ) -> Envelope {
        let mut brakes = VecDeque::new();
        worst_over_delays(fs, x0, |d, d_next, out| {
            fly_real_time(fs, x0, u_prev, in_flight, command, d, d_next, &mut brakes, out)
        })
    }

    #[allow(clippy::too_many_arguments)]
    fn fly_real_time(
        fs: &FailSafe,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        in_flight: &[InFlight],
        command: &[f64; 3],
        d: f64,
        d_next: f64,
        brakes: &mut VecDeque<(f64, [f64; 3])>,
        out: &mut Envelope,
    ) {
        let period = fs.check.min_cycle_s;
        let mut link = Link { x: State::from(*x0), t: 0.0, applied: *u_prev, landed_at: 0.0 };
        let mut landed_at = 0.0f64;
        let sent = in_flight.iter().map(|f| ((d - f.sent_ago_s.max(0.0)).max(0.0), f.command));
        for (at, u) in sent.chain(std::iter::once((d, *command))) {
            landed_at = landed_at.max(at);
            fs.run_until(&mut link, landed_at, out);
            link.land(u);
        }
        brakes.clear();
        let end = period.max(d) + fs.check.horizon_s;
        let mut next_sample = period;
        while out.finite {
            let landing = brakes.front().map(|(at, _)| *at).filter(|at| *at <= next_sample);
            let event = landing.unwrap_or(next_sample);
            if event > end {
                fs.run_until(&mut link, end, out);
                return;
            }
            fs.run_until(&mut link, event, out);
            if landing.is_some() {
                if let Some((_, u)) = brakes.pop_front() {
                    link.land(u);
                }
                if speed_mps(&link.x) < fs.check.stop_speed_mps {
                    return;
                }
            } else {
                let brake =
                    braking_command(&fs.model.params, &fs.bounds, &link.x.into(), fs.brake_gain_per_s);
                landed_at = landed_at.max(link.t + d_next);
                brakes.push_back((landed_at, brake));
                next_sample += period;
            }
        }
    }

    fn fly(
        fs: &FailSafe,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        command: &[f64; 3],
        d: f64,
        d_next: f64,
        out: &mut Envelope,
    ) {
        let t_min = fs.check.min_cycle_s;
        let mut link = Link { x: State::from(*x0), t: 0.0, applied: *u_prev, landed_at: 0.0 };
        fs.run_until(&mut link, d, out);
        link.land(*command);
        let mut sample = t_min.max(d);
        fs.run_until(&mut link, sample, out);
        let end = sample + fs.check.horizon_s;
        while sample < end && out.finite {
            let brake = braking_command(&fs.model.params, &fs.bounds, &link.x.into(), fs.brake_gain_per_s);
            fs.run_until(&mut link, sample + d_next, out);
            link.land(brake);
            sample += t_min.max(d_next);
            fs.run_until(&mut link, sample, out);
            if speed_mps(&link.x) < fs.check.stop_speed_mps {
                break;
            }
        }
    }
}

/// Bit for bit, NaN and the sign of zero included.
fn bits(e: &Envelope) -> (u64, u64, bool) {
    (e.min_clearance_m.to_bits(), e.min_altitude_m.to_bits(), e.finite)
}

/// Mostly ordinary values; sometimes a zero of either sign (a vehicle at rest on the ground:
/// altitudes of +0 and -0 tie in the running minimum), or one that makes the flight non-finite
/// (at the start, at a landing in the middle of the prefix), so the early exit is compared too.
fn value(ordinary: std::ops::Range<f64>) -> impl Strategy<Value = f64> {
    prop_oneof![
        30 => ordinary,
        2 => Just(0.0),
        2 => Just(-0.0),
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(-1e300),
    ]
}

fn arb_state() -> impl Strategy<Value = [f64; 8]> {
    (
        (value(0.0..7.0), value(-1.0..6.0), value(-0.5..3.0)),
        (value(-3.0..3.0), value(-3.0..3.0), value(-2.0..2.0)),
        (value(-0.3..0.3), value(-0.3..0.3)),
    )
        .prop_map(|((px, py, pz), (vx, vy, vz), (phi, theta))| [px, py, pz, vx, vy, vz, phi, theta])
}

fn arb_input() -> impl Strategy<Value = [f64; 3]> {
    (value(0.0..20.0), value(-0.3..0.3), value(-0.3..0.3)).prop_map(|(t, phi, theta)| [t, phi, theta])
}

fn arb_check() -> impl Strategy<Value = BrakingCheck> {
    (
        prop_oneof![1 => Just(0.0), 4 => 0.0f64..3.5],
        0.01f64..0.3,
        2usize..=4,
        (0.05f64..3.0, 0.01f64..0.05),
        prop_oneof![1 => Just(0.0), 4 => 0.0f64..0.3],
        prop::option::of(0.03f64..1.0),
    )
        .prop_map(
            |(
                max_delay_s,
                min_cycle_s,
                delay_samples,
                (horizon_s, step_s),
                stop_speed_mps,
                plant_watchdog_s,
            )| {
                BrakingCheck {
                    max_delay_s,
                    min_cycle_s,
                    delay_samples,
                    horizon_s,
                    step_s,
                    stop_speed_mps,
                    plant_watchdog_s,
                    ..BrakingCheck::default()
                }
            },
        )
}

fn arb_in_flight() -> impl Strategy<Value = Vec<InFlight>> {
    prop::collection::vec(
        (prop_oneof![20 => -0.1f64..1.0, 1 => Just(f64::NAN)], arb_input())
            .prop_map(|(sent_ago_s, command)| InFlight { sent_ago_s, command }),
        0..5,
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    /// Sharing each `d`'s prefix changes no bit of either envelope, whatever the state, the
    /// inputs, the commands in flight and the check's settings (watchdog firing in the prefix,
    /// delays past the first sample or not, early stops, non-finite flights).
    #[test]
    fn the_shared_prefix_gives_the_pair_by_pair_envelopes_bit_for_bit(
        check in arb_check(),
        x0 in arb_state(),
        (u_prev, command) in (arb_input(), arb_input()),
        in_flight in arb_in_flight(),
        gain_per_s in 0.5f64..3.0,
        cylinders in prop::collection::vec((0.0f64..7.0, -1.0f64..6.0, 0.1f64..0.8), 0..4),
    ) {
        prop_assert!(check.validate().is_ok());
        let p = ModelParams::default();
        let cylinders = cylinders.into_iter().map(|(x, y, r)| Cylinder::new(x, y, r)).collect();
        let fs = FailSafe::new(check, p, InputBounds::paper(p.gravity_mps2), cylinders, gain_per_s);
        let shared = fs.envelope(&x0, &u_prev, &command);
        let reference = pair_by_pair::envelope(&fs, &x0, &u_prev, &command);
        prop_assert_eq!(bits(&shared), bits(&reference), "lockstep {:?} {:?}", shared, reference);
        let shared = fs.envelope_real_time(&x0, &u_prev, &in_flight, &command);
        let reference = pair_by_pair::envelope_real_time(&fs, &x0, &u_prev, &in_flight, &command);
        prop_assert_eq!(bits(&shared), bits(&reference), "real time {:?} {:?}", shared, reference);
    }
}

#[test]
fn the_benchmark_checks_are_the_pair_by_pair_ones_bit_for_bit() {
    // `benches/cycle.rs`'s instance, and the same with the range widened to the longest
    // covered delay (a heavy tail seen), where the long prefixes are.
    let s = Scenario::paper_2();
    let x0 = [3.1, 1.2, 0.6, 0.1, 1.5, 0.2, 0.05, -0.02];
    let (u_prev, u) = ([10.5, 0.05, -0.02], [10.0, 0.1, 0.0]);
    let in_flight: Vec<InFlight> =
        [0.15, 0.1, 0.05].iter().map(|&sent_ago_s| InFlight { sent_ago_s, command: u_prev }).collect();
    for check in [BrakingCheck::default(), BrakingCheck::default().covering(0.33, Some(MAX_COVERED_DELAY_S))]
    {
        let fs = FailSafe::new(check, s.model, s.bounds, s.obstacles.clone(), 1.0);
        let (shared, reference) =
            (fs.envelope(&x0, &u_prev, &u), pair_by_pair::envelope(&fs, &x0, &u_prev, &u));
        assert_eq!(bits(&shared), bits(&reference), "{check:?}");
        let shared = fs.envelope_real_time(&x0, &u_prev, &in_flight, &u);
        let reference = pair_by_pair::envelope_real_time(&fs, &x0, &u_prev, &in_flight, &u);
        assert_eq!(bits(&shared), bits(&reference), "{check:?}");
    }
}
