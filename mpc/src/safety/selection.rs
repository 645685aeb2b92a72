//! What a selection reports: the decision, each candidate's check and why it was rejected, and
//! a one-line reason for logs.

use std::fmt::Write as _;

use crate::qp::{QpReport, QpStatus};
use crate::solver::SolveStatus;

/// Which command was selected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Decision {
    Panoc,
    Qp,
    ShiftedPlan,
    Brake,
}

impl Decision {
    pub fn name(self) -> &'static str {
        match self {
            Decision::Panoc => "panoc",
            Decision::Qp => "qp",
            Decision::ShiftedPlan => "shifted_plan",
            Decision::Brake => "brake",
        }
    }

    /// True for the fallbacks (anything but PANOC).
    pub fn is_fallback(self) -> bool {
        self != Decision::Panoc
    }
}

/// Why a candidate was not selected.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Rejection {
    /// PANOC ended with a status the settings do not accept.
    PanocStatus { status: SolveStatus },
    /// PANOC's solve returned an error (no plan).
    PanocError,
    /// PANOC ran no iteration (zero budget): its plan is the warm start, not a solution.
    NoIterations,
    /// The QP had no solution.
    QpStatus { status: QpStatus },
    /// The QP did not run (schedule) or refused the instance.
    NotRun,
    /// Inputs or predictions are not finite.
    NotFinite,
    /// Inputs outside the input bounds.
    OutOfBounds,
    /// A predicted point is closer to a cylinder than required (true clearance, m).
    Collision { min_clearance_m: f64 },
    /// A predicted point is below the floor, or, for the fail-safe check without a floor,
    /// below the ground (lowest altitude, m).
    BelowFloor { min_altitude_m: f64 },
    /// No previous plan, or it was shifted `max_plan_shifts` times already.
    NoPlan,
    /// The cycle's state, last input or weights are not finite or malformed.
    InvalidInstance,
}

impl Rejection {
    fn describe(&self, out: &mut String) {
        let _ = match self {
            Rejection::PanocStatus { status } => write!(out, "status {}", status.name()),
            Rejection::PanocError => write!(out, "solve error"),
            Rejection::NoIterations => write!(out, "no iterations"),
            Rejection::QpStatus { status } => write!(out, "status {}", status.name()),
            Rejection::NotRun => write!(out, "not run"),
            Rejection::NotFinite => write!(out, "not finite"),
            Rejection::OutOfBounds => write!(out, "out of bounds"),
            Rejection::Collision { min_clearance_m } => write!(out, "clearance {min_clearance_m:.3} m"),
            Rejection::BelowFloor { min_altitude_m } => write!(out, "altitude {min_altitude_m:.3} m"),
            Rejection::NoPlan => write!(out, "no plan"),
            Rejection::InvalidInstance => write!(out, "invalid instance"),
        };
    }
}

/// One candidate plan checked on the nonlinear model.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CandidateCheck {
    /// The spec's objective on the nonlinear model (NaN when not evaluated).
    pub cost: f64,
    /// Smallest true clearance of its predictions, m (NaN when not evaluated).
    pub min_clearance_m: f64,
    /// Lowest predicted altitude, m (NaN when not evaluated).
    pub min_altitude_m: f64,
    /// `None` when acceptable.
    pub rejection: Option<Rejection>,
}

impl CandidateCheck {
    pub(super) fn rejected(r: Rejection) -> Self {
        Self { cost: f64::NAN, min_clearance_m: f64::NAN, min_altitude_m: f64::NAN, rejection: Some(r) }
    }

    pub fn accepted(&self) -> bool {
        self.rejection.is_none()
    }
}

/// The outcome of one cycle's selection.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Selection {
    pub decision: Decision,
    /// The command to send: finite and inside the input bounds.
    pub command: [f64; 3],
    pub panoc: CandidateCheck,
    /// The QP's check; `rejection: NotRun` when the schedule skipped it.
    pub qp: CandidateCheck,
    /// The QP's own report when it ran.
    pub qp_report: Option<QpReport>,
    /// The shifted previous plan's check (`NotRun` when a better candidate was accepted).
    pub shifted: CandidateCheck,
    /// The braking command held over the horizon (`NotRun` when a better candidate was
    /// accepted).
    pub brake: CandidateCheck,
    /// QP cost minus PANOC cost, both on the nonlinear model (positive: PANOC is better);
    /// `None` unless both were evaluated.
    pub cost_gap: Option<f64>,
    /// True when the selected plan passed the checks.
    pub verified_safe: bool,
}

impl Selection {
    /// One line for logs and telemetry, e.g. `qp (panoc: clearance -0.120 m; gap 3.2)`.
    pub fn reason(&self) -> String {
        let mut out = String::from(self.decision.name());
        let mut parts = Vec::new();
        let candidates =
            [("panoc", &self.panoc), ("qp", &self.qp), ("shifted", &self.shifted), ("brake", &self.brake)];
        // The rejected candidates before the selected one; every one when none passed.
        let skip = match self.decision {
            _ if !self.verified_safe => 4,
            Decision::Panoc => 0,
            Decision::Qp => 1,
            Decision::ShiftedPlan => 2,
            Decision::Brake => 3,
        };
        if !self.verified_safe {
            out.push_str(crate::record::BEST_EFFORT);
        }
        for (name, c) in candidates.iter().take(skip) {
            let mut s = format!("{name}: ");
            match &c.rejection {
                Some(r) => r.describe(&mut s),
                None => s.push_str("ok"),
            }
            parts.push(s);
        }
        if let Some(gap) = self.cost_gap {
            parts.push(format!("gap {gap:.4}"));
        }
        if !parts.is_empty() {
            let _ = write!(out, " ({})", parts.join("; "));
        }
        out
    }
}
