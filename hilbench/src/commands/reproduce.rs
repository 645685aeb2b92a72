//! `hilbench reproduce`: the paper's three scenarios with the standard and the multi-stage
//! NMPC in paper mode, and the paper's tables beside what the bench measures.

use mav::{Scenario, TimeMode};
use mpc::ControllerMode;

use super::{Exit, Options, Written, exit_of, fly_and_write};
use crate::cli::ReproduceArgs;
use crate::drive::Driver;
use crate::output::{ReportParts, paper, terminal};
use crate::run::Job;

pub fn reproduce(args: ReproduceArgs, opts: &Options) -> anyhow::Result<Exit> {
    let driver = if args.in_process {
        anyhow::ensure!(!args.tls.given(), "--in-process has no links: the TLS flags need the services");
        Driver::InProcess
    } else {
        let mut endpoints = args.services.endpoints(TimeMode::Lockstep);
        endpoints.tls = args.tls.load()?.into();
        Driver::Services(endpoints)
    };
    let mut jobs = paper_jobs(&args.scenario)?;
    for job in &mut jobs {
        job.scenario.seed = args.seed.unwrap_or(job.scenario.seed);
        job.scenario.continue_after_collision = args.continue_after_collision;
    }
    let header = format!(
        "Paper reproduction: docs/spec.md paper mode (RK4 plant at 1 ms, Gamma(12, 0.015) round-trip delays, seed {}), lockstep, {}",
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
            jobs.push(Job { scenario: scenario.clone(), mode });
        }
    }
    Ok(jobs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_paper_scenarios_are_refused() {
        assert!(paper_jobs(&["paper-9".to_string()]).is_err());
        assert_eq!(paper_jobs(&[]).expect("all").len(), 6);
    }
}
