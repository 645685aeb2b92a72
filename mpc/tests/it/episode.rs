//! The one control cycle (`mpc::Episode`) as a driver sees it: samples in, commands out, delays
//! measured from the samples' stamps alone.

use mav::{CommandMeta, Input, PlantSim, Scenario, SimSettings};
use mpc::{ControllerMode, CycleTiming, Episode, EpisodeSettings, MpcSettings, RunEnd};

fn settings(mode: ControllerMode, delays_expected: bool) -> EpisodeSettings {
    EpisodeSettings { delays_expected, ..EpisodeSettings::new(mode, MpcSettings::default()) }
}

/// Flies `cycles` cycles of paper-2 on `PlantSim`, each command landing `delay_ns` after its
/// sample; returns the episode and the known delay of every cycle.
fn fly(delay_ns: u64, cycles: usize, delays_expected: bool) -> (Episode, Vec<Option<f64>>, Vec<Vec<f64>>) {
    let scenario = Scenario::paper_2();
    let mut episode =
        Episode::new(scenario.clone(), settings(ControllerMode::Multistage, delays_expected)).expect("valid");
    let mut sim = PlantSim::new(&scenario, SimSettings::default()).expect("valid");
    let (mut known, mut weights) = (Vec::new(), Vec::new());
    for _ in 0..cycles {
        let sample = sim.sample();
        let out = episode.on_sample(&sample, &CycleTiming::Lockstep).expect("valid sample");
        known.push(out.record.known_delay_s);
        weights.push(out.record.weights.clone());
        assert_eq!(out.meta.based_on_sample_time_ns, sample.time_ns);
        sim.advance(delay_ns, |_| {});
        sim.apply(Input::from(out.record.command), out.meta).expect("a sanitised command is valid");
        sim.advance(episode.min_cycle_ns().max(delay_ns) - delay_ns, |_| {});
    }
    (episode, known, weights)
}

#[test]
fn the_delay_of_each_command_is_measured_from_the_next_samples_stamps_to_the_nanosecond() {
    let (episode, known, _) = fly(123_456_789, 4, true);
    assert_eq!(known[0], None, "nothing is known before the first command lands");
    for (k, delay_s) in known.iter().enumerate().skip(1) {
        assert_eq!(delay_s.map(f64::to_bits), Some(mav::ns_to_s(123_456_789).to_bits()), "cycle {k}");
    }
    assert_eq!(episode.commands_sent(), 4);
    assert_eq!(episode.cycles(), 4);
}

#[test]
fn multistage_weights_follow_the_measured_delays_only_when_delays_are_expected() {
    let nominal = Scenario::paper_2().nominal_weights;
    let (_, _, fixed) = fly(200_000_000, 8, false);
    assert!(fixed.iter().all(|w| *w == nominal), "no delays expected: the nominal weights throughout");
    let (_, _, fitted) = fly(200_000_000, 8, true);
    // Constant delays are a degenerate window: the prior until enough samples, then still the
    // prior; either way not the nominal weights, and always a distribution over the scenarios.
    assert!(fitted.iter().all(|w| *w != nominal));
    for w in &fitted {
        assert!(w.iter().all(|v| v.is_finite() && *v >= 0.0), "{w:?}");
    }
}

#[test]
fn a_stamp_the_episode_did_not_send_is_not_taken_for_a_delay() {
    let scenario = Scenario::paper_2();
    let mut episode = Episode::new(scenario.clone(), settings(ControllerMode::Nmpc, true)).expect("valid");
    let mut sim = PlantSim::new(&scenario, SimSettings::default()).expect("valid");
    // A command from another client (sequence 7, never sent by this episode) lands first.
    sim.advance(30_000_000, |_| {});
    let foreign = CommandMeta { command_seq: 7, based_on_sample_seq: 0, based_on_sample_time_ns: 0 };
    sim.apply(Input::from(scenario.model.hover_input()), foreign).expect("valid");
    let out = episode.on_sample(&sim.sample(), &CycleTiming::Lockstep).expect("valid");
    assert_eq!(out.record.known_delay_s, None);
    assert_eq!(out.meta.command_seq, 1);
}

#[test]
fn an_episode_finishes_at_the_goal_or_at_the_time_limit_and_not_before() {
    let mut scenario = Scenario::paper_2();
    scenario.max_duration_s = 1.0;
    let episode = Episode::new(scenario.clone(), settings(ControllerMode::Nmpc, false)).expect("valid");
    let mut sim = PlantSim::new(&scenario, SimSettings::default()).expect("valid");
    assert_eq!(episode.finish(&sim.sample()), None);
    sim.advance(1_000_000_000, |_| {});
    assert_eq!(episode.finish(&sim.sample()), Some(RunEnd::TimeLimit));
    let mut at_goal = scenario.clone();
    at_goal.start[..3].copy_from_slice(&scenario.goal_m);
    let mut sim = PlantSim::new(&at_goal, SimSettings::default()).expect("valid");
    assert!(episode.finish(&sim.sample()).is_some_and(RunEnd::reached));
}

#[test]
fn a_goal_the_scenario_cannot_have_is_refused_and_changes_nothing() {
    let scenario = Scenario::paper_2();
    let mut episode = Episode::new(scenario.clone(), settings(ControllerMode::Nmpc, false)).expect("valid");
    // Inside paper-2's cylinder.
    let cylinder = &scenario.obstacles[0];
    assert!(episode.set_goal([cylinder.x_m, cylinder.y_m, 0.5]).is_err());
    assert_eq!(episode.scenario().goal_m, scenario.goal_m);
    assert!(episode.set_goal([3.0, 4.5, 1.2]).is_ok());
    assert_eq!(episode.scenario().goal_m, [3.0, 4.5, 1.2]);
}

#[test]
fn in_real_time_commands_not_yet_applied_are_in_flight_and_forgotten_with_the_link() {
    let scenario = Scenario::paper_2();
    let mut episode = Episode::new(scenario.clone(), settings(ControllerMode::Nmpc, true)).expect("valid");
    let mut sim = PlantSim::new(&scenario, SimSettings::default()).expect("valid");
    let timing = CycleTiming::RealTime { deadline: std::time::Duration::from_secs(1) };
    // Commands that never land: at each cycle, every earlier one is in flight.
    for k in 0..3 {
        episode.on_sample(&sim.sample(), &timing).expect("valid");
        assert_eq!(episode.in_flight().len(), k, "cycle {k}");
        sim.advance(50_000_000, |_| {});
    }
    episode.forget_in_flight();
    episode.on_sample(&sim.sample(), &timing).expect("valid");
    assert_eq!(episode.in_flight().len(), 0, "forgotten commands are not flown again");
}

#[test]
fn a_sample_of_another_plant_flight_ends_the_episode_with_a_plant_reset_and_changes_nothing() {
    let scenario = Scenario::paper_2();
    let mut episode = Episode::new(scenario.clone(), settings(ControllerMode::Nmpc, false)).expect("valid");
    let mut sim = PlantSim::new(&scenario, SimSettings::default()).expect("valid");
    sim.set_flight_id(41);
    episode.on_sample(&sim.sample(), &CycleTiming::Lockstep).expect("the first flight");
    sim.advance(300_000_000, |_| {});
    episode.on_sample(&sim.sample(), &CycleTiming::Lockstep).expect("the same flight");
    // The plant restarts: a new flight, from time zero.
    let mut restarted = PlantSim::new(&scenario, SimSettings::default()).expect("valid");
    restarted.set_flight_id(7);
    restarted.advance(100_000_000, |_| {});
    let err = episode.on_sample(&restarted.sample(), &CycleTiming::Lockstep).expect_err("another flight");
    assert_eq!(err, mpc::MpcError::PlantReset { last_time_s: 0.3, time_s: 0.1 });
    assert_eq!((episode.cycles(), episode.commands_sent()), (2, 2), "nothing flown changed");
    // A plant that does not number its flights (0) is not checked.
    let mut anonymous = Episode::new(scenario.clone(), settings(ControllerMode::Nmpc, false)).expect("valid");
    anonymous.on_sample(&sim.sample(), &CycleTiming::Lockstep).expect("valid");
    let mut unnumbered = PlantSim::new(&scenario, SimSettings::default()).expect("valid");
    anonymous.on_sample(&unnumbered.sample(), &CycleTiming::Lockstep).expect("not checked");
}

#[test]
fn a_scenario_that_names_a_solver_is_solved_by_it_whatever_the_controllers_setting() {
    let run = |scenario: &Scenario, solver: mpc::PanocSolver| {
        let mut settings = mpc::ClosedLoopSettings::paper(ControllerMode::Multistage);
        settings.episode.mpc.solver = solver;
        let (summary, records) = mpc::run_closed_loop(scenario, &settings).expect("a paper run");
        let iterations: Vec<usize> = records.iter().map(|r| r.report.iterations).collect();
        (summary.path_length_m.to_bits(), iterations)
    };
    let paper = Scenario::paper_2();
    let own = run(&paper, mpc::PanocSolver::Own);
    let open = run(&paper, mpc::PanocSolver::OpEn);
    assert_ne!(own, open, "the two solvers take different iterations on paper-2");
    // The scenario's choice wins over the controller's setting, both ways, to the bit.
    let pinned_own = Scenario { solver: Some(mpc::PanocSolver::Own), ..paper.clone() };
    assert_eq!(run(&pinned_own, mpc::PanocSolver::OpEn), own);
    let pinned_open = Scenario { solver: Some(mpc::PanocSolver::OpEn), ..paper };
    assert_eq!(run(&pinned_open, mpc::PanocSolver::Own), open);
}
