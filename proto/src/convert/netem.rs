//! Conversions of the netem API messages (see the module above for the rules).
//!
//! Profiles are validated by `delay` itself ([`delay::DirectionProfile::validate`]); its field
//! paths (`delay.gamma.shape`, `loss_probability`, ...) are those of `hilbench.v1.DirectionProfile`,
//! so an error only needs the parent's name (`profile.`) in front.

use std::sync::Arc;

use delay::{Direction, DirectionProfile, DirectionStats, Distribution, Ordering, ProfileError, Record};

use super::{FieldError, finite, required};
use crate::pb;
use crate::pb::delay_distribution::Kind;

impl From<ProfileError> for FieldError {
    fn from(e: ProfileError) -> Self {
        FieldError::new(e.field, e.reason)
    }
}

/// A direction; `Ok(None)` for `DIRECTION_UNSPECIFIED`.
pub fn direction_from_pb(field: &str, v: i32) -> Result<Option<Direction>, FieldError> {
    match pb::Direction::try_from(v) {
        Ok(pb::Direction::Unspecified) => Ok(None),
        Ok(pb::Direction::PlantToController) => Ok(Some(Direction::PlantToController)),
        Ok(pb::Direction::ControllerToPlant) => Ok(Some(Direction::ControllerToPlant)),
        Err(_) => Err(FieldError::new(field, format!("unknown direction {v}"))),
    }
}

impl From<Direction> for pb::Direction {
    fn from(d: Direction) -> Self {
        match d {
            Direction::PlantToController => pb::Direction::PlantToController,
            Direction::ControllerToPlant => pb::Direction::ControllerToPlant,
        }
    }
}

/// A validated profile. `ORDERING_UNSPECIFIED` means FIFO (what one gRPC connection does).
pub fn profile_from_pb(p: &pb::DirectionProfile) -> Result<DirectionProfile, FieldError> {
    let kind = required("delay", &p.delay)?;
    let kind = required("delay.kind", &kind.kind)?;
    let delay = match kind {
        Kind::Constant(c) => Distribution::Constant { delay_s: c.delay_s },
        Kind::Uniform(u) => Distribution::Uniform { min_s: u.min_s, max_s: u.max_s },
        Kind::Normal(n) => Distribution::Normal { mean_s: n.mean_s, std_s: n.std_s },
        Kind::Gamma(g) => Distribution::Gamma { shape: g.shape, scale_s: g.scale_s },
        Kind::GammaMoments(g) => Distribution::GammaMoments { mean_s: g.mean_s, std_s: g.std_s },
        Kind::Lognormal(l) => Distribution::Lognormal { mu: l.mu, sigma: l.sigma },
        Kind::Pareto(p) => Distribution::Pareto { scale_s: p.scale_s, shape: p.shape },
        Kind::Trace(t) => {
            Distribution::Trace { delays_s: Arc::from(t.delays_s.as_slice()), looping: t.looping }
        }
    };
    let ordering = match pb::Ordering::try_from(p.ordering) {
        Ok(pb::Ordering::Unspecified | pb::Ordering::Fifo) => Ordering::Fifo,
        Ok(pb::Ordering::Independent) => Ordering::Independent,
        Err(_) => return Err(FieldError::new("ordering", format!("unknown ordering {}", p.ordering))),
    };
    let profile = DirectionProfile {
        delay,
        loss_probability: p.loss_probability,
        duplicate_probability: p.duplicate_probability,
        ordering,
        seed: p.seed,
    };
    profile.validate()?;
    Ok(profile)
}

impl From<&DirectionProfile> for pb::DirectionProfile {
    fn from(p: &DirectionProfile) -> Self {
        let kind = match &p.delay {
            Distribution::Constant { delay_s } => Kind::Constant(pb::ConstantDelay { delay_s: *delay_s }),
            Distribution::Uniform { min_s, max_s } => {
                Kind::Uniform(pb::UniformDelay { min_s: *min_s, max_s: *max_s })
            }
            Distribution::Normal { mean_s, std_s } => {
                Kind::Normal(pb::NormalDelay { mean_s: *mean_s, std_s: *std_s })
            }
            Distribution::Gamma { shape, scale_s } => {
                Kind::Gamma(pb::GammaDelay { shape: *shape, scale_s: *scale_s })
            }
            Distribution::GammaMoments { mean_s, std_s } => {
                Kind::GammaMoments(pb::GammaMomentsDelay { mean_s: *mean_s, std_s: *std_s })
            }
            Distribution::Lognormal { mu, sigma } => {
                Kind::Lognormal(pb::LognormalDelay { mu: *mu, sigma: *sigma })
            }
            Distribution::Pareto { scale_s, shape } => {
                Kind::Pareto(pb::ParetoDelay { scale_s: *scale_s, shape: *shape })
            }
            Distribution::Trace { delays_s, looping } => {
                Kind::Trace(pb::TraceDelay { delays_s: delays_s.to_vec(), looping: *looping })
            }
        };
        pb::DirectionProfile {
            delay: Some(pb::DelayDistribution { kind: Some(kind) }),
            loss_probability: p.loss_probability,
            duplicate_probability: p.duplicate_probability,
            ordering: match p.ordering {
                Ordering::Fifo => pb::Ordering::Fifo,
                Ordering::Independent => pb::Ordering::Independent,
            } as i32,
            seed: p.seed,
        }
    }
}

/// The statistics of one direction, with the number of copies netem holds right now.
pub fn stats_to_pb(s: &DirectionStats, in_flight: u64) -> pb::DirectionStats {
    let secs = |ns: u64| ns as f64 / 1e9;
    let d = s.delay_percentiles().unwrap_or_default();
    let e = s.release_error_percentiles().unwrap_or_default();
    let (bin_ns, counts) = s.histogram();
    pb::DirectionStats {
        sent: s.sent,
        delivered: s.delivered,
        dropped: s.dropped,
        duplicated: s.duplicated,
        delay_p50_s: secs(d.p50_ns),
        delay_p95_s: secs(d.p95_ns),
        delay_p99_s: secs(d.p99_ns),
        delay_max_s: secs(d.max_ns),
        histogram: Some(pb::DelayHistogram { bin_width_s: secs(bin_ns), counts: counts.to_vec() }),
        release_error_p99_s: secs(e.p99_ns),
        in_flight,
        release_error_max_s: secs(e.max_ns),
    }
}

impl From<&Record> for pb::TraceRecord {
    fn from(r: &Record) -> Self {
        pb::TraceRecord {
            direction: pb::Direction::from(r.direction) as i32,
            message_seq: r.message_seq,
            sent_time_ns: r.send_time_ns,
            release_time_ns: r.release_time_ns,
            injected_delay_s: r.injected_delay_s,
            dropped: r.dropped,
            duplicate: r.duplicate,
            payload_seq: r.payload_seq,
            drop_reason: r.drop_reason.clone(),
            release_error_ns: r.release_error_ns,
        }
    }
}

/// Checks a command before netem holds it: a command that would be refused when it reaches
/// the plant is refused now, while the controller is still waiting for an answer.
pub fn check_command(field: &str, c: &pb::Command) -> Result<(), FieldError> {
    let input = required(&format!("{field}.input"), &c.input)?;
    finite(&format!("{field}.input.thrust_mps2"), input.thrust_mps2)?;
    finite(&format!("{field}.input.roll_rad"), input.roll_rad)?;
    finite(&format!("{field}.input.pitch_rad"), input.pitch_rad)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profiles_round_trip_and_bad_ones_name_the_field() -> Result<(), FieldError> {
        let p = DirectionProfile {
            delay: Distribution::Gamma { shape: 12.0, scale_s: 0.015 },
            loss_probability: 0.1,
            duplicate_probability: 0.0,
            ordering: Ordering::Independent,
            seed: 7,
        };
        assert_eq!(profile_from_pb(&pb::DirectionProfile::from(&p))?, p);
        let mut bad = pb::DirectionProfile::from(&p);
        bad.delay = Some(pb::DelayDistribution {
            kind: Some(Kind::Gamma(pb::GammaDelay { shape: f64::NAN, scale_s: 0.1 })),
        });
        assert_eq!(profile_from_pb(&bad).map_err(|e| e.field), Err("delay.gamma.shape".into()));
        bad.delay = None;
        assert_eq!(profile_from_pb(&bad).map_err(|e| e.field), Err("delay".into()));
        let mut bad = pb::DirectionProfile::from(&p);
        bad.loss_probability = -0.5;
        assert_eq!(
            profile_from_pb(&bad).map_err(|e| e.within("profile").field),
            Err("profile.loss_probability".into())
        );
        bad.loss_probability = 0.0;
        bad.ordering = 9;
        assert_eq!(profile_from_pb(&bad).map_err(|e| e.field), Err("ordering".into()));
        assert_eq!(direction_from_pb("direction", 7).map_err(|e| e.field), Err("direction".into()));
        assert_eq!(direction_from_pb("direction", 0)?, None);
        Ok(())
    }
}
