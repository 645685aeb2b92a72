//! The gateway's core and the simulator's autopilot talking MAVLink 2 frames to each other on
//! a clock the test moves (no sockets, no threads): the contracts of both, decision by
//! decision.

use mav::{CommandMeta, Input, Scenario};
use mavbridge::mavlink::dialects::common::{MavAutopilot, MavCmd, MavMessage, MavResult};
use mavbridge::mavlink::{self, MavHeader, MavlinkVersion};
use mavbridge::{
    AutopilotSettings, Bridge, BridgeSettings, Firmware, ModeRequest, Peer, Reboot, ResetRefusal,
    SimAutopilot, SimMode, modes,
};

const MS: u64 = 1_000_000;

/// Through the bytes of a MAVLink 2 frame, as on the wire.
fn wire(msg: &MavMessage, system_id: u8) -> (MavHeader, MavMessage) {
    let mut bytes = Vec::new();
    let header = MavHeader { system_id: u32::from(system_id), component_id: 1, sequence: 0 };
    mavlink::write_v2_msg(&mut bytes, header, msg).expect("encodes");
    mavlink::MavlinkReader::new(&bytes[..]).read_message::<MavMessage>(MavlinkVersion::V2).expect("decodes")
}

/// A gateway core and a simulated vehicle on one clock (the vehicle booted 3 s before the
/// gateway started: its clock is the gateway's + 3 s, until it reboots).
struct Pair {
    bridge: Bridge,
    vehicle: SimAutopilot,
    now_ns: u64,
    /// The vehicle's clock minus the gateway's, ns.
    vehicle_ahead_ns: i64,
    acks: Vec<(MavCmd, MavResult)>,
    /// `PARAM_VALUE`s heard: names and values.
    params: Vec<(String, f32)>,
    samples: Vec<mav::PlantSample>,
    /// The reboots the bridge reported, one event each.
    reboots: Vec<Reboot>,
    /// `COMMAND_LONG`s the bridge scheduled on its own (it must never).
    unasked_commands: usize,
    /// The vehicle does not hear the gateway, nor the gateway the vehicle.
    silent_vehicle: bool,
}

const VEHICLE_AHEAD_NS: u64 = 3_000 * MS;
/// Where the vehicle's frames come from (a serial device: one peer).
const VEHICLE: Peer = None;

fn sim_autopilot(scenario: &Scenario) -> SimAutopilot {
    SimAutopilot::new(scenario, AutopilotSettings { yaw_rad: 0.7, ..Default::default() }).expect("valid")
}

impl Pair {
    fn new(scenario: &Scenario) -> Self {
        Self::booted_before(scenario, VEHICLE_AHEAD_NS)
    }

    /// The vehicle booted `ahead_ns` before the gateway started.
    fn booted_before(scenario: &Scenario, ahead_ns: u64) -> Self {
        Self {
            bridge: Bridge::new(scenario.clone(), BridgeSettings::default(), 0, 1).expect("valid"),
            vehicle: sim_autopilot(scenario),
            now_ns: 0,
            vehicle_ahead_ns: ahead_ns as i64,
            acks: Vec::new(),
            params: Vec::new(),
            samples: Vec::new(),
            reboots: Vec::new(),
            unasked_commands: 0,
            silent_vehicle: false,
        }
        .heard()
    }

    /// The vehicle's first heartbeat has reached the gateway, which locked to it (its other
    /// first messages are not delivered: the tests start without a state).
    fn heard(mut self) -> Self {
        let mut out = Vec::new();
        self.vehicle.poll(self.vehicle_ns(), &mut out);
        out.retain(|m| matches!(m, MavMessage::HEARTBEAT(_)));
        self.send_to_gateway(out);
        assert!(self.bridge.vehicle().is_some(), "locked to the vehicle");
        self
    }

    /// The vehicle's clock now, ns.
    fn vehicle_ns(&self) -> u64 {
        u64::try_from(self.now_ns as i64 + self.vehicle_ahead_ns).expect("the vehicle has booted")
    }

    /// The vehicle reboots now: a fresh autopilot (disarmed, POSCTL, at the scenario's start)
    /// whose boot clock starts at 0.
    fn reboot_vehicle(&mut self, scenario: &Scenario) {
        self.vehicle = sim_autopilot(scenario);
        self.vehicle_ahead_ns = -(self.now_ns as i64);
    }

    fn send_to_vehicle(&mut self, msgs: Vec<MavMessage>) {
        for m in msgs {
            let (_, m) = wire(&m, 255);
            let mut answers = Vec::new();
            self.vehicle.on_message(&m, self.vehicle_ns(), &mut answers);
            self.send_to_gateway(answers);
        }
    }

    fn send_to_gateway(&mut self, msgs: Vec<MavMessage>) {
        if self.silent_vehicle {
            return;
        }
        for m in msgs {
            let (h, m) = wire(&m, 1);
            let event = self.bridge.on_message(VEHICLE, &h, &m, self.now_ns);
            self.samples.extend(event.sample);
            self.acks.extend(event.ack);
            self.params.extend(event.param);
            self.reboots.extend(event.reboot);
            if let Some(reply) = event.reply {
                self.send_to_vehicle(vec![reply]);
            }
        }
    }

    /// Runs both sides for `ms`, one millisecond at a time.
    fn run(&mut self, ms: u64) {
        for _ in 0..ms {
            self.now_ns += MS;
            let mut out = Vec::new();
            self.bridge.poll(self.now_ns, &mut out);
            self.unasked_commands += out.iter().filter(|m| matches!(m, MavMessage::COMMAND_LONG(_))).count();
            if !self.silent_vehicle {
                self.send_to_vehicle(out);
            }
            let mut out = Vec::new();
            self.vehicle.poll(self.vehicle_ns(), &mut out);
            self.send_to_gateway(out);
        }
    }

    fn command(&mut self, msg: MavMessage) -> (MavCmd, MavResult) {
        let before = self.acks.len();
        self.send_to_vehicle(vec![msg]);
        *self.acks.get(before).expect("acknowledged")
    }
}

#[test]
fn offboard_needs_the_setpoint_stream_and_the_gateway_never_arms_or_switches_on_its_own() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::new(&scenario);
    // The vehicle refuses OFFBOARD before any setpoint arrives.
    p.silent_vehicle = false;
    let ask = p.bridge.mode_message(ModeRequest::Px4Offboard);
    assert_eq!(p.command(ask.clone()), (MavCmd::MAV_CMD_DO_SET_MODE, MavResult::MAV_RESULT_DENIED));
    // Two seconds of streaming: still disarmed in POSCTL (nothing asked), and at rest.
    p.run(2_000);
    assert!(!p.vehicle.armed());
    assert_eq!(p.vehicle.mode(), SimMode::Posctl);
    assert!(p.bridge.link_alive(p.now_ns));
    assert_eq!(p.bridge.status(p.now_ns).mode, "POSCTL");
    assert!(p.bridge.counters().setpoints_sent >= 100, "50 Hz: {:?}", p.bridge.counters());
    assert_eq!(
        p.command(p.bridge.arm_message(true)),
        (MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, MavResult::MAV_RESULT_ACCEPTED)
    );
    p.run(1_100);
    assert!(!p.bridge.flies_setpoints(), "armed in POSCTL: the setpoints are not flown");
    assert_eq!(p.command(ask), (MavCmd::MAV_CMD_DO_SET_MODE, MavResult::MAV_RESULT_ACCEPTED));
    p.run(1_100);
    let status = p.bridge.status(p.now_ns);
    assert!(status.armed && status.mode == "OFFBOARD", "{status:?}");
    assert!(p.bridge.flies_setpoints());
    assert_eq!(status.battery_voltage_v, Some(16.0));
    // The yaw held is the vehicle's at arming.
    assert!((p.bridge.yaw_hold_rad() - 0.7).abs() < 1e-6);
}

#[test]
fn setpoints_are_sent_and_counted_only_once_the_vehicle_is_heard_so_five_counted_let_offboard_in() {
    let scenario = Scenario::paper_2();
    // The vehicle's heartbeat locked the link, then nothing reaches either side for 200 ms
    // (on a `udpin` link the gateway has no address yet to send to).
    let mut p = Pair::new(&scenario);
    p.silent_vehicle = true;
    p.run(200);
    assert_eq!(p.bridge.counters().setpoints_sent, 0, "no setpoint a vehicle could hear");
    // The link carries: once five setpoints are counted (what vehiclectl and the tests wait
    // for), the vehicle has heard them and takes arming and OFFBOARD at once.
    p.silent_vehicle = false;
    while p.bridge.counters().setpoints_sent < 5 {
        assert!(p.now_ns < 1_000 * MS, "setpoints within 0.8 s of the vehicle's attitude");
        p.run(1);
    }
    assert!(p.bridge.link_alive(p.now_ns));
    assert_eq!(
        p.command(p.bridge.arm_message(true)),
        (MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, MavResult::MAV_RESULT_ACCEPTED)
    );
    let ask = p.bridge.mode_message(ModeRequest::Px4Offboard);
    assert_eq!(p.command(ask), (MavCmd::MAV_CMD_DO_SET_MODE, MavResult::MAV_RESULT_ACCEPTED));
}

#[test]
fn commands_fly_the_vehicle_and_the_samples_carry_the_plants_stamps() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::new(&scenario);
    p.run(1_000);
    p.command(p.bridge.arm_message(true));
    p.command(p.bridge.mode_message(ModeRequest::Px4Offboard));
    p.run(100);
    let reset = p.bridge.reset(scenario.clone(), None, p.now_ns, 2).expect("at the start");
    assert_eq!((reset.seq, reset.time_ns, reset.flight_id), (0, 0, 2));
    assert!(reset.last_command.initial);
    p.samples.clear();
    // Climb: 12 m/s^2 for 300 ms.
    let meta = CommandMeta { command_seq: 1, based_on_sample_seq: 0, based_on_sample_time_ns: 0 };
    let (applied, msg) = p.bridge.apply(Input::new(12.0, 0.0, 0.05), meta, p.now_ns);
    // TIMESYNC measured the clocks on loopback: the command is stamped with the vehicle's time
    // since the reset (the reset was at the vehicle's latest state, at most 10 ms before).
    assert!(applied.applied_time_ns <= 11 * MS, "{applied:?}");
    assert!(
        p.bridge
            .status(p.now_ns)
            .clock_offset_ns
            .is_some_and(|(o, measured)| measured && o == VEHICLE_AHEAD_NS as i64)
    );
    p.send_to_vehicle(msg.into_iter().collect());
    p.run(300);
    let last = p.samples.last().expect("samples").clone();
    assert!(last.state[2] > 0.05, "climbed: {:?}", last.state);
    assert!(last.state[7] > 0.0, "pitched towards +x: {:?}", last.state);
    assert_eq!(last.last_command.meta.command_seq, 1);
    assert!(!last.watchdog_hover);
    // Samples: numbered in order, plant time from the reset, 10 ms apart (two messages each).
    let seqs: Vec<u64> = p.samples.iter().map(|s| s.seq).collect();
    assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1));
    assert!(p.samples.iter().all(|s| s.time_ns <= 320 * MS));
    // The vehicle's own truth agrees with what the gateway reports (frames both ways).
    let truth = p.vehicle.sim().state();
    for i in 0..8 {
        assert!((truth[i] - last.state[i]).abs() < 0.02, "x[{i}]: {} vs {}", truth[i], last.state[i]);
    }
}

#[test]
fn controller_silence_holds_level_hover_and_a_stopped_stream_fails_the_vehicle_safe() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::new(&scenario);
    p.run(1_000);
    p.command(p.bridge.arm_message(true));
    p.command(p.bridge.mode_message(ModeRequest::Px4Offboard));
    p.bridge.reset(scenario.clone(), None, p.now_ns, 2).expect("at the start");
    // Nobody commanded since the start: the gateway has held hover once already.
    let holds = p.bridge.counters().watchdog_holds;
    assert_eq!(holds, 1);
    let (_, msg) = p.bridge.apply(Input::new(11.0, 0.1, 0.0), CommandMeta::default(), p.now_ns);
    p.send_to_vehicle(msg.into_iter().collect());
    p.run(400);
    assert!(!p.samples.last().expect("samples").watchdog_hover);
    p.run(150);
    let s = p.samples.last().expect("samples");
    assert!(s.watchdog_hover, "500 ms without a command");
    assert_eq!(p.bridge.setpoint_input(), scenario.model.hover_input());
    assert_eq!(p.bridge.counters().watchdog_holds, holds + 1);
    assert_eq!(p.vehicle.mode(), SimMode::Offboard, "the setpoints go on: the vehicle stays in OFFBOARD");
    // The gateway goes silent: the vehicle leaves OFFBOARD for a hold within 0.5 s.
    p.silent_vehicle = true;
    let mut vehicle_out = Vec::new();
    let t0 = p.now_ns + VEHICLE_AHEAD_NS;
    for k in 1..=600 {
        p.vehicle.poll(t0 + k * MS, &mut vehicle_out);
    }
    assert_eq!(p.vehicle.mode(), SimMode::Hold);
    assert_eq!(p.vehicle.counters().offboard_failsafes, 1);
    // And the gateway, hearing no heartbeat for 2 s, calls the link lost.
    assert!(!p.bridge.link_alive(p.now_ns + 2_100 * MS));
}

#[test]
fn a_reset_never_teleports_the_vehicle() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::new(&scenario);
    assert_eq!(p.bridge.reset(scenario.clone(), None, 0, 2), Err(ResetRefusal::NoState));
    p.run(50);
    let mut far = scenario.start_state();
    far[0] += 2.0;
    match p.bridge.reset(scenario.clone(), Some(far), p.now_ns, 2) {
        Err(ResetRefusal::FarFromVehicle { distance_m, .. }) => assert!((distance_m - 2.0).abs() < 1e-3),
        other => panic!("not refused: {other:?}"),
    }
    // Within the tolerance: accepted, and the sample is the vehicle's state, not the request.
    let mut near = scenario.start_state();
    near[1] += 0.2;
    let s = p.bridge.reset(scenario, Some(near), p.now_ns, 3).expect("within 0.5 m");
    assert!((s.state[1] - 0.0).abs() < 1e-6 && s.flight_id == 3);
}

/// The vehicle's state messages (ATTITUDE, LOCAL_POSITION_NED) stamped `vehicle_ms`, at rest at
/// the scenario's start.
fn state_at(scenario: &Scenario, vehicle_ms: u64) -> Vec<MavMessage> {
    let (attitude, position) =
        mavbridge::messages::state_messages(&scenario.start_state(), 0.7, vehicle_ms * MS);
    vec![MavMessage::ATTITUDE(attitude), MavMessage::LOCAL_POSITION_NED(position)]
}

#[test]
fn a_state_30_ms_older_than_the_last_is_a_reordered_datagram_dropped_as_stale_not_a_reboot() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::new(&scenario);
    p.run(1_000);
    let newest = p.bridge.sample().expect("served").clone();
    let stale = p.bridge.counters().stale_messages;
    let n = p.samples.len();
    p.send_to_gateway(state_at(&scenario, p.vehicle_ns() / MS - 30));
    assert_eq!(p.samples.len(), n, "no sample of an older state");
    assert_eq!(p.bridge.counters().stale_messages, stale + 2);
    assert_eq!(p.bridge.counters().reboots, 0);
    assert!(p.reboots.is_empty());
    assert_eq!(p.bridge.awaiting_reset(), None);
    assert_eq!(p.bridge.sample(), Some(&newest), "the newest sample is still served");
    p.run(20);
    assert!(p.samples.len() > n, "the stream goes on");
}

/// The vehicle was up for 3 s, went silent, rebooted, and came back 10 s later: its new boot
/// clock (about 10 s) is ahead of the last stamp (3 s), so it never goes back; but it counted
/// 7 s less than the silence lasted, and no more than the silence: it restarted.
#[test]
fn a_vehicle_silent_longer_than_its_new_uptime_is_a_reboot_though_its_clock_came_back_ahead() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::booted_before(&scenario, 2_000 * MS);
    p.run(1_000);
    let before_ms = u32::try_from(p.vehicle_ns() / MS).expect("ms");
    let n = p.samples.len();
    p.silent_vehicle = true;
    p.run(500);
    p.reboot_vehicle(&scenario);
    p.run(9_500);
    p.silent_vehicle = false;
    p.run(100);
    assert_eq!(p.bridge.counters().reboots, 1, "counted once");
    assert_eq!(p.reboots.len(), 1, "reported once");
    let reboot = p.reboots[0];
    assert!(reboot.after_ms > reboot.before_ms, "the clock came back ahead: {reboot:?}");
    assert!(reboot.before_ms + 10 >= before_ms && reboot.silence_ns >= 10_000 * MS, "{reboot:?}");
    assert_eq!(p.bridge.awaiting_reset(), Some(reboot));
    assert_eq!(p.samples.len(), n, "no sample on the new clock before a reset");
    let text = reboot.to_string();
    assert!(text.contains("restarted during the silence") && text.contains("Reset"), "{text}");

    p.bridge.reset(scenario.clone(), None, p.now_ns, 2).expect("at the start");
    p.run(100);
    assert!(p.samples.len() >= n + 9, "served again: {}", p.samples.len() - n);
    assert_eq!(p.bridge.counters().reboots, 1);
}

/// The reboot is confirmed by one message of one kind (a position or an attitude); the
/// messages of the other kind on the new clock, held while it was being confirmed, come with
/// it: a `Reset` the moment the reboot is reported finds the vehicle's state (it was refused
/// with "no state yet" until the next message of the other kind).
#[test]
fn a_reset_the_moment_a_reboot_is_confirmed_finds_the_state_held_on_the_new_clock() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::booted_before(&scenario, 2_000 * MS);
    p.run(1_000);
    p.silent_vehicle = true;
    p.run(500);
    p.reboot_vehicle(&scenario);
    p.run(5_000);
    p.silent_vehicle = false;
    let mut waited_ms = 0;
    while p.reboots.is_empty() {
        p.run(1);
        waited_ms += 1;
        assert!(waited_ms < 1_000, "the reboot was never confirmed");
    }
    let s = p.bridge.reset(scenario.clone(), None, p.now_ns, 2).expect("a state on the new clock");
    assert_eq!((s.seq, s.time_ns, s.flight_id), (0, 0, 2));
    assert_eq!(p.bridge.awaiting_reset(), None);
}

/// A link that holds the vehicle's messages back for 1.5 s, then delivers one: its stamp is a
/// little ahead of the last after a long wait, as a restarted clock's would be, but it reads
/// the vehicle's ten minutes of uptime, which a clock restarted in the silence cannot. Nor is a
/// plain silence (the vehicle's clock counted what the gateway's did) a reboot.
#[test]
fn a_late_message_after_a_stalled_link_and_a_plain_silence_are_not_reboots() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::booted_before(&scenario, 600_000 * MS);
    p.run(1_000);
    let last_ms = p.vehicle_ns() / MS;
    p.silent_vehicle = true;
    p.run(1_500);
    p.silent_vehicle = false;
    let n = p.samples.len();
    p.send_to_gateway(state_at(&scenario, last_ms + 10));
    assert_eq!(p.samples.len(), n + 2, "the late state is served");
    p.run(100);
    let m = p.samples.len();
    assert!(m >= n + 2 + 9, "served after it: {}", m - n);
    p.silent_vehicle = true;
    p.run(5_000);
    p.silent_vehicle = false;
    p.run(100);
    assert_eq!(p.bridge.counters().reboots, 0);
    assert!(p.reboots.is_empty(), "{:?}", p.reboots);
    assert_eq!(p.bridge.awaiting_reset(), None);
    assert!(p.samples.len() >= m + 9, "served after the silence: {}", p.samples.len() - m);
}

#[test]
fn shows_reboot_by_the_clock_gone_back_or_restarted_in_a_silence() {
    use mavbridge::shows_reboot;
    // Back by the whole uptime; back by a reordered datagram's few ms.
    assert!(shows_reboot(600_000, 5, 20 * MS));
    assert!(!shows_reboot(600_000, 599_970, 0));
    // Ahead: 4 s after a 10 s silence, having read 3 s: restarted.
    assert!(shows_reboot(3_000, 4_000, 10_000 * MS));
    // Ahead by what the silence lasted, give or take: a clock that kept running.
    assert!(!shows_reboot(3_000, 13_000, 10_000 * MS));
    assert!(!shows_reboot(3_000, 12_100, 10_000 * MS));
    // Ahead by little after a long wait, but reading more than the silence: a late message.
    assert!(!shows_reboot(600_000, 600_010, 1_500 * MS));
    // Rebooted as the silence began, the new clock reads the silence, give or take jitter.
    assert!(shows_reboot(3_000, 5_003, 5_000 * MS));
}

#[test]
fn a_clock_gone_back_by_minutes_is_a_reboot_refused_until_reset_counted_once_then_served_on_the_new_clock() {
    let scenario = Scenario::paper_2();
    // The vehicle has been up for ten minutes.
    let mut p = Pair::booted_before(&scenario, 600_000 * MS);
    p.run(1_000);
    p.command(p.bridge.arm_message(true));
    p.command(p.bridge.mode_message(ModeRequest::Px4Offboard));
    p.bridge.reset(scenario.clone(), None, p.now_ns, 2).expect("at the start");
    let (_, msg) = p.bridge.apply(Input::new(10.0, 0.0, 0.0), CommandMeta::default(), p.now_ns);
    p.send_to_vehicle(msg.into_iter().collect());
    p.run(200);
    let before_ms = u32::try_from(p.vehicle_ns() / MS).expect("ms");
    assert_eq!(p.bridge.status(p.now_ns).clock_offset_ns, Some((600_000 * MS as i64, true)));

    p.reboot_vehicle(&scenario);
    let n = p.samples.len();
    let acks = p.acks.len();
    p.run(1_200);
    assert_eq!(p.samples.len(), n, "no sample between the reboot and the reset");
    assert_eq!(p.bridge.counters().reboots, 1, "counted once");
    assert_eq!(p.reboots.len(), 1, "reported once");
    let reboot = p.reboots[0];
    assert_eq!(p.bridge.awaiting_reset(), Some(reboot));
    assert!(reboot.before_ms + 10 >= before_ms && reboot.after_ms <= 10, "{reboot:?}");
    assert_eq!(p.bridge.sample(), None, "the frozen sample is not served");
    assert!(reboot.to_string().contains("rebooted") && reboot.to_string().contains("Reset"), "{reboot}");
    // The gateway neither armed nor switched the rebooted vehicle; it streams level hover.
    assert_eq!((p.unasked_commands, p.acks.len()), (0, acks));
    assert!(!p.vehicle.armed());
    assert_eq!(p.vehicle.mode(), SimMode::Posctl);
    let status = p.bridge.status(p.now_ns);
    assert!(status.link_alive && !status.armed && status.mode == "POSCTL", "{status:?}");
    assert_eq!(p.bridge.setpoint_input(), scenario.model.hover_input());
    // TIMESYNC measured the new clock (it booted at the gateway's now - 1.2 s).
    let rebooted_at_ns = -p.vehicle_ahead_ns;
    assert_eq!(status.clock_offset_ns, Some((-rebooted_at_ns, true)));

    let s = p.bridge.reset(scenario.clone(), None, p.now_ns, 3).expect("at the start");
    assert_eq!((s.seq, s.time_ns, s.flight_id), (0, 0, 3));
    assert!(s.last_command.initial);
    assert_eq!(p.bridge.awaiting_reset(), None);
    let meta = CommandMeta { command_seq: 7, based_on_sample_seq: 0, based_on_sample_time_ns: 0 };
    let (applied, msg) = p.bridge.apply(Input::new(10.0, 0.0, 0.0), meta, p.now_ns);
    assert!(applied.applied_time_ns <= 11 * MS, "stamped on the new clock: {applied:?}");
    p.send_to_vehicle(msg.into_iter().collect());
    p.samples.clear();
    p.run(100);
    assert!(p.samples.len() >= 9, "served again: {}", p.samples.len());
    assert!(p.samples.windows(2).all(|w| w[1].seq == w[0].seq + 1 && w[1].time_ns >= w[0].time_ns));
    assert!(p.samples.iter().all(|s| s.time_ns <= 111 * MS && s.flight_id == 3), "{:?}", p.samples.last());
    assert_eq!(p.samples.last().expect("samples").last_command.meta.command_seq, 7);
    assert_eq!(p.bridge.counters().reboots, 1);
}

/// The yaw of the setpoints the bridge sends next (decoded from their quaternion).
fn next_setpoint_yaw(p: &mut Pair) -> f64 {
    let mut out = Vec::new();
    for _ in 0..100 {
        p.now_ns += MS;
        p.bridge.poll(p.now_ns, &mut out);
        if let Some(d) = out.iter().find_map(|m| match m {
            MavMessage::SET_ATTITUDE_TARGET(d) => Some(d.clone()),
            _ => None,
        }) {
            let thrust = mavbridge::ThrustMap::new(0.5, 9.81).expect("valid");
            return mavbridge::messages::setpoint_input(&d, &thrust).expect("a setpoint").1;
        }
    }
    panic!("no setpoint in 100 ms");
}

/// An `ATTITUDE` from the vehicle at `yaw_rad`, 1 ms after its clock's now.
fn attitude_at_yaw(p: &Pair, yaw_rad: f32) -> MavMessage {
    MavMessage::ATTITUDE(mavbridge::mavlink::dialects::common::ATTITUDE_DATA {
        time_boot_ms: mavbridge::messages::boot_ms(p.vehicle_ns()) + 1,
        yaw: yaw_rad,
        ..Default::default()
    })
}

#[test]
fn setpoints_hold_the_yaw_of_arming_while_the_vehicle_turns_and_follow_it_again_after_disarm() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::new(&scenario);
    p.run(1_500);
    assert_eq!(
        p.command(p.bridge.arm_message(true)),
        (MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, MavResult::MAV_RESULT_ACCEPTED)
    );
    p.run(1_100);
    assert!(p.bridge.status(p.now_ns).armed);
    // Armed, the vehicle reports another yaw: the setpoints keep the yaw of arming.
    let turned = attitude_at_yaw(&p, 1.2);
    p.send_to_gateway(vec![turned]);
    assert!((p.bridge.yaw_hold_rad() - 0.7).abs() < 1e-6, "{}", p.bridge.yaw_hold_rad());
    assert!((next_setpoint_yaw(&mut p) - 0.7).abs() < 1e-6);
    // Disarm (asked, as the gateway's Disarm does): accepted, the heartbeat says so within its
    // period, and the heartbeat's age stays under it.
    assert_eq!(
        p.command(p.bridge.arm_message(false)),
        (MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, MavResult::MAV_RESULT_ACCEPTED)
    );
    p.run(1_100);
    assert!(!p.vehicle.armed());
    let status = p.bridge.status(p.now_ns);
    assert!(!status.armed, "{status:?}");
    assert!(status.heartbeat_age_ns.is_some_and(|age| age <= 1_000 * MS), "{status:?}");
    // Disarmed, the setpoints follow the vehicle's yaw again.
    let turned = attitude_at_yaw(&p, 1.2);
    p.send_to_gateway(vec![turned]);
    assert!((p.bridge.yaw_hold_rad() - 1.2).abs() < 1e-6, "{}", p.bridge.yaw_hold_rad());
    assert!((next_setpoint_yaw(&mut p) - 1.2).abs() < 1e-6);
}

/// Flies `input` from the gateway every 20 ms (as a controller would) for `ms`.
fn fly_for(p: &mut Pair, input: Input, ms: u64) {
    for _ in 0..ms / 20 {
        let (_, msg) = p.bridge.apply(input, CommandMeta::default(), p.now_ns);
        p.send_to_vehicle(msg.into_iter().collect());
        p.run(20);
    }
}

#[test]
fn arducopter_enters_guided_nogps_without_a_stream_and_levels_holding_its_height_when_the_setpoints_stop() {
    let scenario = Scenario::paper_2();
    let firmware = Firmware::ArduCopter { guid_options: 8 };
    let mut vehicle =
        SimAutopilot::new(&scenario, AutopilotSettings { firmware, ..Default::default() }).expect("valid");
    let bridge = Bridge::new(scenario.clone(), BridgeSettings::default(), 0, 1).expect("valid");
    let mut out = Vec::new();
    vehicle.on_message(&bridge.mode_message(ModeRequest::ArduGuidedNoGps), 1_000 * MS, &mut out);
    assert!(
        matches!(&out[..], [MavMessage::COMMAND_ACK(a)] if a.result == MavResult::MAV_RESULT_ACCEPTED),
        "no setpoint stream needed: {out:?}"
    );
    assert_eq!(vehicle.mode(), SimMode::Offboard);
    // PX4's OFFBOARD is not an ArduCopter mode.
    out.clear();
    vehicle.on_message(&bridge.mode_message(ModeRequest::Px4Offboard), 1_001 * MS, &mut out);
    assert!(
        matches!(&out[..], [MavMessage::COMMAND_ACK(a)] if a.result == MavResult::MAV_RESULT_UNSUPPORTED)
    );

    // Setpoints climb (T = 1.5 g, tilted), then stop: the vehicle levels once, stays in
    // GUIDED_NOGPS and stops climbing (climb rate 0), where plain hover thrust would coast up.
    let mut p = Pair::new(&scenario);
    p.vehicle =
        SimAutopilot::new(&scenario, AutopilotSettings { firmware, ..Default::default() }).expect("valid");
    p.run(1_000);
    p.command(p.bridge.arm_message(true));
    p.command(p.bridge.mode_message(ModeRequest::ArduGuidedNoGps));
    p.run(200);
    assert_eq!(p.bridge.status(p.now_ns).mode, "GUIDED_NOGPS");
    fly_for(&mut p, Input::new(1.5 * scenario.model.gravity_mps2, 0.2, 0.0), 600);
    assert!(p.vehicle.sim().state()[5] > 1.5, "climbing: {:?}", p.vehicle.sim().state());
    p.silent_vehicle = true;
    p.run(2_500);
    assert_eq!(p.vehicle.mode(), SimMode::Offboard, "ArduCopter stays in GUIDED_NOGPS");
    assert_eq!(p.vehicle.counters().offboard_failsafes, 1, "levelled once");
    let x = p.vehicle.sim().state();
    assert!(x[5].abs() < 0.1 && x[6].abs() < 0.05, "level, not climbing: {x:?}");
}

#[test]
fn arducopter_answers_guid_options_and_flies_the_thrust_as_thrust_only_with_bit_3() {
    let scenario = Scenario::paper_2();
    let mut climb_after_1_5_s = Vec::new();
    for guid_options in [0, 8] {
        let mut p = Pair::new(&scenario);
        let firmware = Firmware::ArduCopter { guid_options };
        p.vehicle = SimAutopilot::new(&scenario, AutopilotSettings { firmware, ..Default::default() })
            .expect("valid");
        p.run(1_000);
        let status = p.bridge.status(p.now_ns);
        assert_eq!(
            (status.autopilot, status.mode.as_str()),
            (MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA, "LOITER")
        );
        p.send_to_vehicle(vec![p.bridge.param_request(modes::ARDU_GUID_OPTIONS)]);
        assert_eq!(p.params, [(modes::ARDU_GUID_OPTIONS.to_owned(), guid_options as f32)]);
        // Unknown parameters are not answered (as ArduPilot does).
        p.send_to_vehicle(vec![p.bridge.param_request("NOT_A_PARAM")]);
        assert_eq!(p.params.len(), 1);

        p.command(p.bridge.arm_message(true));
        p.command(p.bridge.mode_message(ModeRequest::ArduGuidedNoGps));
        p.run(100);
        // T = 1.5 g: normalised thrust 0.75 at --hover-thrust 0.5; as a climb rate, 1.25 m/s.
        let g = scenario.model.gravity_mps2;
        fly_for(&mut p, Input::new(1.5 * g, 0.0, 0.0), 1_500);
        climb_after_1_5_s.push(p.vehicle.sim().state()[5]);
    }
    let [as_climb_rate, as_thrust] = climb_after_1_5_s[..] else { unreachable!() };
    assert!((as_climb_rate - 1.25).abs() < 0.15, "GUID_OPTIONS 0 climbs at 1.25 m/s: {as_climb_rate}");
    assert!(as_thrust > 3.0, "GUID_OPTIONS 8 accelerates at 0.5 g: {as_thrust}");
}

/// An attacker on another UDP port, and one on the vehicle's own link with another system id.
const ATTACKER: Peer =
    Some(std::net::SocketAddr::V4(std::net::SocketAddrV4::new(std::net::Ipv4Addr::LOCALHOST, 40_000)));

impl Pair {
    /// `msgs` as system `system_id` from `peer` (not the vehicle's frames): the events.
    fn forge(&mut self, peer: Peer, system_id: u8, msgs: Vec<MavMessage>) -> Vec<mavbridge::bridge::Event> {
        msgs.iter()
            .map(|m| {
                let (h, m) = wire(m, system_id);
                self.bridge.on_message(peer, &h, &m, self.now_ns)
            })
            .collect()
    }
}

/// A state 40 m north of the vehicle, stamped ahead of its clock.
fn spoofed_state(p: &Pair, scenario: &Scenario) -> Vec<MavMessage> {
    let mut x = scenario.start_state();
    x[0] += 40.0;
    let (attitude, position) = mavbridge::messages::state_messages(&x, 0.0, p.vehicle_ns() + 5 * MS);
    vec![MavMessage::ATTITUDE(attitude), MavMessage::LOCAL_POSITION_NED(position)]
}

#[test]
fn spoofed_states_from_another_address_or_system_are_dropped_counted_by_name_and_never_served() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::new(&scenario);
    p.run(500);
    let served = p.bridge.sample().expect("served").clone();
    for (peer, system_id) in [(ATTACKER, 1), (ATTACKER, 77), (VEHICLE, 77)] {
        let spoofed = spoofed_state(&p, &scenario);
        let events = p.forge(peer, system_id, spoofed);
        assert!(events.iter().all(|e| e.sample.is_none() && e.dropped.is_some()), "{events:?}");
        assert_eq!(p.bridge.sample(), Some(&served), "still the vehicle's");
    }
    let status = p.bridge.status(p.now_ns);
    assert_eq!((status.dropped.foreign_address, status.dropped.foreign_system), (4, 2), "{status:?}");
    assert_eq!(status.dropped.by_message.get("LOCAL_POSITION_NED"), Some(&3));
    assert_eq!(status.dropped.by_message.get("ATTITUDE"), Some(&3));
    // A burst of them does not let through a Reset the vehicle's position refuses.
    let mut far = scenario.clone();
    far.start[0] += 40.0;
    for _ in 0..100 {
        let spoofed = spoofed_state(&p, &scenario);
        p.forge(ATTACKER, 1, spoofed);
        p.run(1);
    }
    assert!(matches!(p.bridge.reset(far, None, p.now_ns, 2), Err(ResetRefusal::FarFromVehicle { .. })));
}

#[test]
fn heartbeats_of_other_systems_neither_retarget_the_setpoints_nor_change_the_status() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::new(&scenario);
    p.run(100);
    let offboard_armed = MavMessage::HEARTBEAT(mavlink::dialects::common::HEARTBEAT_DATA {
        custom_mode: ModeRequest::px4_custom_mode(6, 0),
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        base_mode: mavlink::dialects::common::MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED
            | mavlink::dialects::common::MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
        ..Default::default()
    });
    for system_id in 2..=250u8 {
        let peer = if system_id % 2 == 0 { ATTACKER } else { VEHICLE };
        p.forge(peer, system_id, vec![offboard_armed.clone()]);
    }
    let status = p.bridge.status(p.now_ns);
    assert!(!status.armed && status.mode == "POSCTL", "{status:?}");
    assert_eq!(status.vehicle.map(|v| (v.system_id, v.component_id)), Some((1, 1)));
    assert_eq!(status.dropped.by_message.get("HEARTBEAT"), Some(&249));
    let mut out = Vec::new();
    p.bridge.poll(p.now_ns + 20 * MS, &mut out);
    let targets: Vec<_> = out
        .iter()
        .filter_map(|m| match m {
            MavMessage::SET_ATTITUDE_TARGET(s) => Some((s.target_system, s.target_component)),
            _ => None,
        })
        .collect();
    assert_eq!(targets, vec![(1, 1)]);
}

#[test]
fn a_forged_ack_is_not_an_answer() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::new(&scenario);
    let ack = MavMessage::COMMAND_ACK(mavlink::dialects::common::COMMAND_ACK_DATA {
        command: MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
        result: MavResult::MAV_RESULT_ACCEPTED,
    });
    for (peer, system_id) in [(ATTACKER, 99), (VEHICLE, 99), (ATTACKER, 1)] {
        let events = p.forge(peer, system_id, vec![ack.clone()]);
        assert!(events[0].ack.is_none(), "{events:?}");
    }
    let events = p.forge(VEHICLE, 1, vec![ack]);
    assert_eq!(events[0].ack, Some((MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, MavResult::MAV_RESULT_ACCEPTED)));
}

#[test]
fn one_stamp_of_zero_even_from_the_vehicle_is_no_reboot_and_is_counted() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::new(&scenario);
    p.run(500);
    // Another address: dropped before anything looks at its stamp.
    p.forge(ATTACKER, 1, state_at(&scenario, 0));
    // The vehicle's own link: one position stamped 0, then the vehicle's clock goes on.
    let zero = state_at(&scenario, 0).pop().expect("a position");
    p.forge(VEHICLE, 1, vec![zero]);
    p.run(100);
    let c = p.bridge.counters();
    assert_eq!((c.reboots, c.reboot_stamps_refused), (0, 1), "{c:?}");
    assert!(p.reboots.is_empty() && p.bridge.awaiting_reset().is_none());
    assert!(p.bridge.status(p.now_ns).dropped.foreign_address == 2);
}

#[test]
fn timesync_answers_going_backwards_and_states_outside_the_envelope_are_refused_and_counted() {
    let scenario = Scenario::paper_2();
    let mut p = Pair::new(&scenario);
    p.run(1_100);
    let offset = p.bridge.status(p.now_ns).clock_offset_ns;
    assert_eq!(offset, Some((VEHICLE_AHEAD_NS as i64, true)));
    // Answers from the vehicle's link to requests never sent, or with a clock gone back.
    let back = |ts1: i64| MavMessage::TIMESYNC(mavlink::dialects::common::TIMESYNC_DATA { tc1: 1, ts1 });
    let events = p.forge(VEHICLE, 1, vec![back(p.now_ns as i64 - MS as i64), back(0)]);
    assert!(events.iter().all(|e| e.reply.is_none()));
    p.run(600);
    let status = p.bridge.status(p.now_ns);
    assert_eq!(status.clock_offset_ns, offset, "unchanged");
    assert_eq!(status.counters.timesync_refused, 2, "{status:?}");
    // A position of 3e38 m and one at 1 km/s: not served, path length unchanged.
    let path = p.bridge.sample().expect("served").path_length_m;
    let n = p.samples.len();
    let mut wild = state_at(&scenario, p.vehicle_ns() / MS + 1);
    if let MavMessage::LOCAL_POSITION_NED(pos) = &mut wild[1] {
        pos.x = 3e38;
    }
    let mut fast = state_at(&scenario, p.vehicle_ns() / MS + 2);
    if let MavMessage::LOCAL_POSITION_NED(pos) = &mut fast[1] {
        pos.vx = 1_000.0;
    }
    let events = p.forge(VEHICLE, 1, vec![wild[1].clone(), fast[1].clone()]);
    assert!(events.iter().all(|e| e.sample.is_none()));
    assert_eq!(p.samples.len(), n);
    assert_eq!(p.bridge.counters().implausible_states, 2);
    p.run(100);
    let s = p.bridge.sample().expect("served");
    assert!(s.path_length_m < path + 1.0, "{} then {}", path, s.path_length_m);
}
