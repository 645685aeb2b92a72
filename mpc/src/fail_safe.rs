//! The fail-safe check of one command under round-trip delays: the command the controller is
//! about to send, followed by braking from the next cycle on, flown on the continuous model
//! (RK4) for every delay the command and the brakes can meet.
//!
//! Why this and not the plan's own predictions: only the first input of a plan is ever
//! applied, and it is applied for a span the controller does not know. It lands after the
//! round-trip delay `d in [0, D]` (until then the previous command stays on) and stays on
//! until the next command lands, at `max(T, d) + d'`. The prediction model knows neither: its
//! scenarios hold every input for their own sampling time (0.05-0.33 s, Euler), so a plan that
//! keeps its clearance in every scenario does not make the plan shifted one cycle later keep
//! it (measured on paper-2 with full-range uniform delays: shifted plans of accepted plans
//! came out 0.1-0.4 m inside a cylinder one cycle later), and the layer ran out of candidates
//! that pass a few cycles before the cylinder. Checking a command together with a way out
//! (braking) under every delay gives a recursive argument: if this cycle's command passed,
//! then next cycle braking passes too (its check is this one's continuation), so some command
//! that passes always exists. Up to two things: the delays are sampled (the ends of the range
//! and points between), and a flight here keeps one delay for all braking commands while the
//! next cycle's check varies the later ones again, so the argument is approximate (measured:
//! 14 cycles without a passing candidate in the 120 runs of the survey; the plant kept at
//! least 4 cm of clearance).
//! The model is the plant's (the same dynamics, RK4), so model error is not the gap.
//!
//! Two timings. [`FailSafe::envelope`] is the bench's lockstep protocol (`docs/spec.md`): the next
//! sample is taken when this cycle's command has landed, `max(T, d)` later, so one command is
//! in flight at a time. [`FailSafe::envelope_real_time`] is real time: the controller samples
//! every `T` whatever the delay, so commands sent before this cycle's may still be in flight
//! ([`InFlight`]); they land first (the link is first in, first out), then this cycle's, then
//! a braking command computed at every later sample.

use std::cell::RefCell;
use std::collections::VecDeque;

use mav::{Cylinder, InputBounds, MavModel, ModelParams, Scenario, State, rk4_step};

use crate::command::{DEFAULT_BRAKE_GAIN_PER_S, braking_command};
use crate::error::MpcError;

/// The longest round-trip delay the fail-safe check widens its range to, s: beyond it a link
/// is down rather than slow (the plant's watchdog takes over).
pub const MAX_COVERED_DELAY_S: f64 = 3.0;

/// Most braking cycles one flight of the check flies: a backstop that no setting or scenario
/// can get past, however short its cycle (a `min_cycle_s` of 1e-300 made `t + min_cycle_s ==
/// t`, and the loop spun for ever). Validated settings never reach it: `horizon_s` at most
/// [`MAX_HORIZON_S`] over cycles of at least `mav::MIN_CYCLE_S` is 60,000 cycles.
pub const MAX_BRAKING_CYCLES: usize = 100_000;
/// Longest `horizon_s` of the check, s.
pub const MAX_HORIZON_S: f64 = 60.0;

/// [`BrakingCheck::plan_coast_s`]'s default, s: a coast of 0.96 s over the tree's 0.33 s range.
/// Measured (`scripts/bench-lost-time.sh`, docs/robustness.md "Where the time goes"): 0.3
/// to 0.8 and fixed coasts of 0.5 to 2 s all kept the survey and the paper-2 field free of
/// collisions and cut the lost time, within a few per cent of each other (the closed loops
/// are chaotic: nearby settings fly other paths); this one was among the best on both.
pub const DEFAULT_PLAN_COAST_S: Option<f64> = Some(0.3);

/// Settings of the fail-safe check (validated with the safety layer's settings).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BrakingCheck {
    /// Largest round-trip delay the check covers, s: the command may land anywhere in
    /// `[0, max_delay_s]` after the sample it came from.
    pub max_delay_s: f64,
    /// Shortest cycle, s: the next sample is `max(min_cycle_s, d)` after this one.
    pub min_cycle_s: f64,
    /// Delays sampled in `[0, max_delay_s]`, evenly, ends included (for this cycle's command
    /// and, independently, for the braking cycles after it): `delay_samples^2` flights
    /// (`(delay_samples + 1)^2` with the plant's watchdog).
    pub delay_samples: usize,
    /// How long braking is flown after the next sample, s.
    pub horizon_s: f64,
    /// Largest RK4 step, s (also the spacing of the points whose clearance is checked).
    pub step_s: f64,
    /// A flight stops early once the speed is below this, m/s (the vehicle hovers).
    pub stop_speed_mps: f64,
    /// The plant's watchdog, s: a command that has been on this long without a newer one
    /// landing gives way to the plant's own braking (`mav::WatchdogAction::Brake`, the default
    /// of the bench's plants) until the next lands. Then no command is held longer than this,
    /// whatever the delay, and the check covers every delay: the sampled delays up to
    /// `min(max_delay_s, plant_watchdog_s)` and one long delay ([`MAX_COVERED_DELAY_S`]) for
    /// every delay past the watchdog. `None`: the plant holds a command until the next one
    /// lands, and the check covers delays up to `max_delay_s` only.
    pub plant_watchdog_s: Option<f64>,
    /// The ground, m. The check judges what the vehicle will physically do, so a flight that
    /// goes below it fails even where the problem has no floor (paper mode); a floor, when
    /// there is one, is checked instead. A vehicle already lower may not sink further. `None`:
    /// no ground (only the floor, if any).
    pub ground_z_m: Option<f64>,
    /// The plans' side of the check, s: with it, the problem keeps each predicted point's
    /// straight coast clear of the inflated cylinders ([`crate::OcpDefinition::coast_time_s`])
    /// over [`BrakingCheck::plan_coast_time_s`], the longest time before a brake lands plus
    /// this, so that PANOC plans the room to stop that the check asks for (it grows with the
    /// speed toward a cylinder) instead of grazing the cylinders at full speed and being
    /// refused. `None`: the plans keep only their points clear.
    pub plan_coast_s: Option<f64>,
}

impl Default for BrakingCheck {
    fn default() -> Self {
        Self {
            max_delay_s: 0.33,
            min_cycle_s: 0.05,
            delay_samples: 3,
            horizon_s: 5.0,
            step_s: 0.02,
            stop_speed_mps: 0.005,
            plant_watchdog_s: Some(mav::ns_to_s(mav::DEFAULT_WATCHDOG_TIMEOUT_NS)),
            ground_z_m: Some(0.0),
            plan_coast_s: DEFAULT_PLAN_COAST_S,
        }
    }
}

impl BrakingCheck {
    /// The check over `scenario`'s delay range: delays up to its largest sampling time (the
    /// longest delay its scenario tree covers), cycles no shorter than its `min_cycle_s`.
    pub fn for_scenario(scenario: &Scenario) -> Self {
        Self {
            max_delay_s: scenario.sampling_times_s.iter().copied().fold(0.0, f64::max),
            min_cycle_s: scenario.min_cycle_s,
            ground_z_m: Some(scenario.ground_z_m),
            ..Self::default()
        }
    }

    /// Names the first invalid setting.
    pub fn validate(&self) -> Result<(), MpcError> {
        let bad = |field: &'static str, reason: &'static str| Err(MpcError::InvalidSetting { field, reason });
        if !(self.max_delay_s.is_finite() && self.max_delay_s >= 0.0) {
            return bad("braking_check.max_delay_s", "must be finite and >= 0");
        }
        if !(self.min_cycle_s.is_finite() && self.min_cycle_s >= mav::MIN_CYCLE_S) {
            return bad("braking_check.min_cycle_s", "must be finite and at least mav::MIN_CYCLE_S (1 ms)");
        }
        if self.delay_samples < 2 {
            return bad("braking_check.delay_samples", "must be >= 2 (both ends of the range)");
        }
        if !(self.horizon_s.is_finite() && self.horizon_s > 0.0 && self.horizon_s <= MAX_HORIZON_S) {
            return bad("braking_check.horizon_s", "must be finite, > 0 and at most MAX_HORIZON_S (60 s)");
        }
        if !(self.step_s.is_finite() && self.step_s > 0.0 && self.step_s <= self.horizon_s) {
            return bad("braking_check.step_s", "must be finite, > 0 and <= horizon_s");
        }
        if !(self.stop_speed_mps.is_finite() && self.stop_speed_mps >= 0.0) {
            return bad("braking_check.stop_speed_mps", "must be finite and >= 0");
        }
        if self.plant_watchdog_s.is_some_and(|w| !(w.is_finite() && w > 0.0)) {
            return bad("braking_check.plant_watchdog_s", "must be finite and > 0");
        }
        if self.ground_z_m.is_some_and(|z| !z.is_finite()) {
            return bad("braking_check.ground_z_m", "must be finite");
        }
        if self.plan_coast_s.is_some_and(|c| !(c.is_finite() && (0.0..=crate::MAX_COAST_TIME_S).contains(&c)))
        {
            return bad("braking_check.plan_coast_s", "must be finite and in [0, MAX_COAST_TIME_S] (5 s)");
        }
        Ok(())
    }

    /// The check over delays up to the larger of `base_max_delay_s` (the scenario tree's
    /// range) and `observed_max_s` (the longest delay measured lately), capped at
    /// [`MAX_COVERED_DELAY_S`]: a tail beyond the tree's largest sampling time is still a delay
    /// the next command may meet, and braking must hold for it too.
    pub fn covering(self, base_max_delay_s: f64, observed_max_s: Option<f64>) -> Self {
        let observed = observed_max_s.filter(|d| d.is_finite()).unwrap_or(0.0);
        Self { max_delay_s: base_max_delay_s.max(observed.min(MAX_COVERED_DELAY_S)), ..self }
    }

    /// The coast the plans keep clear ([`BrakingCheck::plan_coast_s`]), s: the longest time
    /// before a brake lands, twice the longest delay covered (the command lands after one, the
    /// brake computed at the next sample after another), at most twice the plant's watchdog
    /// (past it the plant brakes by itself), plus `plan_coast_s`; at most
    /// [`crate::MAX_COAST_TIME_S`]. 0 without `plan_coast_s`.
    pub fn plan_coast_time_s(&self) -> f64 {
        let Some(extra_s) = self.plan_coast_s else { return 0.0 };
        let delay_s = self.plant_watchdog_s.map_or(self.max_delay_s, |w| self.max_delay_s.min(w));
        (2.0 * delay_s + extra_s).clamp(0.0, crate::MAX_COAST_TIME_S)
    }

    /// The coast a problem in `formulation` keeps with this check: [`Self::plan_coast_time_s`]
    /// for the distance form, `None` without `plan_coast_s` or for the penalty form (it has no
    /// coast; the problem's own stays). The one rule the controller and `controller solve`
    /// follow.
    pub fn coast_for(&self, formulation: crate::ObstacleFormulation) -> Option<f64> {
        (self.plan_coast_s.is_some() && formulation == crate::ObstacleFormulation::DistanceAlm)
            .then(|| self.plan_coast_time_s())
    }

    /// The sampled delays, s: `delay_samples` evenly over `[0, max_delay_s]` (ends
    /// included), or with the plant's watchdog over `[0, min(max_delay_s, plant_watchdog_s)]`
    /// and then [`MAX_COVERED_DELAY_S`] for the delays past it (see
    /// [`BrakingCheck::plant_watchdog_s`]).
    fn delays(&self) -> impl Iterator<Item = f64> + '_ {
        let (even_s, long) = match self.plant_watchdog_s {
            Some(w) => (self.max_delay_s.min(w), Some(MAX_COVERED_DELAY_S.max(w))),
            None => (self.max_delay_s, None),
        };
        let n = self.delay_samples;
        (0..n).map(move |k| even_s * k as f64 / (n - 1) as f64).chain(long)
    }
}

/// The worst of all flights of one command.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Envelope {
    /// Smallest true clearance to any cylinder, m.
    pub min_clearance_m: f64,
    /// Lowest altitude, m.
    pub min_altitude_m: f64,
    /// False when a state became non-finite.
    pub finite: bool,
}

/// A command sent before this cycle's that had not landed when the cycle's state was sampled.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InFlight {
    /// How long before this cycle's sample it was sent (the age of the sample it came from),
    /// s. A negative or NaN value counts as 0 (sent at the sample), so a command in flight
    /// lands within the delay of the flight.
    pub sent_ago_s: f64,
    pub command: [f64; 3],
}

/// The model and obstacles the check flies in.
#[derive(Debug, Clone)]
pub struct FailSafe {
    pub check: BrakingCheck,
    model: MavModel,
    bounds: InputBounds,
    cylinders: Vec<Cylinder>,
    /// Gain of the braking law, 1/s.
    brake_gain_per_s: f64,
    /// Scratch of [`FailSafe::envelope_real_time`]: the braking commands computed but not
    /// landed yet (landing time, command), allocated here once.
    brakes: RefCell<VecDeque<(f64, [f64; 3])>>,
}

impl FailSafe {
    pub fn new(
        check: BrakingCheck,
        params: ModelParams,
        bounds: InputBounds,
        cylinders: Vec<Cylinder>,
        brake_gain_per_s: f64,
    ) -> Self {
        // About one braking command per cycle of the longest delay is in flight at a time
        // (more grow the queue).
        let longest_s = check.delays().fold(0.0, f64::max);
        let in_flight = (longest_s / check.min_cycle_s).ceil().min(256.0) as usize + 2;
        Self {
            check,
            model: MavModel::new(params),
            bounds,
            cylinders,
            brake_gain_per_s,
            brakes: RefCell::new(VecDeque::with_capacity(in_flight)),
        }
    }

    /// Flies `u_prev` for the delay `d`, then `command` until the next command lands at
    /// `max(T, d) + d'`, then the braking law sampled every `max(T, d')` and landing `d'`
    /// after its sample, for every sampled pair `(d, d')`; returns the worst clearance and
    /// altitude over all of them. The flight up to the next sample, `max(T, d)`, is flown once
    /// per `d` ([`FailSafe::worst_over_delays`]).
    pub fn envelope(&self, x0: &[f64; 8], u_prev: &[f64; 3], command: &[f64; 3]) -> Envelope {
        self.worst_over_delays(
            x0,
            |d_s, out| self.lockstep_prefix(x0, u_prev, command, d_s, out),
            |fork, d_next_s, out| self.brake_lockstep(fork, d_next_s, out),
        )
    }

    /// The worst flight over every sampled pair of delays `(d, d')`, from `x0` on: `prefix(d)`
    /// flies up to where the flights of one `d` part (the next sample: the first braking
    /// command is computed there and `d'` only says when it lands) and returns that point,
    /// `branch(point, d')` flies each `d'` on from it.
    ///
    /// Why the prefix is shared: the check used to fly every pair whole, the prefix again for
    /// every `d'`, and with the plant's watchdog the long delay's prefix alone is 150 RK4
    /// steps (3 s at 20 ms), flown for each of the four `d'`. Flown once, the result is the
    /// pair-by-pair flight's to the bit: each branch starts from the same state, time and
    /// landing, and goes through the same steps in the same order; the prefix's states were
    /// observed into the running minimum when they were first flown, and observing them again
    /// (as the pair-by-pair flight did for every further `d'`) leaves a minimum that already
    /// holds them unchanged (by value; `f64::min` may return either of two equal zeros, so
    /// only an altitude of exactly -0 against +0 could differ in sign, and the property test
    /// flies both). The first non-finite state ends the check where it ended the
    /// pair-by-pair loop: after the prefix (whose flight did nothing more once a state was
    /// non-finite) or after the branch. `mpc/src/fail_safe/tests.rs` keeps the pair-by-pair
    /// flight and compares the two bit for bit.
    fn worst_over_delays<P>(
        &self,
        x0: &[f64; 8],
        mut prefix: impl FnMut(f64, &mut Envelope) -> P,
        mut branch: impl FnMut(&P, f64, &mut Envelope),
    ) -> Envelope {
        let mut out =
            Envelope { min_clearance_m: f64::INFINITY, min_altitude_m: f64::INFINITY, finite: true };
        self.observe(&State::from(*x0), &mut out);
        for d_s in self.check.delays() {
            let fork = prefix(d_s, &mut out);
            if !out.finite {
                return out;
            }
            for d_next_s in self.check.delays() {
                branch(&fork, d_next_s, &mut out);
                if !out.finite {
                    return out;
                }
            }
        }
        out
    }

    /// Real time: for every sampled pair `(d, d')`, `u_prev` until the first command in flight
    /// lands (`d` after it was sent, not before now), each in turn until the next lands, then
    /// `command` from `d`, and from the next sample on (every `T`) the braking law computed
    /// from the state at each sample (at a sample before `command` has landed, from the state
    /// where it lands: the flight is not stopped at a sample it has passed), landing `d'`
    /// later and never before the command sent before it. `in_flight` oldest first. The flight
    /// up to the first sample after the command has landed is flown once per `d`
    /// ([`FailSafe::worst_over_delays`]).
    pub fn envelope_real_time(
        &self,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        in_flight: &[InFlight],
        command: &[f64; 3],
    ) -> Envelope {
        let mut brakes = self.brakes.borrow_mut();
        self.worst_over_delays(
            x0,
            |d_s, out| self.real_time_prefix(x0, u_prev, in_flight, command, d_s, out),
            |fork, d_next_s, out| self.brake_real_time(fork, d_next_s, &mut brakes, out),
        )
    }

    /// Real time up to where the flights of one `d` part: the commands in flight and this
    /// cycle's land, then on to the first sample `T` (no braking command is on its way
    /// before it). Later the flights differ: the brake computed at the first sample lands `d'`
    /// after it (and, the link being first in, first out, no earlier than this cycle's
    /// command), and until it has, the next brakes only queue behind it.
    fn real_time_prefix(
        &self,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        in_flight: &[InFlight],
        command: &[f64; 3],
        d_s: f64,
        out: &mut Envelope,
    ) -> RealTimeFork {
        let period_s = self.check.min_cycle_s;
        let mut link = Link { x: State::from(*x0), t: 0.0, applied: *u_prev, landed_at: 0.0 };
        let mut landed_at_s = 0.0f64;
        // What was sent up to this cycle lands in order.
        // (`sent_ago_s` at least 0, so every one lands within `[0, d]`.)
        let sent = in_flight.iter().map(|f| ((d_s - f.sent_ago_s.max(0.0)).max(0.0), f.command));
        for (at, u) in sent.chain(std::iter::once((d_s, *command))) {
            landed_at_s = landed_at_s.max(at);
            self.run_until(&mut link, landed_at_s, out);
            link.land(u);
        }
        // The first event of every branch: the first sample (nothing is queued before it).
        // A non-finite state ends the check before it (see `worst_over_delays`).
        if out.finite {
            self.run_until(&mut link, period_s, out);
        }
        RealTimeFork { link, landed_at_s, end_s: period_s.max(d_s) + self.check.horizon_s }
    }

    /// Real time from the first sample on, every braking command `d_next_s` late (a brake can
    /// be computed at a sample before the command lands). At the fork the vehicle is already
    /// at the first sample or later, so the first event, that sample, flies nothing more and
    /// its brake comes from the fork's state, as in the pair-by-pair flight.
    fn brake_real_time(
        &self,
        fork: &RealTimeFork,
        d_next_s: f64,
        brakes: &mut VecDeque<(f64, [f64; 3])>,
        out: &mut Envelope,
    ) {
        let period_s = self.check.min_cycle_s;
        let (mut link, mut landed_at_s, end_s) = (fork.link, fork.landed_at_s, fork.end_s);
        brakes.clear();
        let mut next_sample_s = period_s;
        let mut cycles = 0;
        while out.finite && cycles < MAX_BRAKING_CYCLES {
            let landing_s = brakes.front().map(|(at, _)| *at).filter(|at| *at <= next_sample_s);
            let event_s = landing_s.unwrap_or(next_sample_s);
            if event_s > end_s {
                self.run_until(&mut link, end_s, out);
                return;
            }
            self.run_until(&mut link, event_s, out);
            if landing_s.is_some() {
                if let Some((_, u)) = brakes.pop_front() {
                    link.land(u);
                }
                if speed_mps(&link.x) < self.check.stop_speed_mps {
                    return;
                }
            } else {
                let brake =
                    braking_command(&self.model.params, &self.bounds, &link.x.into(), self.brake_gain_per_s);
                landed_at_s = landed_at_s.max(link.t + d_next_s);
                brakes.push_back((landed_at_s, brake));
                next_sample_s += period_s;
                cycles += 1;
            }
        }
    }

    /// Lockstep up to where the flights of one `d` part: `u_prev` until the command lands at
    /// `d`, then the command until the next sample at `max(T, d)`. Returns the vehicle there
    /// and the sample's time, s.
    fn lockstep_prefix(
        &self,
        x0: &[f64; 8],
        u_prev: &[f64; 3],
        command: &[f64; 3],
        d_s: f64,
        out: &mut Envelope,
    ) -> (Link, f64) {
        // The previous command landed at the sample at the latest (the lockstep protocol
        // samples when it lands): the latest landing holds it longest before a watchdog.
        let mut link = Link { x: State::from(*x0), t: 0.0, applied: *u_prev, landed_at: 0.0 };
        // Until the command lands, the previous one; then the command until the next sample.
        self.run_until(&mut link, d_s, out);
        link.land(*command);
        let sample_s = self.check.min_cycle_s.max(d_s);
        self.run_until(&mut link, sample_s, out);
        (link, sample_s)
    }

    /// Lockstep from the next sample on: the controller brakes, every command `d_next_s` late.
    fn brake_lockstep(&self, fork: &(Link, f64), d_next_s: f64, out: &mut Envelope) {
        let t_min_s = self.check.min_cycle_s;
        let (mut link, mut sample_s) = *fork;
        let end_s = sample_s + self.check.horizon_s;
        for _ in 0..MAX_BRAKING_CYCLES {
            if !(sample_s < end_s && out.finite) {
                break;
            }
            let brake =
                braking_command(&self.model.params, &self.bounds, &link.x.into(), self.brake_gain_per_s);
            self.run_until(&mut link, sample_s + d_next_s, out);
            link.land(brake);
            sample_s += t_min_s.max(d_next_s);
            self.run_until(&mut link, sample_s, out);
            if speed_mps(&link.x) < self.check.stop_speed_mps {
                break;
            }
        }
    }

    /// Flies the link's applied command on to time `t_s`; with the plant's braking watchdog
    /// ([`BrakingCheck::plant_watchdog_s`]), a command on for that long gives way to the
    /// plant's own braking, recomputed every `step_s`, until the next command lands.
    fn run_until(&self, link: &mut Link, t_s: f64, out: &mut Envelope) {
        if t_s <= link.t {
            return;
        }
        let fires_at = self.check.plant_watchdog_s.map_or(f64::INFINITY, |w| link.landed_at + w);
        if t_s <= fires_at {
            link.x = self.hold(link.x, &link.applied, t_s - link.t, out);
            link.t = t_s;
            return;
        }
        if fires_at > link.t {
            link.x = self.hold(link.x, &link.applied, fires_at - link.t, out);
            link.t = fires_at;
        }
        // The plant brakes with its own gain (mav's default), every `step_s`.
        while link.t < t_s && out.finite {
            let step = self.check.step_s.min(t_s - link.t);
            let brake =
                braking_command(&self.model.params, &self.bounds, &link.x.into(), DEFAULT_BRAKE_GAIN_PER_S);
            link.x = self.hold(link.x, &brake, step, out);
            link.t += step;
        }
    }

    /// Integrates `u` held for `duration_s` in equal RK4 steps no longer than `step_s`,
    /// watching every step's end.
    fn hold(&self, mut x: State, u: &[f64; 3], duration_s: f64, out: &mut Envelope) -> State {
        if duration_s <= 0.0 {
            return x;
        }
        let steps = (duration_s / self.check.step_s).ceil().max(1.0);
        let h = duration_s / steps;
        let u = mav::Input::from(*u);
        for _ in 0..steps as usize {
            x = rk4_step(&self.model, &x, &u, h);
            self.observe(&x, out);
        }
        x
    }

    fn observe(&self, x: &State, out: &mut Envelope) {
        if !x.iter().all(|v| v.is_finite()) {
            out.finite = false;
            return;
        }
        let (c, _) = mav::geometry::min_clearance(&self.cylinders, x[0], x[1], x[2]);
        out.min_clearance_m = out.min_clearance_m.min(c);
        out.min_altitude_m = out.min_altitude_m.min(x[2]);
    }
}

/// The vehicle in one flight of the check: its state at time `t` (s after the sample), the
/// command applied and when it landed. `Copy`: the flights of one `d` part from one `Link`.
#[derive(Clone, Copy)]
struct Link {
    x: State,
    t: f64,
    applied: [f64; 3],
    landed_at: f64,
}

impl Link {
    /// A command lands now.
    fn land(&mut self, u: [f64; 3]) {
        (self.applied, self.landed_at) = (u, self.t);
    }
}

/// Where the real-time flights of one `d` part: the vehicle at the first sample, when the
/// last command sent so far lands, s, and when the flights end, s.
struct RealTimeFork {
    link: Link,
    landed_at_s: f64,
    end_s: f64,
}

/// The speed of state `x`, m/s.
fn speed_mps(x: &State) -> f64 {
    (x[3] * x[3] + x[4] * x[4] + x[5] * x[5]).sqrt()
}

#[cfg(test)]
mod tests;
