//! `hilbench reproduce`: the paper's three scenarios with the standard and the multi-stage
//! NMPC in paper mode, and the paper's tables beside what the bench measures.

use mav::{Scenario, TimeMode};
use mpc::ControllerMode;

use super::{Exit, Options, Written, exit_of, fly_and_write};
use crate::cli::ReproduceArgs;
use crate::drive::Driver;
use crate::output::{ReportParts, paper, terminal};
use crate::run::{Controller, Job};

pub fn reproduce(args: ReproduceArgs, opts: &Options) -> anyhow::Result<Exit> {
    let driver = if args.in_process {
        anyhow::ensure!(!args.tls.given(), "--in-process has no links: the TLS flags need the services");
        Driver::InProcess
    } else {
        let mut endpoints = super::endpoints(args.services, TimeMode::Lockstep);
        endpoints.tls = super::load_tls(&args.tls)?.into();
        Driver::Services(endpoints)
    };
    let mut jobs = paper_jobs(&args.scenario)?;
    for job in &mut jobs {
        job.scenario.seed = args.seed.unwrap_or(job.scenario.seed);
        job.scenario.continue_after_collision = args.continue_after_collision;
    }
    let header = format!(
        "Paper reproduction: docs/spec.md paper mode (RK4 plant at 1 ms, {}, seed {}), lockstep, {}",
        delays_text(&jobs),
        args.seed.unwrap_or(Scenario::paper_1().seed),
        driver.describe()
    );
    let written = fly_and_write("reproduce", &jobs, args.out, args.json, opts, &driver, |batch| {
        let summaries = batch.summaries();
        ReportParts {
            title: "Paper reproduction".to_string(),
            header: header.clone(),
            tables: Some(paper::tables(&summaries)),
            verdicts: paper::verdicts(&summaries),
        }
    })?;
    let Written { batch, summary, dir, show } = match written {
        Ok(w) => w,
        Err(exit) => return Ok(exit),
    };
    if show {
        let summaries = batch.summaries();
        println!();
        println!("{header}");
        println!();
        print!("{}", paper::tables(&summaries));
        println!();
        println!("What reproduces");
        for v in paper::verdicts(&summaries) {
            println!("  - {v}");
        }
        println!();
        println!();
        terminal::print_time(&summary, opts.plots, opts.mcap, opts.started);
        terminal::print_outputs(&dir);
    }
    Ok(exit_of(&batch))
}

/// The built-in scenarios (`only` these, when given), each with the standard and the
/// multi-stage NMPC.
pub fn paper_jobs(only: &[String]) -> anyhow::Result<Vec<Job>> {
    for o in only {
        if !Scenario::BUILT_IN.contains(&o.as_str()) {
            anyhow::bail!("--scenario {o:?}: unknown (known: {})", Scenario::BUILT_IN.join(", "));
        }
    }
    let mut jobs = Vec::new();
    for name in Scenario::BUILT_IN {
        if !only.is_empty() && !only.iter().any(|o| o == name) {
            continue;
        }
        let scenario = Scenario::by_name(name)?;
        for mode in [ControllerMode::Nmpc, ControllerMode::Multistage] {
            jobs.push(Job { scenario: scenario.clone(), controller: Controller::Bench(mode) });
        }
    }
    Ok(jobs)
}

/// The delays the jobs fly, as the header says them: the paper's Gamma for the scenarios that
/// have delays, "no delays" for those that have none (paper-3).
fn delays_text(jobs: &[Job]) -> String {
    let mut with = Vec::new();
    let mut without = Vec::new();
    for job in jobs {
        let names = if job.scenario.delays_expected() { &mut with } else { &mut without };
        if !names.contains(&job.scenario.name.as_str()) {
            names.push(job.scenario.name.as_str());
        }
    }
    let gamma = "Gamma(12, 0.015) round-trip delays";
    match (with.is_empty(), without.is_empty()) {
        (_, true) => gamma.to_string(),
        (true, false) => "no delays".to_string(),
        (false, false) => format!("{gamma} for {}, no delays for {}", with.join(", "), without.join(", ")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_header_says_paper_3_flies_no_delays() {
        let jobs = paper_jobs(&[]).expect("the paper's jobs");
        assert_eq!(
            delays_text(&jobs),
            "Gamma(12, 0.015) round-trip delays for paper-1, paper-2, no delays for paper-3"
        );
        let paper_3: Vec<Job> = jobs.iter().filter(|j| j.scenario.name == "paper-3").cloned().collect();
        assert_eq!(delays_text(&paper_3), "no delays");
    }

    #[test]
    fn unknown_paper_scenarios_are_refused() {
        assert!(paper_jobs(&["paper-9".to_string()]).is_err());
        assert_eq!(paper_jobs(&[]).expect("all").len(), 6);
    }
}
