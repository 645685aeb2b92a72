//! The `[scenario.delays]` table of a scenario file (and the whole of a `netem --profile-file`),
//! as written, and the one conversion into a [`NetworkProfile`].
//!
//! ```toml
//! [scenario.delays]          # the whole round trip, on commands (nothing on samples)
//! kind = "gamma"             # constant, uniform, normal, gamma, lognormal, pareto, trace, regime
//! shape = 12.0               # gamma: shape and scale_s, or mean_s and std_s
//! scale_s = 0.015
//! loss_probability = 0.0     # optional, per direction: loss, duplication, ordering
//! duplicate_probability = 0.0
//! ordering = "fifo"          # or "independent"
//! ```
//!
//! Each direction instead: `[scenario.delays.to_plant]` (commands) and
//! `[scenario.delays.to_controller]` (state samples), each a table of the same keys; a
//! direction left out has no delay. The kinds and their keys:
//!
//! | kind | keys |
//! |---|---|
//! | `none` | (no delay) |
//! | `constant` | `delay_s` |
//! | `uniform` | `min_s`, `max_s` |
//! | `normal` | `mean_s`, `std_s` (truncated at 0) |
//! | `gamma` | `shape`, `scale_s`; or `mean_s`, `std_s` |
//! | `lognormal` | `mean_s`, `std_s` of the delay itself; or `mu`, `sigma` of its log |
//! | `pareto` | `scale_s` (the minimum), `shape` (the tail index) |
//! | `trace` | `file` (one delay in s per line or `lost`, optional first line `delay_s`; see [`crate::trace`]), `looping` (default false) |
//! | `regime` | `[[...states]]`: each a kind above but trace, with `mean_dwell_messages` or `mean_dwell_s`, and optionally its own `loss_probability` (a message sent in the state is lost with it instead of the direction's) |
//!
//! `gamma_moments` and `lognormal_moments`, the names of netem's API, are accepted too. A
//! trace without `looping = true` ends the run when it is used up ([`crate::TraceEnd::Stop`]).
//!
//! Reading trace files is the caller's (this crate does no I/O): [`DelaysTable::to_network`]
//! asks for each `file` through a closure.

use std::sync::Arc;

use crate::profile::{DirectionProfile, Distribution, Dwell, NetworkProfile, Ordering, RegimeState};
use crate::trace::Trace;

/// A delays table as written: every key of every kind, checked against its `kind` by
/// [`DelaysTable::to_network`]. Unknown keys are refused by serde with the key named.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DelaysTable {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub kind: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub delay_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub std_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shape: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scale_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mu: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma: Option<f64>,
    /// A trace's file.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub file: Option<String>,
    /// A trace's delays written inline, s, `-1.0` ([`crate::LOST_S`]) for a lost message (the
    /// scenario file loader puts a trace file's entries here, keeping `file` as the trace's
    /// name, so that a loaded scenario is self-contained).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub delays_s: Option<Vec<f64>>,
    /// A trace replays from its start once used up (default: the run ends there).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub looping: Option<bool>,
    /// A regime's states, each a table of a kind's keys and a mean dwell.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub states: Option<Vec<DelaysTable>>,
    /// A regime state's mean dwell, in messages (>= 1)...
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_dwell_messages: Option<f64>,
    /// ...or in seconds (> 0).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_dwell_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub loss_probability: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub duplicate_probability: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ordering: Option<Ordering>,
    /// Commands, controller to plant (instead of a round trip).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub to_plant: Option<Box<DelaysTable>>,
    /// State samples, plant to controller.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub to_controller: Option<Box<DelaysTable>>,
}

/// A delays table that does not describe a network: the key (a path relative to the table,
/// e.g. `to_plant.shape` or `states[1].mean_dwell_s`) and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid field `{field}`: {reason}")]
pub struct SpecError {
    pub field: String,
    pub reason: String,
}

fn err(field: impl Into<String>, reason: impl Into<String>) -> SpecError {
    SpecError { field: field.into(), reason: reason.into() }
}

fn join(path: &str, key: &str) -> String {
    if path.is_empty() { key.to_string() } else { format!("{path}.{key}") }
}

/// The keys of each kind: alternatives of required keys, then optional keys.
fn kind_keys(kind: &str) -> Option<(&'static [&'static [&'static str]], &'static [&'static str])> {
    Some(match kind {
        "none" => (&[&[]], &[]),
        "constant" => (&[&["delay_s"]], &[]),
        "uniform" => (&[&["min_s", "max_s"]], &[]),
        "normal" | "gamma_moments" | "lognormal_moments" => (&[&["mean_s", "std_s"]], &[]),
        "gamma" => (&[&["shape", "scale_s"], &["mean_s", "std_s"]], &[]),
        "lognormal" => (&[&["mean_s", "std_s"], &["mu", "sigma"]], &[]),
        "pareto" => (&[&["scale_s", "shape"]], &[]),
        "trace" => (&[&["delays_s"], &["file"]], &["looping", "file"]),
        "regime" => (&[&["states"]], &[]),
        _ => return None,
    })
}

/// Every kind a table may name.
pub const KINDS: [&str; 11] = [
    "none",
    "constant",
    "uniform",
    "normal",
    "gamma",
    "gamma_moments",
    "lognormal",
    "lognormal_moments",
    "pareto",
    "trace",
    "regime",
];

/// Where a table sits, which decides the keys it may hold besides its kind's.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Place {
    /// `[scenario.delays]` itself: a round trip, or the two direction tables.
    Top,
    /// `to_plant` or `to_controller`.
    Direction,
}

impl DelaysTable {
    /// The keys of a distribution that are present.
    fn distribution_keys(&self) -> Vec<&'static str> {
        let keys = [
            ("delay_s", self.delay_s.is_some()),
            ("min_s", self.min_s.is_some()),
            ("max_s", self.max_s.is_some()),
            ("mean_s", self.mean_s.is_some()),
            ("std_s", self.std_s.is_some()),
            ("shape", self.shape.is_some()),
            ("scale_s", self.scale_s.is_some()),
            ("mu", self.mu.is_some()),
            ("sigma", self.sigma.is_some()),
            ("file", self.file.is_some()),
            ("delays_s", self.delays_s.is_some()),
            ("looping", self.looping.is_some()),
            ("states", self.states.is_some()),
        ];
        keys.into_iter().filter(|(_, set)| *set).map(|(k, _)| k).collect()
    }

    /// The network this table describes, both directions seeded with `seed`.
    /// `read_trace(file)` gives the delays of a trace file named in the table (resolving a
    /// relative path is the caller's business), or why it cannot. Errors name the key as a
    /// path relative to the table.
    pub fn to_network(
        &self,
        seed: u64,
        read_trace: &mut dyn FnMut(&str) -> Result<Vec<f64>, String>,
    ) -> Result<NetworkProfile, SpecError> {
        if self.to_plant.is_none() && self.to_controller.is_none() {
            let to_plant = self.direction("", Place::Top, seed, read_trace)?;
            let mut network = NetworkProfile::none(seed);
            network.to_plant = to_plant;
            return Ok(network);
        }
        // Each direction in its own table: nothing else at the top.
        let mut top: Vec<&str> = self.distribution_keys();
        for (key, set) in [
            ("kind", self.kind.is_some()),
            ("loss_probability", self.loss_probability.is_some()),
            ("duplicate_probability", self.duplicate_probability.is_some()),
            ("ordering", self.ordering.is_some()),
            ("mean_dwell_messages", self.mean_dwell_messages.is_some()),
            ("mean_dwell_s", self.mean_dwell_s.is_some()),
        ] {
            if set {
                top.push(key);
            }
        }
        if let Some(key) = top.first() {
            return Err(err(
                *key,
                "with to_plant or to_controller, each direction is described in its own table (a round trip at the top is the alternative)",
            ));
        }
        let mut network = NetworkProfile::none(seed);
        if let Some(t) = &self.to_plant {
            network.to_plant = t.direction("to_plant", Place::Direction, seed, read_trace)?;
        }
        if let Some(t) = &self.to_controller {
            network.to_controller = t.direction("to_controller", Place::Direction, seed, read_trace)?;
        }
        Ok(network)
    }

    /// One direction's profile, the table at `path`.
    fn direction(
        &self,
        path: &str,
        place: Place,
        seed: u64,
        read_trace: &mut dyn FnMut(&str) -> Result<Vec<f64>, String>,
    ) -> Result<DirectionProfile, SpecError> {
        for (key, set) in [
            ("to_plant", self.to_plant.is_some()),
            ("to_controller", self.to_controller.is_some()),
            ("mean_dwell_messages", self.mean_dwell_messages.is_some()),
            ("mean_dwell_s", self.mean_dwell_s.is_some()),
        ] {
            if set {
                let reason = if place == Place::Direction {
                    "does not belong in a direction's table"
                } else {
                    "belongs to a regime's state ([[...states]])"
                };
                return Err(err(join(path, key), reason));
            }
        }
        let profile = DirectionProfile {
            delay: self.distribution(path, read_trace)?,
            loss_probability: self.loss_probability.unwrap_or(0.0),
            duplicate_probability: self.duplicate_probability.unwrap_or(0.0),
            ordering: self.ordering.unwrap_or_default(),
            seed,
        };
        profile.validate().map_err(|e| err(join(path, &file_field(&e.field)), e.reason))?;
        Ok(profile)
    }

    /// The distribution of the table at `path` (its kind and the kind's keys).
    fn distribution(
        &self,
        path: &str,
        read_trace: &mut dyn FnMut(&str) -> Result<Vec<f64>, String>,
    ) -> Result<Distribution, SpecError> {
        let Some(kind) = self.kind.as_deref() else {
            return Err(err(join(path, "kind"), format!("missing (one of {})", KINDS.join(", "))));
        };
        let Some((alternatives, optional)) = kind_keys(kind) else {
            return Err(err(
                join(path, "kind"),
                format!("unknown kind {kind:?} (known: {})", KINDS.join(", ")),
            ));
        };
        let present = self.distribution_keys();
        let takes = alternatives.iter().map(|a| a.join(" and ")).collect::<Vec<_>>().join(", or ");
        let takes = if takes.is_empty() { "no key".to_string() } else { takes };
        // The first alternative whose keys are all there; else the one with most of them, to
        // name what it misses.
        let chosen = alternatives.iter().find(|a| a.iter().all(|k| present.contains(k)));
        let Some(chosen) = chosen else {
            let best = alternatives
                .iter()
                .max_by_key(|a| a.iter().filter(|k| present.contains(k)).count())
                .copied()
                .unwrap_or(&[]);
            let missing = best.iter().find(|k| !present.contains(k)).copied().unwrap_or("kind");
            return Err(err(join(path, missing), format!("missing: kind {kind:?} takes {takes}")));
        };
        if let Some(extra) = present.iter().find(|k| !chosen.contains(k) && !optional.contains(k)) {
            return Err(err(
                join(path, extra),
                format!("does not apply to kind {kind:?} (it takes {takes})"),
            ));
        }
        let f = |v: Option<f64>| v.unwrap_or(f64::NAN);
        let by_moments = chosen.contains(&"mean_s");
        Ok(match kind {
            "none" => Distribution::Constant { delay_s: 0.0 },
            "constant" => Distribution::Constant { delay_s: f(self.delay_s) },
            "uniform" => Distribution::Uniform { min_s: f(self.min_s), max_s: f(self.max_s) },
            "normal" => Distribution::Normal { mean_s: f(self.mean_s), std_s: f(self.std_s) },
            "gamma" | "gamma_moments" if by_moments => {
                Distribution::GammaMoments { mean_s: f(self.mean_s), std_s: f(self.std_s) }
            }
            "gamma" => Distribution::Gamma { shape: f(self.shape), scale_s: f(self.scale_s) },
            "lognormal" | "lognormal_moments" if by_moments => {
                Distribution::LognormalMoments { mean_s: f(self.mean_s), std_s: f(self.std_s) }
            }
            "lognormal" => Distribution::Lognormal { mu: f(self.mu), sigma: f(self.sigma) },
            "pareto" => Distribution::Pareto { scale_s: f(self.scale_s), shape: f(self.shape) },
            "trace" => {
                let file = self.file.as_deref().unwrap_or_default();
                let delays = match &self.delays_s {
                    Some(inline) => inline.clone(),
                    None => read_trace(file).map_err(|reason| err(join(path, "file"), reason))?,
                };
                let name = if file.is_empty() { "(inline)" } else { file };
                Distribution::Trace(Trace::from_file(name, delays, self.looping.unwrap_or(false)))
            }
            _ => {
                let tables = self.states.as_deref().unwrap_or_default();
                let mut states = Vec::with_capacity(tables.len());
                for (i, s) in tables.iter().enumerate() {
                    states.push(s.state(&join(path, &format!("states[{i}]")), read_trace)?);
                }
                Distribution::Regime { states: Arc::from(states) }
            }
        })
    }

    /// A regime's state, the table at `path`.
    fn state(
        &self,
        path: &str,
        read_trace: &mut dyn FnMut(&str) -> Result<Vec<f64>, String>,
    ) -> Result<RegimeState, SpecError> {
        for (key, set) in [
            ("duplicate_probability", self.duplicate_probability.is_some()),
            ("ordering", self.ordering.is_some()),
            ("to_plant", self.to_plant.is_some()),
            ("to_controller", self.to_controller.is_some()),
        ] {
            if set {
                return Err(err(join(path, key), "belongs to a direction, not to a regime's state"));
            }
        }
        if matches!(self.kind.as_deref(), Some("trace" | "regime")) {
            return Err(err(join(path, "kind"), "a regime's state may be any kind but trace or regime"));
        }
        let mean_dwell = match (self.mean_dwell_messages, self.mean_dwell_s) {
            (Some(m), None) => Dwell::Messages(m),
            (None, Some(s)) => Dwell::Seconds(s),
            (Some(_), Some(_)) => {
                return Err(err(
                    join(path, "mean_dwell_s"),
                    "give mean_dwell_messages or mean_dwell_s, not both",
                ));
            }
            (None, None) => {
                return Err(err(
                    join(path, "mean_dwell_s"),
                    "missing: a state needs mean_dwell_messages or mean_dwell_s",
                ));
            }
        };
        Ok(RegimeState {
            delay: self.distribution(path, read_trace)?,
            mean_dwell,
            loss_probability: self.loss_probability,
        })
    }
}

impl DelaysTable {
    /// No delay (what a scenario without a `[scenario.delays]` table has).
    pub fn none() -> Self {
        Self { kind: Some("none".into()), ..Self::default() }
    }

    /// A round trip `~ Gamma(shape, scale_s)` on commands (the paper's process).
    pub fn gamma(shape: f64, scale_s: f64) -> Self {
        Self { kind: Some("gamma".into()), shape: Some(shape), scale_s: Some(scale_s), ..Self::default() }
    }

    /// A round trip replaying `delays_s` (ending the run once used up unless `looping`),
    /// named `name` in errors.
    pub fn trace(name: &str, delays_s: Vec<f64>, looping: bool) -> Self {
        Self {
            kind: Some("trace".into()),
            file: Some(name.to_string()),
            delays_s: Some(delays_s),
            looping: looping.then_some(true),
            ..Self::default()
        }
    }

    /// Reads the delays of every trace named by `file` and not yet loaded into `delays_s`
    /// (keeping `file` as its name). Errors name the key as [`DelaysTable::to_network`] does.
    pub fn load_traces(
        &mut self,
        read_trace: &mut dyn FnMut(&str) -> Result<Vec<f64>, String>,
    ) -> Result<(), SpecError> {
        fn load(
            t: &mut DelaysTable,
            path: &str,
            read_trace: &mut dyn FnMut(&str) -> Result<Vec<f64>, String>,
        ) -> Result<(), SpecError> {
            if t.kind.as_deref() == Some("trace")
                && t.delays_s.is_none()
                && let Some(file) = t.file.clone()
            {
                t.delays_s = Some(read_trace(&file).map_err(|reason| err(join(path, "file"), reason))?);
            }
            Ok(())
        }
        load(self, "", read_trace)?;
        if let Some(t) = self.to_plant.as_deref_mut() {
            load(t, "to_plant", read_trace)?;
        }
        if let Some(t) = self.to_controller.as_deref_mut() {
            load(t, "to_controller", read_trace)?;
        }
        Ok(())
    }

    /// The table that describes `network` (seeds aside: a table takes its seed from the
    /// scenario): the inverse of [`DelaysTable::to_network`], a round trip at the top when
    /// samples go undisturbed, else a table per direction. A trace is written inline.
    pub fn from_network(network: &NetworkProfile) -> Self {
        let undisturbed = |p: &DirectionProfile| {
            p.delay.is_zero()
                && p.loss_probability == 0.0
                && p.duplicate_probability == 0.0
                && p.ordering == Ordering::default()
        };
        if undisturbed(&network.to_controller) {
            return Self::of_direction(&network.to_plant);
        }
        Self {
            to_plant: Some(Box::new(Self::of_direction(&network.to_plant))),
            to_controller: Some(Box::new(Self::of_direction(&network.to_controller))),
            ..Self::default()
        }
    }

    /// A direction's table: its distribution, and loss, duplication and ordering when they
    /// are not the defaults.
    fn of_direction(p: &DirectionProfile) -> Self {
        let mut t = Self::of_distribution(&p.delay);
        t.loss_probability = (p.loss_probability != 0.0).then_some(p.loss_probability);
        t.duplicate_probability = (p.duplicate_probability != 0.0).then_some(p.duplicate_probability);
        t.ordering = (p.ordering != Ordering::default()).then_some(p.ordering);
        t
    }

    /// A distribution's keys (a zero constant is kind `none`).
    fn of_distribution(d: &Distribution) -> Self {
        let with = |kind: &str| Self { kind: Some(kind.to_string()), ..Self::default() };
        match d {
            d if d.is_zero() => with("none"),
            Distribution::Constant { delay_s } => Self { delay_s: Some(*delay_s), ..with("constant") },
            Distribution::Uniform { min_s, max_s } => {
                Self { min_s: Some(*min_s), max_s: Some(*max_s), ..with("uniform") }
            }
            Distribution::Normal { mean_s, std_s } => {
                Self { mean_s: Some(*mean_s), std_s: Some(*std_s), ..with("normal") }
            }
            Distribution::Gamma { shape, scale_s } => Self::gamma(*shape, *scale_s),
            Distribution::GammaMoments { mean_s, std_s } => {
                Self { mean_s: Some(*mean_s), std_s: Some(*std_s), ..with("gamma") }
            }
            Distribution::Lognormal { mu, sigma } => {
                Self { mu: Some(*mu), sigma: Some(*sigma), ..with("lognormal") }
            }
            Distribution::LognormalMoments { mean_s, std_s } => {
                Self { mean_s: Some(*mean_s), std_s: Some(*std_s), ..with("lognormal") }
            }
            Distribution::Pareto { scale_s, shape } => {
                Self { scale_s: Some(*scale_s), shape: Some(*shape), ..with("pareto") }
            }
            Distribution::Trace(t) => Self {
                file: (!t.name.is_empty() && &*t.name != "(inline)").then(|| t.name.to_string()),
                delays_s: Some(t.delays_s.to_vec()),
                looping: (t.end == crate::TraceEnd::Loop).then_some(true),
                ..with("trace")
            },
            Distribution::Regime { states } => Self {
                states: Some(
                    states
                        .iter()
                        .map(|s| {
                            let mut t = Self::of_distribution(&s.delay);
                            match s.mean_dwell {
                                Dwell::Messages(m) => t.mean_dwell_messages = Some(m),
                                Dwell::Seconds(d) => t.mean_dwell_s = Some(d),
                            }
                            t.loss_probability = s.loss_probability;
                            t
                        })
                        .collect(),
                ),
                ..with("regime")
            },
        }
    }
}

/// The table key of a field that [`DirectionProfile::validate`] names by its path in the
/// `hilbench.v1.DirectionProfile` message: `delay.gamma.shape` is `shape`,
/// `delay.regime.states[1].delay.uniform.max_s` is `states[1].max_s` (a state's keys sit in
/// its table), a trace's delays are its `file`.
pub fn file_field(path: &str) -> String {
    let mut out: Vec<&str> = Vec::new();
    let mut parts = path.split('.').peekable();
    while let Some(part) = parts.next() {
        if part == "delay" {
            match parts.peek() {
                Some(k) if KINDS.contains(k) => {
                    parts.next();
                }
                Some(_) => out.push(part),
                None => out.push("kind"),
            }
            continue;
        }
        if part.starts_with("delays_s") {
            out.push("file");
            break;
        }
        out.push(part);
    }
    out.join(".")
}

#[cfg(test)]
mod tests;
