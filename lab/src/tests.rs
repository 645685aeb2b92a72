//! The command line: flags left unset give the libraries' defaults, each flag reaches its
//! setting, and a value that does not parse is a usage error (the environment variables go
//! through the same parsers).
use clap::Parser;
use clap::error::ErrorKind;
use mpc::{InactiveSetTolerances, MpcSettings, QpSettings};

use super::{Aid, Args};
use crate::traces::TraceId;

/// Parses `lab ARGS...`; the variables the flags read must be unset in the test's environment.
fn parse(args: &[&str]) -> Result<Aid, clap::Error> {
    Args::try_parse_from(std::iter::once("lab").chain(args.iter().copied())).map(|a| a.aid)
}

#[test]
fn unset_flags_give_the_default_solver_and_qp_settings() {
    let Ok(Aid::FixedInstances(a)) = parse(&["fixed-instances"]) else { panic!("fixed-instances") };
    assert_eq!(a.mpc.settings(), MpcSettings::default());
    let Ok(Aid::ProfileQp(a)) = parse(&["profile-qp"]) else { panic!("profile-qp") };
    assert_eq!(a.qp.settings(), QpSettings::default());
}

#[test]
fn solver_flags_reach_their_settings() {
    let Ok(Aid::FixedInstances(a)) = parse(&[
        "fixed-instances",
        "--tolerance=2e-3",
        "--max-inner-iterations=50",
        "--penalty-slack-m=-1",
        "--max-inner-per-outer=0",
        "--elapsed-warm-start",
        "--inactive-set=measured",
    ]) else {
        panic!("fixed-instances with flags")
    };
    let s = a.mpc.settings();
    assert_eq!(s.tolerance, 2e-3);
    assert_eq!(s.max_inner_iterations, 50);
    assert_eq!(s.penalty_preconditioner_slack_m, None);
    assert_eq!(s.max_inner_iterations_per_outer, None);
    assert!(s.warm_start_by_elapsed_time);
    assert_eq!(s.inactive_set, Some(InactiveSetTolerances::MEASURED));
}

#[test]
fn survey_flags_set_up_paper_2_and_the_fail_safe_check() {
    let Ok(Aid::DelayRobustness(a)) = parse(&[
        "delay-robustness",
        "--compensation",
        "--floor-m=0",
        "--margin-m=0.2",
        "--fail-safe",
        "--max-delay-s=0.2",
    ]) else {
        panic!("delay-robustness with flags")
    };
    let (scenario, settings) = a.survey.setup();
    assert_eq!(scenario.name, "paper-2");
    assert!(scenario.delay_compensation);
    assert_eq!(scenario.min_altitude_m, Some(0.0));
    assert_eq!(settings.episode.mpc.obstacle_margin_m, 0.2);
    let check = settings.episode.safety.and_then(|s| s.braking_check).expect("the fail-safe check is on");
    assert_eq!(check.max_delay_s, 0.2);
}

#[test]
fn values_that_do_not_parse_are_usage_errors() {
    for args in [
        &["delay-robustness", "--cases", "abc"][..],
        &["delay-robustness", "--floor-m", "low"],
        &["delay-robustness", "--only", "uniform"],
        &["accuracy", "--mode", "mpc"],
        &["accuracy", "--inactive-set", "1,2"],
        &["cycles", "paper-4", "nmpc"],
        &["qp-states", "0"],
        &["fresh", "--repeat", "0"],
    ] {
        let e = parse(args).expect_err(&format!("{args:?} must be refused"));
        assert!(
            matches!(e.kind(), ErrorKind::ValueValidation | ErrorKind::InvalidValue),
            "{args:?}: {:?}",
            e.kind()
        );
    }
}

#[test]
fn a_trace_id_is_a_known_kind_and_a_seed() {
    assert_eq!("gamma:3".parse::<TraceId>(), Ok(TraceId { kind: "gamma", seed: 3 }));
    assert!("wifi:3".parse::<TraceId>().is_err());
    assert!("gamma:-1".parse::<TraceId>().is_err());
    assert!("gamma".parse::<TraceId>().is_err());
}
