//! The delay line of one direction: send times in, release decisions out.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution as _, Gamma, LogNormal, Normal, Pareto, Uniform};

use crate::delay_ns;
use crate::profile::{Direction, DirectionProfile, Distribution, Dwell, Ordering, ProfileError};
use crate::trace::{Trace, TraceEnd, TraceEnded};

/// A ready-to-draw form of a [`Distribution`], built once when the profile is set.
#[derive(Debug, Clone)]
enum Sampler {
    Constant(f64),
    Uniform(Uniform<f64>),
    Normal(Normal<f64>),
    Gamma(Gamma<f64>),
    Lognormal(LogNormal<f64>),
    Pareto(Pareto<f64>),
    Trace { trace: Trace, next: usize },
    Regime(Box<RegimeSampler>),
}

/// The state of a regime process: its states' samplers, the current one, and when a state
/// of [`Dwell::Seconds`] ends.
#[derive(Debug, Clone)]
struct RegimeSampler {
    states: Vec<(Sampler, Dwell)>,
    /// Each state's own loss probability, if it has one.
    losses: Vec<Option<f64>>,
    current: usize,
    /// The state the latest message was sent in (its loss is that state's).
    sent_in: usize,
    /// End of the current state's dwell, ns, for a state of [`Dwell::Seconds`] once entered
    /// at a known time (`None` before the first message).
    until_ns: Option<u64>,
}

impl RegimeSampler {
    /// Moves to another state, uniformly among the others, entered at `time_ns`.
    fn switch(&mut self, time_ns: u64, rng: &mut ChaCha8Rng) {
        let n = self.states.len();
        if n < 2 {
            return;
        }
        let k = rng.random_range(0..n - 1);
        self.current = if k >= self.current { k + 1 } else { k };
        self.until_ns = self.dwell_end(time_ns, rng);
    }

    /// When the current state, entered at `time_ns`, ends (`None` for a state of messages).
    fn dwell_end(&self, time_ns: u64, rng: &mut ChaCha8Rng) -> Option<u64> {
        if self.states.len() < 2 {
            return None;
        }
        match self.states[self.current].1 {
            Dwell::Messages(_) => None,
            Dwell::Seconds(mean_s) => {
                // Inverse transform of Exp(1) on (0, 1]: never infinite.
                let u: f64 = 1.0 - rng.random::<f64>();
                Some(time_ns.saturating_add(delay_ns(-u.ln() * mean_s).max(1)))
            }
        }
    }

    /// The state of a message sent at `time_ns`; then its delay from `delay_rng`; then, for a
    /// state of messages, whether the process leaves it after this message.
    fn sample(&mut self, time_ns: u64, delay_rng: &mut ChaCha8Rng, regime_rng: &mut ChaCha8Rng) -> f64 {
        if self.until_ns.is_none() {
            self.until_ns = self.dwell_end(time_ns, regime_rng);
        }
        // Seconds states that ended by now are left at their end times (a continuous-time
        // chain observed at this send time); a state of messages stops the walk.
        while let Some(end) = self.until_ns.filter(|end| *end <= time_ns) {
            self.switch(end, regime_rng);
        }
        self.sent_in = self.current;
        let (sampler, dwell) = &mut self.states[self.current];
        let delay_s = sampler.sample(time_ns, delay_rng, regime_rng).unwrap_or(0.0);
        if let Dwell::Messages(mean) = *dwell
            && regime_rng.random::<f64>() < 1.0 / mean
        {
            self.switch(time_ns, regime_rng);
        }
        delay_s
    }
}

impl Sampler {
    /// Builds the sampler of a distribution that passed [`Distribution::validate`].
    fn new(d: &Distribution) -> Result<Self, ProfileError> {
        fn bad(field: &str, e: impl std::fmt::Display) -> ProfileError {
            ProfileError::new(field, e.to_string())
        }
        Ok(match d {
            Distribution::Constant { delay_s } => Sampler::Constant(*delay_s),
            Distribution::Uniform { min_s, max_s } => {
                Sampler::Uniform(Uniform::new_inclusive(*min_s, *max_s).map_err(|e| bad("delay.uniform", e))?)
            }
            Distribution::Normal { mean_s, std_s } => {
                Sampler::Normal(Normal::new(*mean_s, *std_s).map_err(|e| bad("delay.normal", e))?)
            }
            Distribution::Gamma { shape, scale_s } => {
                Sampler::Gamma(Gamma::new(*shape, *scale_s).map_err(|e| bad("delay.gamma", e))?)
            }
            Distribution::GammaMoments { mean_s, std_s } => {
                let (shape, scale) = Distribution::gamma_from_moments(*mean_s, *std_s);
                Sampler::Gamma(Gamma::new(shape, scale).map_err(|e| bad("delay.gamma_moments", e))?)
            }
            Distribution::Lognormal { mu, sigma } => {
                Sampler::Lognormal(LogNormal::new(*mu, *sigma).map_err(|e| bad("delay.lognormal", e))?)
            }
            Distribution::LognormalMoments { mean_s, std_s } => {
                let (mu, sigma) = Distribution::lognormal_from_moments(*mean_s, *std_s);
                Sampler::Lognormal(LogNormal::new(mu, sigma).map_err(|e| bad("delay.lognormal_moments", e))?)
            }
            Distribution::Pareto { scale_s, shape } => {
                Sampler::Pareto(Pareto::new(*scale_s, *shape).map_err(|e| bad("delay.pareto", e))?)
            }
            Distribution::Trace(trace) => Sampler::Trace { trace: trace.clone(), next: 0 },
            Distribution::Regime { states } => Sampler::Regime(Box::new(RegimeSampler {
                losses: states.iter().map(|s| s.loss_probability).collect(),
                sent_in: 0,
                states: states.iter().map(|s| Ok((Sampler::new(&s.delay)?, s.mean_dwell))).collect::<Result<
                    _,
                    ProfileError,
                >>(
                )?,
                current: 0,
                until_ns: None,
            })),
        })
    }

    /// The delay of a message sent at `time_ns`, s; `None` past the end of a trace that
    /// stops there.
    fn sample(&mut self, time_ns: u64, rng: &mut ChaCha8Rng, regime_rng: &mut ChaCha8Rng) -> Option<f64> {
        Some(match self {
            Sampler::Constant(d) => *d,
            Sampler::Uniform(u) => u.sample(rng),
            Sampler::Normal(n) => {
                // Truncation at zero by rejection: validation keeps the mean >= 0, so at least
                // half of the draws are accepted. A zero std never draws a negative value.
                loop {
                    let d = n.sample(rng);
                    if d >= 0.0 {
                        break d;
                    }
                }
            }
            Sampler::Gamma(g) => g.sample(rng),
            Sampler::Lognormal(l) => l.sample(rng),
            Sampler::Pareto(p) => p.sample(rng),
            Sampler::Trace { trace, next } => {
                let d = trace.delay_of(*next);
                *next = next.saturating_add(1);
                return d;
            }
            Sampler::Regime(r) => r.sample(time_ns, rng, regime_rng),
        })
    }

    /// The loss probability of the latest message sampled, when it is its regime state's own
    /// (`None`: the direction's).
    fn state_loss(&self) -> Option<f64> {
        match self {
            Sampler::Regime(r) => r.losses[r.sent_in],
            _ => None,
        }
    }

    /// The trace has no delay for the next message.
    fn ended(&self) -> Option<TraceEnded> {
        match self {
            Sampler::Trace { trace, next } if trace.delay_of(*next).is_none() => Some(TraceEnded {
                name: trace.name.to_string(),
                delays: trace.delays_s.len(),
                message: *next as u64,
            }),
            _ => None,
        }
    }

    fn exhausted(&self) -> bool {
        matches!(self, Sampler::Trace { trace, next } if trace.end != TraceEnd::Loop && *next >= trace.delays_s.len())
    }
}

/// The random part of a decision, before any scheduling.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Draw {
    pub seq: u64,
    /// NaN when the trace ended or records this message as lost.
    pub sampled_delay_s: f64,
    /// Lost on the way (the loss probability, or a trace's `lost` entry), or no delay left in
    /// a trace that stops at its end (`trace_ended`).
    pub lost: bool,
    pub duplicated: bool,
    /// The line's trace ([`TraceEnd::Stop`]) had no delay for this message: it is lost, and the
    /// run must stop ([`DelayLine::check_next`] says so before the message is sent).
    pub trace_ended: bool,
}

/// One copy of a message and when it leaves the line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Release {
    /// When the copy is released, ns (same clock as the send time).
    pub release_time_ns: u64,
    /// The delay actually injected, `release_time_ns - send_time_ns` (FIFO queueing included).
    pub delay_ns: u64,
    /// The delay drawn for this copy, s (before FIFO queueing and rounding to ns).
    pub sampled_delay_s: f64,
    /// This copy is the duplicate.
    pub duplicate: bool,
}

/// What happens to a message.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Fate {
    /// Lost on the way.
    Dropped,
    /// Delivered at `original.release_time_ns`, and a second time if `duplicate` is set.
    Delivered { original: Release, duplicate: Option<Release> },
}

/// The decision for one message.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decision {
    /// Number of the message on this line since the last reset (0, 1, 2, ...).
    pub seq: u64,
    pub send_time_ns: u64,
    /// The delay drawn for the message, s. It is drawn even for a lost message, so the delay of
    /// message `k` does not depend on the loss or duplicate probability. NaN when the trace
    /// ended or records the message as lost (a trace's loss is a [`Fate::Dropped`], counted
    /// as any loss).
    pub sampled_delay_s: f64,
    pub fate: Fate,
    /// Dropped because the line's trace has no delay left for it ([`TraceEnd::Stop`]).
    pub trace_ended: bool,
}

impl Decision {
    /// The copies to deliver, original first.
    pub fn releases(&self) -> impl Iterator<Item = Release> + '_ {
        let (a, b) = match self.fate {
            Fate::Dropped => (None, None),
            Fate::Delivered { original, duplicate } => (Some(original), duplicate),
        };
        a.into_iter().chain(b)
    }
}

/// The independent random streams of a line. Giving delay, loss, duplication, the
/// duplicate's delay and a regime's state changes their own streams means that changing a
/// probability never shifts the delays drawn for the other messages.
#[derive(Debug, Clone)]
struct Streams {
    delay: ChaCha8Rng,
    loss: ChaCha8Rng,
    duplicate: ChaCha8Rng,
    duplicate_delay: ChaCha8Rng,
    regime: ChaCha8Rng,
}

impl Streams {
    fn new(seed: u64, direction: Direction) -> Self {
        let stream = |id: u64| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(id);
            rng
        };
        let d = direction.index() as u64;
        // Streams 0..8 are the first four of each direction (as numbered since the first
        // recorded runs); later streams go after them, so that those runs stay as they were.
        Self {
            delay: stream(d * 4),
            loss: stream(d * 4 + 1),
            duplicate: stream(d * 4 + 2),
            duplicate_delay: stream(d * 4 + 3),
            regime: stream(8 + d),
        }
    }
}

/// The delay line of one direction: seeded, pure, and cheap to drive.
///
/// Feed it the send time of every message in order with [`DelayLine::send`]; it answers with
/// the message's [`Decision`]. The line only remembers what FIFO ordering needs (the last
/// release time); holding the messages is the caller's job (see [`crate::ReleaseQueue`]).
#[derive(Debug, Clone)]
pub struct DelayLine {
    direction: Direction,
    profile: DirectionProfile,
    sampler: Sampler,
    streams: Streams,
    last_release_ns: Option<u64>,
    next_seq: u64,
    /// Send time of the latest message (the regime clock of [`DelayLine::sample_delay_s`]).
    last_send_ns: u64,
}

impl DelayLine {
    /// A line for `direction` with a validated `profile`.
    pub fn new(direction: Direction, profile: DirectionProfile) -> Result<Self, ProfileError> {
        profile.validate()?;
        let sampler = Sampler::new(&profile.delay)?;
        let streams = Streams::new(profile.seed, direction);
        Ok(Self { direction, profile, sampler, streams, last_release_ns: None, next_seq: 0, last_send_ns: 0 })
    }

    pub fn direction(&self) -> Direction {
        self.direction
    }

    pub fn profile(&self) -> &DirectionProfile {
        &self.profile
    }

    /// Replaces the profile at run time. An invalid profile is refused and changes nothing.
    /// A valid one restarts the generators from its seed (so what follows is reproducible from
    /// the moment of the change) and keeps the FIFO state and the message numbering, so
    /// messages already in flight keep their release times and are never overtaken under FIFO.
    pub fn set_profile(&mut self, profile: DirectionProfile) -> Result<(), ProfileError> {
        profile.validate()?;
        let sampler = Sampler::new(&profile.delay)?;
        self.streams = Streams::new(profile.seed, self.direction);
        self.sampler = sampler;
        self.profile = profile;
        Ok(())
    }

    /// Back to the state of a new line with the same profile: generators restarted from the
    /// seed, message numbering from 0, no FIFO history.
    pub fn reset(&mut self) {
        // The profile was valid when it was set, so rebuilding its sampler cannot fail; keep
        // the old sampler (rewound) if it somehow did.
        if let Ok(s) = Sampler::new(&self.profile.delay) {
            self.sampler = s;
        }
        self.streams = Streams::new(self.profile.seed, self.direction);
        self.last_release_ns = None;
        self.next_seq = 0;
        self.last_send_ns = 0;
    }

    /// A non-looping trace has been used up: it now holds its last delay
    /// ([`TraceEnd::Hold`]) or has none left ([`TraceEnd::Stop`]).
    pub fn trace_exhausted(&self) -> bool {
        self.sampler.exhausted()
    }

    /// Whether the next message gets a delay: `Err` when the line replays a trace that stops
    /// at its end and has none left. A caller that must not drop such a message (the run
    /// stops instead) asks before sending it.
    pub fn check_next(&self) -> Result<(), TraceEnded> {
        self.sampler.ended().map_or(Ok(()), Err)
    }

    /// The latest release time handed out (what FIFO queues behind).
    pub fn last_release_ns(&self) -> Option<u64> {
        self.last_release_ns
    }

    /// Draws one delay, s, from the delay stream (what [`DelayLine::send`] does for each
    /// message), at the time of the latest message; NaN past the end of a trace that stops
    /// there and for a message a trace records as lost. Exposed for benchmarks and
    /// statistical tests.
    pub fn sample_delay_s(&mut self) -> f64 {
        self.sample_delay_at(self.last_send_ns)
    }

    /// [`DelayLine::sample_delay_s`] for a message sent at `time_ns` (a regime's clock).
    pub fn sample_delay_at(&mut self, time_ns: u64) -> f64 {
        self.last_send_ns = time_ns;
        match self.sampler.sample(time_ns, &mut self.streams.delay, &mut self.streams.regime) {
            Some(d) if !crate::trace::is_lost(d) => d,
            _ => f64::NAN,
        }
    }

    fn release(&mut self, send_time_ns: u64, sampled_delay_s: f64, duplicate: bool) -> Release {
        let own = send_time_ns.saturating_add(delay_ns(sampled_delay_s));
        let release_time_ns = match (self.profile.ordering, self.last_release_ns) {
            (Ordering::Fifo, Some(prev)) => own.max(prev),
            _ => own,
        };
        self.last_release_ns = Some(self.last_release_ns.map_or(release_time_ns, |p| p.max(release_time_ns)));
        Release { release_time_ns, delay_ns: release_time_ns - send_time_ns, sampled_delay_s, duplicate }
    }

    /// Draws what happens to a message sent at `time_ns` without scheduling it (no FIFO state
    /// is used or changed). [`DelayLine::send`] is `draw` plus scheduling; a shell that maps
    /// delays to times its own way (netem's lockstep samples) uses `draw` directly.
    pub fn draw(&mut self, time_ns: u64) -> Draw {
        let seq = self.next_seq;
        self.next_seq += 1;
        self.last_send_ns = time_ns;
        let sampled = self.sampler.sample(time_ns, &mut self.streams.delay, &mut self.streams.regime);
        // One draw per message on each of the loss and duplicate streams, always, so that the
        // streams stay aligned with the message numbers whatever the probabilities are.
        let loss_probability = self.sampler.state_loss().unwrap_or(self.profile.loss_probability);
        let lost = self.streams.loss.random::<f64>() < loss_probability;
        let duplicated = self.streams.duplicate.random::<f64>() < self.profile.duplicate_probability;
        match sampled {
            // A message the trace records as lost is lost here too, whatever the loss stream
            // says: it has no delay.
            Some(d) if crate::trace::is_lost(d) => {
                Draw { seq, sampled_delay_s: f64::NAN, lost: true, duplicated: false, trace_ended: false }
            }
            Some(sampled_delay_s) => Draw { seq, sampled_delay_s, lost, duplicated, trace_ended: false },
            None => Draw { seq, sampled_delay_s: f64::NAN, lost: true, duplicated: false, trace_ended: true },
        }
    }

    /// Decides the fate of a message sent at `send_time_ns`.
    pub fn send(&mut self, send_time_ns: u64) -> Decision {
        let Draw { seq, sampled_delay_s, lost, duplicated, trace_ended } = self.draw(send_time_ns);
        let fate = if lost {
            Fate::Dropped
        } else {
            let original = self.release(send_time_ns, sampled_delay_s, false);
            let duplicate = duplicated.then(|| {
                let d = self.sampler_for_duplicate();
                self.release(send_time_ns, d, true)
            });
            Fate::Delivered { original, duplicate }
        };
        Decision { seq, send_time_ns, sampled_delay_s, fate, trace_ended }
    }

    /// The duplicate's delay: drawn from its own stream (a regime's from its current state,
    /// which the duplicate does not move); a trace replays the original's delay.
    fn sampler_for_duplicate(&mut self) -> f64 {
        let time_ns = self.last_send_ns;
        match &self.sampler {
            Sampler::Trace { trace, next } => trace.delay_of(next.saturating_sub(1)).unwrap_or(0.0),
            Sampler::Regime(r) => {
                let mut s = r.states[r.current].0.clone();
                s.sample(time_ns, &mut self.streams.duplicate_delay, &mut self.streams.regime.clone())
                    .unwrap_or(0.0)
            }
            _ => {
                let mut s = self.sampler.clone();
                s.sample(time_ns, &mut self.streams.duplicate_delay, &mut self.streams.regime.clone())
                    .unwrap_or(0.0)
            }
        }
    }
}

#[cfg(test)]
mod tests;
