//! What one direction of the emulated network does to messages, and the named presets.

use std::sync::Arc;

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

/// The delay distribution of one direction. Every parameter is in seconds unless it is a shape
/// or the `mu`/`sigma` of a log.
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
    /// Pareto (type I) with minimum `scale_s > 0` and tail index `shape > 0`.
    Pareto { scale_s: f64, shape: f64 },
    /// Replay of recorded delays, in order. A non-looping trace holds its last delay once it is
    /// exhausted (see [`crate::DelayLine::trace_exhausted`]).
    Trace { delays_s: Arc<[f64]>, looping: bool },
}

impl Distribution {
    /// The Gamma parameters `(shape, scale_s)` of a `GammaMoments` distribution.
    pub fn gamma_from_moments(mean_s: f64, std_s: f64) -> (f64, f64) {
        let var = std_s * std_s;
        (mean_s * mean_s / var, var / mean_s)
    }

    /// Checks every parameter; the error names the field as `delay.<kind>.<field>`, the path of
    /// the same field in the `hilbench.v1.DelayDistribution` message.
    pub fn validate(&self) -> Result<(), ProfileError> {
        fn nonneg(field: &str, v: f64) -> Result<(), ProfileError> {
            if !v.is_finite() || v < 0.0 {
                return Err(ProfileError::new(field, format!("must be finite and >= 0, got {v}")));
            }
            if v > MAX_DELAY_S {
                return Err(ProfileError::new(field, format!("must be at most {MAX_DELAY_S} s, got {v}")));
            }
            Ok(())
        }
        fn positive(field: &str, v: f64) -> Result<(), ProfileError> {
            if !v.is_finite() || v <= 0.0 {
                return Err(ProfileError::new(field, format!("must be finite and > 0, got {v}")));
            }
            Ok(())
        }
        match self {
            Distribution::Constant { delay_s } => nonneg("delay.constant.delay_s", *delay_s),
            Distribution::Uniform { min_s, max_s } => {
                nonneg("delay.uniform.min_s", *min_s)?;
                nonneg("delay.uniform.max_s", *max_s)?;
                if max_s < min_s {
                    return Err(ProfileError::new(
                        "delay.uniform.max_s",
                        format!("must be >= min_s ({min_s}), got {max_s}"),
                    ));
                }
                Ok(())
            }
            Distribution::Normal { mean_s, std_s } => {
                nonneg("delay.normal.mean_s", *mean_s)?;
                nonneg("delay.normal.std_s", *std_s)
            }
            Distribution::Gamma { shape, scale_s } => {
                positive("delay.gamma.shape", *shape)?;
                positive("delay.gamma.scale_s", *scale_s)?;
                nonneg("delay.gamma.scale_s", *scale_s)
            }
            Distribution::GammaMoments { mean_s, std_s } => {
                positive("delay.gamma_moments.mean_s", *mean_s)?;
                nonneg("delay.gamma_moments.mean_s", *mean_s)?;
                positive("delay.gamma_moments.std_s", *std_s)?;
                nonneg("delay.gamma_moments.std_s", *std_s)?;
                let (shape, scale) = Self::gamma_from_moments(*mean_s, *std_s);
                if !shape.is_finite() || !scale.is_finite() || shape <= 0.0 || scale <= 0.0 {
                    return Err(ProfileError::new("delay.gamma_moments.std_s", "gives a degenerate Gamma"));
                }
                Ok(())
            }
            Distribution::Lognormal { mu, sigma } => {
                if !mu.is_finite() || *mu > MAX_DELAY_S.ln() {
                    return Err(ProfileError::new(
                        "delay.lognormal.mu",
                        format!("must be finite and <= ln({MAX_DELAY_S}), got {mu}"),
                    ));
                }
                if !sigma.is_finite() || *sigma < 0.0 {
                    return Err(ProfileError::new(
                        "delay.lognormal.sigma",
                        format!("must be finite and >= 0, got {sigma}"),
                    ));
                }
                Ok(())
            }
            Distribution::Pareto { scale_s, shape } => {
                positive("delay.pareto.scale_s", *scale_s)?;
                nonneg("delay.pareto.scale_s", *scale_s)?;
                positive("delay.pareto.shape", *shape)
            }
            Distribution::Trace { delays_s, .. } => {
                if delays_s.is_empty() {
                    return Err(ProfileError::new("delay.trace.delays_s", "must hold at least one delay"));
                }
                for (i, d) in delays_s.iter().enumerate() {
                    nonneg(&format!("delay.trace.delays_s[{i}]"), *d)?;
                }
                Ok(())
            }
        }
    }
}

/// Ordering of releases on one direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
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
        for (field, p) in [
            ("loss_probability", self.loss_probability),
            ("duplicate_probability", self.duplicate_probability),
        ] {
            if !p.is_finite() || !(0.0..=1.0).contains(&p) {
                return Err(ProfileError::new(field, format!("must be a probability in [0, 1], got {p}")));
            }
        }
        Ok(())
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

/// A named pair of profiles, one per direction.
#[derive(Debug, Clone, PartialEq)]
pub struct Preset {
    pub plant_to_controller: DirectionProfile,
    pub controller_to_plant: DirectionProfile,
}

impl Preset {
    pub fn get(&self, direction: Direction) -> &DirectionProfile {
        match direction {
            Direction::PlantToController => &self.plant_to_controller,
            Direction::ControllerToPlant => &self.controller_to_plant,
        }
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
/// SPEC.md's paper mode draws one round-trip delay `d_k ~ Gamma(12, 0.015)` per cycle and
/// applies the new input at `t_k + d_k` to an exact sample `x(t_k)`. `"paper"` reproduces
/// exactly that: the whole round trip is put on the command direction and the state samples
/// travel without delay. `"paper-split"` is the alternative that keeps the round-trip law and
/// splits it evenly: the sum of two independent Gamma(6, θ) is Gamma(12, θ), so the round trip
/// has the paper's distribution while each sample is also stale.
pub fn preset(name: &str, seed: u64) -> Result<Preset, ProfileError> {
    let none = DirectionProfile::with_delay(Distribution::Constant { delay_s: 0.0 }, seed);
    let gamma =
        |shape: f64| DirectionProfile::with_delay(Distribution::Gamma { shape, scale_s: 0.015 }, seed);
    match name {
        "paper" => Ok(Preset { plant_to_controller: none, controller_to_plant: gamma(12.0) }),
        "paper-split" => Ok(Preset { plant_to_controller: gamma(6.0), controller_to_plant: gamma(6.0) }),
        "none" => Ok(Preset { plant_to_controller: none.clone(), controller_to_plant: none }),
        other => {
            let known: Vec<&str> = PRESETS.iter().map(|(n, _)| *n).collect();
            Err(ProfileError::new("preset", format!("unknown preset `{other}`; known: {}", known.join(", "))))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field_of(p: DirectionProfile) -> String {
        p.validate().map_err(|e| e.field).err().unwrap_or_default()
    }

    #[test]
    fn bad_parameters_name_their_field() {
        let with = |delay| DirectionProfile::with_delay(delay, 1);
        assert_eq!(field_of(with(Distribution::Constant { delay_s: -1.0 })), "delay.constant.delay_s");
        assert_eq!(field_of(with(Distribution::Gamma { shape: 0.0, scale_s: 1.0 })), "delay.gamma.shape");
        assert_eq!(
            field_of(with(Distribution::Gamma { shape: 2.0, scale_s: f64::NAN })),
            "delay.gamma.scale_s"
        );
        assert_eq!(field_of(with(Distribution::Uniform { min_s: 0.2, max_s: 0.1 })), "delay.uniform.max_s");
        assert_eq!(
            field_of(with(Distribution::Normal { mean_s: 0.1, std_s: f64::INFINITY })),
            "delay.normal.std_s"
        );
        assert_eq!(
            field_of(with(Distribution::GammaMoments { mean_s: 0.0, std_s: 0.1 })),
            "delay.gamma_moments.mean_s"
        );
        assert_eq!(
            field_of(with(Distribution::Lognormal { mu: -3.0, sigma: -0.1 })),
            "delay.lognormal.sigma"
        );
        assert_eq!(field_of(with(Distribution::Pareto { scale_s: 0.01, shape: 0.0 })), "delay.pareto.shape");
        assert_eq!(
            field_of(with(Distribution::Trace { delays_s: Arc::from(vec![]), looping: false })),
            "delay.trace.delays_s"
        );
        assert_eq!(
            field_of(with(Distribution::Trace { delays_s: Arc::from(vec![0.1, -0.1]), looping: false })),
            "delay.trace.delays_s[1]"
        );
        let mut p = DirectionProfile { loss_probability: 1.5, ..DirectionProfile::default() };
        assert_eq!(field_of(p.clone()), "loss_probability");
        p.loss_probability = 0.5;
        p.duplicate_probability = f64::NAN;
        assert_eq!(field_of(p), "duplicate_probability");
        assert!(DirectionProfile::default().validate().is_ok());
    }

    #[test]
    fn paper_preset_is_the_spec_round_trip_on_commands() -> Result<(), ProfileError> {
        let p = preset("paper", 42)?;
        assert_eq!(p.controller_to_plant.delay, Distribution::Gamma { shape: 12.0, scale_s: 0.015 });
        assert_eq!(p.plant_to_controller.delay, Distribution::Constant { delay_s: 0.0 });
        assert_eq!(p.controller_to_plant.seed, 42);
        let split = preset("paper-split", 7)?;
        assert_eq!(
            split.get(Direction::PlantToController).delay,
            Distribution::Gamma { shape: 6.0, scale_s: 0.015 }
        );
        assert_eq!(preset("nope", 1).map_err(|e| e.field), Err("preset".to_string()));
        for (name, _) in PRESETS {
            let p = preset(name, 3)?;
            p.plant_to_controller.validate()?;
            p.controller_to_plant.validate()?;
        }
        Ok(())
    }
}
