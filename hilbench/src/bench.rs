//! What `hilbench reproduce` and `hilbench run` share: running (scenario, controller) pairs in
//! lockstep over gRPC or in process, and the `summary.json` they write (schema in docs/output.md).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use mav::Scenario;
use mpc::RunSummary;
use mpc::{ClosedLoopSettings, ControllerMode, run_closed_loop};

use crate::external::{ExternalFacts, ExternalFailure, ExternalRun, run_external};
use crate::grpc::{
    DelayProfileInForce, Endpoints, GrpcSettings, LinkFaults, RunFailure, RunTiming, run_against,
};
use crate::report;
use crate::scenario_file::{Mode, ScenarioFile};

/// A run to make: a scenario and a controller.
pub type Job = (Scenario, ControllerMode);

/// `hilbench reproduce`: the built-in scenarios (`only` these, when given), each with the
/// standard and the multi-stage NMPC.
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
            jobs.push((scenario.clone(), mode));
        }
    }
    Ok(jobs)
}

/// `hilbench run`: the file's scenario with `modes`, or with the file's `run.modes`.
pub fn file_jobs(file: &ScenarioFile, modes: Option<&[Mode]>) -> Vec<Job> {
    let modes = modes.unwrap_or(&file.run.modes);
    modes.iter().map(|m| (file.scenario.clone(), controller_mode(*m))).collect()
}

/// The controller a file's or the command line's mode names.
pub fn controller_mode(mode: Mode) -> ControllerMode {
    match mode {
        Mode::Nmpc => ControllerMode::Nmpc,
        Mode::Multistage => ControllerMode::Multistage,
    }
}

/// How the runs talk to the plant.
#[derive(Debug, Clone)]
pub enum Transport {
    /// `mpc::run_closed_loop`, no services.
    InProcess,
    /// Plant, netem and controller over gRPC; what `Endpoints` does not name is started here.
    Grpc(Endpoints),
    /// An external controller's process against a plant and netem started here, judged from
    /// the plant's truth (`crate::external`); a job's controller mode is not used.
    External(crate::external::ExternalController),
}

impl Transport {
    /// The `transport` value of `summary.json`.
    pub fn name(&self) -> &'static str {
        match self {
            Transport::InProcess => "in-process",
            Transport::Grpc(_) => "grpc",
            Transport::External(_) => "external",
        }
    }

    /// One phrase for the printed header.
    pub fn describe(&self) -> &'static str {
        match self {
            Transport::InProcess => "in process",
            Transport::Grpc(e) if e.is_local() => "over gRPC (plant, netem, controller on loopback)",
            Transport::Grpc(_) => "over gRPC (given services)",
            Transport::External(_) => "over gRPC (an external controller; plant and netem on loopback)",
        }
    }
}

/// Where the time of a run went (gRPC runs only).
#[derive(Debug, Clone, serde::Serialize)]
pub struct TimedRun {
    pub scenario: String,
    pub controller: String,
    #[serde(flatten)]
    pub timing: RunTiming,
    pub loop_overhead_s: f64,
}

/// The runs of one command.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub runs: Vec<RunSummary>,
    /// Per-cycle rows of each run, in the order of `runs`.
    pub cycles: Vec<Vec<crate::cycle_log::CycleRow>>,
    /// Each run's records, predicted trajectories included (the MCAP logs), in the order of
    /// `runs`.
    pub records: Vec<Vec<mpc::CycleRecord>>,
    /// The goal of each run's scenario, m, in the order of `runs`.
    pub goals: Vec<[f64; 3]>,
    pub timings: Vec<TimedRun>,
    /// Link faults of each run, in the order of `runs` (none in process).
    pub faults: Vec<LinkFaults>,
    /// The delay process of each run, in the order of `runs`.
    pub delay_profiles: Vec<DelayProfileInForce>,
    /// What each run's external controller did, in the order of `runs` (`None` for the
    /// bench's controller).
    pub external: Vec<Option<ExternalFacts>>,
    /// The error that ended the command early (a run that failed: a service died, a trace
    /// ran out, ...): `runs` holds the runs that finished before it, and no later run started.
    pub error: Option<String>,
    /// The last of `runs` is the failed run, as far as it flew (its `summary.json` entry
    /// carries the `error`, its `end_reason` is "error").
    pub failed_run_kept: bool,
    /// Ctrl-C stopped the command: `runs` holds the runs that finished before it.
    pub interrupted: bool,
    pub transport: &'static str,
    /// `lockstep` or `real-time`.
    pub time_mode: &'static str,
    pub wall_time_s: f64,
}

impl Outcome {
    pub fn any_collided(&self) -> bool {
        self.runs.iter().any(|r| r.collided)
    }

    /// Solver time summed over every run, s.
    pub fn solver_s(&self) -> f64 {
        self.runs.iter().map(|r| r.solve_ms_mean * r.cycles as f64 * 1e-3).sum()
    }

    /// `summary.json` (names are stable; see docs/output.md).
    pub fn summary_json(&self) -> serde_json::Value {
        let timing = serde_json::json!({
            "wall_time_s": self.wall_time_s,
            "solver_s": self.solver_s(),
            "setup_s": self.timings.iter().map(|t| t.timing.setup_s).sum::<f64>(),
            "loop_overhead_s": self.timings.iter().map(|t| t.loop_overhead_s).sum::<f64>(),
            "teardown_s": self.timings.iter().map(|t| t.timing.teardown_s).sum::<f64>(),
            "runs": self.timings,
        });
        serde_json::json!({
            "runs": self
                .runs
                .iter()
                .zip(&self.cycles)
                .zip(&self.goals)
                .zip(&self.faults)
                .zip(&self.delay_profiles)
                .enumerate()
                .map(|(i, ((((r, rows), goal), faults), delay_profile))| {
                    let mut v = run_json(r);
                    add_cycle_metrics(&mut v, rows, goal);
                    faults.add_to(&mut v);
                    v["delay_profile"] = serde_json::json!(delay_profile);
                    if let Some(Some(facts)) = self.external.get(i) {
                        v["external_controller"] = serde_json::json!(facts);
                    }
                    if self.failed_run_kept && i + 1 == self.runs.len() {
                        v["error"] = serde_json::json!(self.error);
                    }
                    v
                })
                .collect::<Vec<_>>(),
            "verdicts": report::verdicts(&self.runs),
            "transport": self.transport,
            "time_mode": self.time_mode,
            "wall_time_s": self.wall_time_s,
            "timing": timing,
            "error": self.error,
            "interrupted": self.interrupted,
            "hilbench_version": env!("CARGO_PKG_VERSION"),
            "hilbench_commit": env!("HILBENCH_COMMIT"),
        })
    }
}

/// One run's result, from either transport.
enum Ran {
    Grpc(Box<Result<crate::grpc::GrpcRun, RunFailure>>),
    Local(Box<Result<(mpc::RunSummary, Vec<mpc::CycleTrace>), String>>),
    External(Box<Result<ExternalRun, ExternalFailure>>),
}

/// What `run_all` keeps of a run, whichever way it flew.
struct Flown {
    summary: RunSummary,
    rows: Vec<crate::cycle_log::CycleRow>,
    /// The controller's records (none for an external controller, which has no telemetry).
    records: Vec<mpc::CycleRecord>,
    /// Where the wall time went (runs over services only).
    timing: Option<RunTiming>,
    faults: LinkFaults,
    delay_profile: DelayProfileInForce,
    external: Option<ExternalFacts>,
}

/// A run, or its error (`what` failed: ...) with the part that flew, if any.
type FlownOrFailed = Result<Flown, (String, Option<Box<Flown>>)>;

impl Flown {
    fn over_grpc(run: Result<crate::grpc::GrpcRun, RunFailure>, what: &str) -> FlownOrFailed {
        let flown = |run: crate::grpc::GrpcRun| Flown {
            rows: crate::cycle_log::from_records(&run.records),
            records: run.records,
            summary: run.summary,
            timing: Some(run.timing),
            faults: run.faults,
            delay_profile: run.delay_profile,
            external: None,
        };
        run.map(flown).map_err(|f| (format!("{what}: {:#}", f.error), f.partial.map(|p| Box::new(flown(*p)))))
    }

    fn external(run: Result<ExternalRun, ExternalFailure>, what: &str) -> FlownOrFailed {
        let flown = |run: ExternalRun| Flown {
            summary: run.summary,
            rows: run.rows,
            records: Vec::new(),
            timing: Some(run.timing),
            faults: run.faults,
            delay_profile: run.delay_profile,
            external: Some(run.facts),
        };
        run.map(flown).map_err(|f| (format!("{what}: {:#}", f.error), f.partial.map(|p| Box::new(flown(*p)))))
    }
}

/// How often a real-time run without a terminal says it is still flying.
const HEARTBEAT: std::time::Duration = std::time::Duration::from_secs(5);

/// Runs every (scenario, controller) pair in order (in lockstep, or in real time when the
/// transport says so). `progress` shows a progress bar on stderr when it is a terminal, and a
/// line per finished run (and every few seconds of a real-time run) either way.
pub fn run_all(jobs: &[Job], transport: &Transport, progress: bool) -> anyhow::Result<Outcome> {
    let started = Instant::now();
    // In process too: the runtime watches for Ctrl-C while a run goes on.
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name(crate::panics::RUN_THREAD)
        .enable_all()
        .build()
        .context("cannot start the tokio runtime")?;
    let mut runs = Vec::with_capacity(jobs.len());
    let mut cycles = Vec::with_capacity(jobs.len());
    let mut records = Vec::with_capacity(jobs.len());
    let mut goals = Vec::with_capacity(jobs.len());
    let mut timings = Vec::new();
    let mut faults = Vec::with_capacity(jobs.len());
    let mut delay_profiles = Vec::with_capacity(jobs.len());
    let mut external = Vec::with_capacity(jobs.len());
    let mut error = None;
    let mut failed_run_kept = false;
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
    let real_time = match transport {
        Transport::Grpc(e) => e.time_mode == crate::grpc::TimeMode::RealTime,
        Transport::External(c) => c.time_mode == crate::grpc::TimeMode::RealTime,
        Transport::InProcess => false,
    };
    for (scenario, mode) in jobs {
        let name = &scenario.name;
        // The controller flown: the job's mode, or the external controller.
        let controller = match transport {
            Transport::External(_) => crate::external::CONTROLLER_NAME,
            _ => mode.name(),
        };
        bar.set_message(format!("{name} with {controller}"));
        let mut ctrl_c = ctrl_c_rx.clone();
        if *ctrl_c.borrow_and_update() {
            interrupted = true;
            break;
        }
        let run_started = Instant::now();
        let ran = runtime.block_on(async {
            let job = async {
                match transport {
                    Transport::Grpc(endpoints) => {
                        // On a task of its own: a panic of the driver is this run's error.
                        let (scenario, mode, endpoints) = (scenario.clone(), *mode, endpoints.clone());
                        let task = tokio::spawn(async move {
                            run_against(&scenario, mode, &GrpcSettings::default(), &endpoints).await
                        });
                        Ran::Grpc(Box::new(task.await.unwrap_or_else(|e| {
                            Err(anyhow::anyhow!("the run {}", hilbench_svc::task_failure(e)).into())
                        })))
                    }
                    Transport::External(ext) => {
                        let (scenario, ext) = (scenario.clone(), ext.clone());
                        let task = tokio::spawn(async move { run_external(&scenario, &ext).await });
                        Ran::External(Box::new(task.await.unwrap_or_else(|e| {
                            Err(anyhow::anyhow!("the run {}", hilbench_svc::task_failure(e)).into())
                        })))
                    }
                    Transport::InProcess => {
                        let (scenario, mode) = (scenario.clone(), *mode);
                        // With the predicted trajectories, as the gRPC telemetry carries them.
                        let settings = ClosedLoopSettings {
                            record_predictions: true,
                            ..ClosedLoopSettings::paper(mode)
                        };
                        let task = tokio::task::spawn_blocking(move || run_closed_loop(&scenario, &settings));
                        match task.await {
                            Ok(run) => Ran::Local(Box::new(run.map_err(|e| e.to_string()))),
                            Err(e) => Ran::Local(Box::new(Err(format!(
                                "the closed loop {}",
                                hilbench_svc::task_failure(e)
                            )))),
                        }
                    }
                }
            };
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
            tokio::select! {
                ran = job => Some(ran),
                Ok(()) = ctrl_c.changed() => None,
                () = heartbeat, if real_time && bar.is_hidden() => None,
            }
        });
        let Some(ran) = ran else {
            interrupted = true;
            break;
        };
        let flown = match ran {
            Ran::Grpc(run) => Flown::over_grpc(*run, &format!("{name} with {controller} over gRPC")),
            Ran::External(run) => Flown::external(*run, &format!("{name} with an external controller")),
            Ran::Local(run) => match *run {
                Ok((summary, traces)) => {
                    let records: Vec<_> = traces.into_iter().map(|t| t.record).collect();
                    let network =
                        scenario.network()?.unwrap_or_else(|| delay::NetworkProfile::none(scenario.seed));
                    Ok(Flown {
                        summary,
                        rows: crate::cycle_log::from_records(&records),
                        records,
                        timing: None,
                        faults: LinkFaults::default(),
                        delay_profile: DelayProfileInForce::of("scenario", &network),
                        external: None,
                    })
                }
                Err(e) => Err((format!("{name} with {controller}: {e}"), None)),
            },
        };
        let (run, failed) = match flown {
            Ok(run) => (run, None),
            Err((e, Some(partial))) => (*partial, Some(e)),
            Err((e, None)) => {
                error = Some(e);
                break;
            }
        };
        if let Some(timing) = run.timing {
            timings.push(TimedRun {
                scenario: name.clone(),
                controller: controller.to_string(),
                timing,
                loop_overhead_s: timing.loop_overhead_s(),
            });
        }
        cycles.push(run.rows);
        records.push(run.records);
        faults.push(run.faults);
        delay_profiles.push(run.delay_profile);
        external.push(run.external);
        if let Some(e) = failed {
            runs.push(run.summary);
            goals.push(scenario.goal_m);
            error = Some(e);
            failed_run_kept = true;
            break;
        }
        let summary = run.summary;
        let mut collided = if summary.collided {
            format!("; COLLIDED: {}", report::collisions_text(&summary))
        } else {
            String::new()
        };
        if !summary.reached || summary.collided {
            for line in &summary.explanation {
                collided.push_str("; ");
                collided.push_str(line);
            }
        }
        let done = format!(
            "  {name} {controller:<11} done ({} cycles, {:.2} s){collided}",
            summary.cycles,
            run_started.elapsed().as_secs_f64()
        );
        crate::progress::line(&bar, progress, &done);
        bar.inc(1);
        runs.push(summary);
        goals.push(scenario.goal_m);
    }
    bar.finish_and_clear();
    // An interrupted run's services and solve are abandoned, not awaited.
    runtime.shutdown_background();
    Ok(Outcome {
        runs,
        cycles,
        records,
        goals,
        timings,
        faults,
        delay_profiles,
        external,
        error,
        failed_run_kept,
        interrupted,
        transport: transport.name(),
        time_mode: match transport {
            Transport::Grpc(e) => e.time_mode.name(),
            Transport::External(c) => c.time_mode.name(),
            Transport::InProcess => "lockstep",
        },
        wall_time_s: started.elapsed().as_secs_f64(),
    })
}

/// `runs/<unix time>`.
pub fn default_out_dir() -> PathBuf {
    let secs =
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
    PathBuf::from("runs").join(secs.to_string())
}

/// Writes the per-cycle CSV log of every run of `outcome` into `dir`.
pub fn write_cycle_logs(dir: &Path, outcome: &Outcome) -> anyhow::Result<Vec<PathBuf>> {
    outcome
        .runs
        .iter()
        .zip(&outcome.cycles)
        .map(|(r, rows)| crate::cycle_log::write(dir, &r.scenario, &r.controller, rows))
        .collect()
}

/// Writes `summary` as `dir/summary.json` (creating `dir`); returns the file's path.
pub fn write_summary(dir: &Path, summary: &serde_json::Value) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join("summary.json");
    std::fs::write(&path, serde_json::to_string_pretty(summary)?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(path)
}

/// Writes each scenario of `jobs` as flown (seed, delay trace and every override applied, trace
/// delays inline) to `dir/<name>.scenario.toml`: a scenario file `hilbench run` takes back.
pub fn write_scenarios(dir: &Path, jobs: &[Job]) -> anyhow::Result<()> {
    let mut written: Vec<&str> = Vec::new();
    for (scenario, _) in jobs {
        if written.contains(&scenario.name.as_str()) {
            continue;
        }
        written.push(&scenario.name);
        let modes: Vec<Mode> = jobs
            .iter()
            .filter(|(s, _)| s.name == scenario.name)
            .map(|(_, m)| match m {
                ControllerMode::Nmpc => Mode::Nmpc,
                ControllerMode::Multistage => Mode::Multistage,
            })
            .collect();
        let path = dir.join(format!("{}.scenario.toml", scenario.name));
        let text = ScenarioFile::as_flown(scenario, modes).map_err(anyhow::Error::msg)?;
        std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

/// One entry of `summary.json` (names are stable; see docs/output.md).
pub fn run_json(r: &RunSummary) -> serde_json::Value {
    serde_json::json!({
        "scenario": r.scenario,
        "controller": r.controller,
        "reached": r.reached,
        "collided": r.collided,
        "end_reason": r.end_reason,
        "time_to_goal_s": r.time_to_goal_s,
        "path_length_m": r.path_length_m,
        "min_clearance_m": r.min_clearance_m,
        "cycles": r.cycles,
        "solve_ms": { "mean": r.solve_ms_mean, "median": r.solve_ms_median, "p95": r.solve_ms_p95, "max": r.solve_ms_max },
        "iterations_median": r.iterations_median,
        "fallbacks": r.fallbacks,
        "decisions": r.decisions,
        "best_effort_cycles": r.best_effort_cycles,
        "explanation": r.explanation,
        "cost_gap": r.cost_gap,
        "collisions": r.collisions,
        "final_position_m": r.final_position_m,
    })
}

/// Adds the keys computed from the per-cycle log to a run's `summary.json` entry:
/// `deadline_misses` (solves stopped by the wall-clock deadline; always 0 in lockstep),
/// `end_to_end_latency_ms` (median and p95 of the round-trip delays measured from plant stamps:
/// command applied minus the time of the sample it came from), and `tracking_rmse_m` (RMS over
/// cycles of the distance between the plant's position and the scenario's goal, the reference
/// of the tracking term of the cost).
pub fn add_cycle_metrics(
    entry: &mut serde_json::Value,
    rows: &[crate::cycle_log::CycleRow],
    goal_m: &[f64; 3],
) {
    use mpc::record::percentile;
    let deadline_misses = rows.iter().filter(|r| r.status == "deadline").count();
    // Row k knows the delay of command k-1; row 0 knows none.
    let mut latency_ms: Vec<f64> = rows.iter().skip(1).map(|r| r.known_delay_s * 1e3).collect();
    let latency = if latency_ms.is_empty() {
        serde_json::Value::Null
    } else {
        serde_json::json!({
            "median": percentile(&mut latency_ms, 50.0),
            "p95": percentile(&mut latency_ms, 95.0),
        })
    };
    let tracking = (!rows.is_empty()).then(|| {
        let sum: f64 =
            rows.iter().map(|r| (0..3).map(|k| (r.state[k] - goal_m[k]).powi(2)).sum::<f64>()).sum();
        (sum / rows.len() as f64).sqrt()
    });
    entry["deadline_misses"] = serde_json::json!(deadline_misses);
    entry["end_to_end_latency_ms"] = latency;
    entry["tracking_rmse_m"] = serde_json::json!(tracking);
}

/// A short table of the runs of one scenario file.
pub fn run_table(runs: &[RunSummary]) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<16} {:<11} {:>8} {:>9} {:>9} {:>10} {:>7} {:>9} {:>9}",
        "scenario",
        "controller",
        "reached",
        "time [s]",
        "path [m]",
        "clear. [m]",
        "cycles",
        "solve ms",
        "collided"
    );
    // A number that does not exist prints as "-": no goal reached (time), no obstacle
    // (clearance +inf), no solver the bench can see (an external controller's solve time).
    let finite = |v: f64, text: String| if v.is_finite() { text } else { "-".to_string() };
    for r in runs {
        let time = r.time_to_goal_s.map_or_else(|| "-".to_string(), |t| format!("{t:.2}"));
        let _ = writeln!(
            out,
            "{:<16} {:<11} {:>8} {:>9} {:>9.2} {:>10} {:>7} {:>9} {:>9}",
            r.scenario,
            r.controller,
            if r.reached { "yes" } else { "no" },
            time,
            r.path_length_m,
            finite(r.min_clearance_m, format!("{:+.3}", r.min_clearance_m)),
            r.cycles,
            finite(r.solve_ms_median, format!("{:.2}", r.solve_ms_median)),
            if r.collided { "YES" } else { "no" },
        );
    }
    for r in runs.iter().filter(|r| r.collided) {
        let _ = writeln!(out, "  {} {} collided: {}", r.scenario, r.controller, report::collisions_text(r));
    }
    for r in runs {
        for line in &r.explanation {
            let _ = writeln!(out, "  {} {}: {line}", r.scenario, r.controller);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    fn load(name: &str) -> ScenarioFile {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios").join(name);
        ScenarioFile::load(&path).unwrap_or_else(|e| panic!("{e}"))
    }

    /// `summary.json` entries without the wall-clock solve times.
    fn deterministic(outcome: &Outcome) -> Vec<serde_json::Value> {
        outcome
            .runs
            .iter()
            .map(|r| {
                let mut v = run_json(r);
                if let Some(o) = v.as_object_mut() {
                    o.remove("solve_ms");
                }
                v
            })
            .collect()
    }

    #[test]
    fn run_of_the_paper_3_file_gives_the_summary_of_reproduce_paper_3() {
        let grpc = Transport::Grpc(Endpoints::default());
        let reproduce: Vec<Job> = paper_jobs(&["paper-3".to_string()])
            .expect("paper-3")
            .into_iter()
            .filter(|(_, m)| *m == ControllerMode::Nmpc)
            .collect();
        let run = file_jobs(&load("paper-3.toml"), Some(&[Mode::Nmpc]));
        assert_eq!(run, reproduce);
        let a = run_all(&reproduce, &grpc, false).expect("reproduce");
        let b = run_all(&run, &grpc, false).expect("run");
        assert_eq!(deterministic(&a), deterministic(&b));
        assert_eq!(b.runs.len(), 1);
        assert_eq!((b.runs[0].scenario.as_str(), b.runs[0].controller.as_str()), ("paper-3", "nmpc"));
        assert!(b.runs[0].reached && !b.any_collided());
        let summary = b.summary_json();
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
        let grpc = run_all(&jobs, &Transport::Grpc(Endpoints::default()), false).expect("grpc");
        let local = run_all(&jobs, &Transport::InProcess, false).expect("in process");
        assert_eq!(deterministic(&grpc), deterministic(&local));
        for r in &grpc.runs {
            assert_eq!(r.scenario, "slalom-4");
            assert!(r.cycles > 10, "{} cycles", r.cycles);
        }
        // The per-cycle logs agree row for row, but for the wall-clock solve time.
        let strip = |o: &Outcome| -> Vec<Vec<crate::cycle_log::CycleRow>> {
            o.cycles
                .iter()
                .map(|rows| {
                    rows.iter().cloned().map(|r| crate::cycle_log::CycleRow { solve_ms: 0.0, ..r }).collect()
                })
                .collect()
        };
        assert_eq!(strip(&grpc), strip(&local));
        for (run, rows) in grpc.runs.iter().zip(&grpc.cycles) {
            assert_eq!(rows.len() as u64, run.cycles);
            let csv = crate::cycle_log::to_csv(rows);
            assert_eq!(csv.lines().count(), rows.len() + 1);
            assert!(csv.starts_with("cycle,t_s,px_m"));
        }
    }

    #[test]
    fn the_run_table_prints_a_dash_for_a_clearance_or_solve_time_that_does_not_exist() {
        let file = load("slalom-4.toml");
        let flown = run_all(&file_jobs(&file, Some(&[Mode::Multistage])), &Transport::InProcess, false)
            .expect("in process");
        let mut run = flown.runs[0].clone();
        let row = |table: &str| table.lines().nth(1).expect("a row").to_string();
        let numbers = row(&run_table(std::slice::from_ref(&run)));
        assert!(numbers.contains(&format!("{:+.3}", run.min_clearance_m)), "{numbers}");
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
        let without = run_all(&file_jobs(&file, Some(&[Mode::Nmpc])), &Transport::InProcess, false)
            .expect("in process");
        file.scenario.fail_safe = true;
        let jobs = file_jobs(&file, Some(&[Mode::Nmpc]));
        let grpc = run_all(&jobs, &Transport::Grpc(Endpoints::default()), false).expect("grpc");
        let local = run_all(&jobs, &Transport::InProcess, false).expect("in process");
        assert_eq!(deterministic(&grpc), deterministic(&local));
        assert_ne!(deterministic(&local), deterministic(&without), "the check changed nothing");
        assert!(!local.runs[0].collided);
    }

    #[test]
    fn cycle_metrics_are_computed_from_the_rows() {
        let row = |k: u64, delay_s: f64, px: f64, status: &str| crate::cycle_log::CycleRow {
            cycle: k,
            t_s: k as f64 * 0.1,
            state: [px, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            command: [9.81, 0.0, 0.0],
            known_delay_s: delay_s,
            injected_delay_s: Some(delay_s),
            weights: vec![1.0],
            status: status.to_string(),
            iterations: 3,
            solve_ms: 0.1,
            cost: 1.0,
            constraint_violation: 0.0,
            predicted_clearance_m: 1.0,
            decision: "panoc".to_string(),
            reason: "panoc".to_string(),
            cost_gap: None,
        };
        // Positions 3 and 4 m from a goal at the origin (z on target): RMS = sqrt((9 + 16) / 2).
        let rows = vec![row(0, 0.0, 3.0, "converged"), row(1, 0.2, 4.0, "deadline")];
        let mut entry = serde_json::json!({});
        add_cycle_metrics(&mut entry, &rows, &[0.0, 0.0, 1.0]);
        assert_eq!(entry["deadline_misses"], 1);
        assert_eq!(entry["end_to_end_latency_ms"]["median"], 200.0);
        let rmse = entry["tracking_rmse_m"].as_f64().expect("a number");
        assert!((rmse - 12.5f64.sqrt()).abs() < 1e-12, "{rmse}");
    }

    #[test]
    fn unknown_paper_scenarios_are_refused() {
        assert!(paper_jobs(&["paper-9".to_string()]).is_err());
        assert_eq!(paper_jobs(&[]).expect("all").len(), 6);
    }
}
