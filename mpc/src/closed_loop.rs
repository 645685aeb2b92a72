//! The closed-loop protocol of `docs/spec.md` ("paper mode"), in process and deterministic: the
//! RK4 truth plant at 1 ms, a seeded round-trip delay `d_k` per cycle, the new input applied at
//! `t_k + d_k`, the next cycle at `t_k + max(0.05, d_k)`. The cycle itself is
//! [`crate::episode::Episode`]'s, the same one the controller service runs over gRPC.

use mav::{Input, PlantSim, Scenario, SimSettings};

use crate::episode::{CycleTiming, Episode, EpisodeSettings};
use crate::error::MpcError;
use crate::problem::ControllerMode;
use crate::record::{CycleRecord, RunSummary, summarize};
use crate::safety::Selection;
use crate::solver::{MpcSettings, SolveReport};

/// Where the round-trip delays of a run come from.
#[derive(Debug, Clone)]
pub enum DelaySource {
    /// `d_k = 0`.
    None,
    /// A recorded trace, replayed in order and looped.
    Trace(Vec<f64>),
    /// Whatever the command direction of a scenario's network does (`delay::spec`'s kinds,
    /// loss included), seeded.
    Commands(delay::DirectionProfile),
}

impl DelaySource {
    /// The delays of `scenario`'s network (its `[scenario.delays]`, seeded with its seed); no
    /// delay when the scenario describes none. An in-process run puts the round trip on
    /// commands, as paper mode does: a network that delays, loses or reorders samples, or
    /// duplicates commands, needs netem and is refused here with the field named.
    pub fn of_scenario(scenario: &Scenario) -> Result<Self, MpcError> {
        let network = scenario.network().map_err(|e| MpcError::InvalidProblem(e.to_string()))?;
        let Some(network) = network else { return Ok(DelaySource::None) };
        let samples = &network.to_controller;
        let over_netem =
            "an in-process run delays commands only; run it over the services (without --in-process)";
        if !samples.delay.is_zero() || samples.loss_probability > 0.0 || samples.duplicate_probability > 0.0 {
            return Err(crate::error::invalid_input("delays.to_controller", over_netem));
        }
        if network.to_plant.duplicate_probability > 0.0 {
            return Err(crate::error::invalid_input("delays.to_plant.duplicate_probability", over_netem));
        }
        if !network.has_delays() && network.to_plant.loss_probability == 0.0 {
            return Ok(DelaySource::None);
        }
        Ok(DelaySource::Commands(network.to_plant))
    }

    /// The command-direction delay line netem's lockstep uses for the same profile and seed,
    /// so that an in-process run and a run through netem draw the same `d_k`, bit for bit.
    fn delay_line(&self) -> Result<Option<delay::DelayLine>, MpcError> {
        let (distribution, seed) = match self {
            DelaySource::None => return Ok(None),
            DelaySource::Trace(trace) => {
                (delay::Distribution::Trace(delay::Trace::looping(trace.clone())), 0)
            }
            DelaySource::Commands(profile) => {
                return delay::DelayLine::new(delay::Direction::ControllerToPlant, profile.clone())
                    .map(Some)
                    .map_err(|e| crate::error::invalid_input(format!("delays.{}", e.field), e.reason));
            }
        };
        let profile = delay::DirectionProfile::with_delay(distribution, seed);
        delay::DelayLine::new(delay::Direction::ControllerToPlant, profile)
            .map(Some)
            .map_err(|e| MpcError::InvalidInput { field: format!("delays.{}", e.field), reason: e.reason })
    }

    /// Some command is delayed (a loss alone delays nothing): what the controller's
    /// `delays_expected` is, as `mav::Scenario::delays_expected` for a scenario's network.
    pub fn has_delays(&self) -> bool {
        match self {
            DelaySource::None => false,
            DelaySource::Commands(profile) => !profile.delay.is_zero(),
            DelaySource::Trace(_) => true,
        }
    }
}

/// Settings of an in-process closed-loop run.
#[derive(Debug, Clone)]
pub struct ClosedLoopSettings {
    /// The controller's: mode, solver, safety layer, fault. Its `delays_expected` is the
    /// loop's to decide, from the delays it flies (as the controller service decides it from
    /// the scenario): whatever it holds here is replaced.
    pub episode: EpisodeSettings,
    /// `None`: the scenario's own delay model and seed.
    pub delays: Option<DelaySource>,
    /// Keep the predicted trajectories of every cycle in the records.
    pub record_predictions: bool,
}

impl ClosedLoopSettings {
    /// `mode` with the default solver and safety layer ([`EpisodeSettings::new`]).
    pub fn paper(mode: ControllerMode) -> Self {
        Self {
            episode: EpisodeSettings::new(mode, MpcSettings::default()),
            delays: None,
            record_predictions: false,
        }
    }
}

/// One control cycle of an in-process run: the record both drivers keep, and what only an
/// in-process run can see (PANOC's whole report, the safety layer's checks, the plan, the delay
/// drawn for this cycle's command).
#[derive(Debug, Clone, serde::Serialize)]
pub struct CycleTrace {
    #[serde(flatten)]
    pub record: CycleRecord,
    /// The delay drawn for this cycle's command (applied at `t + delay_s`), s.
    pub delay_s: f64,
    pub report: SolveReport,
    /// The safety layer's decision (`None` when the layer is off).
    pub selection: Option<Selection>,
    /// The fault forced on PANOC in this cycle, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fault: Option<crate::cycle::PanocFault>,
    /// The selected input plan of this cycle (`N x 3`, flattened).
    pub plan: Vec<f64>,
}

/// Runs `scenario` in paper mode with the controller of `settings.mode`.
pub fn run_closed_loop(
    scenario: &Scenario,
    settings: &ClosedLoopSettings,
) -> Result<(RunSummary, Vec<CycleTrace>), MpcError> {
    let delays = match &settings.delays {
        Some(d) => d.clone(),
        None => DelaySource::of_scenario(scenario)?,
    };
    let mut delay_line = delays.delay_line()?;
    // As the controller service does from the scenario it flies, unless the delays are the
    // caller's own.
    let delays_expected =
        if settings.delays.is_some() { delays.has_delays() } else { scenario.delays_expected() };
    let mut episode =
        Episode::new(scenario.clone(), EpisodeSettings { delays_expected, ..settings.episode.clone() })?;
    let mut sim = PlantSim::new(scenario, SimSettings::default())
        .map_err(|e| MpcError::InvalidProblem(e.to_string()))?;
    let min_cycle_ns = episode.min_cycle_ns();
    let mut traces = Vec::new();
    let end = loop {
        let sample = sim.sample();
        if let Some(end) = episode.finish(&sample) {
            break end;
        }
        let mut out = episode.on_sample(&sample, &CycleTiming::Lockstep)?;
        if settings.record_predictions {
            // The weights the solve used (updated from this sample's stamps), as the controller
            // service streams them.
            out.record.predictions = episode.predictions(&out.record.weights);
        }
        // A trace that ends the run: an error naming it and the cycle, never a made-up delay.
        if let Some(Err(ended)) = delay_line.as_ref().map(|line| line.check_next()) {
            return Err(MpcError::TraceEnded { cycle: traces.len(), reason: ended.to_string() });
        }
        let delay_ns = match delay_line.as_mut().map(|line| line.send(sample.time_ns).fate) {
            None => Some(0),
            Some(delay::Fate::Delivered { original, .. }) => Some(original.delay_ns),
            // A lost command leaves the old input on (as through netem in lockstep).
            Some(delay::Fate::Dropped) => None,
        };
        sim.advance(delay_ns.unwrap_or(0), |_| {});
        if delay_ns.is_some() {
            sim.apply(Input::from(out.record.command), out.meta)
                .map_err(|e| MpcError::InvalidProblem(e.to_string()))?;
        }
        out.record.injected_delay_s = delay_ns.map(mav::ns_to_s);
        out.record.command_lost = delay_ns.is_none();
        let delay_ns = delay_ns.unwrap_or(0);
        sim.advance(min_cycle_ns.max(delay_ns) - delay_ns, |_| {});
        traces.push(CycleTrace {
            record: out.record,
            delay_s: mav::ns_to_s(delay_ns),
            report: out.outcome.report,
            selection: out.outcome.selection,
            fault: out.outcome.fault,
            plan: episode.controller().plan().to_vec(),
        });
    };
    let records: Vec<CycleRecord> = traces.iter().map(|t| t.record.clone()).collect();
    let summary = summarize(&scenario.name, settings.episode.mode.name(), &records, &sim.peek(), end);
    Ok((summary, traces))
}
