//! `hilbench.v1.NetemControl`: change the network at run time, read what it did.

use std::pin::Pin;
use std::sync::Arc;

use delay::Direction;
use hilbench_proto::convert::FieldError;
use hilbench_proto::convert::netem::{HeldCounts, direction_from_pb, profile_from_pb, stats_to_pb};
use hilbench_proto::pb;
use tokio_stream::StreamExt;
use tokio_stream::wrappers::BroadcastStream;
use tonic::{Request, Response, Status};

use crate::core::Net;

/// The control service.
#[derive(Clone)]
pub struct Control {
    pub(crate) shared: Arc<Net>,
}

type RecordStream =
    Pin<Box<dyn tokio_stream::Stream<Item = Result<pb::TraceRecord, Status>> + Send + 'static>>;

#[tonic::async_trait]
impl pb::netem_control_server::NetemControl for Control {
    /// Validates everything before touching anything: a bad request leaves the running
    /// profiles as they were, and messages in flight keep their release times either way.
    async fn set_profile(
        &self,
        request: Request<pb::SetProfileRequest>,
    ) -> Result<Response<pb::DirectionProfile>, Status> {
        let req = request.into_inner();
        let direction = direction_from_pb("direction", req.direction)?;
        let updates: Vec<(Direction, delay::DirectionProfile)> = if !req.preset.is_empty() {
            if req.profile.is_some() {
                return Err(FieldError::new("preset", "give either `profile` or `preset`, not both").into());
            }
            let preset = delay::preset(&req.preset, self.shared.seed).map_err(FieldError::from)?;
            match direction {
                Some(d) => vec![(d, preset.get(d).clone())],
                None => Direction::ALL.iter().map(|d| (*d, preset.get(*d).clone())).collect(),
            }
        } else {
            let profile = hilbench_proto::convert::required("profile", &req.profile)?;
            let profile = profile_from_pb(profile).map_err(|e| e.within("profile"))?;
            let Some(d) = direction else {
                return Err(FieldError::new("direction", "is required with a profile").into());
            };
            vec![(d, profile)]
        };
        let mut inner = self.shared.lock();
        for (d, p) in &updates {
            // Already validated; `set_profile` validates again and would refuse atomically.
            inner.lines[d.index()]
                .set_profile(p.clone())
                .map_err(FieldError::from)
                .map_err(|e| e.within("profile"))?;
            tracing::info!(direction = ?d, profile = ?p, "profile set");
        }
        let shown = match direction {
            Some(d) => d,
            None => Direction::ControllerToPlant,
        };
        Ok(Response::new(pb::DirectionProfile::from(inner.lines[shown.index()].profile())))
    }

    async fn get_profile(
        &self,
        request: Request<pb::GetProfileRequest>,
    ) -> Result<Response<pb::DirectionProfile>, Status> {
        let Some(d) = direction_from_pb("direction", request.get_ref().direction)? else {
            return Err(FieldError::new("direction", "is required").into());
        };
        Ok(Response::new(pb::DirectionProfile::from(self.shared.lock().lines[d.index()].profile())))
    }

    async fn get_stats(
        &self,
        _request: Request<pb::GetStatsRequest>,
    ) -> Result<Response<pb::NetemStats>, Status> {
        let inner = self.shared.lock();
        let dir = |d: Direction| {
            let held = HeldCounts {
                in_flight: inner.in_flight[d.index()],
                stream_overflow_dropped: inner.stream_overflow_dropped[d.index()],
                refused_invalid: if d == Direction::ControllerToPlant { inner.refused_invalid } else { 0 },
            };
            stats_to_pb(&inner.stats[d.index()], held)
        };
        Ok(Response::new(pb::NetemStats {
            plant_to_controller: Some(dir(Direction::PlantToController)),
            controller_to_plant: Some(dir(Direction::ControllerToPlant)),
            upstream_connected: inner.upstream_connected,
            upstream_failures: inner.upstream_failures,
            deliveries_lagged: inner.deliveries_lagged,
            udp: inner.udp.as_ref().map(udp_stats),
            time_mode: inner.mode.map_or(pb::TimeMode::Unspecified, pb::TimeMode::from) as i32,
        }))
    }

    async fn reset_stats(
        &self,
        _request: Request<pb::ResetStatsRequest>,
    ) -> Result<Response<pb::ResetStatsResponse>, Status> {
        let mut inner = self.shared.lock();
        for s in &mut inner.stats {
            s.reset();
        }
        inner.stream_overflow_dropped = [0; 2];
        inner.refused_invalid = 0;
        inner.deliveries_lagged = 0;
        if let Some(p) = inner.udp.as_mut() {
            p.reset_counts();
        }
        // Copies still in flight will be counted when they arrive; keep the books balanced
        // by starting the new period with them as sent.
        let in_flight = inner.in_flight;
        for (s, n) in inner.stats.iter_mut().zip(in_flight) {
            s.sent = n;
        }
        Ok(Response::new(pb::ResetStatsResponse {}))
    }

    async fn start_trace(
        &self,
        _request: Request<pb::StartTraceRequest>,
    ) -> Result<Response<pb::StartTraceResponse>, Status> {
        self.shared.lock().recording = Some(Vec::new());
        Ok(Response::new(pb::StartTraceResponse {}))
    }

    async fn stop_trace(
        &self,
        _request: Request<pb::StopTraceRequest>,
    ) -> Result<Response<pb::Trace>, Status> {
        let Some(records) = self.shared.lock().recording.take() else {
            return Err(Status::failed_precondition("no trace is being recorded (call StartTrace first)"));
        };
        Ok(Response::new(pb::Trace { records: records.iter().map(pb::TraceRecord::from).collect() }))
    }

    async fn commands_sent_before(
        &self,
        request: Request<pb::CommandsSentBeforeRequest>,
    ) -> Result<Response<pb::CommandsSentBeforeResponse>, Status> {
        let t = request.get_ref().before_plant_time_ns;
        let inner = self.shared.lock();
        if inner.mode != Some(mav::TimeMode::Lockstep) {
            return Err(Status::failed_precondition(
                "commands are counted by plant time in lockstep only (netem's clock is not the plant's)",
            ));
        }
        let commands = inner.command_times.before(t).ok_or_else(|| {
            Status::out_of_range(format!(
                "plant time {t} ns is older than the {} plant times netem keeps",
                crate::command_times::KEPT_TIMES
            ))
        })?;
        Ok(Response::new(pb::CommandsSentBeforeResponse { commands }))
    }

    type StreamDeliveriesStream = RecordStream;

    async fn stream_deliveries(
        &self,
        request: Request<pb::StreamDeliveriesRequest>,
    ) -> Result<Response<Self::StreamDeliveriesStream>, Status> {
        let slot = self.shared.slots.acquire(&request, "StreamDeliveries")?;
        let rx = self.shared.lock().deliveries.subscribe();
        let shared = self.shared.clone();
        let s = BroadcastStream::new(rx).filter_map(move |r| match r {
            Ok(rec) => Some(Ok(rec)),
            Err(tokio_stream::wrappers::errors::BroadcastStreamRecvError::Lagged(n)) => {
                shared.lock().deliveries_lagged(n);
                None
            }
        });
        let s = crate::core::until_closed(s, self.shared.closed());
        Ok(Response::new(Box::pin(hilbench_svc::streams::Guarded::new(s, slot))))
    }
}

/// The UDP proxy's part of `NetemStats`.
fn udp_stats(p: &crate::peers::Peers) -> pb::UdpStats {
    pb::UdpStats {
        listen_address: p.listen.to_string(),
        forward_address: p.forward.to_string(),
        client_address: p.client.map(|c| c.to_string()).unwrap_or_default(),
        plant_side: p.plant_side.name().into(),
        refused_foreign_client: p.refused_foreign_client,
        refused_foreign_forward: p.refused_foreign_forward,
        refused_no_client: p.refused_no_client,
        send_errors: p.send_errors,
        dropped_held_cap: p.dropped_held_cap,
        held_bytes: p.held_bytes,
    }
}
