//! Conversions of the netem API messages (see the module above for the rules).
//!
//! Profiles are validated by `delay` itself ([`delay::DirectionProfile::validate`]); its field
//! paths (`delay.gamma.shape`, `loss_probability`, ...) are those of `hilbench.v1.DirectionProfile`,
//! so an error only needs the parent's name (`profile.`) in front.

use std::sync::Arc;

use delay::{
    Direction, DirectionProfile, DirectionStats, Distribution, Dwell, Ordering, ProfileError, Record,
    RegimeState, Trace, TraceEnd,
};

use super::{FieldError, required};
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

/// The distribution of a `DelayDistribution` at `field` (unvalidated: the profile's
/// validation names bad parameters).
fn distribution_from_pb(field: &str, d: Option<&pb::DelayDistribution>) -> Result<Distribution, FieldError> {
    let d = d.ok_or_else(|| FieldError::new(field, "is required"))?;
    let kind = required(&format!("{field}.kind"), &d.kind)?;
    Ok(match kind {
        Kind::Constant(c) => Distribution::Constant { delay_s: c.delay_s },
        Kind::Uniform(u) => Distribution::Uniform { min_s: u.min_s, max_s: u.max_s },
        Kind::Normal(n) => Distribution::Normal { mean_s: n.mean_s, std_s: n.std_s },
        Kind::Gamma(g) => Distribution::Gamma { shape: g.shape, scale_s: g.scale_s },
        Kind::GammaMoments(g) => Distribution::GammaMoments { mean_s: g.mean_s, std_s: g.std_s },
        Kind::Lognormal(l) => Distribution::Lognormal { mu: l.mu, sigma: l.sigma },
        Kind::LognormalMoments(l) => Distribution::LognormalMoments { mean_s: l.mean_s, std_s: l.std_s },
        Kind::Pareto(p) => Distribution::Pareto { scale_s: p.scale_s, shape: p.shape },
        Kind::Trace(t) => Distribution::Trace(Trace {
            delays_s: Arc::from(t.delays_s.as_slice()),
            end: match (t.looping, t.stop_at_end) {
                (true, _) => TraceEnd::Loop,
                (false, false) => TraceEnd::Hold,
                (false, true) => TraceEnd::Stop,
            },
            name: Arc::from(t.name.as_str()),
        }),
        Kind::Regime(r) => {
            if r.states.len() > delay::MAX_REGIME_STATES {
                return Err(FieldError::new(
                    format!("{field}.regime.states"),
                    format!("must hold at most {} states, got {}", delay::MAX_REGIME_STATES, r.states.len()),
                ));
            }
            let mut states = Vec::with_capacity(r.states.len());
            for (i, s) in r.states.iter().enumerate() {
                let at = format!("{field}.regime.states[{i}]");
                let mean_dwell = match s.mean_dwell {
                    Some(pb::regime_state::MeanDwell::MeanDwellMessages(m)) => Dwell::Messages(m),
                    Some(pb::regime_state::MeanDwell::MeanDwellS(t)) => Dwell::Seconds(t),
                    None => return Err(FieldError::new(format!("{at}.mean_dwell"), "is required")),
                };
                let delay = distribution_from_pb(&format!("{at}.delay"), s.delay.as_ref())?;
                states.push(RegimeState { delay, mean_dwell, loss_probability: s.loss_probability });
            }
            Distribution::Regime { states: Arc::from(states) }
        }
    })
}

/// A validated profile. `ORDERING_UNSPECIFIED` means FIFO (what one gRPC connection does).
pub fn profile_from_pb(p: &pb::DirectionProfile) -> Result<DirectionProfile, FieldError> {
    let delay = distribution_from_pb("delay", p.delay.as_ref())?;
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

impl From<&Distribution> for pb::DelayDistribution {
    fn from(d: &Distribution) -> Self {
        let kind = match d {
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
            Distribution::LognormalMoments { mean_s, std_s } => {
                Kind::LognormalMoments(pb::LognormalMomentsDelay { mean_s: *mean_s, std_s: *std_s })
            }
            Distribution::Pareto { scale_s, shape } => {
                Kind::Pareto(pb::ParetoDelay { scale_s: *scale_s, shape: *shape })
            }
            Distribution::Trace(t) => Kind::Trace(pb::TraceDelay {
                delays_s: t.delays_s.to_vec(),
                looping: t.end == TraceEnd::Loop,
                stop_at_end: t.end == TraceEnd::Stop,
                name: t.name.to_string(),
            }),
            Distribution::Regime { states } => Kind::Regime(pb::RegimeDelay {
                states: states
                    .iter()
                    .map(|s| pb::RegimeState {
                        delay: Some((&s.delay).into()),
                        mean_dwell: Some(match s.mean_dwell {
                            Dwell::Messages(m) => pb::regime_state::MeanDwell::MeanDwellMessages(m),
                            Dwell::Seconds(t) => pb::regime_state::MeanDwell::MeanDwellS(t),
                        }),
                        loss_probability: s.loss_probability,
                    })
                    .collect(),
            }),
        };
        pb::DelayDistribution { kind: Some(kind) }
    }
}

impl From<&DirectionProfile> for pb::DirectionProfile {
    fn from(p: &DirectionProfile) -> Self {
        pb::DirectionProfile {
            delay: Some((&p.delay).into()),
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

/// What netem's shell counts of one direction beside the delay line's statistics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct HeldCounts {
    /// Copies netem holds right now (in the release queue or a stream's buffer).
    pub in_flight: u64,
    /// Copies evicted from a state stream's full buffer (also counted in `dropped`).
    pub stream_overflow_dropped: u64,
    /// Commands refused as invalid before they were delayed.
    pub refused_invalid: u64,
}

/// The statistics of one direction, with what netem's shell counts of it.
pub fn stats_to_pb(s: &DirectionStats, held: HeldCounts) -> pb::DirectionStats {
    let secs = delay::ns_to_s;
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
        in_flight: held.in_flight,
        release_error_max_s: secs(e.max_ns),
        stream_overflow_dropped: held.stream_overflow_dropped,
        refused_invalid: held.refused_invalid,
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
    super::check_input(&format!("{field}.input"), input)?;
    Ok(())
}

/// What a stamp in a unary Plant answer is about (`netem.proto`'s header): the command of
/// `ApplyCommand`/`Step` (`netem-command-*`) or the sample answered (`netem-sample-*`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stamped {
    Command,
    Sample,
}

impl Stamped {
    /// The metadata keys of [`Stamp`]'s fields, in its order: seq, send time, release time,
    /// delay, outcome.
    fn keys(self) -> [&'static str; 5] {
        match self {
            Stamped::Command => [
                "netem-command-seq",
                "netem-command-send-time-ns",
                "netem-command-release-time-ns",
                "netem-command-delay-ns",
                "netem-command-outcome",
            ],
            Stamped::Sample => [
                "netem-sample-seq",
                "netem-sample-send-time-ns",
                "netem-sample-release-time-ns",
                "netem-sample-delay-ns",
                "netem-sample-outcome",
            ],
        }
    }
}

/// What netem did with a message it stamped, as the `-outcome` key spells it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StampOutcome {
    /// Released upstream (a command) or to the controller (a sample).
    Delivered,
    /// Held: released later, after the answer (a command in real time or lockstep's `Step`).
    InFlight,
    Dropped,
}

impl StampOutcome {
    pub fn name(self) -> &'static str {
        match self {
            StampOutcome::Delivered => "delivered",
            StampOutcome::InFlight => "in-flight",
            StampOutcome::Dropped => "dropped",
        }
    }
}

/// netem's stamps of one message in a unary answer's metadata: the one writer (netem) and
/// reader (the controller, the tests) of the `netem-command-*` and `netem-sample-*` keys.
/// Times are ns on netem's clock (`netem-clock`: plant time in lockstep, netem's own in real
/// time).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stamp {
    /// netem's number of the message in its direction (a trace record's `message_seq`).
    pub seq: u64,
    pub send_time_ns: u64,
    pub release_time_ns: u64,
    /// `release_time_ns - send_time_ns` (0 when released at once).
    pub delay_ns: u64,
    pub outcome: StampOutcome,
}

impl Stamp {
    /// The stamp of a message sent at `send_time_ns` and released at `release_time_ns`.
    pub fn new(seq: u64, send_time_ns: u64, release_time_ns: u64, outcome: StampOutcome) -> Self {
        let delay_ns = release_time_ns.saturating_sub(send_time_ns);
        Self { seq, send_time_ns, release_time_ns, delay_ns, outcome }
    }

    /// Writes the stamp under `stamped`'s keys.
    pub fn write(&self, md: &mut tonic::metadata::MetadataMap, stamped: Stamped) {
        let [seq, send, release, delay, outcome] = stamped.keys();
        for (key, value) in [
            (seq, self.seq),
            (send, self.send_time_ns),
            (release, self.release_time_ns),
            (delay, self.delay_ns),
        ] {
            md.insert(key, value.into());
        }
        md.insert(outcome, tonic::metadata::MetadataValue::from_static(self.outcome.name()));
    }

    /// The stamp under `stamped`'s keys; `Ok(None)` when there is none (no netem on the link),
    /// an error naming the key when one is missing or does not parse.
    pub fn read(md: &tonic::metadata::MetadataMap, stamped: Stamped) -> Result<Option<Self>, FieldError> {
        let [seq, send, release, delay, outcome] = stamped.keys();
        let text = |key: &str| -> Result<&str, FieldError> {
            let value = md.get(key).ok_or_else(|| FieldError::new(key, "is missing"))?;
            value.to_str().map_err(|_| FieldError::new(key, "is not text"))
        };
        let number = |key: &str| -> Result<u64, FieldError> {
            let t = text(key)?;
            t.parse().map_err(|_| FieldError::new(key, format!("{t:?} is not a number of ns")))
        };
        if md.get(outcome).is_none() {
            return Ok(None);
        }
        let outcome = match text(outcome)? {
            "delivered" => StampOutcome::Delivered,
            "in-flight" => StampOutcome::InFlight,
            "dropped" => StampOutcome::Dropped,
            other => return Err(FieldError::new(outcome, format!("unknown outcome {other:?}"))),
        };
        Ok(Some(Self {
            seq: number(seq)?,
            send_time_ns: number(send)?,
            release_time_ns: number(release)?,
            delay_ns: number(delay)?,
            outcome,
        }))
    }
}

/// The `netem-clock` key: whose clock a stamp's times are on, `plant` (lockstep: plant time)
/// or `netem` (real time: ns since netem started).
pub const CLOCK_KEY: &str = "netem-clock";

/// Writes [`CLOCK_KEY`] for a netem in `mode`.
pub fn write_clock(md: &mut tonic::metadata::MetadataMap, mode: mav::TimeMode) {
    let clock = match mode {
        mav::TimeMode::Lockstep => "plant",
        mav::TimeMode::RealTime => "netem",
    };
    md.insert(CLOCK_KEY, tonic::metadata::MetadataValue::from_static(clock));
}

/// The time mode of the netem whose answer carries `md` ([`CLOCK_KEY`]); `None` without it.
pub fn read_clock(md: &tonic::metadata::MetadataMap) -> Option<mav::TimeMode> {
    match md.get(CLOCK_KEY)?.to_str().ok()? {
        "plant" => Some(mav::TimeMode::Lockstep),
        "netem" => Some(mav::TimeMode::RealTime),
        _ => None,
    }
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

    #[test]
    fn every_kind_round_trips_and_a_bad_regime_state_is_named() -> Result<(), FieldError> {
        let state = RegimeState::new;
        let kinds = [
            Distribution::LognormalMoments { mean_s: 0.1, std_s: 0.05 },
            Distribution::Trace(Trace::holding(vec![0.1, 0.2])),
            Distribution::Trace(Trace::looping(vec![0.1])),
            Distribution::Trace(Trace::from_file("wifi.csv", vec![0.3], false)),
            Distribution::Regime {
                states: Arc::from(vec![
                    state(Distribution::Gamma { shape: 2.0, scale_s: 0.01 }, Dwell::Messages(10.0)),
                    state(Distribution::Uniform { min_s: 0.1, max_s: 0.3 }, Dwell::Seconds(2.5)),
                    RegimeState {
                        loss_probability: Some(0.08),
                        ..state(Distribution::Constant { delay_s: 0.4 }, Dwell::Messages(3.0))
                    },
                ]),
            },
        ];
        for delay in kinds {
            let p = DirectionProfile::with_delay(delay, 3);
            assert_eq!(profile_from_pb(&pb::DirectionProfile::from(&p))?, p);
        }
        let bad = DirectionProfile::with_delay(
            Distribution::Regime {
                states: Arc::from(vec![state(Distribution::Constant { delay_s: -1.0 }, Dwell::Seconds(1.0))]),
            },
            3,
        );
        let mut m = pb::DirectionProfile::from(&bad);
        assert_eq!(
            profile_from_pb(&m).map_err(|e| e.field),
            Err("delay.regime.states[0].delay.constant.delay_s".into())
        );
        if let Some(Kind::Regime(r)) = m.delay.as_mut().and_then(|d| d.kind.as_mut()) {
            r.states[0].mean_dwell = None;
        }
        assert_eq!(profile_from_pb(&m).map_err(|e| e.field), Err("delay.regime.states[0].mean_dwell".into()));
        let mut lossy = pb::DirectionProfile::from(&DirectionProfile::with_delay(
            Distribution::Regime {
                states: Arc::from(vec![state(Distribution::Constant { delay_s: 0.1 }, Dwell::Seconds(1.0))]),
            },
            3,
        ));
        if let Some(Kind::Regime(r)) = lossy.delay.as_mut().and_then(|d| d.kind.as_mut()) {
            r.states[0].loss_probability = Some(1.5);
        }
        assert_eq!(
            profile_from_pb(&lossy).map_err(|e| e.field),
            Err("delay.regime.states[0].loss_probability".into())
        );
        Ok(())
    }

    #[test]
    fn stamps_read_back_as_written_under_their_own_keys_and_a_bad_one_is_named() {
        let mut md = tonic::metadata::MetadataMap::new();
        assert_eq!(Stamp::read(&md, Stamped::Command), Ok(None));
        let command = Stamp::new(7, 1_000, 31_000, StampOutcome::InFlight);
        let sample = Stamp::new(9, 2_000, 2_000, StampOutcome::Delivered);
        command.write(&mut md, Stamped::Command);
        sample.write(&mut md, Stamped::Sample);
        write_clock(&mut md, mav::TimeMode::Lockstep);
        assert_eq!(command.delay_ns, 30_000);
        assert_eq!(Stamp::read(&md, Stamped::Command), Ok(Some(command)));
        assert_eq!(Stamp::read(&md, Stamped::Sample), Ok(Some(sample)));
        assert_eq!(read_clock(&md), Some(mav::TimeMode::Lockstep));
        assert_eq!(md.get("netem-command-delay-ns").and_then(|v| v.to_str().ok()), Some("30000"));
        assert_eq!(md.get("netem-command-outcome").and_then(|v| v.to_str().ok()), Some("in-flight"));
        md.insert("netem-command-send-time-ns", tonic::metadata::MetadataValue::from_static("soon"));
        let e = Stamp::read(&md, Stamped::Command).expect_err("refused");
        assert_eq!(e.field, "netem-command-send-time-ns");
        md.remove("netem-sample-seq");
        assert_eq!(Stamp::read(&md, Stamped::Sample).map_err(|e| e.field), Err("netem-sample-seq".into()));
    }
}
