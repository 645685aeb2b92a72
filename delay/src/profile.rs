//! What one direction of the emulated network does to messages, and the named presets.

use std::sync::Arc;

use crate::trace::Trace;

/// Largest delay a profile may produce, s. Samples of unbounded distributions (Pareto,
/// lognormal, Gamma) are clamped here so that release times stay representable.
pub const MAX_DELAY_S: f64 = 3600.0;

/// The two directions of the link between a controller and its plant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// State samples, plant to controller.
    PlantToController,
    /// Commands, controller to plant.
    ControllerToPlant,
}

impl Direction {
    pub const ALL: [Direction; 2] = [Direction::PlantToController, Direction::ControllerToPlant];

    /// Index of the direction (0 or 1), used to give each direction its own random streams.
    pub fn index(self) -> usize {
        match self {
            Direction::PlantToController => 0,
            Direction::ControllerToPlant => 1,
        }
    }
}

/// The delay distribution of one direction: the one vocabulary of delay kinds (scenario files,
/// netem's API and its `--profile-file` all name these). Every parameter is in seconds unless
/// it is a shape or the `mu`/`sigma` of a log.
#[derive(Debug, Clone, PartialEq)]
pub enum Distribution {
    /// Always `delay_s` (>= 0).
    Constant { delay_s: f64 },
    /// Uniform on `[min_s, max_s]`, `0 <= min_s <= max_s`.
    Uniform { min_s: f64, max_s: f64 },
    /// Normal with `mean_s >= 0` and `std_s >= 0`, truncated at zero (negative draws are
    /// redrawn, so this is the conditional law given `delay >= 0`, not a clamp).
    Normal { mean_s: f64, std_s: f64 },
    /// Gamma with `shape > 0` and `scale_s > 0`: mean `shape * scale_s`.
    Gamma { shape: f64, scale_s: f64 },
    /// Gamma given by its moments (`mean_s > 0`, `std_s > 0`):
    /// `shape = mean^2 / std^2`, `scale = std^2 / mean`.
    GammaMoments { mean_s: f64, std_s: f64 },
    /// `ln(delay_s) ~ Normal(mu, sigma)`, `sigma >= 0`.
    Lognormal { mu: f64, sigma: f64 },
    /// Lognormal given by the mean and standard deviation of the delay itself (`mean_s > 0`,
    /// `std_s >= 0`): `sigma^2 = ln(1 + std^2 / mean^2)`, `mu = ln(mean) - sigma^2 / 2`.
    LognormalMoments { mean_s: f64, std_s: f64 },
    /// Pareto (type I) with minimum `scale_s > 0` and tail index `shape > 0`.
    Pareto { scale_s: f64, shape: f64 },
    /// Replay of recorded delays, in order (an entry [`crate::LOST_S`] is a lost message);
    /// what happens past the end is the trace's [`crate::TraceEnd`].
    Trace(Trace),
    /// A Markov-modulated process for bursty links (Wi-Fi, LTE): the link is in one of
    /// `states`, each with its own delay law and mean dwell time; see [`RegimeState`].
    Regime { states: Arc<[RegimeState]> },
}

/// How long a [`Distribution::Regime`] stays in a state, on average.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Dwell {
    /// A geometric number of messages with this mean (>= 1): after each message the process
    /// leaves the state with probability `1 / mean`.
    Messages(f64),
    /// An exponential time with this mean, s (> 0), on the clock of the send times.
    Seconds(f64),
}

/// One state of a [`Distribution::Regime`].
///
/// The process starts in the first state at the first message. When it leaves a state it
/// enters one of the others, chosen uniformly (with a single state it never leaves). A state
/// of [`Dwell::Seconds`] is left at the first message sent at or after its end time; a state
/// entered at time `t` then ends at `t` plus its own exponential dwell, so that the dwell
/// times are those of a continuous-time Markov chain observed at the send times. Every draw
/// comes from the line's seeded streams: the same seed and send times give the same states
/// and delays.
///
/// A state may have a loss of its own (a link that loses 8 % in its spikes and 0.2 %
/// otherwise): a message sent in the state is lost with it, in place of the direction's
/// `loss_probability`. The draw is the same one on the line's loss stream either way, so
/// giving a state its loss changes no other message's fate.
#[derive(Debug, Clone, PartialEq)]
pub struct RegimeState {
    /// The delay law in this state: any kind but a trace or a regime.
    pub delay: Distribution,
    pub mean_dwell: Dwell,
    /// The probability in `[0, 1]` that a message sent in this state is lost; `None`: the
    /// direction's `loss_probability`.
    pub loss_probability: Option<f64>,
}

impl RegimeState {
    /// A state with this delay and dwell and the direction's loss.
    pub fn new(delay: Distribution, mean_dwell: Dwell) -> Self {
        Self { delay, mean_dwell, loss_probability: None }
    }
}

/// Largest number of states of a regime process.
pub const MAX_REGIME_STATES: usize = 64;
/// Largest mean dwell of a regime state, in messages or seconds.
pub const MAX_MEAN_DWELL: f64 = 1e12;

impl Distribution {
    /// The Gamma parameters `(shape, scale_s)` of a `GammaMoments` distribution.
    pub fn gamma_from_moments(mean_s: f64, std_s: f64) -> (f64, f64) {
        let var = std_s * std_s;
        (mean_s * mean_s / var, var / mean_s)
    }

    /// The `(mu, sigma)` of the log of a lognormal delay of mean `mean_s` and standard
    /// deviation `std_s`.
    pub fn lognormal_from_moments(mean_s: f64, std_s: f64) -> (f64, f64) {
        let var_log = (std_s / mean_s).powi(2).ln_1p();
        (mean_s.ln() - var_log / 2.0, var_log.sqrt())
    }

    /// The kind's name, as in `hilbench.v1.DelayDistribution` and in scenario files.
    pub fn kind(&self) -> &'static str {
        match self {
            Distribution::Constant { .. } => "constant",
            Distribution::Uniform { .. } => "uniform",
            Distribution::Normal { .. } => "normal",
            Distribution::Gamma { .. } => "gamma",
            Distribution::GammaMoments { .. } => "gamma_moments",
            Distribution::Lognormal { .. } => "lognormal",
            Distribution::LognormalMoments { .. } => "lognormal_moments",
            Distribution::Pareto { .. } => "pareto",
            Distribution::Trace(_) => "trace",
            Distribution::Regime { .. } => "regime",
        }
    }

    /// No delay at all: a constant zero.
    pub fn is_zero(&self) -> bool {
        matches!(self, Distribution::Constant { delay_s } if *delay_s == 0.0)
    }

    /// Checks every parameter; the error names the field as `delay.<kind>.<field>`, the path of
    /// the same field in the `hilbench.v1.DirectionProfile` message.
    pub fn validate(&self) -> Result<(), ProfileError> {
        self.validate_at("delay")
    }

    /// [`Distribution::validate`] with the path of the distribution given (`prefix`).
    fn validate_at(&self, prefix: &str) -> Result<(), ProfileError> {
        let field = |name: &str| format!("{prefix}.{}.{name}", self.kind());
        let nonneg = |name: &str, v: f64| -> Result<(), ProfileError> {
            if !v.is_finite() || v < 0.0 {
                return Err(ProfileError::new(
                    field(name),
                    format!("must be finite and >= 0, got {}", crate::Number(v)),
                ));
            }
            if v > MAX_DELAY_S {
                return Err(ProfileError::new(
                    field(name),
                    format!("must be at most {MAX_DELAY_S} s, got {}", crate::Number(v)),
                ));
            }
            Ok(())
        };
        let positive = |name: &str, v: f64| -> Result<(), ProfileError> {
            if !v.is_finite() || v <= 0.0 {
                return Err(ProfileError::new(
                    field(name),
                    format!("must be finite and > 0, got {}", crate::Number(v)),
                ));
            }
            Ok(())
        };
        match self {
            Distribution::Constant { delay_s } => nonneg("delay_s", *delay_s),
            Distribution::Uniform { min_s, max_s } => {
                nonneg("min_s", *min_s)?;
                nonneg("max_s", *max_s)?;
                if max_s < min_s {
                    return Err(ProfileError::new(
                        field("max_s"),
                        format!(
                            "must be >= min_s ({}), got {}",
                            crate::Number(*min_s),
                            crate::Number(*max_s)
                        ),
                    ));
                }
                Ok(())
            }
            Distribution::Normal { mean_s, std_s } => {
                nonneg("mean_s", *mean_s)?;
                nonneg("std_s", *std_s)
            }
            Distribution::Gamma { shape, scale_s } => {
                positive("shape", *shape)?;
                positive("scale_s", *scale_s)?;
                nonneg("scale_s", *scale_s)
            }
            Distribution::GammaMoments { mean_s, std_s } => {
                positive("mean_s", *mean_s)?;
                nonneg("mean_s", *mean_s)?;
                positive("std_s", *std_s)?;
                nonneg("std_s", *std_s)?;
                let (shape, scale) = Self::gamma_from_moments(*mean_s, *std_s);
                if !shape.is_finite() || !scale.is_finite() || shape <= 0.0 || scale <= 0.0 {
                    return Err(ProfileError::new(field("std_s"), "gives a degenerate Gamma"));
                }
                Ok(())
            }
            Distribution::Lognormal { mu, sigma } => {
                if !mu.is_finite() || *mu > MAX_DELAY_S.ln() {
                    return Err(ProfileError::new(
                        field("mu"),
                        format!("must be finite and <= ln({MAX_DELAY_S}), got {}", crate::Number(*mu)),
                    ));
                }
                if !sigma.is_finite() || *sigma < 0.0 {
                    return Err(ProfileError::new(
                        field("sigma"),
                        format!("must be finite and >= 0, got {}", crate::Number(*sigma)),
                    ));
                }
                Ok(())
            }
            Distribution::LognormalMoments { mean_s, std_s } => {
                positive("mean_s", *mean_s)?;
                nonneg("mean_s", *mean_s)?;
                nonneg("std_s", *std_s)?;
                let (mu, sigma) = Self::lognormal_from_moments(*mean_s, *std_s);
                if !mu.is_finite() || !sigma.is_finite() {
                    return Err(ProfileError::new(field("std_s"), "gives a degenerate lognormal"));
                }
                Ok(())
            }
            Distribution::Pareto { scale_s, shape } => {
                positive("scale_s", *scale_s)?;
                nonneg("scale_s", *scale_s)?;
                positive("shape", *shape)
            }
            Distribution::Trace(trace) => {
                if trace.delays_s.is_empty() {
                    return Err(ProfileError::new(field("delays_s"), "must hold at least one delay"));
                }
                // A lost message (`LOST_S`) is an entry, not a delay.
                for (i, d) in trace.delays_s.iter().enumerate().filter(|(_, d)| !crate::trace::is_lost(**d)) {
                    nonneg(&format!("delays_s[{i}]"), *d)?;
                }
                Ok(())
            }
            Distribution::Regime { states } => {
                if states.is_empty() {
                    return Err(ProfileError::new(field("states"), "must hold at least one state"));
                }
                if states.len() > MAX_REGIME_STATES {
                    return Err(ProfileError::new(
                        field("states"),
                        format!("must hold at most {MAX_REGIME_STATES} states, got {}", states.len()),
                    ));
                }
                for (i, s) in states.iter().enumerate() {
                    let at = field(&format!("states[{i}]"));
                    if matches!(s.delay, Distribution::Trace(_) | Distribution::Regime { .. }) {
                        return Err(ProfileError::new(
                            format!("{at}.delay"),
                            format!(
                                "a state's delay may be any kind but trace or regime, got {}",
                                s.delay.kind()
                            ),
                        ));
                    }
                    s.delay.validate_at(&format!("{at}.delay"))?;
                    let (name, mean, least) = match s.mean_dwell {
                        Dwell::Messages(m) => ("mean_dwell_messages", m, 1.0),
                        Dwell::Seconds(t) => ("mean_dwell_s", t, f64::MIN_POSITIVE),
                    };
                    if let Some(p) = s.loss_probability {
                        probability(&format!("{at}.loss_probability"), p)?;
                    }
                    if !mean.is_finite() || mean < least || mean > MAX_MEAN_DWELL {
                        let unit = if least == 1.0 { "at least 1 (message)" } else { "> 0" };
                        return Err(ProfileError::new(
                            format!("{at}.{name}"),
                            format!(
                                "must be finite, {unit} and at most {MAX_MEAN_DWELL:e}, got {}",
                                crate::Number(mean)
                            ),
                        ));
                    }
                }
                Ok(())
            }
        }
    }
}

/// `p` is a probability, else the error names `field`.
fn probability(field: &str, p: f64) -> Result<(), ProfileError> {
    if !p.is_finite() || !(0.0..=1.0).contains(&p) {
        return Err(ProfileError::new(
            field,
            format!("must be a probability in [0, 1], got {}", crate::Number(p)),
        ));
    }
    Ok(())
}

/// Ordering of releases on one direction (`"fifo"` or `"independent"` in files).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Ordering {
    /// A message is never released before an earlier one (one TCP stream): the release time
    /// is `max(send + delay, previous release)`, so delays queue up behind a slow message.
    #[default]
    Fifo,
    /// Each message keeps its own delay (datagrams): reordering is allowed.
    Independent,
}

/// Everything one direction of the link does to messages.
#[derive(Debug, Clone, PartialEq)]
pub struct DirectionProfile {
    /// Delay of each message.
    pub delay: Distribution,
    /// Probability in `[0, 1]` that a message is lost.
    pub loss_probability: f64,
    /// Probability in `[0, 1]` that a delivered message is delivered twice (the copy gets its
    /// own delay).
    pub duplicate_probability: f64,
    /// FIFO or independent releases.
    pub ordering: Ordering,
    /// Seed of this direction's generators.
    pub seed: u64,
}

impl Default for DirectionProfile {
    /// No delay, no loss, no duplicates, FIFO, seed 42.
    fn default() -> Self {
        Self {
            delay: Distribution::Constant { delay_s: 0.0 },
            loss_probability: 0.0,
            duplicate_probability: 0.0,
            ordering: Ordering::Fifo,
            seed: 42,
        }
    }
}

impl DirectionProfile {
    /// A loss-free, duplicate-free FIFO profile with this delay.
    pub fn with_delay(delay: Distribution, seed: u64) -> Self {
        Self { delay, seed, ..Self::default() }
    }

    /// Checks every field; the error names it as in `hilbench.v1.DirectionProfile`.
    pub fn validate(&self) -> Result<(), ProfileError> {
        self.delay.validate()?;
        probability("loss_probability", self.loss_probability)?;
        probability("duplicate_probability", self.duplicate_probability)
    }
}

/// A profile or preset that failed validation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid field `{field}`: {reason}")]
pub struct ProfileError {
    /// Dotted path of the field, e.g. `delay.gamma.shape` or `loss_probability`.
    pub field: String,
    pub reason: String,
}

impl ProfileError {
    pub fn new(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self { field: field.into(), reason: reason.into() }
    }
}

/// What the network between a controller and its plant does, both ways: a scenario's delay
/// process, and a netem preset.
#[derive(Debug, Clone, PartialEq)]
pub struct NetworkProfile {
    /// Commands, controller to plant. A scenario's round-trip delay lives here (paper mode:
    /// the new input is applied at `t_k + d_k` to the exact sample `x(t_k)`).
    pub to_plant: DirectionProfile,
    /// State samples, plant to controller.
    pub to_controller: DirectionProfile,
}

impl Default for NetworkProfile {
    /// No delay, loss or duplication either way, seed 42.
    fn default() -> Self {
        Self::none(42)
    }
}

impl NetworkProfile {
    /// No delay, loss or duplication either way.
    pub fn none(seed: u64) -> Self {
        Self::round_trip(Distribution::Constant { delay_s: 0.0 }, seed)
    }

    /// The whole round trip `delay` on commands, nothing on samples, FIFO, no loss.
    pub fn round_trip(delay: Distribution, seed: u64) -> Self {
        Self {
            to_plant: DirectionProfile::with_delay(delay, seed),
            to_controller: DirectionProfile::with_delay(Distribution::Constant { delay_s: 0.0 }, seed),
        }
    }

    pub fn get(&self, direction: Direction) -> &DirectionProfile {
        match direction {
            Direction::PlantToController => &self.to_controller,
            Direction::ControllerToPlant => &self.to_plant,
        }
    }

    /// Some message is delayed (a loss alone delays nothing). A controller expects delays, and
    /// fits their law, exactly when this is true.
    pub fn has_delays(&self) -> bool {
        !self.to_plant.delay.is_zero() || !self.to_controller.delay.is_zero()
    }

    /// The same profile with `seed` for both directions (each direction draws from its own
    /// random streams, so one seed does not make the two directions equal).
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.to_plant.seed = seed;
        self.to_controller.seed = seed;
        self
    }

    /// Checks both directions; the error's field starts with `to_plant.` or `to_controller.`.
    pub fn validate(&self) -> Result<(), ProfileError> {
        for (name, p) in [("to_plant", &self.to_plant), ("to_controller", &self.to_controller)] {
            p.validate().map_err(|e| ProfileError::new(format!("{name}.{}", e.field), e.reason))?;
        }
        Ok(())
    }
}

/// Names accepted by [`preset`], with what they mean.
pub const PRESETS: [(&str, &str); 3] = [
    ("paper", "SPEC paper mode: the whole round trip Gamma(12, 0.015) on commands, none on samples, FIFO"),
    ("paper-split", "round trip Gamma(12, 0.015) split exactly: Gamma(6, 0.015) on each direction, FIFO"),
    ("none", "no delay, loss or duplication on either direction"),
];

/// The named preset `name`, with `seed` for both directions (each direction draws from its
/// own random streams, so one seed does not make the two directions equal).
///
/// docs/spec.md's paper mode draws one round-trip delay `d_k ~ Gamma(12, 0.015)` per cycle and
/// applies the new input at `t_k + d_k` to an exact sample `x(t_k)`. `"paper"` reproduces
/// exactly that: the whole round trip is put on the command direction and the state samples
/// travel without delay. `"paper-split"` is the alternative that keeps the round-trip law and
/// splits it evenly: the sum of two independent Gamma(6, θ) is Gamma(12, θ), so the round trip
/// has the paper's distribution while each sample is also stale.
pub fn preset(name: &str, seed: u64) -> Result<NetworkProfile, ProfileError> {
    let gamma =
        |shape: f64| DirectionProfile::with_delay(Distribution::Gamma { shape, scale_s: 0.015 }, seed);
    match name {
        "paper" => Ok(NetworkProfile::round_trip(Distribution::Gamma { shape: 12.0, scale_s: 0.015 }, seed)),
        "paper-split" => Ok(NetworkProfile { to_plant: gamma(6.0), to_controller: gamma(6.0) }),
        "none" => Ok(NetworkProfile::none(seed)),
        other => {
            let known: Vec<&str> = PRESETS.iter().map(|(n, _)| *n).collect();
            Err(ProfileError::new("preset", format!("unknown preset `{other}`; known: {}", known.join(", "))))
        }
    }
}

#[cfg(test)]
mod tests;
