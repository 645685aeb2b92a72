//! A fit as the tables the bench reads: `[scenario.delays]` (`delay::DelaysTable`, checked
//! through `DelaysTable::to_network`) and `[[sweep.families]]` (svc's `sweep_table`
//! vocabulary: each parameter a range `[lower, upper]`, its 95 % interval).

use delay::DelaysTable;
use toml::{Table, Value};

use super::{Candidate, FitReport, Kind, Model};

/// The widest widening of [`FitReport::sweep_toml_widened`]: a factor of 100 either side.
pub const MAX_WIDEN: f64 = 100.0;
/// The largest loss share a widened range reaches (a share must stay below 1).
const MAX_WIDENED_LOSS: f64 = 0.5;

/// Why a fit gives no table.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TableError {
    #[error("no kind the bench can replay was fitted")]
    NothingReplayable,
    /// The table does not pass `DelaysTable::to_network` (a bug: reported, never written).
    #[error("the fitted table is not a valid delays table: {0}")]
    Invalid(String),
    #[error("TOML: {0}")]
    Toml(String),
}

impl FitReport {
    /// The best candidate by AIC.
    pub fn best(&self) -> Option<&Candidate> {
        self.candidates.first()
    }

    /// The best by AIC among the kinds the bench can replay.
    pub fn best_replayable(&self) -> Option<&Candidate> {
        self.candidates.iter().find(|c| c.kind().replayable())
    }

    /// The candidate of `kind`, if fitted.
    pub fn candidate(&self, kind: Kind) -> Option<&Candidate> {
        self.candidates.iter().find(|c| c.kind() == kind)
    }

    /// The regime's dwell in seconds (`rate_hz` known) rather than in messages.
    fn dwell_in_seconds(&self) -> Option<f64> {
        self.rate_hz
    }

    /// `candidate`'s `[scenario.delays]` table, with the trace's loss rate as
    /// `loss_probability` (when there were losses; a regime's states have each their own),
    /// checked through `DelaysTable::to_network`.
    pub fn delays_table(&self, candidate: &Candidate) -> Result<DelaysTable, TableError> {
        let kind = |k: &str| DelaysTable { kind: Some(k.to_string()), ..DelaysTable::default() };
        let mut table = match candidate.model {
            Model::Weibull { .. } => return Err(TableError::NothingReplayable),
            Model::Gamma { shape, scale_s } => DelaysTable::gamma(shape, scale_s),
            Model::Lognormal { mu, sigma } => {
                DelaysTable { mu: Some(mu), sigma: Some(sigma), ..kind("lognormal") }
            }
            Model::Pareto { scale_s, shape } => {
                DelaysTable { scale_s: Some(scale_s), shape: Some(shape), ..kind("pareto") }
            }
            Model::Regime(r) => {
                let dwell = r.mean_dwell_messages();
                let states = (0..2)
                    .map(|i| {
                        let mut s =
                            DelaysTable { mu: Some(r.mu[i]), sigma: Some(r.sigma[i]), ..kind("lognormal") };
                        match self.dwell_in_seconds() {
                            Some(hz) => s.mean_dwell_s = Some(dwell[i] / hz),
                            None => s.mean_dwell_messages = Some(dwell[i]),
                        }
                        s.loss_probability = r.loss.map(|l| l[i]);
                        s
                    })
                    .collect();
                DelaysTable { states: Some(states), ..kind("regime") }
            }
        };
        // A regime's losses are its states' own.
        let states_lose = matches!(candidate.model, Model::Regime(r) if r.loses());
        table.loss_probability =
            (self.loss_probability > 0.0 && !states_lose).then_some(self.loss_probability);
        table
            .to_network(0, &mut |f| Err(format!("{f}: a fitted table names no file")))
            .map_err(|e| TableError::Invalid(e.to_string()))?;
        Ok(table)
    }

    /// The best replayable fit as a `[scenario.delays]` table, TOML, with comment lines
    /// saying what it is.
    pub fn scenario_toml(&self) -> Result<String, TableError> {
        let best = self.best_replayable().ok_or(TableError::NothingReplayable)?;
        let table = self.delays_table(best)?;
        let delays = Value::try_from(&table).map_err(|e| TableError::Toml(e.to_string()))?;
        let mut scenario = Table::new();
        scenario.insert("delays".into(), delays);
        let mut doc = Table::new();
        doc.insert("scenario".into(), Value::Table(scenario));
        let body = toml::to_string(&doc).map_err(|e| TableError::Toml(e.to_string()))?;
        // The bench's controllers start from a Gamma prior of the delay (the paper's
        // [12, 0.015]) until they have measured a window: this link's Gamma is the one to give.
        let prior = match self.candidate(Kind::Gamma).map(|c| c.model) {
            Some(Model::Gamma { shape, scale_s }) => format!(
                "# For the bench's controllers, the Gamma prior of this link's delays (the file's \
                 `prior_gamma`, used until a window is measured): prior_gamma = [{shape:.4}, {scale_s:.6}]\n"
            ),
            _ => String::new(),
        };
        Ok(format!("{}{prior}{body}", self.comment(best)))
    }

    /// The best replayable fit as a `[[sweep.families]]` table whose parameters range over
    /// their 95 % intervals, and, when the trace lost probes, whose `loss` ranges over the
    /// loss share's (Clopper–Pearson, exact).
    pub fn sweep_toml(&self) -> Result<String, TableError> {
        self.sweep_toml_widened(1.0)
    }

    /// As [`FitReport::sweep_toml`], each range widened to hold at least a factor `widen` (at
    /// least 1) either side of its estimate: `[v / widen, v * widen]` for a scale, shape,
    /// sigma, dwell or loss share (the loss below 1), `mu ± ln widen` for a lognormal's
    /// location (its level `e^mu` within the factor). The intervals alone are the estimate's
    /// uncertainty, which a long recording makes tiny: "my link and links like it" is a
    /// factor, e.g. 2 for a link's bad days.
    pub fn sweep_toml_widened(&self, widen: f64) -> Result<String, TableError> {
        if !(widen.is_finite() && (1.0..=MAX_WIDEN).contains(&widen)) {
            return Err(TableError::Invalid(format!(
                "the widening must be in [1, {MAX_WIDEN}], got {widen}"
            )));
        }
        let best = self.best_replayable().ok_or(TableError::NothingReplayable)?;
        self.delays_table(best)?;
        let range = |name: &str| -> Option<Value> {
            let p = best.params.iter().find(|p| p.name == name)?;
            let (mut lo, mut hi) = (p.lower.min(p.value), p.upper.max(p.value));
            if name == "mu" || name.ends_with(".mu") {
                (lo, hi) = (lo.min(p.value - widen.ln()), hi.max(p.value + widen.ln()));
            } else {
                (lo, hi) = (lo.min(p.value / widen), hi.max(p.value * widen));
            }
            Some(Value::Array(vec![Value::Float(lo), Value::Float(hi)]))
        };
        let mut family = Table::new();
        family.insert("name".into(), Value::String(format!("fit-{}", best.kind().name())));
        family.insert("kind".into(), Value::String(best.kind().name().into()));
        match best.model {
            Model::Regime(_) => {
                let mut states = Vec::new();
                for i in 0..2 {
                    let mut s = Table::new();
                    s.insert("kind".into(), Value::String("lognormal".into()));
                    for key in ["mu", "sigma"] {
                        if let Some(v) = range(&format!("states[{i}].{key}")) {
                            s.insert(key.into(), v);
                        }
                    }
                    if let Some(Value::Array(r)) = range(&format!("states[{i}].mean_dwell_messages")) {
                        let r: Vec<f64> = r
                            .iter()
                            .filter_map(Value::as_float)
                            .map(|v| v.clamp(1.0, delay::MAX_MEAN_DWELL))
                            .collect();
                        let (key, r) = match self.dwell_in_seconds() {
                            Some(hz) => ("mean_dwell_s", r.iter().map(|v| v / hz).collect::<Vec<_>>()),
                            None => ("mean_dwell_messages", r),
                        };
                        s.insert(key.into(), Value::Array(r.into_iter().map(Value::Float).collect()));
                    }
                    // A share widens as the family's `loss` does: below 1, and up to
                    // MAX_WIDENED_LOSS by the factor (its interval's end wherever higher).
                    let name = format!("states[{i}].loss_probability");
                    if let Some(p) = best.params.iter().find(|p| p.name == name) {
                        let lower = p.lower.min(p.value / widen);
                        let upper = p.upper.max((p.value * widen).min(MAX_WIDENED_LOSS)).max(p.value);
                        s.insert("loss".into(), Value::Array(vec![Value::Float(lower), Value::Float(upper)]));
                    }
                    states.push(Value::Table(s));
                }
                family.insert("states".into(), Value::Array(states));
            }
            _ => {
                for p in &best.params {
                    if let Some(v) = range(&p.name) {
                        family.insert(p.name.clone(), v);
                    }
                }
            }
        }
        let losses = self.entries.saturating_sub(self.delivered) as u64;
        let states_lose = matches!(best.model, Model::Regime(r) if r.loses());
        let widened =
            if widen > 1.0 { format!(", widened to a factor of {widen} either side") } else { String::new() };
        let loss = if states_lose {
            format!(
                "# loss: the trace lost {losses} of {} probes ({:.4}); each state's `loss` ranges over its \
                 share's 95 % interval{widened}.\n",
                self.entries,
                losses as f64 / self.entries as f64
            )
        } else if losses > 0 {
            let share = crate::confidence::clopper_pearson(losses, self.entries as u64, 0.95)
                .map_err(|e| TableError::Invalid(e.to_string()))?;
            let lower = share.lower.min(share.rate / widen);
            let upper = share.upper.max((share.rate * widen).min(MAX_WIDENED_LOSS)).max(share.upper);
            family.insert("loss".into(), Value::Array(vec![Value::Float(lower), Value::Float(upper)]));
            format!(
                "# loss: the trace lost {losses} of {} probes ({:.4}); the range is that share's 95 % interval{widened}.\n",
                self.entries, share.rate
            )
        } else {
            String::new()
        };
        let mut sweep = Table::new();
        sweep.insert("families".into(), Value::Array(vec![Value::Table(family)]));
        let mut doc = Table::new();
        doc.insert("sweep".into(), Value::Table(sweep));
        let body = toml::to_string(&doc).map_err(|e| TableError::Toml(e.to_string()))?;
        let ranges = if widen > 1.0 {
            format!(
                "# Ranges: the parameters' 95 % intervals, widened to a factor of {widen} either side of each \
                 estimate (a lognormal's level e^mu too).\n"
            )
        } else {
            "# Ranges: the parameters' 95 % intervals.\n".to_string()
        };
        Ok(format!("{}{ranges}{loss}{body}", self.comment(best)))
    }

    /// Comment lines naming the fit and the ranking.
    fn comment(&self, best: &Candidate) -> String {
        let ranking: Vec<String> = self
            .candidates
            .iter()
            .map(|c| format!("{} (AIC {:.1}, KS {:.4})", c.kind().name(), c.aic, c.ks))
            .collect();
        let mut s = format!(
            "# linkfit: {} of {} delivered delays ({} entries), by AIC: {}.\n",
            best.kind().name(),
            self.delivered,
            self.entries,
            ranking.join(", ")
        );
        if best.kind() == Kind::Regime && self.rate_hz.is_none() {
            s.push_str(
                "# The dwells are in probes (the trace has no rate_hz): a scenario counts them in the controller's \
                 messages, one a cycle (50 ms or more). Probed at another rate? Import again with --rate-hz for \
                 dwells in seconds.\n",
            );
        }
        if self.best().is_some_and(|b| !b.kind().replayable()) {
            s.push_str(
                "# The best fit is weibull, which the bench cannot replay: this is the best it can.\n",
            );
        }
        s
    }
}
