//! netem's face to the controller: the `hilbench.v1.Plant` service, proxied to the upstream
//! plant with a delay per message and direction.
//!
//! ## Lockstep
//! The controller drives plant time with `Advance`/`Step`. A command sent with `ApplyCommand`
//! or `Step` at plant time `t` (the time of the newest sample) is held in the delay line and
//! applied upstream exactly at its release time `t + d`: netem advances the upstream plant
//! piecewise, `Advance(r1 - t)`, `Step(c1, r2 - r1)`, ..., `Step(cn, T - rn)`, up to the end
//! of the call; a `Step` applies its command, then advances (the plant's `ApplyCommand` then
//! `Advance`, in one round trip). A zero delay applies the command at once: an
//! `ApplyCommand`'s with its own upstream `ApplyCommand` (its `ApplyCommandResponse.applied`
//! is then set; a held command answers with `applied` unset), a `Step`'s with the `Step`'s
//! move, one upstream `Step` in all.
//!
//! State samples in lockstep are delayed by staleness: the sample returned at the end of an
//! `Advance`/`Step` to plant time `T` is the state at `T - d`, `d` drawn on the
//! plant-to-controller line, i.e. the sample that was sent `d` ago and arrives now. `d` is
//! clamped to the duration of the call (netem cannot observe the plant before the call
//! started); the stamps report the staleness actually applied. A lost sample leaves the
//! controller with the previous one. Reading the state at `T - d` ends an integration sub-step
//! there, so a profile with sample delays gives a (deterministic) plant trajectory that
//! differs in the last bits from a run without them. `GetState` is a read at the current
//! plant time and is not delayed; `StreamState` in lockstep is a pass-through monitor.
//!
//! ## Real time
//! Every command and every state sample (`StreamState` items and `GetState` answers) is
//! released on netem's clock at `send + d` by the release thread. A `StreamState` item is
//! released into that stream's buffer of `Config::stream_buffer` samples, which drops its
//! oldest sample for a newer one when the controller does not read (counted as a drop,
//! "subscriber too slow", and in `DirectionStats.stream_overflow_dropped`). `ApplyCommand` answers at
//! once with `applied` unset (the command is in flight), unless its delay is zero, in which
//! case it answers with the upstream's answer.
//!
//! `Reset` and `Describe` are control-plane calls and pass through undelayed. A `Reset`
//! drops every command in flight (reason "plant reset") and restarts both delay lines from
//! their seeds, so that a run after a reset is reproducible.

use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering as AtomicOrdering};

use delay::{Direction, Fate};
use hilbench_proto::convert::netem::{Stamp, StampOutcome, Stamped, check_command, write_clock};
use hilbench_proto::pb;
use hilbench_svc::streams::{Guarded, Pushed, Reader, Writer, drop_oldest};
use mav::TimeMode;
use tokio::sync::oneshot;
use tonic::metadata::MetadataMap;
use tonic::{Request, Response, Status};

use crate::core::{Forward, Msg, PendingCommand, Shared};

/// The Plant service as netem serves it.
#[derive(Clone)]
pub struct Proxy {
    pub(crate) shared: Arc<Shared>,
}

/// Writes the stamps of `m` into response metadata (`convert::netem::Stamp`, the one format).
fn stamp(md: &mut MetadataMap, stamped: Stamped, m: &Msg, outcome: StampOutcome) {
    Stamp::new(m.seq, m.send_ns, m.release_ns, outcome).write(md, stamped);
}

fn respond<T>(body: T, md: MetadataMap, mode: TimeMode) -> Response<T> {
    let mut r = Response::new(body);
    *r.metadata_mut() = md;
    write_clock(r.metadata_mut(), mode);
    r
}

impl Proxy {
    /// A command refused as invalid: counted (`DirectionStats.refused_invalid`) and refused to
    /// its sender with the field that is wrong.
    fn refused_invalid(&self, e: hilbench_proto::convert::FieldError) -> Status {
        self.shared.lock().refused_invalid += 1;
        Status::from(e)
    }

    /// Lockstep: plant time now, asked from the upstream when netem does not know it.
    async fn plant_time(&self) -> Result<u64, Status> {
        if let Some(t) = self.shared.lock().plant_time_ns {
            return Ok(t);
        }
        let s = self.shared.up(self.shared.client().get_state(pb::GetStateRequest {})).await?.into_inner();
        self.shared.lock().plant_time_ns = Some(s.time_ns);
        Ok(s.time_ns)
    }

    /// Lockstep: applies one held command upstream at the current plant time.
    async fn apply_upstream(&self, p: PendingCommand) -> Result<Option<pb::ApplyCommandResponse>, Status> {
        match self.shared.up(self.shared.client().apply_command(p.command)).await {
            Ok(r) => {
                self.shared.lock().delivered(&p.msg, 0);
                Ok(Some(r.into_inner()))
            }
            Err(s) if s.code() == tonic::Code::Unavailable => {
                self.shared.lock().dropped(&p.msg, &format!("upstream unavailable: {}", s.message()));
                Err(s)
            }
            Err(s) => {
                // The plant refused it (it passed netem's checks): the command is lost, the
                // run goes on, and the trace says why.
                tracing::warn!(status = %s, "the plant refused a released command");
                self.shared.lock().dropped(&p.msg, &format!("refused by the plant: {}", s.message()));
                Ok(None)
            }
        }
    }

    /// Lockstep: a command sent now. Held until its release, or applied at once when due now.
    async fn lockstep_command(
        &self,
        command: pb::Command,
        md: &mut MetadataMap,
    ) -> Result<Option<pb::ApplyCommandResponse>, Status> {
        let due_now = self.lockstep_send(command, md).await?;
        let mut applied = None;
        for p in due_now {
            let original = !p.msg.duplicate;
            let r = self.apply_upstream(p).await?;
            if original {
                applied = r;
            }
        }
        Ok(applied)
    }

    /// Lockstep: draws a command's fate at the current plant time and holds the copies due
    /// later; returns the copies due now, for the caller to apply (at once, or with the
    /// upstream call that follows).
    async fn lockstep_send(
        &self,
        command: pb::Command,
        md: &mut MetadataMap,
    ) -> Result<Vec<PendingCommand>, Status> {
        let t = self.plant_time().await?;
        let mut due_now = Vec::new();
        {
            let mut inner = self.shared.lock();
            if let Some(ended) = inner.trace_ended(Direction::ControllerToPlant) {
                return Err(trace_ended_status("command", &ended));
            }
            let d = inner.decide(Direction::ControllerToPlant, t, command.command_seq);
            match d.fate {
                Fate::Dropped => {
                    let m = Msg {
                        dir: Direction::ControllerToPlant,
                        seq: d.seq,
                        payload_seq: command.command_seq,
                        send_ns: t,
                        release_ns: t + delay::delay_ns(d.sampled_delay_s),
                        duplicate: false,
                    };
                    stamp(md, Stamped::Command, &m, StampOutcome::Dropped);
                }
                Fate::Delivered { .. } => {
                    for m in Msg::copies(&d, Direction::ControllerToPlant, command.command_seq) {
                        if !m.duplicate {
                            let outcome = if m.release_ns <= t {
                                StampOutcome::Delivered
                            } else {
                                StampOutcome::InFlight
                            };
                            stamp(md, Stamped::Command, &m, outcome);
                        }
                        let p = PendingCommand { msg: m, command };
                        if m.release_ns <= t { due_now.push(p) } else { inner.pending.push(m.release_ns, p) }
                    }
                }
            }
        }
        Ok(due_now)
    }

    /// Lockstep: moves the upstream plant from plant time `now` to `to` (an `Advance`, or a
    /// `GetState` when `to` is `now`) and returns its sample there, having applied the commands
    /// in `due` at `now` first, in order. The last of them goes with the move in one `Step`
    /// (command, duration, sample), which the plant runs as `ApplyCommand` then `Advance`: the
    /// same trajectory, one round trip fewer per command. `due` is empty on return.
    async fn up_to(
        &self,
        due: &mut Vec<PendingCommand>,
        now: u64,
        to: u64,
    ) -> Result<pb::StateSample, Status> {
        let duration_ns = to.saturating_sub(now);
        if let Some(last) = due.pop() {
            for p in std::mem::take(due) {
                self.apply_upstream(p).await?;
            }
            let step = pb::StepRequest { command: Some(last.command), duration_ns, ..Default::default() };
            match self.shared.up(self.shared.client().step(step)).await {
                Ok(r) => {
                    self.shared.lock().delivered(&last.msg, 0);
                    return r.into_inner().sample.ok_or_else(|| {
                        Status::internal("the upstream plant answered Step without a sample")
                    });
                }
                Err(s) if s.code() == tonic::Code::Unavailable => {
                    self.shared.lock().dropped(&last.msg, &format!("upstream unavailable: {}", s.message()));
                    return Err(s);
                }
                // A plant without `Step`: the command on its own, then the move.
                Err(s) if s.code() == tonic::Code::Unimplemented => {
                    self.apply_upstream(last).await?;
                }
                Err(s) => {
                    // The plant refused the command (it passed netem's checks) and, refusing it,
                    // did not move: the command is lost, the move is made without it.
                    tracing::warn!(status = %s, "the plant refused a released command");
                    self.shared.lock().dropped(&last.msg, &format!("refused by the plant: {}", s.message()));
                }
            }
        }
        if duration_ns > 0 { self.up_advance(duration_ns).await } else { self.up_state().await }
    }

    async fn up_advance(&self, duration_ns: u64) -> Result<pb::StateSample, Status> {
        let r = self
            .shared
            .up(self.shared.client().advance(pb::AdvanceRequest { duration_ns, ..Default::default() }))
            .await?
            .into_inner();
        r.sample.ok_or_else(|| Status::internal("the upstream plant answered Advance without a sample"))
    }

    async fn up_state(&self) -> Result<pb::StateSample, Status> {
        Ok(self.shared.up(self.shared.client().get_state(pb::GetStateRequest {})).await?.into_inner())
    }

    /// Lockstep: advances plant time by `duration_ns`, applying every held command exactly at
    /// its release time, and returns the sample the controller receives at the end.
    ///
    /// With `wait_for_command_seq` set (not 0) and that command still held, the call goes on
    /// past `duration_ns` to the command's release (docs/spec.md's `t_k + max(T, d_k)`); a command
    /// already applied or lost does not extend it.
    ///
    /// `due` are commands due at the current plant time, not yet applied (a `Step`'s own): they
    /// are applied first, with the first upstream call.
    async fn lockstep_advance(
        &self,
        mut due: Vec<PendingCommand>,
        duration_ns: u64,
        wait_for_command_seq: u64,
        md: &mut MetadataMap,
    ) -> Result<pb::StateSample, Status> {
        let t0 = self.plant_time().await?;
        let mut target = t0.saturating_add(duration_ns);
        if wait_for_command_seq != 0 {
            let inner = self.shared.lock();
            let release = inner
                .pending
                .iter()
                .filter(|(_, p)| p.msg.payload_seq == wait_for_command_seq && !p.msg.duplicate)
                .map(|(r, _)| r)
                .max();
            if let Some(r) = release {
                target = target.max(r);
            }
        }
        let duration_ns = target - t0;
        if let Some(ended) = self.shared.lock().trace_ended(Direction::PlantToController) {
            return Err(trace_ended_status("sample", &ended));
        }
        // A regime's clock for a lockstep sample is the time it arrives.
        let draw = self.shared.lock().draw_sample(target);
        let staleness = delay::delay_ns(draw.sampled_delay_s).min(duration_ns);
        let t_s = target - staleness;
        let mut now = t0;
        let mut stale_sample: Option<pb::StateSample> = None;
        loop {
            let next = self.shared.lock().pending.next_release_ns().filter(|r| *r <= target);
            // The sample sent at t_s is read once every command due at or before t_s is in.
            if staleness > 0 && stale_sample.is_none() && next.is_none_or(|r| r > t_s) {
                let s = self.up_to(&mut due, now, t_s.max(now)).await?;
                now = t_s.max(now);
                self.shared.lock().plant_time_ns = Some(now);
                stale_sample = Some(s);
                continue;
            }
            let Some(r) = next else { break };
            if r > now {
                self.up_to(&mut due, now, r).await?;
                now = r;
                self.shared.lock().plant_time_ns = Some(now);
            }
            // Applied with the next upstream call, at `now`.
            let popped = self.shared.lock().pending.pop();
            if let Some((_, p)) = popped {
                due.push(p);
            }
        }
        let end = self.up_to(&mut due, now, target.max(now)).await?;
        let mut inner = self.shared.lock();
        inner.plant_time_ns = Some(end.time_ns);
        let sample = stale_sample.unwrap_or(end);
        let m = inner.lockstep_sample(t_s, target, &draw, sample.seq);
        let delivered = if draw.lost {
            stamp(md, Stamped::Sample, &m, StampOutcome::Dropped);
            inner.last_sample.clone().unwrap_or(sample)
        } else {
            stamp(md, Stamped::Sample, &m, StampOutcome::Delivered);
            inner.last_sample = Some(sample.clone());
            sample
        };
        Ok(delivered)
    }

    /// Real time: a command sent now, released by the release thread.
    async fn real_time_command(
        &self,
        command: pb::Command,
        md: &mut MetadataMap,
    ) -> Result<Option<pb::ApplyCommandResponse>, Status> {
        let now = self.shared.clock.now_ns();
        let (d, epoch) = {
            let mut inner = self.shared.lock();
            if let Some(ended) = inner.trace_ended(Direction::ControllerToPlant) {
                return Err(trace_ended_status("command", &ended));
            }
            if !inner.upstream_connected {
                return Err(Status::unavailable(format!(
                    "netem: the upstream plant at {} is unavailable",
                    self.shared.upstream_addr
                )));
            }
            (inner.decide(Direction::ControllerToPlant, now, command.command_seq), inner.epoch)
        };
        let mut wait = None;
        if d.fate == Fate::Dropped {
            let m = Msg {
                dir: Direction::ControllerToPlant,
                seq: d.seq,
                payload_seq: command.command_seq,
                send_ns: now,
                release_ns: now + delay::delay_ns(d.sampled_delay_s),
                duplicate: false,
            };
            stamp(md, Stamped::Command, &m, StampOutcome::Dropped);
        }
        for m in Msg::copies(&d, Direction::ControllerToPlant, command.command_seq) {
            let reply = if !m.duplicate && m.release_ns == now {
                let (tx, rx) = oneshot::channel();
                wait = Some(rx);
                Some(tx)
            } else {
                None
            };
            if !m.duplicate {
                stamp(
                    md,
                    Stamped::Command,
                    &m,
                    if reply.is_some() { StampOutcome::Delivered } else { StampOutcome::InFlight },
                );
            }
            let forward_tx = self.shared.forward_tx.clone();
            let action = Box::new(move |release_error_ns: i64| {
                let _ = forward_tx.send(Forward { msg: m, command, epoch, release_error_ns, reply });
            });
            if self.shared.releaser.schedule(m.release_ns, action).is_err() {
                self.shared.lock().dropped(&m, "netem is shutting down");
            }
        }
        match wait {
            Some(rx) => rx.await.map_err(|_| Status::unavailable("netem is shutting down"))?.map(Some),
            None => Ok(None),
        }
    }

    /// Real time: a sample read now from the upstream, held for its delay.
    async fn real_time_state(&self, md: &mut MetadataMap) -> Result<pb::StateSample, Status> {
        let sample = self.up_state().await?;
        let now = self.shared.clock.now_ns();
        let d = self.shared.lock().decide(Direction::PlantToController, now, sample.seq);
        let mut original = None;
        for m in Msg::copies(&d, Direction::PlantToController, sample.seq) {
            if m.duplicate {
                // A duplicate answer to a request is discarded on arrival; it is counted.
                let shared = self.shared.clone();
                let action = Box::new(move |e: i64| shared.lock().delivered(&m, e));
                let _ = self.shared.releaser.schedule(m.release_ns, action);
                continue;
            }
            // Counted by this task when it wakes (or by whoever drops the delivery), not by the
            // release thread under netem's lock: a task holding it may be preempted, and the
            // real-time thread would wait for it.
            let (tx, rx) = oneshot::channel::<Delivery>();
            let shared = self.shared.clone();
            let action = Box::new(move |release_error_ns: i64| {
                let _ = tx.send(Delivery { shared, msg: m, release_error_ns });
            });
            if self.shared.releaser.schedule(m.release_ns, action).is_err() {
                return Err(Status::unavailable("netem is shutting down"));
            }
            original = Some((m, rx));
        }
        match original {
            Some((m, rx)) => {
                drop(rx.await.map_err(|_| Status::unavailable("netem is shutting down"))?);
                stamp(md, Stamped::Sample, &m, StampOutcome::Delivered);
                self.shared.lock().last_sample = Some(sample.clone());
                Ok(sample)
            }
            None => {
                let m = Msg {
                    dir: Direction::PlantToController,
                    seq: d.seq,
                    payload_seq: sample.seq,
                    send_ns: now,
                    release_ns: now + delay::delay_ns(d.sampled_delay_s),
                    duplicate: false,
                };
                stamp(md, Stamped::Sample, &m, StampOutcome::Dropped);
                Ok(self.shared.lock().last_sample.clone().unwrap_or(sample))
            }
        }
    }
}

type SampleStream =
    Pin<Box<dyn tokio_stream::Stream<Item = Result<pb::StateSample, Status>> + Send + 'static>>;

#[tonic::async_trait]
impl pb::plant_server::Plant for Proxy {
    async fn reset(&self, request: Request<pb::ResetRequest>) -> Result<Response<pb::ResetResponse>, Status> {
        let _guard = self.shared.lockstep.lock().await;
        let r = self.shared.up(self.shared.client().reset(request.into_inner())).await?.into_inner();
        if let Some(d) = &r.description {
            self.shared.learn_mode(d.time_mode);
        }
        let mut inner = self.shared.lock();
        inner.new_epoch("plant reset");
        for line in &mut inner.lines {
            line.reset();
        }
        inner.command_times = Default::default();
        inner.plant_time_ns = r.sample.as_ref().map(|s| s.time_ns);
        inner.last_sample = r.sample.clone();
        tracing::info!(
            scenario = r.description.as_ref().map(|d| d.scenario.as_str()),
            "plant reset through netem"
        );
        Ok(Response::new(r))
    }

    type StreamStateStream = SampleStream;

    async fn stream_state(
        &self,
        request: Request<pb::StreamStateRequest>,
    ) -> Result<Response<Self::StreamStateStream>, Status> {
        // Taken first, so that a refused stream costs no upstream call.
        let slot = self.shared.slots.acquire(&request, "StreamState")?;
        let mode = self.shared.mode().await?;
        let upstream =
            self.shared.up(self.shared.client().stream_state(request.into_inner())).await?.into_inner();
        if mode == TimeMode::Lockstep {
            let shared = self.shared.clone();
            let s = async_stream_map(upstream, shared);
            return Ok(Response::new(Box::pin(Guarded::new(s, slot))));
        }
        let (writer, reader) = drop_oldest(self.shared.stream_buffer);
        tokio::spawn(pump_samples(self.shared.clone(), upstream, writer));
        let stream = RealTimeSamples { reader, shared: self.shared.clone() };
        Ok(Response::new(Box::pin(Guarded::new(stream, slot))))
    }

    async fn get_state(
        &self,
        _request: Request<pb::GetStateRequest>,
    ) -> Result<Response<pb::StateSample>, Status> {
        let mode = self.shared.mode().await?;
        let mut md = MetadataMap::new();
        let sample = match mode {
            TimeMode::Lockstep => {
                let _guard = self.shared.lockstep.lock().await;
                let s = self.up_state().await?;
                self.shared.lock().plant_time_ns = Some(s.time_ns);
                s
            }
            TimeMode::RealTime => self.real_time_state(&mut md).await?,
        };
        Ok(respond(sample, md, mode))
    }

    async fn apply_command(
        &self,
        request: Request<pb::Command>,
    ) -> Result<Response<pb::ApplyCommandResponse>, Status> {
        hilbench_svc::inject_panic("netem-command");
        let command = request.into_inner();
        check_command("command", &command).map_err(|e| self.refused_invalid(e))?;
        let mode = self.shared.mode().await?;
        let mut md = MetadataMap::new();
        let applied = match mode {
            TimeMode::Lockstep => {
                let _guard = self.shared.lockstep.lock().await;
                self.lockstep_command(command, &mut md).await?
            }
            TimeMode::RealTime => self.real_time_command(command, &mut md).await?,
        };
        let applied = applied.and_then(|r| r.applied);
        Ok(respond(pb::ApplyCommandResponse { applied }, md, mode))
    }

    async fn advance(
        &self,
        request: Request<pb::AdvanceRequest>,
    ) -> Result<Response<pb::AdvanceResponse>, Status> {
        let req = request.into_inner();
        let mode = self.shared.mode().await?;
        if mode == TimeMode::RealTime || (req.duration_ns == 0 && req.wait_for_command_seq == 0) {
            // Let the plant answer what it does with it (it refuses both).
            return self.shared.up(self.shared.client().advance(req)).await;
        }
        let _guard = self.shared.lockstep.lock().await;
        let mut md = MetadataMap::new();
        let sample =
            self.lockstep_advance(Vec::new(), req.duration_ns, req.wait_for_command_seq, &mut md).await?;
        Ok(respond(pb::AdvanceResponse { sample: Some(sample) }, md, mode))
    }

    async fn step(&self, request: Request<pb::StepRequest>) -> Result<Response<pb::AdvanceResponse>, Status> {
        let req = request.into_inner();
        if let Some(c) = &req.command {
            hilbench_svc::inject_panic("netem-command");
            check_command("command", c).map_err(|e| self.refused_invalid(e))?;
        }
        let mode = self.shared.mode().await?;
        let mut md = MetadataMap::new();
        let sample = match mode {
            TimeMode::Lockstep => {
                let _guard = self.shared.lockstep.lock().await;
                // The command, when due now, goes upstream with the first move: one `Step`.
                let mut due = match req.command {
                    Some(c) => self.lockstep_send(c, &mut md).await?,
                    None => Vec::new(),
                };
                if req.duration_ns > 0 || req.wait_for_command_seq != 0 {
                    self.lockstep_advance(due, req.duration_ns, req.wait_for_command_seq, &mut md).await?
                } else {
                    let now = self.plant_time().await?;
                    let s = self.up_to(&mut due, now, now).await?;
                    self.shared.lock().plant_time_ns = Some(s.time_ns);
                    s
                }
            }
            TimeMode::RealTime => {
                if req.duration_ns > 0 {
                    return self.shared.up(self.shared.client().step(req)).await;
                }
                if let Some(c) = req.command {
                    self.real_time_command(c, &mut md).await?;
                }
                self.real_time_state(&mut md).await?
            }
        };
        Ok(respond(pb::AdvanceResponse { sample: Some(sample) }, md, mode))
    }

    async fn describe(
        &self,
        request: Request<pb::DescribeRequest>,
    ) -> Result<Response<pb::PlantDescription>, Status> {
        let r = self.shared.up(self.shared.client().describe(request.into_inner())).await?;
        self.shared.learn_mode(r.get_ref().time_mode);
        Ok(r)
    }
}

/// What a real-time state stream's buffer holds: a released copy of a sample (boxed: a slot
/// of the ring is then a few words whatever the sample holds), or the end.
enum Released {
    Sample { msg: Msg, release_error_ns: i64, sample: Box<pb::StateSample> },
    End(Status),
}

/// Real time: reads the upstream's samples for one controller's stream until the controller
/// leaves, netem shuts down or the upstream stream ends. Each sample goes through the
/// plant-to-controller line and is released into the stream's buffer at `send + d` by the
/// release thread; the buffer is bounded and drops its oldest sample for a newer one, so a
/// controller that stops reading costs netem `stream_buffer` samples, never more, and finds
/// the newest ones when it reads again. The upstream is always read at the plant's pace (no
/// backpressure: holding it back would only age every sample the controller gets).
async fn pump_samples(
    shared: Arc<Shared>,
    mut upstream: tonic::Streaming<pb::StateSample>,
    writer: Writer<Released>,
) {
    // Set when netem stops forwarding this stream: copies still in the release thread are
    // then dropped at their release instead of delivered.
    let closed = Arc::new(AtomicBool::new(false));
    let netem_closing = shared.closed();
    tokio::pin!(netem_closing);
    loop {
        let item = tokio::select! {
            item = upstream.message() => item,
            () = writer.closed() => break,
            () = &mut netem_closing => {
                closed.store(true, AtomicOrdering::Release);
                break;
            }
        };
        match item {
            Ok(Some(sample)) => {
                shared.upstream_ok();
                let now = shared.clock.now_ns();
                let d = shared.lock().decide(Direction::PlantToController, now, sample.seq);
                for m in Msg::copies(&d, Direction::PlantToController, sample.seq) {
                    let (closed, sh, w, sample) =
                        (closed.clone(), shared.clone(), writer.clone(), sample.clone());
                    let action = Box::new(move |e: i64| release_sample(&sh, &w, &closed, m, e, sample));
                    if shared.releaser.schedule(m.release_ns, action).is_err() {
                        shared.lock().dropped(&m, "netem is shutting down");
                    }
                }
            }
            Ok(None) => {
                // A clean end: the samples already sent are still on their way; the
                // controller learns of the end after the last of them.
                let last = shared.lock().lines[Direction::PlantToController.index()].last_release_ns();
                let (sh, w) = (shared.clone(), writer.clone());
                let end = Box::new(move |_e: i64| {
                    end_stream(&sh, &w, Status::unavailable("the upstream plant closed the state stream"));
                });
                let _ = shared.releaser.schedule(last.unwrap_or(0), end);
                break;
            }
            Err(s) => {
                closed.store(true, AtomicOrdering::Release);
                let status = if crate::core::is_gone(&s) { shared.upstream_lost(&s) } else { s };
                end_stream(&shared, &writer, status);
                break;
            }
        }
    }
}

/// The release of one copy into a real-time stream's buffer (on the release thread).
/// A real-time sample released to its request: counted as delivered when dropped, so by the
/// request's task once it has it, and still counted if the request is gone.
struct Delivery {
    shared: Arc<Shared>,
    msg: Msg,
    release_error_ns: i64,
}

impl Drop for Delivery {
    fn drop(&mut self) {
        self.shared.lock().delivered(&self.msg, self.release_error_ns);
    }
}

fn release_sample(
    shared: &Shared,
    writer: &Writer<Released>,
    closed: &AtomicBool,
    msg: Msg,
    release_error_ns: i64,
    sample: pb::StateSample,
) {
    if closed.load(AtomicOrdering::Acquire) {
        let mut inner = shared.lock();
        let reason = inner.epoch_reason.clone();
        inner.dropped(&msg, &reason);
        return;
    }
    // Counted as delivered when the controller's side takes it from the buffer.
    match writer.push(Released::Sample { msg, release_error_ns, sample: Box::new(sample) }) {
        Pushed::Queued => {}
        Pushed::Evicted(Released::Sample { msg: oldest, .. }) => shared.lock().overflowed(&oldest),
        // An end is pushed last and never evicted.
        Pushed::Evicted(Released::End(_)) => {}
        Pushed::Closed(_) => shared.lock().dropped(&msg, "controller gone"),
    }
}

/// Ends a real-time state stream with `status` after what its buffer holds (whose oldest
/// sample makes room when it is full).
fn end_stream(shared: &Shared, writer: &Writer<Released>, status: Status) {
    if let Pushed::Evicted(Released::Sample { msg: oldest, .. }) = writer.push_last(Released::End(status)) {
        shared.lock().overflowed(&oldest);
    }
}

/// The controller's side of a real-time state stream: a copy counts as delivered when gRPC
/// takes it from the buffer; copies left in the buffer when the controller leaves are
/// dropped ("controller gone").
struct RealTimeSamples {
    reader: Reader<Released>,
    shared: Arc<Shared>,
}

impl tokio_stream::Stream for RealTimeSamples {
    type Item = Result<pb::StateSample, Status>;

    fn poll_next(
        self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<Self::Item>> {
        let this = self.get_mut();
        this.reader.poll_recv(cx).map(|item| {
            item.map(|released| match released {
                Released::Sample { msg, release_error_ns, sample } => {
                    this.shared.lock().delivered(&msg, release_error_ns);
                    Ok(*sample)
                }
                Released::End(status) => Err(status),
            })
        })
    }
}

impl Drop for RealTimeSamples {
    fn drop(&mut self) {
        let left = self.reader.close();
        if left.is_empty() {
            return;
        }
        let mut inner = self.shared.lock();
        for released in left {
            if let Released::Sample { msg, .. } = released {
                inner.dropped(&msg, "controller gone");
            }
        }
    }
}

/// Lockstep `StreamState`: the upstream's items pass through (the plant-to-controller delay
/// applies to the samples of `Advance`/`Step`, which is what a lockstep controller reads).
fn async_stream_map(upstream: tonic::Streaming<pb::StateSample>, shared: Arc<Shared>) -> SampleStream {
    use tokio_stream::StreamExt;
    let closing = shared.closed();
    let items = upstream.map(move |item| match item {
        Ok(s) => Ok(s),
        Err(s) if crate::core::is_gone(&s) => Err(shared.upstream_lost(&s)),
        Err(s) => Err(s),
    });
    Box::pin(crate::core::until_closed(items, closing))
}

/// A message of a direction whose delay trace has ended (and stops there): refused to its
/// sender, so that the run stops with an error naming the trace and the message, never a
/// silent drop or a made-up delay.
fn trace_ended_status(what: &str, ended: &delay::TraceEnded) -> Status {
    Status::out_of_range(format!("netem: this {what} has no delay: {ended}"))
}
