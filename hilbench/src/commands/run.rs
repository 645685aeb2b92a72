//! `hilbench run FILE`: one scenario file, with the bench's controllers or the user's, over
//! the services, in process, or against given services, in lockstep or real time.

use std::path::Path;

use anyhow::Context;
use mav::{ControllerMode, TimeMode};

use super::{Exit, Options, Written, exit_of, fly_and_write};
use crate::cli::RunArgs;
use crate::drive::Driver;
use crate::drive::external::{ExternalDriver, ExternalSettings};
use crate::output::{ReportParts, terminal};
use crate::run::{Controller, CycleSink, Job};
use crate::scenario_file::ScenarioFile;

pub fn run(args: RunArgs, opts: &Options) -> anyhow::Result<Exit> {
    anyhow::ensure!(
        !args.tls.given() || (args.controller_cmd.is_none() && !args.in_process),
        "the TLS flags need the bench's services (not --in-process or --controller-cmd, whose links stay plaintext on loopback)"
    );
    let file = args.file.as_path();
    let spec = scenario_as_flown(file, &args)?;
    if args.controller_cmd.is_none() {
        spec.nmpc_tuning(file)?;
    }
    let driver = driver(file, &spec, args.controller_cmd.is_some(), &args, opts)?;
    let modes = args.mode.map(|m| m.modes());
    let jobs = match &args.controller_cmd {
        // One run of the file's scenario with the user's controller.
        Some(command) => {
            vec![Job { scenario: spec.scenario.clone(), controller: Controller::External(command.clone()) }]
        }
        None => file_jobs(&spec, modes.as_deref()),
    };
    let header = |batch_time_mode: TimeMode| {
        format!(
            "{} ({}): {}, {}; {}",
            spec.scenario.name,
            file.display(),
            batch_time_mode.name(),
            driver.describe(),
            terminal::delays_text(&spec.scenario)
        )
    };
    let written = fly_and_write("run", &jobs, args.out, args.json, opts, &driver, |batch| ReportParts {
        title: format!("hilbench run {}", file.display()),
        header: header(batch.time_mode),
        tables: None,
        verdicts: Vec::new(),
    })?;
    let Written { batch, summary, dir, show } = match written {
        Ok(w) => w,
        Err(exit) => return Ok(exit),
    };
    if show {
        println!();
        println!("{}", header(batch.time_mode));
        println!();
        print!("{}", terminal::run_table(&batch.summaries()));
        println!();
        terminal::print_time(&summary, opts.plots, opts.mcap, opts.started);
        terminal::print_outputs(&dir);
    }
    Ok(exit_of(&batch))
}

/// The file's scenario with the flags applied: `--sweep-run` (the run as the sweep flies it),
/// `--seed`, `--continue-after-collision`, `--delay-trace`.
fn scenario_as_flown(file: &Path, args: &RunArgs) -> anyhow::Result<ScenarioFile> {
    let mut spec = ScenarioFile::load(file)?;
    if let Some(index) = args.sweep_run {
        // The run as the sweep flies it: the scenario's own seed, delays drawn from the
        // sweep's seed (which --seed sets there) and the index.
        let table = spec
            .sweep
            .as_ref()
            .with_context(|| format!("--sweep-run: {} has no [sweep] table", file.display()))?;
        let seed = args.seed.or(table.seed).unwrap_or(spec.scenario.seed);
        let plan = crate::sweep::draw::plan(table, &spec.scenario, seed, index)
            .map_err(|e| anyhow::anyhow!("--sweep-run {index}: {e}"))?;
        spec.scenario = plan.scenario(&spec.scenario);
    } else if let Some(seed) = args.seed {
        spec.scenario.seed = seed;
    }
    spec.scenario.continue_after_collision |= args.continue_after_collision;
    if let Some(trace) = &args.delay_trace {
        let delays =
            crate::scenario_file::read_trace(trace).map_err(|e| anyhow::anyhow!("--delay-trace: {e}"))?;
        let name = trace.display().to_string();
        spec.scenario.delays = Some(delay::DelaysTable::trace(&name, delays, false));
        spec.scenario.validate().map_err(|e| anyhow::anyhow!("--delay-trace {name}: {e}"))?;
    }
    Ok(spec)
}

/// How the flags fly the file: `--controller-cmd`, `--in-process`, or the services (started
/// here, or given), with the live Foxglove view of `--foxglove-ws`.
fn driver(
    file: &Path,
    spec: &ScenarioFile,
    external: bool,
    args: &RunArgs,
    opts: &Options,
) -> anyhow::Result<Driver> {
    if args.foxglove_ws.is_some() && (external || args.in_process) {
        anyhow::bail!(
            "--foxglove-ws needs the bench's services in real time (not --in-process or --controller-cmd)"
        );
    }
    let time_mode = args.time_mode.unwrap_or(spec.run.time_mode);
    if external {
        let mut settings = ExternalSettings::default();
        if let Some(s) = args.stall_timeout_s {
            settings.stall_timeout = std::time::Duration::from_secs_f64(s);
        }
        return Ok(Driver::External(ExternalDriver {
            time_mode,
            settings,
            plant: args.services.plant.clone(),
            start_from_vehicle: args.services.start_from_vehicle,
        }));
    }
    if args.in_process {
        if spec.run.time_mode == TimeMode::RealTime {
            anyhow::bail!("{}: real time needs the services (not --in-process)", file.display());
        }
        return Ok(Driver::InProcess);
    }
    let mut endpoints = super::endpoints(args.services.clone(), time_mode);
    endpoints.tls = super::load_tls(&args.tls)?.into();
    if let Some(addr) = args.foxglove_ws {
        if endpoints.time_mode != TimeMode::RealTime {
            anyhow::bail!(
                "--foxglove-ws needs --time-mode real-time (a lockstep run is over before a viewer connects; open its .mcap file instead)"
            );
        }
        let live = crate::output::foxglove::Live::start(addr)?;
        if !opts.quiet {
            eprintln!("Foxglove: serving the run live on ws://{}", live.addr());
        }
        endpoints.live = Some(std::sync::Arc::new(live) as std::sync::Arc<dyn CycleSink>);
    }
    Ok(Driver::Services(endpoints))
}

/// The file's scenario with `modes`, or with the file's `run.modes`.
pub fn file_jobs(file: &ScenarioFile, modes: Option<&[ControllerMode]>) -> Vec<Job> {
    let modes = modes.unwrap_or(&file.run.modes);
    modes
        .iter()
        .map(|&mode| Job { scenario: file.scenario.clone(), controller: Controller::Bench(mode) })
        .collect()
}
