//! `hilbench falsify FILE`: search the file's `[falsify]` spaces for a run that fails the
//! property; falsify.json, runs.csv, the worst runs' traces, report.md.

use std::sync::Arc;

use anyhow::Context;
use mav::TimeMode;
use serde_json::{Value, json};

use super::{Exit, Options};
use crate::cli::FalsifyArgs;
use crate::falsification::journal::Journal;
use crate::falsification::{Falsification, execute, output};
use crate::output::out_dir::OutDir;
use crate::run::Controller;
use crate::scenario_file::ScenarioFile;

pub fn falsify(args: FalsifyArgs, opts: &Options) -> anyhow::Result<Exit> {
    let spec = ScenarioFile::load(&args.file)?;
    if args.controller_cmd.is_none() {
        spec.nmpc_tuning(&args.file)?;
    }
    let table = spec.falsify.clone().with_context(|| {
        format!(
            "{}: no [falsify] table (the spaces to search and the property; see docs/falsify.md)",
            args.file.display()
        )
    })?;
    anyhow::ensure!(
        spec.run.time_mode == TimeMode::Lockstep,
        "{}: a falsification flies in lockstep (run.time_mode is real-time)",
        args.file.display()
    );
    let mode = match args.mode {
        Some(m) => match m.modes()[..] {
            [one] => one,
            _ => anyhow::bail!("--mode: one controller per falsification (nmpc or multistage, not both)"),
        },
        None => spec.run.modes[0],
    };
    let seed = args.seed.or(table.seed).unwrap_or(spec.scenario.seed);
    let mut spaces = hilbench_scenario_file::falsify_table::spaces(&table, spec.sweep.as_ref(), seed);
    if !args.space.is_empty() {
        let names: Vec<String> = spaces.iter().map(|s| s.name.clone()).collect();
        if let Some(unknown) = args.space.iter().find(|s| !names.contains(s)) {
            anyhow::bail!("--space: `{unknown}` is none of the file's spaces ({})", names.join(", "));
        }
        spaces.retain(|s| args.space.contains(&s.name));
    }
    let methods = if args.method.is_empty() {
        vec![table.method]
    } else {
        let mut m: Vec<falsify::Method> = args.method.iter().map(|m| m.method()).collect();
        m.dedup();
        m
    };
    let jobs = super::jobs_or_cores(args.jobs);
    let driver =
        super::lockstep_driver(args.controller_cmd.as_deref(), args.grpc, &args.tls, "falsification")?;
    let sweep = spec.sweep.as_ref();
    let falsification = Falsification {
        file: args.file.clone(),
        spaces,
        methods,
        property: table.property,
        budget: args.budget.unwrap_or(table.budget_or_default()),
        seed,
        whole_budget: args.whole_budget,
        population: table.population.map(|p| p as usize),
        sigma0: table.sigma0.unwrap_or(falsify::table::DEFAULT_SIGMA0),
        warmup: args.warmup.or(table.warmup).unwrap_or(0) as usize,
        controller: match &args.controller_cmd {
            Some(command) => Controller::External(command.clone()),
            None => Controller::Bench(mode),
        },
        jobs,
        driver,
        run_timeout: std::time::Duration::from_secs_f64(
            args.run_timeout_s
                .or(sweep.and_then(|s| s.run_timeout_s))
                .unwrap_or(hilbench_scenario_file::sweep_table::DEFAULT_RUN_TIMEOUT_S),
        ),
        shrink_runs: if args.no_shrink {
            0
        } else {
            args.shrink_runs
                .or(sweep.and_then(|s| s.shrink_runs))
                .unwrap_or(hilbench_scenario_file::sweep_table::DEFAULT_SHRINK_RUNS)
        },
        scenario: spec.scenario,
        journal: None,
    };
    // The output directory before the first run: a search that cannot write loses nothing.
    let file_text =
        std::fs::read(&args.file).with_context(|| format!("cannot read {}", args.file.display()))?;
    let identity = identity(&falsification, &file_text);
    let show = !args.json && !opts.quiet;
    // --resume where no falsification was killed starts one, as a sweep does.
    let (out_dir, journal) = match (args.resume, args.out.as_deref()) {
        (true, Some(dir)) if crate::output::out_dir::unfinished(dir) => {
            let (out_dir, _) = OutDir::reclaim(dir, "falsify")?;
            let journal = Journal::resume(dir, &identity)?;
            if show {
                eprintln!("resuming {}: {} run(s) had finished", dir.display(), journal.len());
            }
            (out_dir, journal)
        }
        (_, out) => {
            let out_dir = OutDir::claim_or_new(out, "falsify-", "falsify")?;
            let journal = Journal::start(out_dir.path(), &identity)?;
            (out_dir, journal)
        }
    };
    let dir = out_dir.path().to_path_buf();
    let journal = Arc::new(journal);
    let falsification = Falsification { journal: Some(Arc::clone(&journal)), ..falsification };
    if show {
        eprintln!(
            "falsify {}: {} space(s) x {} method(s), {} runs each at most, property {}",
            falsification.file.display(),
            falsification.spaces.len(),
            falsification.methods.len(),
            falsification.budget,
            falsification.property.name()
        );
    }
    let mut progress = |space: &str, method: falsify::Method, g: &falsify::Generation| {
        if show {
            eprintln!(
                "  {space} {:<6} {:>5} runs  best {:+.4} m{}",
                method.name(),
                g.runs,
                g.best,
                if g.best < 0.0 { "  (failed)" } else { "" }
            );
        }
    };
    let result = execute(&falsification, &mut progress);
    let summary = output::write(&dir, &falsification, &result, opts.plots)?;
    journal.finish()?;
    out_dir.finish()?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else if show {
        crate::output::terminal::print_falsify(&summary, &dir);
    }
    if result.interrupted {
        eprintln!("interrupted: what had flown is in {}", dir.join("falsify.json").display());
        return Ok(Exit::Interrupted);
    }
    // Nothing evaluated is no finding: said, and not a success.
    let runs: usize = result.searches.iter().map(|s| s.evaluations.len()).sum();
    if result.evaluated() == 0 {
        let first = result.searches.iter().flat_map(|s| &s.evaluations).find(|e| !e.error.is_empty());
        anyhow::bail!(
            "no run was evaluated: all {runs} run(s) ended with the bench's own errors{} (falsify.json in {})",
            first.map_or(String::new(), |e| format!("; the first: {}", e.error)),
            dir.display()
        );
    }
    Ok(if result.found() { Exit::Falsified } else { Exit::Success })
}

/// What makes a falsification the same one (`--resume` refuses another): the file's contents
/// and every setting that changes which points fly or what they give; not `--jobs` (the same
/// seed gives the same search whatever it), not the file's path.
fn identity(f: &Falsification, file_text: &[u8]) -> Value {
    json!({
        "file_fnv1a64": format!("{:016x}", crate::sweep::fnv1a64(file_text)),
        "seed": f.seed,
        "spaces": f.spaces.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(),
        "methods": f.methods.iter().map(|m| m.name()).collect::<Vec<_>>(),
        "property": f.property.name(),
        "budget": f.budget,
        "whole_budget": f.whole_budget,
        "warmup": f.warmup,
        "controller": f.controller.name(),
        "controller_cmd": f.controller.command(),
        "transport": f.driver.name(),
        "run_timeout_s": f.run_timeout.as_secs_f64(),
        "shrink_runs": f.shrink_runs,
    })
}
