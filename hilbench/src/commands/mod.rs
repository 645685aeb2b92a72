//! One module per command: each takes its validated flags, does its work through `fly`,
//! `sweep` and `output`, and returns how the process should end ([`Exit`]); only `main` exits.

pub mod certs;
pub mod falsify;
pub mod record;
pub mod reproduce;
pub mod run;
pub mod sweep;
pub mod sweep_merge;
pub mod trace;

use std::path::PathBuf;
use std::time::Instant;

use crate::drive::Driver;
use crate::fly::fly_all;
use crate::output::out_dir::OutDir;
use crate::output::{self, Outputs, ReportParts};
use crate::run::Batch;
use crate::run::Job;

/// How a command that did its work ends (an error is `Err`, exit code 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Exit {
    /// Every run ended without a collision (0).
    Success,
    /// A run collided (3): a result scripts must be able to tell from both success and error.
    Collision,
    /// `falsify` found a run that fails the property (3, as a collision).
    Falsified,
    /// Ctrl-C, after what had finished was written (130, the shells' 128 + SIGINT).
    Interrupted,
}

impl Exit {
    pub fn code(self) -> i32 {
        match self {
            Exit::Success => 0,
            Exit::Collision | Exit::Falsified => 3,
            Exit::Interrupted => 130,
        }
    }
}

/// The global flags.
#[derive(Debug, Clone, Copy)]
pub struct Options {
    pub quiet: bool,
    pub plots: bool,
    /// Write each run's MCAP file.
    pub mcap: bool,
    /// When the command started (for the total wall time).
    pub started: Instant,
}

/// A command's runs, flown and written.
struct Written {
    batch: Batch,
    summary: serde_json::Value,
    dir: PathBuf,
    /// Print the human-readable report (neither `--json` nor `--quiet`).
    show: bool,
}

/// What `reproduce` and `run` do the same way: fly the jobs, write the outputs, print the
/// JSON summary when asked; a run that failed is the command's error (what finished is kept),
/// Ctrl-C its [`Exit::Interrupted`].
fn fly_and_write(
    command: &str,
    jobs: &[Job],
    out: Option<PathBuf>,
    json: bool,
    opts: &Options,
    driver: &Driver,
    report: impl FnOnce(&Batch) -> ReportParts,
) -> anyhow::Result<Result<Written, Exit>> {
    let show = !json && !opts.quiet;
    // The output directory before the first run: one that is refused costs nothing.
    let out_dir = OutDir::claim_or_new(out.as_deref(), "", command)?;
    let batch = fly_all(jobs, driver, show)?;
    let dir = out_dir.path().to_path_buf();
    let outputs = Outputs { plots: opts.plots, mcap: opts.mcap, show };
    let summary = output::write(&dir, jobs, &batch, outputs, report)?;
    out_dir.finish()?;
    if batch.interrupted {
        eprintln!(
            "interrupted: {} run(s) had finished; they are in {}",
            batch.runs.len(),
            dir.join("summary.json").display()
        );
        return Ok(Err(Exit::Interrupted));
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    }
    if let Some(error) = &batch.error {
        let kept = batch.runs.iter().any(|r| r.error.is_some());
        let failed = if kept { ", and the failed run's cycles so far" } else { "" };
        anyhow::bail!(
            "{error}\n({} run(s) finished before it; they{failed} and the error are in {})",
            batch.finished().count(),
            dir.join("summary.json").display()
        );
    }
    Ok(Ok(Written { batch, summary, dir, show }))
}

/// The driver of a command of many lockstep runs (`sweep`, `falsify`, named `what` in the
/// error): the external controller `controller_cmd`, the services on loopback with `--grpc`
/// (over TLS when its flags are given), or in process.
fn lockstep_driver(
    controller_cmd: Option<&str>,
    grpc: bool,
    tls: &crate::cli::TlsArgs,
    what: &str,
) -> anyhow::Result<Driver> {
    use crate::drive::external::{ExternalDriver, ExternalSettings};
    use mav::TimeMode;
    Ok(match controller_cmd {
        Some(_) => Driver::External(ExternalDriver {
            time_mode: TimeMode::Lockstep,
            settings: ExternalSettings::default(),
            plant: None,
            start_from_vehicle: false,
        }),
        None if tls.given() && !grpc => {
            anyhow::bail!("the TLS flags need --grpc (a {what} flies in process otherwise)")
        }
        None if grpc => Driver::Services(crate::drive::services::Endpoints {
            tls: load_tls(tls)?.into(),
            ..Default::default()
        }),
        None => Driver::InProcess,
    })
}

/// `--jobs`, else every core.
fn jobs_or_cores(jobs: Option<u64>) -> usize {
    jobs.map_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()), |j| j as usize)
}

/// The exit of a command whose runs all finished.
fn exit_of(batch: &Batch) -> Exit {
    if batch.any_collided() { Exit::Collision } else { Exit::Success }
}

/// The TLS set-up of `hilbench`'s flags: the files read and checked (errors name the flag).
fn load_tls(args: &crate::cli::TlsArgs) -> anyhow::Result<crate::drive::services::BenchTls> {
    use crate::drive::services::BenchTls;
    use anyhow::Context;
    match &args.tls_dir {
        Some(dir) => BenchTls::from_dir(dir).with_context(|| format!("--tls-dir {}", dir.display())),
        None => BenchTls::shared(&hilbench_svc::tls::TlsFiles::client(&args.identity, &args.trust)),
    }
}

/// The services the flags give (`--plant`, `--netem`, `--controller`), for runs in `time_mode`;
/// what they do not name is started by the driver.
fn endpoints(args: crate::cli::EndpointArgs, time_mode: mav::TimeMode) -> crate::drive::services::Endpoints {
    crate::drive::services::Endpoints {
        plant: args.plant,
        netem: args.netem,
        controller: args.controller,
        time_mode,
        keep_netem_profile: args.keep_netem_profile,
        live: None,
        tls: Default::default(),
        start_from_vehicle: args.start_from_vehicle,
    }
}
