//! Flying jobs: [`fly_all`] runs every [`Job`] in order with one [`Driver`], on a runtime of its
//! own that also watches for Ctrl-C, and gives back each [`FinishedRun`] (the failed one kept as
//! far as it flew). `hilbench reproduce`, `run`, `sweep` and `falsify` (one job per run,
//! [`fly_one`], with a time limit) all fly through here, so whatever a driver gains, every
//! command gains.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use mav::TimeMode;
use mpc::RunSummary;

use anyhow::Context;

use crate::drive::{Driver, grpc, in_process};
use crate::run::{Batch, Controller, FinishedRun, Job, RunError, RunFailure};

/// How often a real-time run without a terminal says it is still flying.
const HEARTBEAT: Duration = Duration::from_secs(5);
/// How long a run interrupted by Ctrl-C is given to hand back what it flew.
const INTERRUPT_GRACE: Duration = Duration::from_secs(3);

/// Runs every job in order (in lockstep, or in real time when the driver says so). `progress`
/// shows a progress bar on stderr when it is a terminal, and a line per finished run (and
/// every few seconds of a real-time run) either way.
pub fn fly_all(jobs: &[Job], driver: &Driver, progress: bool) -> anyhow::Result<Batch> {
    let started = Instant::now();
    // In process too: the runtime watches for Ctrl-C while a run goes on.
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name(crate::panics::RUN_THREAD)
        .enable_all()
        .build()
        .context("cannot start the tokio runtime")?;
    let mut runs = Vec::with_capacity(jobs.len());
    let mut error = None;
    let mut interrupted = false;
    let bar = crate::progress::bar(jobs.len() as u64, "runs", progress);
    // One Ctrl-C listener for all the runs: a listener made per run would miss a Ctrl-C that
    // lands between two runs (tokio's handler, once installed, swallows it).
    let (ctrl_c_tx, ctrl_c_rx) = tokio::sync::watch::channel(false);
    runtime.spawn(async move {
        if tokio::signal::ctrl_c().await.is_ok() {
            let _ = ctrl_c_tx.send(true);
        }
    });
    let real_time = driver.time_mode() == TimeMode::RealTime;
    for job in jobs {
        let name = &job.scenario.name;
        let controller = job.controller.name();
        bar.set_message(format!("{name} with {controller}"));
        let mut ctrl_c = ctrl_c_rx.clone();
        if *ctrl_c.borrow_and_update() {
            interrupted = true;
            break;
        }
        let run_started = Instant::now();
        let flown = runtime.block_on(async {
            // Without a terminal a real-time run would say nothing for its whole flight (tens
            // of seconds): a line every few seconds says it is alive.
            let heartbeat = async {
                let mut tick = tokio::time::interval(HEARTBEAT);
                tick.tick().await;
                loop {
                    tick.tick().await;
                    let text = format!(
                        "  {name} {controller:<11} flying ({:.0} s)",
                        run_started.elapsed().as_secs_f64()
                    );
                    crate::progress::line(&bar, progress, &text);
                }
            };
            let flying = fly(job, driver, ctrl_c.clone());
            tokio::pin!(flying);
            tokio::select! {
                flown = &mut flying => Some(flown),
                Ok(()) = ctrl_c.changed() => {
                    // The driver sees the same Ctrl-C and ends with what it flew: a moment for
                    // it to say so (a driver that cannot is abandoned, its run lost).
                    tokio::time::timeout(INTERRUPT_GRACE, &mut flying).await.ok()
                }
                () = heartbeat, if real_time && bar.is_hidden() => None,
            }
        });
        if *ctrl_c.borrow() {
            // Ctrl-C: the run as far as it flew, kept with its error ("interrupted").
            if let Some(Err((_, partial))) = flown {
                runs.extend(partial);
            }
            interrupted = true;
            break;
        }
        let Some(flown) = flown else {
            interrupted = true;
            break;
        };
        let run = match flown {
            Ok(run) => run,
            Err((e, partial)) => {
                // What flew before the error is kept, its error with it.
                runs.extend(partial);
                error = Some(e);
                break;
            }
        };
        let summary = &run.summary;
        let mut collided = if summary.collided {
            format!("; COLLIDED: {}", summary.collisions_text())
        } else {
            String::new()
        };
        if !summary.reached || summary.collided {
            for line in &summary.explanation {
                collided.push_str("; ");
                collided.push_str(line);
            }
        }
        let lost = match summary.commands_lost {
            Some(n) if n > 0 => format!(", {n} lost by the network"),
            _ => String::new(),
        };
        let done = format!(
            "  {name} {controller:<11} done ({} cycles{lost}, {:.2} s){collided}",
            summary.cycles,
            run_started.elapsed().as_secs_f64()
        );
        crate::progress::line(&bar, progress, &done);
        bar.inc(1);
        runs.push(run);
    }
    bar.finish_and_clear();
    // An interrupted run's services and solve are abandoned, not awaited.
    runtime.shutdown_background();
    Ok(Batch {
        runs,
        error,
        interrupted,
        driver: driver.name(),
        time_mode: driver.time_mode(),
        wall_time_s: started.elapsed().as_secs_f64(),
    })
}

/// A run as flown: its summary and per-cycle rows.
#[derive(Debug, Clone)]
pub struct Flight {
    pub summary: RunSummary,
    pub rows: Vec<crate::run::CycleRow>,
    /// Delays the run drew from its round trip by its end: one per cycle for the bench's
    /// controller, netem's count of the commands delayed before the end for an external one
    /// (`ExternalFacts::commands_delayed`: it can have several in flight, and draws for
    /// commands it never sees applied). `None`: unknown.
    pub delays_drawn: Option<usize>,
}

impl Flight {
    /// The flight of a finished run.
    pub fn of(run: FinishedRun) -> Self {
        let delays_drawn = match &run.external {
            Some(facts) => facts.commands_delayed.and_then(|n| usize::try_from(n).ok()),
            None => Some(run.rows.len()),
        };
        Self { summary: run.summary, rows: run.rows, delays_drawn }
    }

    /// How many of the `available` delays a replay of this run needs: those it drew (all of
    /// them when that is unknown).
    pub fn delays_needed(&self, available: usize) -> usize {
        self.delays_drawn.map_or(available, |n| n.min(available))
    }
}

/// What became of one run of [`fly_one`].
#[derive(Debug, Clone)]
pub enum RunFate {
    Flown(Box<Flight>),
    /// The run stopped with an error (a trace that ran out, a service that failed, the
    /// controller that stopped, ...).
    Failed(RunError),
    /// The run took longer than the time limit; its thread is left to finish on its own.
    TimedOut(Duration),
    /// Ctrl-C.
    Interrupted,
}

/// Flies `job` as `hilbench run` does ([`fly_all`] with one job), on a thread of its own so
/// that a run that hangs past `timeout` is given up (and counted) while the caller goes on.
pub fn fly_one(job: &Job, driver: &Driver, timeout: Duration) -> RunFate {
    let (tx, rx) = mpsc::channel();
    let (job, driver) = (job.clone(), driver.clone());
    let spawned = std::thread::Builder::new().name("hilbench-one-run".into()).spawn(move || {
        let _ = tx.send(fly_all(&[job], &driver, false));
    });
    if let Err(e) = spawned {
        return RunFate::Failed(RunError::bench(format!("cannot start the run's thread: {e}")));
    }
    match rx.recv_timeout(timeout) {
        Ok(Ok(mut batch)) => {
            if batch.interrupted {
                return RunFate::Interrupted;
            }
            if let Some(e) = batch.error {
                return RunFate::Failed(e);
            }
            match batch.runs.pop() {
                Some(run) => RunFate::Flown(Box::new(Flight::of(run))),
                None => RunFate::Failed(RunError::bench("the run ended without a summary")),
            }
        }
        Ok(Err(e)) => RunFate::Failed(RunError::bench(format!("{e:#}"))),
        Err(mpsc::RecvTimeoutError::Timeout) => RunFate::TimedOut(timeout),
        Err(mpsc::RecvTimeoutError::Disconnected) => {
            RunFate::Failed(RunError::bench("the run's thread panicked"))
        }
    }
}

/// Sets `stop` at the first Ctrl-C (SIGINT), from a thread named `thread`. The runs in flight
/// see it too ([`fly_all`] listens for it) and end as interrupted.
pub fn watch_ctrl_c(stop: Arc<AtomicBool>, thread: &str) {
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build();
    if let Ok(runtime) = runtime {
        let _ = std::thread::Builder::new().name(thread.into()).spawn(move || {
            runtime.block_on(async {
                if tokio::signal::ctrl_c().await.is_ok() {
                    stop.store(true, Ordering::Relaxed);
                }
            });
        });
    }
}

/// A driver's run of a job that can fail part-way.
trait DriverRun {
    fn finished(self, job: Job, error: Option<String>) -> FinishedRun;
}

impl DriverRun for grpc::GrpcRun {
    fn finished(self, job: Job, error: Option<String>) -> FinishedRun {
        grpc::GrpcRun::finished(self, job, error)
    }
}

impl DriverRun for crate::drive::external::ExternalRun {
    fn finished(self, job: Job, error: Option<String>) -> FinishedRun {
        crate::drive::external::ExternalRun::finished(self, job, error)
    }
}

/// A spawned driver's result for `job` (`what` flew): the run, or the error with the part
/// that flew, or the task's failure. (The error holds the partial run: once per run, not a hot
/// path, so it is not boxed.)
#[allow(clippy::result_large_err)]
fn settle<R: DriverRun>(
    job: &Job,
    what: &str,
    task: Result<Result<R, RunFailure<R>>, String>,
) -> Result<FinishedRun, (RunError, Option<FinishedRun>)> {
    match task {
        Ok(Ok(run)) => Ok(run.finished(job.clone(), None)),
        Ok(Err(f)) => {
            let e = RunError::of(what, &f.error);
            let partial = f.partial.map(|p| p.finished(job.clone(), Some(e.message.clone())));
            Err((e, partial))
        }
        Err(failed) => Err((RunError::bench(format!("{what}: {failed}")), None)),
    }
}

/// One run, or its error (`what` failed: ...) with the part that flew, if any. Each driver's
/// run is a task of its own: a panic in it is this run's error.
async fn fly(
    job: &Job,
    driver: &Driver,
    cancel: tokio::sync::watch::Receiver<bool>,
) -> Result<FinishedRun, (RunError, Option<FinishedRun>)> {
    let name = &job.scenario.name;
    let failed = |e: tokio::task::JoinError| format!("the run {}", hilbench_svc::task_failure(e));
    match (driver, &job.controller) {
        (Driver::Services(endpoints), &Controller::Bench(mode)) => {
            let what = format!("{name} with {} over gRPC", mode.name());
            let (scenario, endpoints) = (job.scenario.clone(), endpoints.clone());
            let task = tokio::spawn(async move {
                let settings = grpc::GrpcSettings { cancel: Some(cancel), ..grpc::GrpcSettings::default() };
                grpc::run_against(&scenario, mode, &settings, &endpoints).await
            });
            settle(job, &what, task.await.map_err(failed))
        }
        (Driver::External(external), Controller::External(command)) => {
            let what = format!("{name} with an external controller");
            let (scenario, command, external) = (job.scenario.clone(), command.clone(), external.clone());
            let task = tokio::spawn(async move {
                crate::drive::external::run_external(&scenario, &command, &external).await
            });
            settle(job, &what, task.await.map_err(failed))
        }
        (Driver::InProcess, &Controller::Bench(mode)) => {
            let what = format!("{name} with {}", mode.name());
            let task_job = job.clone();
            match tokio::task::spawn_blocking(move || in_process::fly(task_job, mode)).await {
                Ok(Ok(run)) => Ok(run),
                Ok(Err(e)) => Err((RunError { message: format!("{what}: {}", e.message), ..e }, None)),
                Err(join) => Err((
                    RunError::bench(format!("{what}: the closed loop {}", hilbench_svc::task_failure(join))),
                    None,
                )),
            }
        }
        // The commands make their jobs for their driver: any other pair is a bug, said as one.
        (driver, controller) => Err((
            RunError::bench(format!(
                "{name}: the {} driver does not fly the {} controller (a bug of the bench)",
                driver.name(),
                controller.name()
            )),
            None,
        )),
    }
}
