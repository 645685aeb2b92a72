//! A run in this process: `mpc::run_closed_loop`, the same control loop and delay line the
//! services run, without them (lockstep only).

use mpc::{ClosedLoopSettings, ControllerMode, MpcError, run_closed_loop};

use crate::run::{DelayProfileInForce, DelaySource, FinishedRun, IN_PROCESS_PLANT, Job, RunError, RunFaults};

/// Flies `job`, whose controller is the bench's in `mode`, with the predicted trajectories
/// recorded (as the gRPC telemetry carries them). Blocking: call it off the async runtime. An
/// error of the control loop itself (a problem it refused or could not build) is the
/// controller's; a trace that ran out or a plant reset is the bench's.
pub fn fly(job: Job, mode: ControllerMode) -> Result<FinishedRun, RunError> {
    let settings = ClosedLoopSettings { record_predictions: true, ..ClosedLoopSettings::paper(mode) };
    let network = job.scenario.network().map_err(|e| RunError::bench(e.to_string()))?;
    let network = network.unwrap_or_else(|| delay::NetworkProfile::none(job.scenario.seed));
    let (summary, traces) = run_closed_loop(&job.scenario, &settings).map_err(|e| match e {
        MpcError::TraceEnded { .. } | MpcError::PlantReset { .. } => RunError::bench(e.to_string()),
        _ => RunError::controller(e.to_string()),
    })?;
    let records: Vec<_> = traces.into_iter().map(|t| t.record).collect();
    Ok(FinishedRun {
        job,
        summary,
        rows: crate::run::rows_of(&records),
        records,
        timing: None,
        faults: RunFaults::default(),
        delay_profile: DelayProfileInForce::of(DelaySource::Scenario, &network),
        plant: IN_PROCESS_PLANT.to_string(),
        external: None,
        error: None,
    })
}
