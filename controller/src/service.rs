//! The `hilbench.v1.Controller` API: a thin shell over the control loop's shared state.

use std::pin::Pin;
use std::sync::Arc;

use hilbench_proto::convert::FieldError;
use hilbench_proto::convert::controller::{goal_from_pb, scenario_from_pb};
use hilbench_proto::pb;
use hilbench_proto::pb::controller_server::Controller;
use hilbench_svc::streams::{Guarded, StreamSlots};
use tokio_stream::Stream;
use tokio_stream::StreamExt;
use tokio_stream::wrappers::{BroadcastStream, WatchStream};
use tonic::{Request, Response, Status};

use crate::runner::Shared;

#[derive(Debug, Clone)]
pub struct ControllerService {
    shared: Arc<Shared>,
    /// The cap on open `StreamTelemetry` streams.
    slots: StreamSlots,
}

impl ControllerService {
    /// The API over `shared`, serving at most `max_streams` telemetry streams at once,
    /// `per_client` of them to one client.
    pub fn new(shared: Arc<Shared>, max_streams: usize, per_client: usize) -> Self {
        Self { shared, slots: StreamSlots::new("controller", max_streams, per_client) }
    }
}

type TelemetryStream = Pin<Box<dyn Stream<Item = Result<pb::CycleTelemetry, Status>> + Send>>;

#[tonic::async_trait]
impl Controller for ControllerService {
    async fn get_status(
        &self,
        _: Request<pb::GetStatusRequest>,
    ) -> Result<Response<pb::ControllerStatus>, Status> {
        let s = self.shared.status();
        Ok(Response::new(pb::ControllerStatus {
            scenario: s.scenario,
            mode: s.mode,
            plant_connected: s.plant_connected,
            plant_address: s.plant_address,
            cycles: s.cycles,
            goal_m: s.goal_m.to_vec(),
            scenario_weights: s.weights,
            sampling_times_s: s.sampling_times_s,
            last_solve: s.last_solve,
            reconnects: s.reconnects,
            last_error: s.last_error,
            reached: s.reached,
            episode: s.episode,
            episode_finished: s.episode_finished,
            episodes_finished: s.episodes_finished,
            finish_reason: hilbench_proto::convert::controller::finish_reason_to_pb(s.finish_reason) as i32,
            link_losses: s.link_losses,
            link_down_s: s.link_down_s,
            longest_link_down_s: s.longest_link_down_s,
            plant_resets: s.plant_resets,
            plant_reset_time_s: s.plant_reset_time_s,
            iteration_limits: s.iteration_limits,
            infeasible_at_limit: s.infeasible_at_limit,
            definition: s.definition.as_ref().map(Into::into),
        }))
    }

    type StreamTelemetryStream = TelemetryStream;

    async fn stream_telemetry(
        &self,
        request: Request<pb::StreamTelemetryRequest>,
    ) -> Result<Response<Self::StreamTelemetryStream>, Status> {
        let slot = self.slots.acquire(&request, "StreamTelemetry")?;
        // A subscriber that falls behind loses the oldest items (and is told how many in the
        // log); the control loop never waits for it.
        let stream = BroadcastStream::new(self.shared.subscribe()).filter_map(|item| match item {
            Ok(t) => Some(Ok(t)),
            Err(tokio_stream::wrappers::errors::BroadcastStreamRecvError::Lagged(n)) => {
                tracing::warn!(skipped = n, "telemetry subscriber lagging");
                None
            }
        });
        // The stream ends when the service closes (its graceful stop waits for open calls).
        let closing = WatchStream::new(self.shared.closing()).filter(|closing| *closing).map(|_| None);
        let stream = stream.map(Some).merge(closing).take_while(Option::is_some).filter_map(|item| item);
        Ok(Response::new(Box::pin(Guarded::new(stream, slot))))
    }

    async fn set_goal(
        &self,
        request: Request<pb::SetGoalRequest>,
    ) -> Result<Response<pb::SetGoalResponse>, Status> {
        let goal = goal_from_pb(request.get_ref())?;
        self.shared.request_goal(goal).map_err(|e| match e {
            mav::ScenarioError::Invalid { field, reason } => Status::from(FieldError::new(field, reason)),
            other => Status::invalid_argument(other.to_string()),
        })?;
        Ok(Response::new(pb::SetGoalResponse {}))
    }

    async fn set_scenario(
        &self,
        request: Request<pb::SetScenarioRequest>,
    ) -> Result<Response<pb::SetScenarioResponse>, Status> {
        let (scenario, mode) = scenario_from_pb(request.get_ref())?;
        self.shared.request_scenario(scenario, mode);
        Ok(Response::new(pb::SetScenarioResponse {}))
    }
}
