//! Runs flown through the library as the commands fly them (`fly::fly_all` with each driver):
//! a file's run is reproduce's, a user's scenario over gRPC is the in-process run bit for bit,
//! the terminal table, the fail-safe check reaching the controller.

use std::path::Path;

use hilbench::commands::reproduce::paper_jobs;
use hilbench::commands::run::file_jobs;
use hilbench::drive::Driver;
use hilbench::drive::services::Endpoints;
use hilbench::fly::fly_all;
use hilbench::output::cycle_log::to_csv;
use hilbench::output::summary::{OutputTimes, run_entry, summary_json};
use hilbench::output::terminal::run_table;
use hilbench::run::Batch;
use hilbench::run::{CycleRow, Job};
use hilbench::scenario_file::ScenarioFile;
use mav::Scenario;
use mpc::ControllerMode;

fn load(name: &str) -> ScenarioFile {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios").join(name);
    ScenarioFile::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// `summary.json` entries without the wall-clock solve times.
fn deterministic(batch: &Batch) -> Vec<serde_json::Value> {
    batch
        .runs
        .iter()
        .map(|r| {
            let mut v = serde_json::to_value(run_entry(&r.summary)).expect("serialisable");
            if let Some(o) = v.as_object_mut() {
                o.remove("solve_ms");
            }
            v
        })
        .collect()
}

/// Each run's rows.
fn cycles(batch: &Batch) -> Vec<Vec<CycleRow>> {
    batch.runs.iter().map(|r| r.rows.clone()).collect()
}

#[test]
fn run_of_the_paper_3_file_gives_the_summary_of_reproduce_paper_3() {
    let grpc = Driver::Services(Endpoints::default());
    let reproduce: Vec<Job> = paper_jobs(&["paper-3".to_string()])
        .expect("paper-3")
        .into_iter()
        .filter(|j| j.controller.mode() == Some(ControllerMode::Nmpc))
        .collect();
    let run = file_jobs(&load("paper-3.toml"), Some(&[ControllerMode::Nmpc]));
    assert_eq!(run, reproduce);
    let a = fly_all(&reproduce, &grpc, false).expect("reproduce");
    let b = fly_all(&run, &grpc, false).expect("run");
    assert_eq!(deterministic(&a), deterministic(&b));
    assert_eq!(b.runs.len(), 1);
    assert_eq!((b.runs[0].summary.scenario.as_str(), b.runs[0].controller()), ("paper-3", "nmpc"));
    assert!(b.runs[0].summary.reached && !b.any_collided());
    let summary = serde_json::to_value(summary_json(&b, OutputTimes::default())).expect("serialisable");
    for key in ["runs", "verdicts", "transport", "wall_time_s", "timing"] {
        assert!(summary.get(key).is_some(), "summary.json without {key}");
    }
    assert_eq!(summary["transport"], "grpc");
}

#[test]
fn a_user_scenario_over_grpc_is_identical_to_the_in_process_run() {
    // slalom-4 is no built-in: the controller is started with it and `SetGoal` starts it.
    let file = load("slalom-4.toml");
    assert!(Scenario::by_name(&file.scenario.name).is_err());
    let jobs = file_jobs(&file, None);
    assert_eq!(jobs.len(), 2);
    let grpc = fly_all(&jobs, &Driver::Services(Endpoints::default()), false).expect("grpc");
    let local = fly_all(&jobs, &Driver::InProcess, false).expect("in process");
    assert_eq!(deterministic(&grpc), deterministic(&local));
    for r in grpc.summaries() {
        assert_eq!(r.scenario, "slalom-4");
        assert!(r.cycles > 10, "{} cycles", r.cycles);
    }
    // The per-cycle logs agree row for row, but for the wall-clock solve time.
    let strip = |o: &Batch| -> Vec<Vec<CycleRow>> {
        cycles(o)
            .iter()
            .map(|rows| rows.iter().cloned().map(|r| CycleRow { solve_ms: 0.0, ..r }).collect())
            .collect()
    };
    assert_eq!(strip(&grpc), strip(&local));
    for run in &grpc.runs {
        let rows = &run.rows;
        assert_eq!(rows.len() as u64, run.summary.cycles);
        let csv = to_csv(rows);
        assert_eq!(csv.lines().count(), rows.len() + 1);
        assert!(csv.starts_with("cycle,t_s,px_m"));
    }
}

#[test]
fn the_run_table_prints_a_dash_for_a_clearance_or_solve_time_that_does_not_exist() {
    let file = load("slalom-4.toml");
    let flown = fly_all(&file_jobs(&file, Some(&[ControllerMode::Multistage])), &Driver::InProcess, false)
        .expect("in process");
    let mut run = flown.runs[0].summary.clone();
    let row = |table: &str| table.lines().nth(1).expect("a row").to_string();
    let numbers = row(&run_table(std::slice::from_ref(&run)));
    let clearance = format!("{:+}", mpc::record::Millimetres(run.min_clearance_m));
    assert!(clearance.ends_with(" mm") && numbers.contains(&clearance), "{numbers}");
    // No obstacle in the field, and an external controller (no solve times).
    run.min_clearance_m = f64::INFINITY;
    run.solve_ms_median = f64::NAN;
    let dashes = row(&run_table(&[run]));
    assert!(!dashes.contains("inf") && !dashes.contains("NaN"), "{dashes}");
    assert_eq!(dashes.split_whitespace().filter(|w| *w == "-").count(), 2, "{dashes}");
}

#[test]
fn the_fail_safe_check_of_a_scenario_file_reaches_the_controller_over_grpc() {
    // The standard NMPC on slalom-4: its plans ignore the delay, so the check (a file's
    // default) rejects some of them and the flight differs from the one with the plan
    // check; over gRPC it is the in-process flight, bit for bit.
    let mut file = load("slalom-4.toml");
    assert!(file.scenario.fail_safe, "a file's default");
    file.scenario.fail_safe = false;
    let without = fly_all(&file_jobs(&file, Some(&[ControllerMode::Nmpc])), &Driver::InProcess, false)
        .expect("in process");
    file.scenario.fail_safe = true;
    let jobs = file_jobs(&file, Some(&[ControllerMode::Nmpc]));
    let grpc = fly_all(&jobs, &Driver::Services(Endpoints::default()), false).expect("grpc");
    let local = fly_all(&jobs, &Driver::InProcess, false).expect("in process");
    assert_eq!(deterministic(&grpc), deterministic(&local));
    assert_ne!(deterministic(&local), deterministic(&without), "the check changed nothing");
    assert!(!local.runs[0].summary.collided);
}

#[test]
fn commands_the_network_dropped_are_counted_alike_in_process_and_over_grpc() {
    // paper-2's round trip, its commands lost one in ten: the summary counts what the
    // per-cycle log shows.
    let mut jobs = file_jobs(&load("paper-2.toml"), Some(&[ControllerMode::Nmpc]));
    jobs[0].scenario.delays.as_mut().expect("paper-2's delays").loss_probability = Some(0.1);
    let grpc = fly_all(&jobs, &Driver::Services(Endpoints::default()), false).expect("grpc");
    let local = fly_all(&jobs, &Driver::InProcess, false).expect("in process");
    for batch in [&grpc, &local] {
        assert!(batch.error.is_none(), "{}: {:?}", batch.driver, batch.error);
        let run = &batch.runs[0];
        let lost = run.summary.commands_lost.expect("the bench's controller's losses are counted");
        let empty = run.rows.iter().filter(|r| r.injected_delay_s.is_none()).count() as u64;
        assert!(lost > 5, "{lost} of {} commands lost", run.rows.len());
        assert_eq!(lost, empty, "{}", batch.driver);
        assert_eq!(
            serde_json::to_value(run_entry(&run.summary)).expect("serialisable")["commands_lost"],
            lost
        );
    }
    assert_eq!(deterministic(&grpc), deterministic(&local));
}
