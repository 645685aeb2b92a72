//! The closed-loop protocol of `SPEC.md` ("paper mode"), in process and deterministic: the RK4
//! truth plant at 1 ms, a seeded round-trip delay `d_k` per cycle, the new input applied at
//! `t_k + d_k`, the next cycle at `t_k + max(0.05, d_k)`, and `d_k` entering the weight window
//! after the cycle.

use mav::{CommandMeta, DelayModel, Input, PlantSim, Scenario, SimSettings, State, s_to_ns};

use crate::cycle::{CycleController, FaultInjection, PanocFault};
use crate::delays::{GammaParams, ScenarioWeights, WeightSettings};
use crate::problem::{ControllerMode, OcpDefinition};
use crate::safety::{Decision, SafetySettings, Selection};
use crate::solver::{MpcError, MpcSettings, SolveBudget, SolveReport, SolveStatus};

/// Where the round-trip delays of a run come from.
#[derive(Debug, Clone)]
pub enum DelaySource {
    /// `d_k = 0`.
    None,
    /// `d_k ~ Gamma(shape, scale_s)`, drawn by `delay::DelayLine` seeded with `seed`.
    Gamma { shape: f64, scale_s: f64, seed: u64 },
    /// A recorded trace, replayed in order and looped.
    Trace(Vec<f64>),
}

impl DelaySource {
    /// The delays of `scenario` (its delay model and seed).
    pub fn of_scenario(scenario: &Scenario) -> Self {
        match scenario.delays {
            DelayModel::None => DelaySource::None,
            DelayModel::Gamma { shape, scale_s } => {
                DelaySource::Gamma { shape, scale_s, seed: scenario.seed }
            }
        }
    }

    /// The command-direction delay line netem's lockstep uses for the same profile and seed,
    /// so that an in-process run and a run through netem draw the same `d_k`, bit for bit.
    fn delay_line(&self) -> Result<Option<delay::DelayLine>, MpcError> {
        let (distribution, seed) = match self {
            DelaySource::None => return Ok(None),
            DelaySource::Gamma { shape, scale_s, seed } => {
                (delay::Distribution::Gamma { shape: *shape, scale_s: *scale_s }, *seed)
            }
            DelaySource::Trace(trace) => {
                (delay::Distribution::Trace { delays_s: trace.clone().into(), looping: true }, 0)
            }
        };
        let profile = delay::DirectionProfile::with_delay(distribution, seed);
        delay::DelayLine::new(delay::Direction::ControllerToPlant, profile)
            .map(Some)
            .map_err(|e| MpcError::InvalidInput { field: format!("delays.{}", e.field), reason: e.reason })
    }

    pub fn has_delays(&self) -> bool {
        !matches!(self, DelaySource::None)
    }
}

/// Settings of an in-process closed-loop run.
#[derive(Debug, Clone)]
pub struct ClosedLoopSettings {
    pub mode: ControllerMode,
    pub mpc: MpcSettings,
    /// `None`: the scenario's own delay model and seed.
    pub delays: Option<DelaySource>,
    /// Iteration budget only (no deadline), so that runs are bit-identical.
    pub budget: SolveBudget,
    /// Keep the predicted trajectories of every cycle in the records.
    pub record_predictions: bool,
    /// The safety layer (cross-check and selection); `None` sends PANOC's input as it is.
    pub safety: Option<SafetySettings>,
    /// A fault forced on PANOC (tests of the fallbacks).
    pub fault: Option<FaultInjection>,
}

impl ClosedLoopSettings {
    pub fn paper(mode: ControllerMode) -> Self {
        Self {
            mode,
            mpc: MpcSettings::default(),
            delays: None,
            budget: SolveBudget::default(),
            record_predictions: false,
            safety: Some(SafetySettings::default()),
            fault: None,
        }
    }
}

/// One control cycle.
#[derive(Debug, Clone, serde::Serialize)]
pub struct CycleRecord {
    pub cycle: u64,
    /// Plant time at the start of the cycle, s.
    pub t_s: f64,
    pub state: [f64; 8],
    /// The input sent (applied at `t_s + delay_s`).
    pub command: [f64; 3],
    pub delay_s: f64,
    /// Scenario weights the solve used.
    pub weights_used: Vec<f64>,
    /// Scenario weights after this cycle's delay entered the window.
    pub weights: Vec<f64>,
    pub report: SolveReport,
    /// The safety layer's decision (`None` when the layer is off).
    pub selection: Option<Selection>,
    /// The fault forced on PANOC in this cycle, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fault: Option<PanocFault>,
    /// The selected input plan of this cycle (`N x 3`, flattened).
    pub plan: Vec<f64>,
    /// Predicted positions per scenario (when recorded).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub predictions: Vec<Vec<[f64; 3]>>,
}

/// What `SPEC.md` asks to report per run.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RunSummary {
    pub scenario: String,
    pub controller: String,
    pub reached: bool,
    pub collided: bool,
    pub time_to_goal_s: Option<f64>,
    pub end_time_s: f64,
    pub path_length_m: f64,
    /// Smallest true clearance to any cylinder surface on the plant, m (negative: collision).
    pub min_clearance_m: f64,
    pub cycles: u64,
    pub solve_ms_mean: f64,
    pub solve_ms_median: f64,
    pub solve_ms_p95: f64,
    pub solve_ms_max: f64,
    pub iterations_median: f64,
    /// Cycles that did not send PANOC's plan: the safety layer chose a fallback (or, without
    /// the layer, PANOC failed numerically).
    pub fallbacks: u64,
    /// Cycles per decision of the safety layer (`panoc`, `qp`, `shifted_plan`, `brake`).
    pub decisions: std::collections::BTreeMap<String, u64>,
    /// QP cost minus PANOC cost on the nonlinear model, over the cycles where both were
    /// evaluated (positive: PANOC's plan is cheaper).
    pub cost_gap: GapSummary,
    /// Cycles that stopped at the iteration limit.
    pub iteration_limits: u64,
    pub final_position_m: [f64; 3],
    /// Every entry into a cylinder or the ground: (kind, obstacle index, time s, position).
    pub collisions: Vec<CollisionSummary>,
}

/// Statistics of the cross-check's cost gap.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct GapSummary {
    /// Cycles where both costs were evaluated.
    pub cycles: u64,
    pub median: Option<f64>,
    pub min: Option<f64>,
    pub max: Option<f64>,
}

impl GapSummary {
    pub fn of(gaps: &[f64]) -> Self {
        let mut g = gaps.to_vec();
        let stat = |g: &mut [f64], p: f64| (!g.is_empty()).then(|| percentile(g, p));
        Self {
            cycles: g.len() as u64,
            median: stat(&mut g, 50.0),
            min: g.iter().copied().reduce(f64::min),
            max: stat(&mut g, 100.0),
        }
    }
}

/// One collision event of a run.
#[derive(Debug, Clone, serde::Serialize)]
pub struct CollisionSummary {
    /// `cylinder` or `ground`.
    pub kind: String,
    /// Index of the cylinder (none for the ground).
    pub obstacle_index: Option<u32>,
    pub time_s: f64,
    pub position_m: [f64; 3],
}

/// Nearest-rank percentile of a non-empty slice (sorted in place).
pub fn percentile(values: &mut [f64], p: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    let rank = ((p / 100.0) * values.len() as f64).ceil() as usize;
    values[rank.clamp(1, values.len()) - 1]
}

/// Runs `scenario` in paper mode with the controller of `settings.mode`.
pub fn run_closed_loop(
    scenario: &Scenario,
    settings: &ClosedLoopSettings,
) -> Result<(RunSummary, Vec<CycleRecord>), MpcError> {
    scenario.validate().map_err(|e| MpcError::InvalidProblem(e.to_string()))?;
    let delays = settings.delays.clone().unwrap_or_else(|| DelaySource::of_scenario(scenario));
    let mut delay_line = delays.delay_line()?;
    let def = OcpDefinition::from_scenario(
        scenario,
        settings.mode,
        settings.mpc.obstacle_margin_m,
        settings.mpc.formulation,
    );
    let sampling_times = def.sampling_times_s.clone();
    let safety = settings.safety.map(|s| s.for_scenario(scenario));
    let mut controller = CycleController::new(def, settings.mpc, safety)?.with_fault(settings.fault);
    let (prior_shape, prior_scale) = scenario.prior_gamma;
    let weight_settings = WeightSettings {
        window: scenario.delay_window,
        prior: GammaParams { shape: prior_shape, scale_s: prior_scale },
        ..WeightSettings::default()
    };
    let mut weights = match settings.mode {
        ControllerMode::Nmpc => ScenarioWeights::new(weight_settings, &sampling_times, Some(&[1.0])),
        ControllerMode::Multistage if !delays.has_delays() => {
            ScenarioWeights::new(weight_settings, &sampling_times, Some(&scenario.nominal_weights))
        }
        ControllerMode::Multistage => ScenarioWeights::new(weight_settings, &sampling_times, None),
    };

    let mut sim = PlantSim::new(scenario, SimSettings::default())
        .map_err(|e| MpcError::InvalidProblem(e.to_string()))?;
    let min_cycle_ns = s_to_ns(scenario.min_cycle_s).unwrap_or(50_000_000).max(1);
    let max_ns = s_to_ns(scenario.max_duration_s).unwrap_or(60_000_000_000);
    let mut u_prev = scenario.model.hover_input();
    let mut records = Vec::new();
    let mut time_to_goal_s = None;
    let mut cycle = 0u64;
    loop {
        let x: State = *sim.state();
        if scenario.goal_reached(&x) {
            time_to_goal_s = Some(mav::ns_to_s(sim.time_ns()));
            break;
        }
        if sim.time_ns() >= max_ns {
            break;
        }
        let x0: [f64; 8] = x.into();
        let up: [f64; 3] = u_prev.into();
        let weights_used = weights.weights().to_vec();
        let outcome = controller.step(cycle, sim.time_ns(), &x0, &up, &weights_used, &settings.budget)?;
        let command = outcome.command;
        let predictions = if settings.record_predictions {
            controller
                .predictions()
                .iter()
                .map(|traj| traj.iter().map(|s| [s[0], s[1], s[2]]).collect())
                .collect()
        } else {
            Vec::new()
        };
        let sample = sim.sample();
        let delay_ns = match delay_line.as_mut().map(|line| line.send(sample.time_ns).fate) {
            None => 0,
            Some(delay::Fate::Delivered { original, .. }) => original.delay_ns,
            // A loss profile is not part of paper mode; a lost command leaves the old input on.
            Some(delay::Fate::Dropped) => u64::MAX,
        };
        let lost = delay_ns == u64::MAX;
        let delay_ns = if lost { 0 } else { delay_ns };
        let delay_s = mav::ns_to_s(delay_ns);
        sim.advance(delay_ns, |_| {});
        let u = Input::from(command);
        sim.apply(
            u,
            CommandMeta {
                command_seq: cycle + 1,
                based_on_sample_seq: sample.seq,
                based_on_sample_time_ns: sample.time_ns,
            },
        )
        .map_err(|e| MpcError::InvalidProblem(e.to_string()))?;
        sim.advance(min_cycle_ns.max(delay_ns) - delay_ns, |_| {});
        if delays.has_delays() {
            // What a controller measures from plant stamps: applied time minus the time of the
            // sample the command came from, in whole nanoseconds.
            weights.observe(mav::ns_to_s(delay_ns));
        }
        records.push(CycleRecord {
            cycle,
            t_s: mav::ns_to_s(sample.time_ns),
            state: x0,
            command,
            delay_s,
            weights_used,
            weights: weights.weights().to_vec(),
            report: outcome.report,
            selection: outcome.selection,
            fault: outcome.fault,
            plan: controller.plan().to_vec(),
            predictions,
        });
        if !lost {
            u_prev = u;
        }
        cycle += 1;
    }
    let summary = summarize(scenario, settings.mode, &sim, &records, time_to_goal_s);
    Ok((summary, records))
}

/// True when the cycle did not send PANOC's plan.
pub fn is_fallback(selection: Option<&Selection>, report: &SolveReport) -> bool {
    match selection {
        Some(s) => s.decision.is_fallback(),
        None => report.status == SolveStatus::NumericalFailure,
    }
}

/// Cycles per decision (every decision listed, zeros included, when the layer was on).
pub fn decision_counts<'a>(
    selections: impl Iterator<Item = Option<&'a Selection>>,
) -> std::collections::BTreeMap<String, u64> {
    let mut counts = std::collections::BTreeMap::new();
    for s in selections.flatten() {
        if counts.is_empty() {
            for d in [Decision::Panoc, Decision::Qp, Decision::ShiftedPlan, Decision::Brake] {
                counts.insert(d.name().to_string(), 0);
            }
        }
        *counts.entry(s.decision.name().to_string()).or_insert(0) += 1;
    }
    counts
}

fn summarize(
    scenario: &Scenario,
    mode: ControllerMode,
    sim: &PlantSim,
    records: &[CycleRecord],
    time_to_goal_s: Option<f64>,
) -> RunSummary {
    let mut solve_ms: Vec<f64> = records.iter().map(|r| r.report.solve_time.as_secs_f64() * 1e3).collect();
    let mut iterations: Vec<f64> = records.iter().map(|r| r.report.iterations as f64).collect();
    let mean =
        if solve_ms.is_empty() { f64::NAN } else { solve_ms.iter().sum::<f64>() / solve_ms.len() as f64 };
    let x = sim.state();
    RunSummary {
        scenario: scenario.name.clone(),
        controller: mode.name().to_string(),
        reached: time_to_goal_s.is_some(),
        collided: sim.collided(),
        time_to_goal_s,
        end_time_s: mav::ns_to_s(sim.time_ns()),
        path_length_m: sim.path_length_m(),
        min_clearance_m: sim.min_clearance_m(),
        cycles: records.len() as u64,
        solve_ms_mean: mean,
        solve_ms_median: percentile(&mut solve_ms, 50.0),
        solve_ms_p95: percentile(&mut solve_ms, 95.0),
        solve_ms_max: percentile(&mut solve_ms, 100.0),
        iterations_median: percentile(&mut iterations, 50.0),
        fallbacks: records.iter().filter(|r| is_fallback(r.selection.as_ref(), &r.report)).count() as u64,
        decisions: decision_counts(records.iter().map(|r| r.selection.as_ref())),
        cost_gap: GapSummary::of(
            &records.iter().filter_map(|r| r.selection.as_ref().and_then(|s| s.cost_gap)).collect::<Vec<_>>(),
        ),
        iteration_limits: records.iter().filter(|r| r.report.status == SolveStatus::IterationLimit).count()
            as u64,
        final_position_m: [x[0], x[1], x[2]],
        collisions: sim
            .collisions()
            .iter()
            .map(|c| CollisionSummary {
                kind: match c.kind {
                    mav::CollisionKind::Cylinder => "cylinder".to_string(),
                    mav::CollisionKind::Ground => "ground".to_string(),
                },
                obstacle_index: (c.kind == mav::CollisionKind::Cylinder).then_some(c.obstacle_index),
                time_s: mav::ns_to_s(c.time_ns),
                position_m: c.position_m,
            })
            .collect(),
    }
}
