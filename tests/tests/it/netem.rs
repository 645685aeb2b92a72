//! Integration tests: netem.
//! A real plant and a real netem on loopback ports; the controller side talks gRPC to netem.
//! Lockstep runs are checked bit for bit against the in-process truth simulation of `mav`
//! fed with the delays of an independent `delay::DelayLine` with the same seed.

use std::net::SocketAddr;
use std::time::Duration;

use delay::{DelayLine, Direction, DirectionProfile, Distribution, Fate, Ordering};
use hilbench_proto::convert::netem::{Stamp, StampOutcome, Stamped, read_clock};
use hilbench_proto::pb;
use hilbench_proto::pb::netem_control_client::NetemControlClient;
use hilbench_proto::pb::plant_client::PlantClient;
use hilbench_tests::server::{self, Running};
use hilbench_tests::start_plant;
use hilbench_tests::streams::{assert_exhausted, open_when_a_slot_is_free};
use mav::{CommandMeta, Input, PlantSim, Scenario, SimSettings, TimeMode};
use plant::PlantConfig;
use tokio_stream::StreamExt;
use tonic::transport::Channel;
use tonic::{Code, Status};

/// Generous bound for anything that must happen "soon" on a loaded machine.
const PATIENCE: Duration = Duration::from_secs(30);

/// A netem served on `127.0.0.1:<ephemeral>`.
type RunningNetem = Running<netem::NetemError>;

async fn start_netem(config: netem::Config) -> RunningNetem {
    server::start("netem", |listener, shutdown| netem::serve(listener, config, shutdown)).await
}

/// Clients of the two APIs a running netem serves.
trait NetemClients {
    async fn plant(&self) -> PlantClient<Channel>;
    async fn control(&self) -> NetemControlClient<Channel>;
}

impl NetemClients for RunningNetem {
    async fn plant(&self) -> PlantClient<Channel> {
        PlantClient::new(self.channel().await)
    }
    async fn control(&self) -> NetemControlClient<Channel> {
        NetemControlClient::new(self.channel().await)
    }
}

fn lockstep_netem(upstream: SocketAddr, c2p: DirectionProfile, p2c: DirectionProfile) -> netem::Config {
    let mut c = netem::Config::new(upstream.to_string());
    c.time_mode = mav::TimeModeChoice::Fixed(TimeMode::Lockstep);
    c.controller_to_plant = c2p;
    c.plant_to_controller = p2c;
    c
}

fn input(k: u64) -> [f64; 3] {
    let k = k as f64;
    [9.81 + 0.4 * (0.7 * k).sin(), 0.05 * (0.3 * k).cos(), -0.04 * (0.5 * k).sin()]
}

fn command(seq: u64, based_on: &pb::StateSample) -> pb::Command {
    let u = input(seq);
    pb::Command {
        input: Some(pb::ControlInput { thrust_mps2: u[0], roll_rad: u[1], pitch_rad: u[2] }),
        command_seq: seq,
        based_on_sample_seq: based_on.seq,
        based_on_sample_time_ns: based_on.time_ns,
    }
}

fn bits(s: &pb::StateSample) -> Vec<u64> {
    s.state.as_ref().expect("sample carries a state").x.iter().map(|v| v.to_bits()).collect()
}

/// netem's stamp of the command an answer's metadata carries.
fn command_stamp(md: &tonic::metadata::MetadataMap) -> Stamp {
    match Stamp::read(md, Stamped::Command) {
        Ok(Some(stamp)) => stamp,
        Ok(None) => panic!("no command stamp in {md:?}"),
        Err(e) => panic!("{e} in {md:?}"),
    }
}

fn assert_invalid<T: std::fmt::Debug>(r: Result<T, Status>, field: &str) {
    match r {
        Ok(v) => panic!("expected INVALID_ARGUMENT naming `{field}`, got {v:?}"),
        Err(s) => {
            assert_eq!(s.code(), Code::InvalidArgument, "{s:?}");
            assert!(s.message().contains(field), "`{}` does not name `{field}`", s.message());
        }
    }
}

/// Drives a lockstep run through netem: every 50 ms a command computed from the last sample,
/// sent with Step. Returns the samples and the (send, release) times netem stamped.
async fn lockstep_run(
    client: &mut PlantClient<Channel>,
    cycles: u64,
) -> (Vec<pb::StateSample>, Vec<(u64, u64)>) {
    let reset = client
        .reset(pb::ResetRequest { definition: None, scenario: "paper-1".into(), initial_state: None })
        .await
        .expect("reset through netem")
        .into_inner();
    let mut last = reset.sample.expect("reset sample");
    let mut samples = vec![last.clone()];
    let mut stamps = Vec::new();
    for k in 1..=cycles {
        let r = client
            .step(pb::StepRequest {
                command: Some(command(k, &last)),
                duration_ns: 50_000_000,
                ..Default::default()
            })
            .await
            .expect("step through netem");
        let stamp = command_stamp(r.metadata());
        stamps.push((stamp.send_time_ns, stamp.release_time_ns));
        assert_eq!(read_clock(r.metadata()), Some(TimeMode::Lockstep), "plant time");
        last = r.into_inner().sample.expect("sample");
        samples.push(last.clone());
    }
    (samples, stamps)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lockstep_command_takes_effect_exactly_at_send_time_plus_delay() {
    let plant = start_plant(PlantConfig::lockstep(Scenario::paper_1())).await;
    // Gamma(12, 0.015) has a mean of 180 ms, so commands sent every 50 ms overlap in flight
    // and FIFO queueing is exercised too.
    let c2p = DirectionProfile::with_delay(Distribution::Gamma { shape: 12.0, scale_s: 0.015 }, 7);
    let netem = start_netem(lockstep_netem(plant.addr, c2p.clone(), DirectionProfile::default())).await;
    let mut client = netem.plant().await;
    let cycles = 40;
    let (samples, stamps) = lockstep_run(&mut client, cycles).await;

    // The reference: the same delays from an independent delay line, applied in-process.
    let mut line = DelayLine::new(Direction::ControllerToPlant, c2p).expect("valid profile");
    let mut sim = PlantSim::new(&Scenario::paper_1(), SimSettings::default()).expect("valid");
    let mut pending: Vec<(u64, u64, CommandMeta)> = Vec::new(); // (release, seq, meta)
    let mut last = samples[0].clone();
    assert_eq!(bits(&last), sim.peek().state.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
    for k in 1..=cycles {
        let t = sim.time_ns();
        let d = line.send(t);
        let Fate::Delivered { original, duplicate: None } = d.fate else {
            panic!("no loss or duplicates configured")
        };
        assert_eq!(stamps[k as usize - 1], (t, original.release_time_ns), "netem's stamps of command {k}");
        assert!(original.release_time_ns >= t + delay::delay_ns(d.sampled_delay_s));
        let meta = CommandMeta {
            command_seq: k,
            based_on_sample_seq: last.seq,
            based_on_sample_time_ns: last.time_ns,
        };
        pending.push((original.release_time_ns, k, meta));
        pending.sort_by_key(|p| p.0);
        let target = t + 50_000_000;
        while let Some(&(r, seq, meta)) = pending.first().filter(|p| p.0 <= target) {
            sim.advance_to(r, |_| {});
            sim.apply(Input::from(input(seq)), meta).expect("finite");
            pending.remove(0);
        }
        sim.advance_to(target, |_| {});
        let got = &samples[k as usize];
        let want = sim.sample();
        assert_eq!(got.time_ns, want.time_ns, "cycle {k}");
        assert_eq!(bits(got), want.state.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), "cycle {k}: state");
        let lc = got.last_command.as_ref().expect("last command");
        assert_eq!(lc.command_seq, want.last_command.meta.command_seq, "cycle {k}: command in force");
        assert_eq!(
            lc.applied_time_ns, want.last_command.applied_time_ns,
            "cycle {k}: applied at its release"
        );
        last = got.clone();
    }
    // Some command was applied, and at exactly its send time plus its injected delay.
    let applied: Vec<_> =
        samples.iter().filter_map(|s| s.last_command.as_ref()).filter(|c| !c.initial).collect();
    assert!(!applied.is_empty(), "no command took effect in {cycles} cycles");
    for c in applied {
        let (send, release) = stamps[c.command_seq as usize - 1];
        assert_eq!(c.applied_time_ns, release, "command {} sent at {send}", c.command_seq);
        assert!(release > send, "Gamma delays are positive");
    }
    // netem counts each command at the plant time it was sent: those before a time, strictly.
    let mut control = netem.control().await;
    for t in [0, 1, 50_000_000, 50_000_001, 1_000_000_000, u64::MAX] {
        let want = stamps.iter().filter(|(send, _)| *send < t).count() as u64;
        let got = control
            .commands_sent_before(pb::CommandsSentBeforeRequest { before_plant_time_ns: t })
            .await
            .expect("counted in lockstep")
            .into_inner()
            .commands;
        assert_eq!(got, want, "commands sent before {t} ns");
    }
    netem.stop().await.expect("netem served cleanly");
    plant.stop().await.expect("plant stops");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lockstep_runs_through_netem_are_bit_identical_with_sample_delays_loss_and_duplicates() {
    let plant = start_plant(PlantConfig::lockstep(Scenario::paper_1())).await;
    let preset = delay::preset("paper-split", 11).expect("preset");
    let mut c2p = preset.to_plant;
    c2p.loss_probability = 0.1;
    c2p.duplicate_probability = 0.2;
    c2p.ordering = Ordering::Independent;
    let mut p2c = preset.to_controller;
    p2c.loss_probability = 0.1;
    let netem = start_netem(lockstep_netem(plant.addr, c2p, p2c)).await;
    let mut client = netem.plant().await;
    let mut control = netem.control().await;
    control.start_trace(pb::StartTraceRequest {}).await.expect("start trace");
    let (a, sa) = lockstep_run(&mut client, 60).await;
    let trace_a = control.stop_trace(pb::StopTraceRequest {}).await.expect("stop trace").into_inner();
    control.start_trace(pb::StartTraceRequest {}).await.expect("start trace");
    let (b, sb) = lockstep_run(&mut client, 60).await;
    let trace_b = control.stop_trace(pb::StopTraceRequest {}).await.expect("stop trace").into_inner();
    assert_eq!(sa, sb);
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!((x.time_ns, bits(x)), (y.time_ns, bits(y)));
        assert_eq!(x.last_command, y.last_command);
    }
    // The trace is the same too, and it shows stale samples, losses and duplicates.
    // The second run starts with a reset that drops the commands the first left in flight.
    let (reset_drops, rest_b): (Vec<_>, Vec<_>) =
        trace_b.records.iter().partition(|r| r.dropped && r.drop_reason == "plant reset");
    assert!(!reset_drops.is_empty(), "commands in flight at the reset are reported dropped");
    assert_eq!(trace_a.records.len(), rest_b.len());
    for (i, (x, y)) in trace_a.records.iter().zip(rest_b).enumerate() {
        assert_eq!(x, y, "trace record {i}");
    }
    let p2c_records =
        trace_a.records.iter().filter(|r| r.direction == pb::Direction::PlantToController as i32);
    assert!(p2c_records.clone().any(|r| !r.dropped && r.injected_delay_s > 0.0), "no stale sample");
    assert!(trace_a.records.iter().any(|r| r.dropped && r.drop_reason == "loss"), "no loss");
    assert!(trace_a.records.iter().any(|r| r.duplicate), "no duplicate");
    // A stale sample is the state at (end of the step - its delay).
    let stale = a.iter().skip(1).any(|s| s.time_ns % 50_000_000 != 0);
    assert!(stale, "every sample was taken at the end of its step");
    netem.stop().await.expect("netem served cleanly");
    plant.stop().await.expect("plant stops");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn profiles_change_at_run_time_and_invalid_ones_are_refused_keeping_the_old() {
    let plant = start_plant(PlantConfig::lockstep(Scenario::paper_1())).await;
    let config = netem::Config::new(plant.addr.to_string()).with_preset("paper", 42).expect("paper preset");
    let netem = start_netem(config).await; // time mode: auto, from the plant
    let mut client = netem.plant().await;
    let mut control = netem.control().await;
    let c2p = pb::Direction::ControllerToPlant as i32;

    let p = control.get_profile(pb::GetProfileRequest { direction: c2p }).await.expect("get").into_inner();
    let want: pb::DirectionProfile = (&delay::preset("paper", 42).expect("paper").to_plant).into();
    assert_eq!(p, want);

    let constant = |delay_s: f64| pb::DirectionProfile {
        delay: Some(pb::DelayDistribution {
            kind: Some(pb::delay_distribution::Kind::Constant(pb::ConstantDelay { delay_s })),
        }),
        ordering: pb::Ordering::Fifo as i32,
        ..Default::default()
    };
    let set = control
        .set_profile(pb::SetProfileRequest {
            direction: c2p,
            profile: Some(constant(0.03)),
            preset: String::new(),
        })
        .await
        .expect("set a constant delay")
        .into_inner();
    assert_eq!(set, constant(0.03));

    let reset = client.reset(pb::ResetRequest::default()).await.expect("reset").into_inner();
    let start = reset.sample.expect("sample");
    let r = client.apply_command(command(1, &start)).await.expect("apply");
    let stamp = command_stamp(r.metadata());
    assert_eq!((stamp.delay_ns, stamp.outcome), (30_000_000, StampOutcome::InFlight));
    assert!(r.into_inner().applied.is_none(), "a held command has not been applied yet");

    // Bad input while the command is in flight: refused, naming the field; nothing changes.
    let bad_gamma = pb::DirectionProfile {
        delay: Some(pb::DelayDistribution {
            kind: Some(pb::delay_distribution::Kind::Gamma(pb::GammaDelay { shape: -1.0, scale_s: 0.01 })),
        }),
        ..Default::default()
    };
    let req = |profile: Option<pb::DirectionProfile>, preset: &str| pb::SetProfileRequest {
        direction: c2p,
        profile,
        preset: preset.to_string(),
    };
    assert_invalid(control.set_profile(req(Some(bad_gamma), "")).await, "profile.delay.gamma.shape");
    let mut bad_loss = constant(0.01);
    bad_loss.loss_probability = 1.5;
    assert_invalid(control.set_profile(req(Some(bad_loss), "")).await, "profile.loss_probability");
    let empty_trace = pb::DirectionProfile {
        delay: Some(pb::DelayDistribution {
            kind: Some(pb::delay_distribution::Kind::Trace(pb::TraceDelay {
                delays_s: vec![],
                looping: true,
                ..Default::default()
            })),
        }),
        ..Default::default()
    };
    assert_invalid(control.set_profile(req(Some(empty_trace), "")).await, "profile.delay.trace.delays_s");
    assert_invalid(control.set_profile(req(None, "no-such-preset")).await, "preset");
    assert_invalid(
        control.set_profile(req(Some(constant(f64::NAN)), "")).await,
        "profile.delay.constant.delay_s",
    );
    let p = control.get_profile(pb::GetProfileRequest { direction: c2p }).await.expect("get").into_inner();
    assert_eq!(p, constant(0.03), "the running profile is unchanged");

    // The command in flight arrives at its release time.
    let s = client
        .advance(pb::AdvanceRequest { duration_ns: 40_000_000, ..Default::default() })
        .await
        .expect("advance")
        .into_inner();
    let lc = s.sample.expect("sample").last_command.expect("last command");
    assert_eq!((lc.command_seq, lc.applied_time_ns), (1, 30_000_000));
    let stats = control.get_stats(pb::GetStatsRequest {}).await.expect("stats").into_inner();
    let c = stats.controller_to_plant.expect("c2p stats");
    assert_eq!((c.sent, c.delivered, c.dropped, c.in_flight), (1, 1, 0, 0));
    assert_eq!(c.delay_max_s, 0.03);
    assert_eq!(stats.time_mode, pb::TimeMode::Lockstep as i32);

    // wait_for_command_seq: the step goes on to the command's release (t + max(T, d)).
    let now = s_time(&mut client).await;
    let r = client
        .step(pb::StepRequest {
            command: Some(command(5, &start)),
            duration_ns: 10_000_000,
            wait_for_command_seq: 5,
        })
        .await
        .expect("step waiting for its command")
        .into_inner();
    let s = r.sample.expect("sample");
    assert_eq!(s.time_ns, now + 30_000_000, "advanced past 10 ms to the release at +30 ms");
    let lc = s.last_command.expect("last command");
    assert_eq!((lc.command_seq, lc.applied_time_ns), (5, now + 30_000_000));

    // A preset for both directions at run time.
    let both = pb::SetProfileRequest { direction: 0, profile: None, preset: "paper-split".into() };
    control.set_profile(both).await.expect("preset");
    let p2c = pb::Direction::PlantToController as i32;
    let p = control.get_profile(pb::GetProfileRequest { direction: p2c }).await.expect("get").into_inner();
    let want: pb::DirectionProfile =
        (&delay::preset("paper-split", 42).expect("preset").to_controller).into();
    assert_eq!(p, want);
    netem.stop().await.expect("netem served cleanly");
    plant.stop().await.expect("plant stops");
}

async fn s_time(client: &mut PlantClient<Channel>) -> u64 {
    client.get_state(pb::GetStateRequest {}).await.expect("get state").into_inner().time_ns
}

/// Serves a lockstep plant on `addr` (a fixed port, so it can come back at the same address).
async fn serve_plant_at(addr: SocketAddr) -> Running<plant::PlantError> {
    let mut tries = 0;
    let listener = loop {
        match tokio::net::TcpListener::bind(addr).await {
            Ok(l) => break l,
            Err(_) if tries < 100 => {
                tries += 1;
                sleep_ms(50).await;
            }
            Err(e) => panic!("cannot bind {addr} again: {e}"),
        }
    };
    server::start_on("plant server", listener, |listener, shutdown| {
        plant::serve(listener, PlantConfig::lockstep(Scenario::paper_1()), shutdown)
    })
}

async fn sleep_ms(ms: u64) {
    tokio::time::sleep(Duration::from_millis(ms)).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn upstream_loss_gives_unavailable_drops_in_flight_with_a_reason_then_recovers() {
    let addr = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
        l.local_addr().expect("addr")
    };
    let plant = serve_plant_at(addr).await;
    let mut config = lockstep_netem(
        addr,
        DirectionProfile::with_delay(Distribution::Constant { delay_s: 0.1 }, 1),
        DirectionProfile::default(),
    );
    config.probe_interval_ms = 50;
    let netem = start_netem(config).await;
    let mut client = netem.plant().await;
    let mut control = netem.control().await;
    let start =
        client.reset(pb::ResetRequest::default()).await.expect("reset").into_inner().sample.expect("s");
    control.start_trace(pb::StartTraceRequest {}).await.expect("trace");
    client.apply_command(command(1, &start)).await.expect("held command");

    // The plant goes away with the command in flight.
    plant.stop().await.expect("plant serves");
    let err = client
        .advance(pb::AdvanceRequest { duration_ns: 200_000_000, ..Default::default() })
        .await
        .expect_err("plant is gone");
    assert_eq!(err.code(), Code::Unavailable, "{err:?}");
    let stats = control.get_stats(pb::GetStatsRequest {}).await.expect("stats").into_inner();
    assert!(!stats.upstream_connected);
    assert!(stats.upstream_failures >= 1);
    let c = stats.controller_to_plant.expect("c2p");
    assert_eq!((c.sent, c.delivered, c.dropped, c.in_flight), (1, 0, 1, 0));
    let trace = control.stop_trace(pb::StopTraceRequest {}).await.expect("trace").into_inner();
    let dropped: Vec<_> = trace.records.iter().filter(|r| r.dropped).collect();
    assert_eq!(dropped.len(), 1);
    assert_eq!(dropped[0].payload_seq, 1);
    assert!(dropped[0].drop_reason.starts_with("upstream unavailable"), "{}", dropped[0].drop_reason);
    let err = client.apply_command(command(2, &start)).await.expect_err("still gone");
    assert_eq!(err.code(), Code::Unavailable);

    // The plant comes back at the same address; netem reconnects.
    let plant = serve_plant_at(addr).await;
    let deadline = tokio::time::Instant::now() + PATIENCE;
    let reset = loop {
        match client.reset(pb::ResetRequest::default()).await {
            Ok(r) => break r.into_inner(),
            Err(e) if tokio::time::Instant::now() < deadline => {
                assert_eq!(e.code(), Code::Unavailable, "{e:?}");
                sleep_ms(50).await;
            }
            Err(e) => panic!("netem did not reconnect: {e:?}"),
        }
    };
    let start = reset.sample.expect("sample");
    client.apply_command(command(3, &start)).await.expect("apply after recovery");
    let s = client
        .advance(pb::AdvanceRequest { duration_ns: 150_000_000, ..Default::default() })
        .await
        .expect("advance")
        .into_inner();
    let lc = s.sample.expect("sample").last_command.expect("lc");
    assert_eq!((lc.command_seq, lc.applied_time_ns), (3, 100_000_000));
    let stats = control.get_stats(pb::GetStatsRequest {}).await.expect("stats").into_inner();
    assert!(stats.upstream_connected);
    netem.stop().await.expect("netem served cleanly");
    plant.stop().await.expect("plant serves");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn real_time_streams_and_commands_are_delayed_and_stamped() {
    let plant = start_plant(PlantConfig::real_time(Scenario::paper_1())).await;
    let mut config = netem::Config::new(plant.addr.to_string());
    config.controller_to_plant = DirectionProfile::with_delay(Distribution::Constant { delay_s: 0.02 }, 3);
    config.plant_to_controller = DirectionProfile::with_delay(Distribution::Constant { delay_s: 0.005 }, 4);
    let netem = start_netem(config).await;
    let mut client = netem.plant().await;
    let mut control = netem.control().await;
    let mut deliveries =
        control.stream_deliveries(pb::StreamDeliveriesRequest {}).await.expect("deliveries").into_inner();
    let mut stream = client
        .stream_state(pb::StreamStateRequest { period_ns: 10_000_000 })
        .await
        .expect("stream")
        .into_inner();
    let first =
        tokio::time::timeout(PATIENCE, stream.next()).await.expect("a sample").expect("open").expect("ok");
    let r = client.apply_command(command(9, &first)).await.expect("apply");
    assert_eq!(read_clock(r.metadata()), Some(TimeMode::RealTime), "netem's clock");
    assert_eq!(command_stamp(r.metadata()).delay_ns, 20_000_000);
    assert!(r.into_inner().applied.is_none());
    // The command shows up in a later sample.
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        let s =
            tokio::time::timeout(PATIENCE, stream.next()).await.expect("sample").expect("open").expect("ok");
        if s.last_command.as_ref().is_some_and(|c| c.command_seq == 9) {
            break;
        }
        assert!(tokio::time::Instant::now() < deadline, "the command never arrived");
    }
    // Every stream item is described on the delivery stream, with its injected delay.
    let rec =
        tokio::time::timeout(PATIENCE, deliveries.next()).await.expect("record").expect("open").expect("ok");
    assert!(!rec.dropped);
    let want = if rec.direction == pb::Direction::PlantToController as i32 { 5_000_000 } else { 20_000_000 };
    assert_eq!(rec.release_time_ns - rec.sent_time_ns, want);
    assert!(rec.injected_delay_s >= want as f64 / 1e9, "released early: {rec:?}");
    let stats = control.get_stats(pb::GetStatsRequest {}).await.expect("stats").into_inner();
    let p = stats.plant_to_controller.expect("p2c");
    assert!(p.delivered > 0 && p.delay_p50_s >= 0.005, "{p:?}");
    assert_eq!(p.dropped, 0);
    let c = stats.controller_to_plant.expect("c2p");
    assert_eq!((c.sent, c.delivered, c.dropped), (1, 1, 0));
    // Commands are counted by plant time in lockstep only.
    let by_time =
        control.commands_sent_before(pb::CommandsSentBeforeRequest { before_plant_time_ns: 1 }).await;
    assert_eq!(by_time.expect_err("real time").code(), Code::FailedPrecondition);
    drop(stream);
    netem.stop().await.expect("netem served cleanly");
    plant.stop().await.expect("plant stops");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_command_the_plant_would_refuse_is_refused_by_netem_and_time_does_not_move() {
    let plant = start_plant(PlantConfig::lockstep(Scenario::paper_1())).await;
    let c2p = DirectionProfile::with_delay(Distribution::Constant { delay_s: 0.1 }, 7);
    let netem = start_netem(lockstep_netem(plant.addr, c2p, DirectionProfile::default())).await;
    let mut client = netem.plant().await;
    let reset = client
        .reset(pb::ResetRequest { definition: None, scenario: "paper-1".into(), initial_state: None })
        .await
        .expect("reset through netem")
        .into_inner()
        .sample
        .expect("reset sample");
    for (thrust, roll, field) in [
        (-1.0, 0.0, "command.input.thrust_mps2"),
        (5000.0, 0.0, "command.input.thrust_mps2"),
        (1e308, 0.0, "command.input.thrust_mps2"),
        (9.81, 2.0, "command.input.roll_rad"),
    ] {
        let mut bad = command(1, &reset);
        bad.input = Some(pb::ControlInput { thrust_mps2: thrust, roll_rad: roll, pitch_rad: 0.0 });
        assert_invalid(client.apply_command(bad).await, field);
        let step = pb::StepRequest { command: Some(bad), duration_ns: 50_000_000, ..Default::default() };
        assert_invalid(client.step(step).await, field);
    }
    // Nothing was held, applied or advanced: the plant is where the reset left it.
    let now = client.get_state(pb::GetStateRequest {}).await.expect("state").into_inner();
    assert_eq!(now.time_ns, reset.time_ns);
    let stats = netem.control().await.get_stats(pb::GetStatsRequest {}).await.expect("stats").into_inner();
    let commands = stats.controller_to_plant.expect("command stats");
    assert_eq!((commands.sent, commands.dropped, commands.in_flight), (0, 0, 0), "{commands:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn streams_beyond_max_streams_are_resource_exhausted_and_a_dropped_stream_frees_its_slot() {
    let plant = start_plant(PlantConfig::real_time(Scenario::paper_1())).await;
    let mut config = netem::Config::new(plant.addr.to_string());
    config.max_streams = 2;
    let netem = start_netem(config).await;
    let mut client = netem.plant().await;
    let mut control = netem.control().await;
    let request = || pb::StreamStateRequest { period_ns: 0 };
    // StreamState and StreamDeliveries share the cap.
    let mut samples = client.stream_state(request()).await.expect("a state stream").into_inner();
    let deliveries =
        control.stream_deliveries(pb::StreamDeliveriesRequest {}).await.expect("a delivery stream");
    assert_exhausted(client.stream_state(request()).await, 2);
    assert_exhausted(control.stream_deliveries(pb::StreamDeliveriesRequest {}).await, 2);
    tokio::time::timeout(PATIENCE, samples.next()).await.expect("a sample").expect("open").expect("ok");
    drop(deliveries);
    let mut again = open_when_a_slot_is_free("netem StreamState", PATIENCE, || {
        let mut client = client.clone();
        async move { client.stream_state(request()).await }
    })
    .await
    .into_inner();
    tokio::time::timeout(PATIENCE, again.next()).await.expect("a sample").expect("open").expect("ok");
    drop((samples, again));
    netem.stop().await.expect("netem served cleanly");
    plant.stop().await.expect("plant stops");
}

/// A netem in real time in front of a lockstep plant: samples are made only when the test
/// advances the plant (with its own client), and netem releases each into its streams as it
/// comes, so the test knows every sample that was sent without reading a clock.
async fn real_time_netem_on_a_lockstep_plant(
    tweak: impl FnOnce(&mut netem::Config),
) -> (hilbench_tests::RunningPlant, RunningNetem) {
    let plant = start_plant(PlantConfig::lockstep(Scenario::paper_1())).await;
    let mut config = netem::Config::new(plant.addr.to_string());
    config.time_mode = mav::TimeModeChoice::Fixed(TimeMode::RealTime);
    tweak(&mut config);
    let netem = start_netem(config).await;
    (plant, netem)
}

/// A client of netem whose HTTP/2 stream window is small, so that the transport holds a few
/// hundred samples of a stream that is not read, not tonic's default 2 MiB (19,000 samples).
async fn small_window_channel(netem: &RunningNetem) -> Channel {
    let endpoint = Channel::from_shared(netem.uri()).expect("uri").initial_stream_window_size(16 * 1024);
    endpoint.connect().await.expect("connect to netem")
}

/// Polls netem's statistics until `pred` holds; panics with `what` after `PATIENCE`.
async fn wait_for_stats(
    control: &mut NetemControlClient<Channel>,
    what: &str,
    pred: impl Fn(&pb::NetemStats) -> bool,
) -> pb::NetemStats {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        let s = control.get_stats(pb::GetStatsRequest {}).await.expect("stats").into_inner();
        if pred(&s) {
            return s;
        }
        assert!(tokio::time::Instant::now() < deadline, "timed out waiting for {what}: {s:?}");
        sleep_ms(5).await;
    }
}

fn p2c(s: &pb::NetemStats) -> pb::DirectionStats {
    s.plant_to_controller.clone().expect("plant-to-controller stats")
}

/// Advances the plant `steps` ms, 50 ms at a time, each time until netem has received the
/// samples (so that the plant's own buffer for netem never fills).
async fn advance_plant_step_by_step(
    plant: &mut PlantClient<Channel>,
    control: &mut NetemControlClient<Channel>,
    sent_before: u64,
    steps: u64,
) {
    for chunk in 1..=steps / 50 {
        plant
            .advance(pb::AdvanceRequest { duration_ns: 50_000_000, ..Default::default() })
            .await
            .expect("advance the plant");
        let want = sent_before + 50 * chunk;
        wait_for_stats(control, "netem to receive the samples", |s| p2c(s).sent == want).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_state_stream_not_read_holds_at_most_its_buffer_counts_the_discarded_and_resumes_at_the_newest() {
    const BUFFER: usize = 8;
    const STEPS: u64 = 2000;
    let (plant, netem) = real_time_netem_on_a_lockstep_plant(|c| c.stream_buffer = BUFFER).await;
    let mut control = netem.control().await;
    let mut driver = plant.client().await;
    let mut client = PlantClient::new(small_window_channel(&netem).await);
    let mut stream =
        client.stream_state(pb::StreamStateRequest { period_ns: 0 }).await.expect("stream").into_inner();
    let first =
        tokio::time::timeout(PATIENCE, stream.next()).await.expect("sample").expect("open").expect("ok");
    assert_eq!(first.time_ns, 0);
    control.start_trace(pb::StartTraceRequest {}).await.expect("start trace");

    // The reader stops reading while the plant makes STEPS samples.
    advance_plant_step_by_step(&mut driver, &mut control, 1, STEPS).await;
    // Once everything is released, netem holds one buffer's worth and no more: the rest went
    // into the transport (before it filled) or was discarded, oldest first, and counted.
    let held = wait_for_stats(&mut control, "the releases", |s| p2c(s).in_flight <= BUFFER as u64).await;
    let held = p2c(&held);
    assert_eq!(held.in_flight, BUFFER as u64, "{held:?}");
    assert!(held.stream_overflow_dropped > 0, "nothing was discarded: {held:?}");
    assert_eq!(held.dropped, held.stream_overflow_dropped, "every drop is an overflow: {held:?}");
    assert_eq!(held.sent, 1 + STEPS);
    assert_eq!(held.sent, held.delivered + held.dropped + held.in_flight, "the books balance: {held:?}");

    // Reading again: what the transport held, then the buffer, which ends at the newest.
    let mut times = vec![first.time_ns];
    while times.last() != Some(&(STEPS * 1_000_000)) {
        let s =
            tokio::time::timeout(PATIENCE, stream.next()).await.expect("sample").expect("open").expect("ok");
        times.push(s.time_ns);
    }
    // In order, each sample once; the gaps are where the buffer discarded samples (also
    // while the transport still took some: the plant's 50-sample bursts overflow 8 places).
    assert!(times.windows(2).all(|w| w[1] > w[0]), "out of order or repeated: {times:?}");
    let missing: u64 = times.windows(2).map(|w| (w[1] - w[0]) / 1_000_000 - 1).sum();
    assert_eq!(missing, held.stream_overflow_dropped, "the discarded are the ones the reader missed");
    let newest: Vec<u64> = (STEPS + 1 - BUFFER as u64..=STEPS).map(|k| k * 1_000_000).collect();
    assert_eq!(times[times.len() - BUFFER..], newest[..], "after the gap: the newest {BUFFER} samples");

    let after = p2c(&control.get_stats(pb::GetStatsRequest {}).await.expect("stats").into_inner());
    assert_eq!((after.delivered, after.in_flight), (times.len() as u64, 0), "{after:?}");
    let trace = control.stop_trace(pb::StopTraceRequest {}).await.expect("stop trace").into_inner();
    let discarded = trace.records.iter().filter(|r| r.dropped && r.drop_reason == "subscriber too slow");
    assert_eq!(discarded.count() as u64, held.stream_overflow_dropped, "each discarded sample is traced");
    drop(stream);
    netem.stop().await.expect("netem served cleanly");
    plant.stop().await.expect("plant stops");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_delivery_stream_reader_that_falls_behind_misses_the_oldest_records_and_netem_counts_them() {
    const STEPS: u64 = 3000;
    let (plant, netem) = real_time_netem_on_a_lockstep_plant(|c| c.deliveries_buffer = 16).await;
    let mut control = netem.control().await;
    let mut driver = plant.client().await;
    let mut records = NetemControlClient::new(small_window_channel(&netem).await)
        .stream_deliveries(pb::StreamDeliveriesRequest {})
        .await
        .expect("deliveries")
        .into_inner();
    // A state stream read as it comes, so that each sample is one record.
    let mut states = netem
        .plant()
        .await
        .stream_state(pb::StreamStateRequest { period_ns: 0 })
        .await
        .expect("s")
        .into_inner();
    let reader = tokio::spawn(async move {
        let mut newest = pb::StateSample::default();
        while newest.time_ns < STEPS * 1_000_000 {
            newest = tokio::time::timeout(PATIENCE, states.next())
                .await
                .expect("sample")
                .expect("open")
                .expect("ok");
        }
        (newest, states)
    });
    wait_for_stats(&mut control, "the first sample", |s| p2c(s).sent == 1).await;
    advance_plant_step_by_step(&mut driver, &mut control, 1, STEPS).await;
    let (newest, states) = reader.await.expect("state reader");

    // The delivery reader reads again, up to the record of the newest sample.
    let mut read = 0u64;
    loop {
        let r =
            tokio::time::timeout(PATIENCE, records.next()).await.expect("record").expect("open").expect("ok");
        read += 1;
        if r.payload_seq == newest.seq && !r.dropped {
            break;
        }
    }
    let stats = control.get_stats(pb::GetStatsRequest {}).await.expect("stats").into_inner();
    let p = p2c(&stats);
    assert!(stats.deliveries_lagged > 0, "the reader missed nothing: {stats:?}");
    assert_eq!(
        read + stats.deliveries_lagged,
        p.delivered + p.dropped,
        "every record published is read or counted missed: {stats:?}"
    );
    drop((records, states));
    netem.stop().await.expect("netem served cleanly");
    plant.stop().await.expect("plant stops");
}
