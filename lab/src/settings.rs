//! The flags several aids share, each also read from its environment variable (clap's `env`),
//! so that one set of variables configures a series of runs and a value that does not parse is
//! an error rather than a silent default. Unset: the library's defaults.
use clap::builder::BoolishValueParser;
use mpc::{ControllerMode, InactiveSetTolerances, MpcSettings, QpSettings};

/// The loop an aid looks into: a built-in scenario and a controller (positional).
#[derive(Debug, Clone, clap::Args)]
pub struct LoopArgs {
    /// A built-in scenario (`paper-1`, `paper-2`, `paper-3`).
    #[arg(value_parser = crate::scenario)]
    pub scenario: mav::Scenario,
    /// `nmpc` or `multistage`.
    #[arg(value_parser = crate::mode)]
    pub mode: ControllerMode,
}

/// PANOC's and the ALM's settings (`MpcSettings`).
#[derive(Debug, Clone, clap::Args)]
pub struct MpcFlags {
    /// PANOC tolerance, multi-stage.
    #[arg(long, env = "MPC_TOL")]
    pub tolerance: Option<f64>,
    /// Outer (AKKT) tolerance, multi-stage.
    #[arg(long, env = "MPC_AKKT")]
    pub akkt_tolerance: Option<f64>,
    /// L-BFGS memory, multi-stage.
    #[arg(long, env = "MPC_MEM")]
    pub lbfgs_memory: Option<usize>,
    /// PANOC tolerance, standard NMPC.
    #[arg(long, env = "MPC_NMPC_TOL")]
    pub nmpc_tolerance: Option<f64>,
    /// Outer (AKKT) tolerance, standard NMPC.
    #[arg(long, env = "MPC_NMPC_AKKT")]
    pub nmpc_akkt_tolerance: Option<f64>,
    /// L-BFGS memory, standard NMPC.
    #[arg(long, env = "MPC_NMPC_MEM")]
    pub nmpc_lbfgs_memory: Option<usize>,
    /// Constraint violation tolerance (m).
    #[arg(long, env = "MPC_CTOL")]
    pub constraint_tolerance: Option<f64>,
    /// Initial ALM penalty.
    #[arg(long, env = "MPC_C0")]
    pub initial_penalty: Option<f64>,
    /// Largest ALM penalty.
    #[arg(long, env = "MPC_CMAX")]
    pub max_penalty: Option<f64>,
    /// Outer iterations per solve.
    #[arg(long, env = "MPC_OUTER")]
    pub max_outer_iterations: Option<usize>,
    /// PANOC iterations per solve (OpEn's PANOC).
    #[arg(long, env = "MPC_INNER")]
    pub max_inner_iterations: Option<usize>,
    /// PANOC iterations per solve (our PANOC, `--solver own`).
    #[arg(long, env = "MPC_OWN_INNER")]
    pub own_max_inner_iterations: Option<usize>,
    /// Penalty preconditioner slack (m); negative: no preconditioner.
    #[arg(long, env = "MPC_PSLACK", allow_hyphen_values = true)]
    pub penalty_slack_m: Option<f64>,
    /// PANOC iterations per outer iteration; 0: no cap.
    #[arg(long, env = "MPC_PER_OUTER")]
    pub max_inner_per_outer: Option<usize>,
    /// Largest multiplier.
    #[arg(long, env = "MPC_YMAX")]
    pub max_multiplier: Option<f64>,
    /// Standard NMPC warm start shifted by the elapsed time (only where a closed loop runs).
    #[arg(long, env = "MPC_ELAPSED", value_parser = BoolishValueParser::new())]
    pub elapsed_warm_start: bool,
    /// Whose PANOC: `open` (OpEn 0.12's) or `own` (mpc's `solver/panoc.rs`).
    #[arg(long, env = "MPC_SOLVER", value_parser = panoc_solver)]
    pub solver: Option<mpc::PanocSolver>,
    /// Our PANOC's scale-free stopping test (`MpcSettings::cost_gap_tolerance`), multi-stage.
    #[arg(long, env = "MPC_GAP_TOL")]
    pub cost_gap_tolerance: Option<f64>,
    /// The same, standard NMPC.
    #[arg(long, env = "MPC_NMPC_GAP_TOL")]
    pub nmpc_cost_gap_tolerance: Option<f64>,
    /// Our PANOC: restoration iterations at the limit with a plan inside (0: none).
    #[arg(long, env = "MPC_RESTORE_IT")]
    pub restoration_iterations: Option<usize>,
    /// Our PANOC: the restoration's penalty.
    #[arg(long, env = "MPC_RESTORE_C")]
    pub restoration_penalty: Option<f64>,
    /// Our PANOC: the restoration's shift outwards, m.
    #[arg(long, env = "MPC_RESTORE_SHIFT")]
    pub restoration_shift_m: Option<f64>,
    /// Our PANOC: the second restoration's shift outwards, m (0: none).
    #[arg(long, env = "MPC_RESTORE_RETRY_SHIFT")]
    pub restoration_retry_shift_m: Option<f64>,
    /// Multi-stage inactive-set tolerances: `measured` or `TOL,AKKT,GRAD`.
    #[arg(long, env = "MPC_INACTIVE", value_parser = inactive_set)]
    pub inactive_set: Option<InactiveSetTolerances>,
}

impl MpcFlags {
    pub fn settings(&self) -> MpcSettings {
        let d = MpcSettings::default();
        MpcSettings {
            tolerance: self.tolerance.unwrap_or(d.tolerance),
            akkt_tolerance: self.akkt_tolerance.unwrap_or(d.akkt_tolerance),
            single_scenario_tolerance: self.nmpc_tolerance.unwrap_or(d.single_scenario_tolerance),
            single_scenario_akkt_tolerance: self
                .nmpc_akkt_tolerance
                .unwrap_or(d.single_scenario_akkt_tolerance),
            lbfgs_memory: self.lbfgs_memory.unwrap_or(d.lbfgs_memory),
            single_scenario_lbfgs_memory: self.nmpc_lbfgs_memory.unwrap_or(d.single_scenario_lbfgs_memory),
            constraint_tolerance: self.constraint_tolerance.unwrap_or(d.constraint_tolerance),
            initial_penalty: self.initial_penalty.unwrap_or(d.initial_penalty),
            max_penalty: self.max_penalty.unwrap_or(d.max_penalty),
            max_outer_iterations: self.max_outer_iterations.unwrap_or(d.max_outer_iterations),
            max_inner_iterations: self.max_inner_iterations.unwrap_or(d.max_inner_iterations),
            own_max_inner_iterations: self.own_max_inner_iterations.unwrap_or(d.own_max_inner_iterations),
            penalty_preconditioner_slack_m: match self.penalty_slack_m {
                Some(v) if v < 0.0 => None,
                Some(v) => Some(v),
                None => d.penalty_preconditioner_slack_m,
            },
            max_inner_iterations_per_outer: match self.max_inner_per_outer {
                Some(0) => None,
                Some(v) => Some(v),
                None => d.max_inner_iterations_per_outer,
            },
            max_multiplier: self.max_multiplier.unwrap_or(d.max_multiplier),
            warm_start_by_elapsed_time: self.elapsed_warm_start,
            inactive_set: self.inactive_set.or(d.inactive_set),
            solver: self.solver.unwrap_or(d.solver),
            cost_gap_tolerance: self.cost_gap_tolerance.unwrap_or(d.cost_gap_tolerance),
            single_scenario_cost_gap_tolerance: self
                .nmpc_cost_gap_tolerance
                .unwrap_or(d.single_scenario_cost_gap_tolerance),
            restoration_iterations: self.restoration_iterations.unwrap_or(d.restoration_iterations),
            restoration_penalty: self.restoration_penalty.unwrap_or(d.restoration_penalty),
            restoration_shift_m: self.restoration_shift_m.unwrap_or(d.restoration_shift_m),
            restoration_retry_shift_m: self.restoration_retry_shift_m.unwrap_or(d.restoration_retry_shift_m),
            ..d
        }
    }
}

fn panoc_solver(value: &str) -> Result<mpc::PanocSolver, String> {
    mpc::PanocSolver::parse(value).ok_or_else(|| format!("`{value}`: open or own"))
}

fn inactive_set(value: &str) -> Result<InactiveSetTolerances, String> {
    if value == "measured" {
        return Ok(InactiveSetTolerances::MEASURED);
    }
    let v: Vec<f64> = value
        .split(',')
        .map(|x| x.trim().parse().map_err(|e| format!("`{x}`: {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [tolerance, akkt_tolerance, gradient_tolerance] => {
            Ok(InactiveSetTolerances { tolerance, akkt_tolerance, gradient_tolerance })
        }
        _ => Err("`measured` or TOL,AKKT,GRAD".into()),
    }
}

/// The QP fallback's settings (`QpSettings`).
#[derive(Debug, Clone, clap::Args)]
pub struct QpFlags {
    /// Lazy rows: slack below which a row is added (m).
    #[arg(long, env = "QP_LAZY")]
    pub lazy_slack_m: Option<f64>,
    /// Steps without move blocking.
    #[arg(long, env = "QP_UNBLOCKED")]
    pub unblocked_steps: Option<usize>,
    /// Steps per block after them.
    #[arg(long, env = "QP_BLOCK")]
    pub block_steps: Option<usize>,
    /// Rounds of lazy rows.
    #[arg(long, env = "QP_ROUNDS")]
    pub max_lazy_rounds: Option<usize>,
    /// clarabel's iterative refinement (true or false).
    #[arg(long, env = "QP_REFINE", value_parser = BoolishValueParser::new())]
    pub iterative_refinement: Option<bool>,
    /// Elastic rows with this penalty per metre.
    #[arg(long, env = "QP_ELASTIC")]
    pub elastic_penalty_per_m: Option<f64>,
    /// Screen the runs (true or false).
    #[arg(long, env = "QP_SCREEN", value_parser = BoolishValueParser::new())]
    pub screen_runs: Option<bool>,
    /// Margin added to a lazy row (m).
    #[arg(long, env = "QP_ADD")]
    pub lazy_add_margin_m: Option<f64>,
    /// clarabel's gap tolerance.
    #[arg(long, env = "QP_GAP")]
    pub gap_tolerance: Option<f64>,
    /// clarabel's feasibility tolerance.
    #[arg(long, env = "QP_FEAS")]
    pub feasibility_tolerance: Option<f64>,
}

impl QpFlags {
    pub fn settings(&self) -> QpSettings {
        let d = QpSettings::default();
        QpSettings {
            lazy_slack_m: self.lazy_slack_m.unwrap_or(d.lazy_slack_m),
            unblocked_steps: self.unblocked_steps.unwrap_or(d.unblocked_steps),
            block_steps: self.block_steps.unwrap_or(d.block_steps),
            max_lazy_rounds: self.max_lazy_rounds.unwrap_or(d.max_lazy_rounds),
            iterative_refinement: self.iterative_refinement.unwrap_or(d.iterative_refinement),
            elastic_penalty_per_m: self.elastic_penalty_per_m.or(d.elastic_penalty_per_m),
            screen_runs: self.screen_runs.unwrap_or(d.screen_runs),
            lazy_add_margin_m: self.lazy_add_margin_m.unwrap_or(d.lazy_add_margin_m),
            gap_tolerance: self.gap_tolerance.unwrap_or(d.gap_tolerance),
            feasibility_tolerance: self.feasibility_tolerance.unwrap_or(d.feasibility_tolerance),
            ..d
        }
    }
}

/// paper-2 as the delay aids fly it: options beyond the paper.
#[derive(Debug, Clone, clap::Args)]
pub struct ScenarioFlags {
    /// Dead-time compensation.
    #[arg(long, env = "COMP", value_parser = BoolishValueParser::new())]
    pub compensation: bool,
    /// A floor at this altitude (m).
    #[arg(long, env = "FLOOR")]
    pub floor_m: Option<f64>,
    /// The controller's obstacle margin (m).
    #[arg(long, env = "MARGIN")]
    pub margin_m: Option<f64>,
}

impl ScenarioFlags {
    /// paper-2 with these options, and `mode`'s paper settings with the margin.
    pub fn setup(&self, mode: ControllerMode) -> (mav::Scenario, mpc::ClosedLoopSettings) {
        let mut scenario = mav::Scenario::paper_2();
        scenario.delay_compensation = self.compensation;
        scenario.min_altitude_m = self.floor_m;
        let mut settings = mpc::ClosedLoopSettings::paper(mode);
        if let Some(m) = self.margin_m {
            settings.episode.mpc.obstacle_margin_m = m;
        }
        (scenario, settings)
    }
}

/// The robustness survey's set-up: paper-2, the multi-stage controller, its safety layer.
#[derive(Debug, Clone, clap::Args)]
pub struct SurveyFlags {
    #[command(flatten)]
    pub scenario: ScenarioFlags,
    /// No safety layer: PANOC's plans alone.
    #[arg(long, env = "NOSAFETY", value_parser = BoolishValueParser::new())]
    pub no_safety: bool,
    /// The safety layer's fail-safe check (first input, then braking, under every delay up to
    /// `--max-delay-s`).
    #[arg(long, env = "FAILSAFE", value_parser = BoolishValueParser::new())]
    pub fail_safe: bool,
    /// The fail-safe check's largest delay (s).
    #[arg(long, env = "DMAX")]
    pub max_delay_s: Option<f64>,
    /// The fail-safe check's delays per cycle.
    #[arg(long, env = "SAMPLES")]
    pub delay_samples: Option<usize>,
    /// The fail-safe check's `plan_coast_s` (s; the plans keep their coast clear over twice
    /// the longest delay plus this); default: the check's.
    #[arg(long, env = "PLAN_COAST", conflicts_with = "no_plan_coast")]
    pub plan_coast_s: Option<f64>,
    /// The plans keep only their points clear (`plan_coast_s = None`).
    #[arg(long, env = "NO_PLAN_COAST", value_parser = BoolishValueParser::new())]
    pub no_plan_coast: bool,
    /// Width of the uniform jitter (s): delays uniform in `[a, a + width]`, `a` random.
    #[arg(long, env = "WIDTH", default_value_t = 0.33)]
    pub width_s: f64,
}

impl SurveyFlags {
    pub fn setup(&self) -> (mav::Scenario, mpc::ClosedLoopSettings) {
        let (scenario, mut settings) = self.scenario.setup(ControllerMode::Multistage);
        if self.no_safety {
            settings.episode.safety = None;
        }
        if self.fail_safe
            && let Some(safety) = settings.episode.safety.as_mut()
        {
            let mut check = mpc::BrakingCheck::default();
            if let Some(d) = self.max_delay_s {
                check.max_delay_s = d;
            }
            if let Some(n) = self.delay_samples {
                check.delay_samples = n;
            }
            if self.plan_coast_s.is_some() {
                check.plan_coast_s = self.plan_coast_s;
            }
            if self.no_plan_coast {
                check.plan_coast_s = None;
            }
            safety.braking_check = Some(check);
        }
        (scenario, settings)
    }
}
