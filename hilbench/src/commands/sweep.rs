//! `hilbench sweep FILE`: N lockstep runs, each under a delay process drawn from the file's
//! `[sweep]` table; outcomes as distributions.

use std::sync::Arc;

use anyhow::Context;
use mav::TimeMode;
use serde_json::{Value, json};

use super::{Exit, Options};
use crate::cli::SweepArgs;
use crate::output::out_dir::OutDir;
use crate::output::terminal;
use crate::scenario_file::ScenarioFile;
use crate::sweep::journal::Journal;
use crate::sweep::{Sweep, execute, fnv1a64, output, shard, shrink_failures, until};

pub fn sweep(args: SweepArgs, opts: &Options) -> anyhow::Result<Exit> {
    let spec = ScenarioFile::load(&args.file)?;
    if args.controller_cmd.is_none() {
        spec.nmpc_tuning(&args.file)?;
    }
    let table = spec.sweep.clone().with_context(|| {
        format!(
            "{}: no [sweep] table (the delay families to draw from; see docs/sweep.md)",
            args.file.display()
        )
    })?;
    // --until-bound: --runs is the cap, the file's number of runs does not apply.
    let cap = args.until_bound.map(|_| args.runs.unwrap_or(crate::sweep::until::MAX_RUNS));
    let runs = cap.or(args.runs).or(table.runs).with_context(|| {
        format!(
            "--runs: how many runs? (give --runs N, or `runs` in the [sweep] table of {})",
            args.file.display()
        )
    })?;
    let modes = args.mode.map_or_else(|| spec.run.modes.clone(), |m| m.modes());
    let controllers = crate::run::Controller::of(args.controller_cmd.as_deref(), &modes);
    anyhow::ensure!(
        spec.run.time_mode == TimeMode::Lockstep,
        "{}: a sweep flies in lockstep (run.time_mode is real-time)",
        args.file.display()
    );
    // --shard auto: the scheduler's variables, read here and nowhere else (a value that is not
    // UTF-8 is kept, lossily, to be refused as not a number).
    let env = || {
        std::env::vars_os()
            .map(|(k, v)| (k.to_string_lossy().into_owned(), v.to_string_lossy().into_owned()))
            .collect()
    };
    let shard = args.shard.map(|arg| shard::resolve(arg, &env())).transpose().map_err(anyhow::Error::msg)?;
    let jobs = super::jobs_or_cores(args.jobs);
    let driver = super::lockstep_driver(args.controller_cmd.as_deref(), args.grpc, &args.tls, "sweep")?;
    let sweep = Sweep {
        file: args.file.clone(),
        seed: args.seed.or(table.seed).unwrap_or(spec.scenario.seed),
        runs,
        controllers,
        shard,
        jobs,
        driver,
        run_timeout: std::time::Duration::from_secs_f64(
            args.run_timeout_s
                .or(table.run_timeout_s)
                .unwrap_or(hilbench_scenario_file::sweep_table::DEFAULT_RUN_TIMEOUT_S),
        ),
        shrink: args.shrink,
        shrink_runs: args
            .shrink_runs
            .or(table.shrink_runs)
            .unwrap_or(hilbench_scenario_file::sweep_table::DEFAULT_SHRINK_RUNS),
        shrink_total_runs: args
            .shrink_total_runs
            .or(table.shrink_total_runs)
            .unwrap_or(hilbench_scenario_file::sweep_table::DEFAULT_SHRINK_TOTAL_RUNS),
        shrink_wall: args.shrink_wall_s.map(std::time::Duration::from_secs_f64),
        scenario: spec.scenario,
        table,
        batch: None,
        journal: None,
        finished: Default::default(),
    };
    check_runs(&sweep, args.runs.is_some())?;
    // A bound the cap cannot reach is refused before --out is claimed: nothing flew, nothing
    // to resume.
    if let Some(bound) = args.until_bound {
        until::check(bound, sweep.runs)?;
    }
    let show = !args.json && !opts.quiet;
    let items = (sweep.indices().end - sweep.indices().start) * sweep.controllers.len() as u64;
    // The output directory before the first run: a sweep that cannot write loses nothing.
    let file_text =
        std::fs::read(&args.file).with_context(|| format!("cannot read {}", args.file.display()))?;
    let identity = identity(&sweep, &file_text, args.until_bound, args.per_family);
    // --resume where no sweep was killed starts one: a scheduler's retry of a task is the same
    // command line whether the first try was killed or never started.
    let (out_dir, journal, finished) = match (args.resume, args.out.as_deref()) {
        (true, Some(dir)) if crate::output::out_dir::unfinished(dir) => {
            let (out_dir, _) = OutDir::reclaim(dir, "sweep")?;
            let (journal, finished) = Journal::resume(dir, &identity)?;
            if show {
                eprintln!("resuming {}: {} of {items} runs had finished", dir.display(), finished.len());
            }
            (out_dir, journal, finished)
        }
        (_, out) => {
            let out_dir = OutDir::claim_or_new(out, "sweep-", "sweep")?;
            let journal = Journal::start(out_dir.path(), &identity)?;
            (out_dir, journal, Default::default())
        }
    };
    let dir = out_dir.path().to_path_buf();
    let journal = Arc::new(journal);
    let sweep = Sweep { journal: Some(Arc::clone(&journal)), finished: Arc::new(finished), ..sweep };
    let bar = crate::progress::bar_with_eta(items, "runs", show);
    let (mut result, sweep) = match args.until_bound {
        None => (execute(&sweep, &bar, show), sweep),
        Some(bound) => {
            let (result, runs) = until::execute_until(&sweep, bound, args.per_family, &bar, show)?;
            (result, Sweep { runs, ..sweep })
        }
    };
    bar.finish_and_clear();
    if sweep.shrink && !result.interrupted {
        let spent = shrink_failures(&sweep, &mut result, !opts.quiet);
        result.interrupted |= spent.interrupted;
        result.shrinking = Some(spent);
    }
    let summary = output::write(&dir, &sweep, &result, opts.plots)?;
    journal.finish()?;
    out_dir.finish()?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else if show {
        terminal::print_sweep(&summary, &dir);
    }
    if let (Some(until), false) = (&result.until_bound, opts.quiet) {
        eprintln!("{}", until::say(until));
    }
    if result.interrupted {
        eprintln!(
            "interrupted: {} run(s) had finished; they are in {}",
            result.done.len(),
            dir.join("sweep.json").display()
        );
        return Ok(Exit::Interrupted);
    }
    // A sweep's failures are its findings, in sweep.json: the command itself succeeded.
    Ok(Exit::Success)
}

/// Refuses a sweep whose process would fly more than `sweep_table::MAX_RUNS` runs (its shard's
/// with `--shard`), naming where the number came from, before anything is allocated or flown.
fn check_runs(sweep: &Sweep, from_flag: bool) -> anyhow::Result<()> {
    let max = hilbench_scenario_file::sweep_table::MAX_RUNS;
    let here = sweep.indices().end - sweep.indices().start;
    let source =
        if from_flag { "--runs".to_string() } else { format!("{}: sweep.runs", sweep.file.display()) };
    anyhow::ensure!(
        here <= max,
        "{source} {}: {here} runs in this process, more than the {max} one sweep process flies (each \
         run's row is kept until the end); split it into shards (--shard I/K) and merge them",
        sweep.runs
    );
    Ok(())
}

/// What makes a sweep the same sweep (`--resume` refuses another): the file's contents and
/// every setting that changes which runs fly or what they give; not `--jobs`, not the file's
/// path (the same file may be named from elsewhere).
fn identity(sweep: &Sweep, file_text: &[u8], until_bound: Option<f64>, per_family: bool) -> Value {
    let mut identity = json!({
        "file_fnv1a64": format!("{:016x}", fnv1a64(file_text)),
        "seed": sweep.seed,
        "runs": sweep.runs,
        "controllers": sweep.controller_names(),
        "controller_cmd": sweep.controller_cmd(),
        "transport": sweep.driver.name(),
        "shard": sweep.shard.map(|s| format!("{}/{}", s.index, s.count)),
        "until_bound": until_bound,
        "run_timeout_s": sweep.run_timeout.as_secs_f64(),
        "shrink": sweep.shrink,
        "shrink_runs": sweep.shrink_runs,
        "shrink_total_runs": sweep.shrink_total_runs,
        "shrink_wall_s": sweep.shrink_wall.map(|w| w.as_secs_f64()),
    });
    // Only when given, so that every other sweep's identity is as before.
    if per_family {
        identity["per_family"] = json!(true);
    }
    identity
}
