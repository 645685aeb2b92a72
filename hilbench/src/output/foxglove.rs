//! Runs as Foxglove sees them: an MCAP file per run (`<scenario>-<controller>.mcap`) and, in
//! real time, the same channels live over the Foxglove WebSocket protocol ([`Live`]). Both go
//! through the official `foxglove` SDK and [`Channels`], so a file and a live view hold the same
//! messages. Log time is plant time.
//!
//! Channels (docs/output.md lists every field): `/scene` (`foxglove.SceneUpdate`: ground,
//! cylinders with their height, start, goal), `/plan` (`foxglove.SceneUpdate`: one line per
//! sampling-time scenario of the plan flown, coloured by its weight), `/tf`
//! (`foxglove.FrameTransform`, `world` to `mav`), `/pose` (`foxglove.PoseInFrame`), and, as
//! JSON with a JSON schema, `/state`, `/command` (with the input bounds), `/delays` (injected
//! by the network, measured by the controller, the weights) and `/safety` (the safety layer's
//! decision and reason, the solve).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context as _;
use foxglove::messages::{
    Color, CubePrimitive, CylinderPrimitive, FrameTransform, KeyValuePair, LinePrimitive, Point3, Pose,
    PoseInFrame, Quaternion, SceneEntity, SceneUpdate, SpherePrimitive, Timestamp, Vector3, line_primitive,
};
use foxglove::{Channel, Context, Encode, Schema};
use mav::Scenario;
use mpc::CycleRecord;
use schemars::JsonSchema;
use serde::Serialize;

use crate::run::{Batch, CycleRow};

/// The frame of the scene, the plan and the poses.
pub const WORLD_FRAME: &str = "world";
/// The vehicle's frame (`/tf` places it in [`WORLD_FRAME`]).
pub const VEHICLE_FRAME: &str = "mav";

/// A message of ours, sent as JSON with a JSON schema named [`JsonMessage::SCHEMA`].
pub trait JsonMessage: Serialize + JsonSchema {
    const SCHEMA: &'static str;
}

/// `T` as a Foxglove message (JSON, its schema generated once per channel by schemars).
pub struct Json<T>(pub T);

impl<T: JsonMessage> Encode for Json<T> {
    type Error = serde_json::Error;

    fn get_schema() -> Option<Schema> {
        let schema = schemars::schema_for!(T);
        let data = serde_json::to_vec(&schema).ok()?;
        Some(Schema::new(T::SCHEMA, "jsonschema", data))
    }

    fn get_message_encoding() -> String {
        "json".to_string()
    }

    fn encode(&self, buf: &mut impl bytes::BufMut) -> Result<(), Self::Error> {
        serde_json::to_writer(bytes::BufMut::writer(buf), &self.0)
    }
}

/// `/state`: the state the controller solved from.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct StateMsg {
    pub cycle: u64,
    pub t_s: f64,
    pub px_m: f64,
    pub py_m: f64,
    pub pz_m: f64,
    pub vx_mps: f64,
    pub vy_mps: f64,
    pub vz_mps: f64,
    pub roll_rad: f64,
    pub pitch_rad: f64,
    /// The plant's watchdog held hover when the sample was taken.
    pub watchdog_hover: bool,
}

impl JsonMessage for StateMsg {
    const SCHEMA: &'static str = "hilbench.State";
}

/// `/command`: the command sent, beside the input bounds (to plot one against the other).
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct CommandMsg {
    pub cycle: u64,
    pub command_seq: u64,
    pub thrust_mps2: f64,
    pub roll_rad: f64,
    pub pitch_rad: f64,
    pub thrust_min_mps2: f64,
    pub thrust_max_mps2: f64,
    pub roll_min_rad: f64,
    pub roll_max_rad: f64,
    pub pitch_min_rad: f64,
    pub pitch_max_rad: f64,
}

impl JsonMessage for CommandMsg {
    const SCHEMA: &'static str = "hilbench.Command";
}

/// `/delays`: what the network did to this cycle's command and what the controller knew.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct DelaysMsg {
    pub cycle: u64,
    /// The delay the network put on this cycle's command (netem's stamps, or the in-process
    /// delay line's draw), s; null when the command was lost or nothing stamped it.
    pub injected_delay_s: Option<f64>,
    /// The round-trip delay the controller had measured from plant stamps at this cycle
    /// (that of an earlier command), s; null before the first measurement.
    pub measured_delay_s: Option<f64>,
    /// The command was lost on its way (no injected delay).
    pub lost: bool,
    /// The scenario weights of this cycle's solve, one per sampling time.
    pub weights: Vec<f64>,
    pub sampling_times_s: Vec<f64>,
}

impl JsonMessage for DelaysMsg {
    const SCHEMA: &'static str = "hilbench.Delays";
}

/// `/safety`: the safety layer's decision and the solve behind it.
#[derive(Debug, Clone, Serialize, JsonSchema)]
pub struct SafetyMsg {
    pub cycle: u64,
    /// `panoc`, `qp`, `shifted_plan`, `brake`; empty when the layer is off.
    pub decision: String,
    /// Why (empty when the layer is off).
    pub reason: String,
    pub fallback: bool,
    /// PANOC's status: `converged`, `iteration_limit`, `infeasible_at_limit`, `deadline`,
    /// `numerical_failure`.
    pub status: String,
    pub iterations: u64,
    pub solve_ms: f64,
    pub cost: Option<f64>,
    pub constraint_violation: Option<f64>,
    /// Smallest true clearance of the plan's predictions, m (null: no obstacle).
    pub predicted_clearance_m: Option<f64>,
    /// QP cost minus PANOC cost on the nonlinear model, when the cross-check ran.
    pub cost_gap: Option<f64>,
}

impl JsonMessage for SafetyMsg {
    const SCHEMA: &'static str = "hilbench.Safety";
}

/// Every channel of a run, on one Foxglove context (a file's, or the live server's).
pub struct Channels {
    scene: Channel<SceneUpdate>,
    plan: Channel<SceneUpdate>,
    tf: Channel<FrameTransform>,
    pose: Channel<PoseInFrame>,
    state: Channel<Json<StateMsg>>,
    command: Channel<Json<CommandMsg>>,
    delays: Channel<Json<DelaysMsg>>,
    safety: Channel<Json<SafetyMsg>>,
}

/// The topics, in the order of [`Channels`].
pub const TOPICS: [&str; 8] = ["/scene", "/plan", "/tf", "/pose", "/state", "/command", "/delays", "/safety"];

impl Channels {
    pub fn new(ctx: &Arc<Context>) -> Self {
        Self {
            scene: ctx.channel_builder(TOPICS[0]).build(),
            plan: ctx.channel_builder(TOPICS[1]).build(),
            tf: ctx.channel_builder(TOPICS[2]).build(),
            pose: ctx.channel_builder(TOPICS[3]).build(),
            state: ctx.channel_builder(TOPICS[4]).build(),
            command: ctx.channel_builder(TOPICS[5]).build(),
            delays: ctx.channel_builder(TOPICS[6]).build(),
            safety: ctx.channel_builder(TOPICS[7]).build(),
        }
    }

    /// The scene of `scenario` at plant time `time_ns`: the ground, the cylinders, start and goal.
    pub fn scene(&self, scenario: &Scenario, time_ns: u64) {
        self.scene.log_with_time(&scene_update(scenario, time_ns), time_ns);
    }

    /// Everything one cycle logs, at the plant time of the sample it solved from.
    pub fn cycle(&self, scenario: &Scenario, record: &CycleRecord) {
        let t = record.sample_time_ns;
        self.vehicle(t, record.cycle, &record.state, record.watchdog_hover);
        self.plan.log_with_time(&plan_update(t, record), t);
        self.command.log_with_time(
            &Json(command_msg(scenario, record.cycle, record.command_seq, &record.command)),
            t,
        );
        let sampling_times_s = match record.weights.len() {
            1 => vec![scenario.nmpc_sampling_time_s],
            _ => scenario.sampling_times_s.clone(),
        };
        self.delays.log_with_time(
            &Json(DelaysMsg {
                cycle: record.cycle,
                injected_delay_s: record.injected_delay_s,
                measured_delay_s: record.known_delay_s,
                lost: record.command_lost,
                weights: record.weights.clone(),
                sampling_times_s,
            }),
            t,
        );
        self.safety.log_with_time(
            &Json(SafetyMsg {
                cycle: record.cycle,
                decision: record.decision.map_or(String::new(), |d| d.name().to_string()),
                reason: record.reason.clone(),
                fallback: record.is_fallback(),
                status: record.solve.status.name().to_string(),
                iterations: record.solve.iterations,
                solve_ms: record.solve.solve_ms,
                cost: finite(record.solve.cost),
                constraint_violation: finite(record.solve.constraint_violation),
                predicted_clearance_m: finite(record.solve.min_clearance_m),
                cost_gap: record.cost_gap.and_then(finite),
            }),
            t,
        );
    }

    /// The vehicle at plant time `t` (ns) of `cycle`: `/tf`, `/pose` and `/state`.
    fn vehicle(&self, t: u64, cycle: u64, s: &[f64; 8], watchdog_hover: bool) {
        self.tf.log_with_time(&frame_transform(t, s), t);
        self.pose.log_with_time(&pose_in_frame(t, s), t);
        self.state.log_with_time(
            &Json(StateMsg {
                cycle,
                t_s: mav::ns_to_s(t),
                px_m: s[0],
                py_m: s[1],
                pz_m: s[2],
                vx_mps: s[3],
                vy_mps: s[4],
                vz_mps: s[5],
                roll_rad: s[6],
                pitch_rad: s[7],
                watchdog_hover,
            }),
            t,
        );
    }

    /// A command the plant applied, seen from the plant (an external controller's run: no
    /// plan, no solve): the vehicle's pose and state at that step, and the command.
    pub fn applied(&self, scenario: &Scenario, row: &CycleRow) {
        let t = mav::s_to_ns(row.t_s).unwrap_or(0);
        self.vehicle(t, row.cycle, &row.state, false);
        self.command.log_with_time(&Json(command_msg(scenario, row.cycle, row.command_seq, &row.command)), t);
    }

    /// The vehicle where the run ended (the plant's last state, at its time): the last pose.
    pub fn final_pose(&self, time_ns: u64, state: &[f64; 8]) {
        self.tf.log_with_time(&frame_transform(time_ns, state), time_ns);
        self.pose.log_with_time(&pose_in_frame(time_ns, state), time_ns);
    }
}

/// The `/command` message of `command` (with the scenario's input bounds).
fn command_msg(scenario: &Scenario, cycle: u64, command_seq: u64, command: &[f64; 3]) -> CommandMsg {
    let (lo, hi) = (scenario.bounds.min, scenario.bounds.max);
    CommandMsg {
        cycle,
        command_seq,
        thrust_mps2: command[0],
        roll_rad: command[1],
        pitch_rad: command[2],
        thrust_min_mps2: lo[0],
        thrust_max_mps2: hi[0],
        roll_min_rad: lo[1],
        roll_max_rad: hi[1],
        pitch_min_rad: lo[2],
        pitch_max_rad: hi[2],
    }
}

/// JSON has no NaN or infinity: those are null.
fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

fn timestamp(time_ns: u64) -> Timestamp {
    Timestamp::new((time_ns / 1_000_000_000) as u32, (time_ns % 1_000_000_000) as u32)
}

/// The attitude of roll `phi` and pitch `theta` (the model has no yaw), as Z-Y-X Euler angles.
fn attitude(roll_rad: f64, pitch_rad: f64) -> Quaternion {
    let (sr, cr) = (roll_rad / 2.0).sin_cos();
    let (sp, cp) = (pitch_rad / 2.0).sin_cos();
    Quaternion { x: sr * cp, y: cr * sp, z: -sr * sp, w: cr * cp }
}

fn vehicle_pose(state: &[f64; 8]) -> Pose {
    Pose {
        position: Some(Vector3 { x: state[0], y: state[1], z: state[2] }),
        orientation: Some(attitude(state[6], state[7])),
    }
}

fn frame_transform(time_ns: u64, state: &[f64; 8]) -> FrameTransform {
    let pose = vehicle_pose(state);
    FrameTransform {
        timestamp: Some(timestamp(time_ns)),
        parent_frame_id: WORLD_FRAME.to_string(),
        child_frame_id: VEHICLE_FRAME.to_string(),
        translation: pose.position,
        rotation: pose.orientation,
    }
}

fn pose_in_frame(time_ns: u64, state: &[f64; 8]) -> PoseInFrame {
    PoseInFrame {
        timestamp: Some(timestamp(time_ns)),
        frame_id: WORLD_FRAME.to_string(),
        pose: Some(vehicle_pose(state)),
    }
}

fn color(r: f64, g: f64, b: f64, a: f64) -> Color {
    Color { r, g, b, a }
}

fn at(x: f64, y: f64, z: f64) -> Pose {
    Pose {
        position: Some(Vector3 { x, y, z }),
        orientation: Some(Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }),
    }
}

fn entity(time_ns: u64, id: &str) -> SceneEntity {
    SceneEntity {
        timestamp: Some(timestamp(time_ns)),
        frame_id: WORLD_FRAME.to_string(),
        id: id.to_string(),
        ..SceneEntity::default()
    }
}

/// The ground (a thin plate under everything, at the scenario's ground level), the cylinders
/// (from z = 0 to their height), the start and the goal (a sphere of the goal tolerance).
pub fn scene_update(scenario: &Scenario, time_ns: u64) -> SceneUpdate {
    let (start, goal) = (&scenario.start, &scenario.goal_m);
    let mut xs = vec![start[0], goal[0]];
    let mut ys = vec![start[1], goal[1]];
    for c in &scenario.obstacles {
        xs.extend([c.x_m - c.radius_m, c.x_m + c.radius_m]);
        ys.extend([c.y_m - c.radius_m, c.y_m + c.radius_m]);
    }
    let span = |v: &[f64]| {
        let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        ((lo + hi) / 2.0, hi - lo + 4.0)
    };
    let ((cx, sx), (cy, sy)) = (span(&xs), span(&ys));
    let plate_m = 0.02;
    let mut ground = entity(time_ns, "ground");
    ground.cubes.push(CubePrimitive {
        pose: Some(at(cx, cy, scenario.ground_z_m - plate_m / 2.0)),
        size: Some(Vector3 { x: sx, y: sy, z: plate_m }),
        color: Some(color(0.55, 0.6, 0.55, 0.6)),
    });
    let mut obstacles = entity(time_ns, "obstacles");
    for (i, c) in scenario.obstacles.iter().enumerate() {
        obstacles.cylinders.push(CylinderPrimitive {
            pose: Some(at(c.x_m, c.y_m, c.height_m / 2.0)),
            size: Some(Vector3 { x: 2.0 * c.radius_m, y: 2.0 * c.radius_m, z: c.height_m }),
            bottom_scale: 1.0,
            top_scale: 1.0,
            color: Some(color(0.75, 0.3, 0.25, 0.8)),
        });
        obstacles.metadata.push(KeyValuePair {
            key: format!("cylinder {i}"),
            value: format!("x {} m, y {} m, radius {} m, height {} m", c.x_m, c.y_m, c.radius_m, c.height_m),
        });
    }
    let sphere = |id: &str, p: [f64; 3], d: f64, c: Color| {
        let mut e = entity(time_ns, id);
        e.spheres.push(SpherePrimitive {
            pose: Some(at(p[0], p[1], p[2])),
            size: Some(Vector3 { x: d, y: d, z: d }),
            color: Some(c),
        });
        e
    };
    let goal_d = 2.0 * scenario.goal_tolerance_m;
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![
            ground,
            obstacles,
            sphere("start", [start[0], start[1], start[2]], 0.15, color(0.3, 0.3, 0.9, 0.9)),
            sphere("goal", *goal, goal_d.max(0.1), color(0.2, 0.8, 0.3, 0.7)),
        ],
    }
}

/// The colour of a scenario's line: from pale blue (weight 0) to deep orange (weight 1), more
/// opaque as the weight grows.
pub fn weight_color(weight: f64) -> Color {
    let w = if weight.is_finite() { weight.clamp(0.0, 1.0) } else { 0.0 };
    color(0.35 + 0.65 * w, 0.6 - 0.25 * w, 0.9 - 0.8 * w, 0.25 + 0.75 * w)
}

/// The plan flown at a cycle: an entity per sampling-time scenario (`plan/<i>`, replaced at
/// every cycle), its predicted positions as a line coloured by the scenario's weight.
pub fn plan_update(time_ns: u64, record: &CycleRecord) -> SceneUpdate {
    let entities = record
        .predictions
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let mut e = entity(time_ns, &format!("plan/{i}"));
            e.metadata = vec![
                KeyValuePair { key: "sampling_time_s".into(), value: p.sampling_time_s.to_string() },
                KeyValuePair { key: "weight".into(), value: p.weight.to_string() },
            ];
            e.lines.push(LinePrimitive {
                r#type: line_primitive::Type::LineStrip as i32,
                pose: Some(at(0.0, 0.0, 0.0)),
                thickness: 2.0 + 4.0 * p.weight.clamp(0.0, 1.0),
                scale_invariant: true,
                points: p.positions_m.iter().map(|q| Point3 { x: q[0], y: q[1], z: q[2] }).collect(),
                color: Some(weight_color(p.weight)),
                colors: Vec::new(),
                indices: Vec::new(),
            });
            e
        })
        .collect();
    SceneUpdate { deletions: Vec::new(), entities }
}

/// The MCAP file of a run's log: `dir/<scenario>-<controller>.mcap` (as the CSV log).
pub fn mcap_path(dir: &Path, scenario: &str, controller: &str) -> PathBuf {
    dir.join(format!("{scenario}-{controller}.mcap"))
}

/// Writes one run as an MCAP file: the scene, every cycle (the bench's controller's
/// `records`; for a run without them, an external controller's, the commands the plant
/// `applied`), and the plant's last state as the last pose (at `end_time_ns`).
pub fn write_mcap(
    path: &Path,
    scenario: &Scenario,
    controller: &str,
    records: &[CycleRecord],
    applied: &[CycleRow],
    end: Option<(u64, [f64; 8])>,
) -> anyhow::Result<()> {
    let ctx = Context::new();
    let _ = std::fs::remove_file(path);
    let writer = ctx
        .mcap_writer()
        .create_new_buffered_file(path)
        .with_context(|| format!("cannot create {}", path.display()))?;
    let channels = Channels::new(&ctx);
    let metadata = [
        ("scenario".to_string(), scenario.name.clone()),
        ("controller".to_string(), controller.to_string()),
        ("seed".to_string(), scenario.seed.to_string()),
        ("hilbench_version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
        ("hilbench_commit".to_string(), env!("HILBENCH_COMMIT").to_string()),
    ];
    writer
        .write_metadata("hilbench", metadata.into_iter().collect())
        .with_context(|| format!("cannot write {}", path.display()))?;
    channels.scene(scenario, records.first().map_or(0, |r| r.sample_time_ns));
    for record in records {
        channels.cycle(scenario, record);
    }
    if records.is_empty() {
        for row in applied {
            channels.applied(scenario, row);
        }
    }
    if let Some((time_ns, state)) = end {
        channels.final_pose(time_ns, &state);
    }
    writer.close().with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

/// Writes the MCAP file of every run of `batch` into `dir`. The failed run kept as far as it
/// flew ends at its last cycle (no plant state after it).
pub fn write_batch(dir: &Path, batch: &Batch) -> anyhow::Result<Vec<PathBuf>> {
    let mut paths = Vec::with_capacity(batch.runs.len());
    for run in &batch.runs {
        let summary = &run.summary;
        let end =
            run.error.is_none().then(|| (mav::s_to_ns(summary.end_time_s).unwrap_or(0), summary.final_state));
        let path = mcap_path(dir, &summary.scenario, &summary.controller);
        write_mcap(&path, &run.job.scenario, &summary.controller, &run.records, &run.rows, end)?;
        paths.push(path);
    }
    Ok(paths)
}

/// The live view of a real-time run: a Foxglove WebSocket server serving [`Channels`] as the
/// cycles arrive. Cheap to clone (one server).
#[derive(Clone)]
pub struct Live {
    inner: Arc<LiveInner>,
}

struct LiveInner {
    /// Kept alive with the server: the channels' context.
    _ctx: Arc<Context>,
    channels: Channels,
    server: std::sync::Mutex<Option<foxglove::WebSocketServerHandle>>,
    addr: std::net::SocketAddr,
}

impl std::fmt::Debug for Live {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Live").field("addr", &self.inner.addr).finish()
    }
}

/// Every so many cycles the live view sends the scene again, for viewers that connect late
/// (the protocol keeps no message for later subscribers).
const LIVE_SCENE_EVERY: u64 = 20;

impl Live {
    /// Starts the server on `addr` (port 0: any free one); it runs on the SDK's own runtime.
    pub fn start(addr: std::net::SocketAddr) -> anyhow::Result<Self> {
        let ctx = Context::new();
        let channels = Channels::new(&ctx);
        let handle = foxglove::WebSocketServer::new()
            .name("hilbench")
            .context(&ctx)
            .bind(addr.ip().to_string(), addr.port())
            .start_blocking()
            .with_context(|| format!("--foxglove-ws: cannot serve on {addr}"))?;
        let addr = std::net::SocketAddr::new(addr.ip(), handle.port());
        Ok(Self {
            inner: Arc::new(LiveInner {
                _ctx: ctx,
                channels,
                server: std::sync::Mutex::new(Some(handle)),
                addr,
            }),
        })
    }

    /// Where it listens.
    pub fn addr(&self) -> std::net::SocketAddr {
        self.inner.addr
    }

    /// Stops the server (its clients are disconnected).
    pub fn stop(&self) {
        let handle = self.inner.server.lock().ok().and_then(|mut s| s.take());
        if let Some(handle) = handle {
            // Waits for the server to stop; there is nothing to do if it fails.
            handle.stop().wait_blocking();
        }
    }
}

impl crate::run::CycleSink for Live {
    /// A cycle of a run of `scenario` (the scene with its first cycle and every
    /// [`LIVE_SCENE_EVERY`] cycles).
    fn cycle(&self, scenario: &Scenario, record: &CycleRecord) {
        if record.cycle.is_multiple_of(LIVE_SCENE_EVERY) {
            self.inner.channels.scene(scenario, record.sample_time_ns);
        }
        self.inner.channels.cycle(scenario, record);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `q v q*` for a unit quaternion.
    fn rotate(q: &Quaternion, v: [f64; 3]) -> [f64; 3] {
        let (w, x, y, z) = (q.w, q.x, q.y, q.z);
        [
            (1.0 - 2.0 * (y * y + z * z)) * v[0]
                + 2.0 * (x * y - w * z) * v[1]
                + 2.0 * (x * z + w * y) * v[2],
            2.0 * (x * y + w * z) * v[0]
                + (1.0 - 2.0 * (x * x + z * z)) * v[1]
                + 2.0 * (y * z - w * x) * v[2],
            2.0 * (x * z - w * y) * v[0]
                + 2.0 * (y * z + w * x) * v[1]
                + (1.0 - 2.0 * (x * x + y * y)) * v[2],
        ]
    }

    #[test]
    fn the_attitude_points_the_thrust_axis_where_the_model_accelerates() {
        // mav::MavModel: thrust acts along (cos phi sin theta, -sin phi, cos phi cos theta).
        for (phi, theta) in [(0.0, 0.0), (0.17, 0.0), (0.0, -0.17), (0.1, 0.15), (-0.17, 0.17)] {
            let q = attitude(phi, theta);
            let norm = (q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z).sqrt();
            assert!((norm - 1.0).abs() < 1e-12);
            let axis = rotate(&q, [0.0, 0.0, 1.0]);
            let model = [phi.cos() * theta.sin(), -phi.sin(), phi.cos() * theta.cos()];
            for k in 0..3 {
                assert!((axis[k] - model[k]).abs() < 1e-12, "{phi} {theta}: {axis:?} vs {model:?}");
            }
        }
    }

    #[test]
    fn heavier_scenarios_are_drawn_more_opaque_and_warmer() {
        let (light, heavy) = (weight_color(0.05), weight_color(0.9));
        assert!(heavy.a > light.a && heavy.r > light.r && heavy.b < light.b);
        for w in [f64::NAN, -1.0, 2.0] {
            let c = weight_color(w);
            assert!([c.r, c.g, c.b, c.a].iter().all(|v| (0.0..=1.0).contains(v)), "{w}: {c:?}");
        }
    }

    /// The fields of the JSON schema of `T`.
    fn fields<T: JsonMessage>() -> Vec<String> {
        let schema = serde_json::to_value(schemars::schema_for!(T)).expect("a JSON schema");
        schema["properties"].as_object().expect("properties").keys().cloned().collect()
    }

    #[test]
    fn the_layout_plots_only_fields_the_channels_carry() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/foxglove-layout.json");
        let layout: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).expect("docs/foxglove-layout.json"))
                .expect("the layout is JSON");
        let known: Vec<(&str, Vec<String>)> = vec![
            ("/state", fields::<StateMsg>()),
            ("/command", fields::<CommandMsg>()),
            ("/delays", fields::<DelaysMsg>()),
            ("/safety", fields::<SafetyMsg>()),
        ];
        let mut plotted = 0;
        for (id, config) in layout["configById"].as_object().expect("configById") {
            for p in config["paths"].as_array().into_iter().flatten() {
                let value = p["value"].as_str().expect("a message path");
                let (topic, field) = value.split_once('.').expect("topic.field");
                let field = field.split('[').next().unwrap_or(field);
                let (_, names) =
                    known.iter().find(|(t, _)| *t == topic).unwrap_or_else(|| panic!("{id}: {value}"));
                assert!(names.iter().any(|n| n == field), "{id}: {value}: no field {field} in {names:?}");
                plotted += 1;
            }
            if let Some(topics) = config["topics"].as_object() {
                for topic in topics.keys() {
                    assert!(TOPICS.contains(&topic.as_str()), "{id}: {topic}");
                }
            }
        }
        assert!(plotted >= 10, "{plotted} series");
    }
}
