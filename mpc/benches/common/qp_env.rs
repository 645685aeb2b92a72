//! QP fallback settings from the environment for the tuning aids (`examples/profile_qp.rs`,
//! `examples/qp_states.rs`): `QP_LAZY` (lazy_slack_m), `QP_UNBLOCKED`, `QP_BLOCK`, `QP_ROUNDS`
//! (max_lazy_rounds), `QP_REFINE` (1: iterative refinement on), `QP_ELASTIC`
//! (elastic_penalty_per_m), `QP_SCREEN` (screen_runs), `QP_ADD` (lazy_add_margin_m), `QP_GAP`,
//! `QP_FEAS`; the defaults where unset.
use mpc::QpSettings;

pub fn qp_settings_from_env() -> QpSettings {
    let env = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<f64>().ok());
    let mut settings = QpSettings::default();
    if let Some(v) = env("QP_LAZY") {
        settings.lazy_slack_m = v;
    }
    if let Some(v) = env("QP_UNBLOCKED") {
        settings.unblocked_steps = v as usize;
    }
    if let Some(v) = env("QP_BLOCK") {
        settings.block_steps = v as usize;
    }
    if let Some(v) = env("QP_ROUNDS") {
        settings.max_lazy_rounds = v as usize;
    }
    if let Some(v) = env("QP_REFINE") {
        settings.iterative_refinement = v > 0.0;
    }
    if let Some(v) = env("QP_ELASTIC") {
        settings.elastic_penalty_per_m = Some(v);
    }
    if let Some(v) = env("QP_SCREEN") {
        settings.screen_runs = v > 0.0;
    }
    if let Some(v) = env("QP_ADD") {
        settings.lazy_add_margin_m = v;
    }
    if let Some(v) = env("QP_GAP") {
        settings.gap_tolerance = v;
    }
    if let Some(v) = env("QP_FEAS") {
        settings.feasibility_tolerance = v;
    }
    settings
}
