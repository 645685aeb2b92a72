//! The vehicle: `quad::QuadSim` flown by the firmware's motor packets, fed to the firmware as
//! state packets, and published as a pose stream. A thread owns the sockets and the
//! simulation; the time comes from a [`Clock`] passed in (real time) or from the exchange
//! itself (lockstep), and is handed to the pure simulation as plant time.
//!
//! Real time: every `fdm_period_ns` of the clock the simulation is advanced to the clock's
//! time and a state packet stamped with it is sent; motor packets are applied at the clock's
//! time they arrive. Lockstep: a state packet, then its motor packet (or a timeout), then the
//! simulation advances by one fixed step: plant time is the number of exchanges times the
//! step, whatever the wall clock does.

use crate::packets::{FDM_PACKET_LEN, decode_servo, encode_fdm};
use crate::pose::{bench_to_enu, encode_odometry};
use crate::stats::LinkStats;
use nalgebra::{UnitQuaternion, Vector3};
use quad::betaflight::{FdmState, motors_from_servo_packet, wall_clock_timestamp_s};
use quad::{QuadParams, QuadSample, QuadSim, QuadState, SimSettings};
use std::io::Write;
use std::net::{SocketAddr, UdpSocket};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A monotonic time source, ns since some origin.
pub trait Clock: Send + 'static {
    fn now_ns(&self) -> u64;
}

/// `Instant` since construction.
#[derive(Debug, Clone, Copy)]
pub struct MonotonicClock {
    origin: Instant,
}

impl MonotonicClock {
    pub fn new() -> Self {
        Self { origin: Instant::now() }
    }
}

impl Default for MonotonicClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for MonotonicClock {
    fn now_ns(&self) -> u64 {
        u64::try_from(self.origin.elapsed().as_nanos()).unwrap_or(u64::MAX)
    }
}

/// How plant time advances.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TimeMode {
    /// Plant time is the clock's; a state packet every `fdm_period_ns`.
    RealTime,
    /// Plant time advances by `fdm_period_ns` per exchange; a state packet without an answer
    /// within `reply_timeout` counts as a timeout and time moves on with the motors held.
    Lockstep { reply_timeout: Duration },
}

/// Settings of the vehicle.
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleSettings {
    /// Start position in the bench's world (x north, y west, z up; ground at 0), m. Level,
    /// nose north, motors stopped.
    pub start_m: [f64; 3],
    /// Plant time between state packets, ns: 1 ms or 2 ms.
    pub fdm_period_ns: u64,
    pub time_mode: TimeMode,
    /// Where the pose stream (MAVLink 2 ODOMETRY) goes.
    pub pose_out: SocketAddr,
    /// Pose frames per second of plant time (0: none).
    pub pose_rate_hz: f64,
    /// The firmware's state port.
    pub fdm_to: SocketAddr,
    /// Where the firmware's motor packets arrive.
    pub servo_bind: SocketAddr,
    pub params: QuadParams,
    /// Every motor packet applied, one line each (plant time ns, then the four floats' bits in
    /// hex), for determinism checks.
    pub motor_log: Option<PathBuf>,
}

impl Default for VehicleSettings {
    fn default() -> Self {
        Self {
            start_m: [0.0; 3],
            fdm_period_ns: 1_000_000,
            time_mode: TimeMode::RealTime,
            pose_out: SocketAddr::from(([127, 0, 0, 1], 14560)),
            pose_rate_hz: 100.0,
            fdm_to: SocketAddr::from(([127, 0, 0, 1], crate::firmware::FDM_PORT)),
            servo_bind: SocketAddr::from(([0, 0, 0, 0], crate::firmware::SERVO_PORT)),
            params: QuadParams::default(),
            motor_log: None,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum VehicleError {
    #[error("invalid `{field}`: {reason}")]
    Invalid { field: &'static str, reason: String },
    #[error(transparent)]
    Sim(#[from] quad::SimError),
    #[error("{what}: {source}")]
    Io { what: String, source: std::io::Error },
}

impl VehicleSettings {
    pub fn validate(&self) -> Result<(), VehicleError> {
        let invalid = |field, reason: &str| Err(VehicleError::Invalid { field, reason: reason.into() });
        if !self.start_m.iter().all(|v| v.is_finite()) || self.start_m[2] < 0.0 {
            return invalid("start_m", "must be finite, z >= 0 (the ground)");
        }
        if ![1_000_000, 2_000_000].contains(&self.fdm_period_ns) {
            return invalid("fdm_period_ns", "must be 1 ms or 2 ms");
        }
        if !self.pose_rate_hz.is_finite() || !(0.0..=1000.0).contains(&self.pose_rate_hz) {
            return invalid("pose_rate_hz", "must be in [0, 1000]");
        }
        Ok(())
    }

    /// The start state in `quad`'s frames: level, nose north.
    pub fn initial_state(&self) -> QuadState {
        let mut s = QuadState::resting_at(0.0, 0.0);
        s.position_m = bench_to_enu(self.start_m);
        s.attitude = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
        s
    }
}

/// What the loop shares with its owner.
#[derive(Debug)]
struct Shared {
    stats: LinkStats,
    sample: QuadSample,
}

/// A running vehicle; stopped when dropped.
pub struct Vehicle {
    shared: Arc<Mutex<Shared>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<(), VehicleError>>>,
}

fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> VehicleError {
    let what = what.into();
    move |source| VehicleError::Io { what, source }
}

impl Vehicle {
    /// Binds the sockets and starts the loop with `clock` (real time) or the exchange
    /// (lockstep) as plant time.
    pub fn start(settings: &VehicleSettings, clock: impl Clock) -> Result<Self, VehicleError> {
        settings.validate()?;
        let sim = QuadSim::new(settings.params, SimSettings::default(), settings.initial_state())?;
        let servo =
            UdpSocket::bind(settings.servo_bind).map_err(io(format!("bind {}", settings.servo_bind)))?;
        let fdm = UdpSocket::bind(("0.0.0.0", 0)).map_err(io("bind the state socket"))?;
        let pose = UdpSocket::bind(("0.0.0.0", 0)).map_err(io("bind the pose socket"))?;
        let motor_log = match &settings.motor_log {
            Some(p) => Some(std::io::BufWriter::new(
                std::fs::File::create(p).map_err(io(format!("create {}", p.display())))?,
            )),
            None => None,
        };
        let shared = Arc::new(Mutex::new(Shared { stats: LinkStats::default(), sample: sim.sample() }));
        let stop = Arc::new(AtomicBool::new(false));
        let mut lp = Loop {
            settings: settings.clone(),
            sim,
            servo,
            fdm,
            pose,
            pose_frame: Vec::with_capacity(300),
            pose_seq: 0,
            next_pose_ns: 0,
            motor_log,
            shared: shared.clone(),
            stop: stop.clone(),
            stats: LinkStats::default(),
        };
        let thread = std::thread::Builder::new()
            .name("bfsim-loop".into())
            .spawn(move || match lp.settings.time_mode {
                TimeMode::RealTime => lp.run_real_time(&clock),
                TimeMode::Lockstep { reply_timeout } => lp.run_lockstep(reply_timeout),
            })
            .map_err(io("spawn the loop"))?;
        Ok(Self { shared, stop, thread: Some(thread) })
    }

    pub fn stats(&self) -> LinkStats {
        self.shared.lock().unwrap_or_else(PoisonError::into_inner).stats.clone()
    }

    pub fn sample(&self) -> QuadSample {
        self.shared.lock().unwrap_or_else(PoisonError::into_inner).sample
    }

    /// Whether the loop has ended (an error, or a stop).
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_none_or(JoinHandle::is_finished)
    }

    /// Stops the loop; its outcome and the final counters.
    pub fn stop(mut self) -> (Result<(), VehicleError>, LinkStats) {
        let r = self.join();
        (r, self.stats())
    }

    fn join(&mut self) -> Result<(), VehicleError> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take() {
            Some(t) => t.join().unwrap_or_else(|_| {
                Err(VehicleError::Invalid { field: "loop", reason: "the loop panicked".into() })
            }),
            None => Ok(()),
        }
    }
}

impl Drop for Vehicle {
    fn drop(&mut self) {
        let _ = self.join();
    }
}

struct Loop {
    settings: VehicleSettings,
    sim: QuadSim,
    servo: UdpSocket,
    fdm: UdpSocket,
    pose: UdpSocket,
    pose_frame: Vec<u8>,
    pose_seq: u8,
    next_pose_ns: u64,
    motor_log: Option<std::io::BufWriter<std::fs::File>>,
    shared: Arc<Mutex<Shared>>,
    stop: Arc<AtomicBool>,
    /// The loop's own counters, published with the sample every so often.
    stats: LinkStats,
}

/// Motor packets silent this long while state packets flow: the firmware is stuck.
const SILENCE_NS: u64 = 300_000_000;
/// How long the state packets then pause: more than the firmware's 500 ms stale-state limit.
const RESYNC_PAUSE_NS: u64 = 600_000_000;

/// How often the loop publishes its counters and sample, ns of plant time.
const PUBLISH_NS: u64 = 10_000_000;

impl Loop {
    fn send_state(&mut self) {
        let mut state = FdmState::from_sample(&self.sim.sample());
        if self.settings.time_mode == TimeMode::RealTime {
            // The firmware keeps the wall clock (`wall_clock_timestamp_s`); lockstep's stamps are
            // its plant time, which is what it measures.
            state.timestamp_s = wall_clock_timestamp_s(self.sim.time_ns());
        }
        let packet: [u8; FDM_PACKET_LEN] = encode_fdm(&state);
        // Unconnected sockets (`send_to`): a port nobody listens on yet does not turn the next
        // sends into errors (ICMP port unreachable is reported on connected sockets only).
        match self.fdm.send_to(&packet, self.settings.fdm_to) {
            Ok(_) => self.stats.fdm_sent += 1,
            Err(_) => self.stats.fdm_send_errors += 1,
        }
    }

    fn send_pose_if_due(&mut self) {
        if self.settings.pose_rate_hz <= 0.0 || self.sim.time_ns() < self.next_pose_ns {
            return;
        }
        let period = (1e9 / self.settings.pose_rate_hz) as u64;
        self.next_pose_ns += period;
        if self.next_pose_ns <= self.sim.time_ns() {
            self.next_pose_ns = self.sim.time_ns() + period;
        }
        encode_odometry(&self.sim.sample(), self.pose_seq, &mut self.pose_frame);
        self.pose_seq = self.pose_seq.wrapping_add(1);
        if self.pose.send_to(&self.pose_frame, self.settings.pose_out).is_ok() {
            self.stats.pose_sent += 1;
        }
    }

    /// One datagram from the motor port: applied when it is a motor packet, else counted.
    fn apply(&mut self, datagram: &[u8]) -> bool {
        match decode_servo(datagram) {
            Ok(m) => {
                let report = self.sim.set_commands(motors_from_servo_packet(m));
                self.stats.servo_received += 1;
                self.stats.sanitised += u64::from(report.clamped + report.non_finite);
                if let Some(log) = &mut self.motor_log {
                    let _ = writeln!(
                        log,
                        "{} {:08x} {:08x} {:08x} {:08x}",
                        self.sim.time_ns(),
                        m[0].to_bits(),
                        m[1].to_bits(),
                        m[2].to_bits(),
                        m[3].to_bits()
                    );
                }
                true
            }
            Err(_) => {
                self.stats.bad_packets += 1;
                false
            }
        }
    }

    fn publish(&mut self) {
        let mut s = self.shared.lock().unwrap_or_else(PoisonError::into_inner);
        s.stats.clone_from(&self.stats);
        s.sample = self.sim.sample();
    }

    fn finish(&mut self) -> Result<(), VehicleError> {
        self.publish();
        if let Some(log) = &mut self.motor_log {
            log.flush().map_err(io("flush the motor log"))?;
        }
        Ok(())
    }

    /// Waits up to `ns` for a datagram on the motor port; whether one is there.
    fn wait_readable(&self, ns: u64) -> bool {
        let timeout = rustix::event::Timespec {
            tv_sec: i64::try_from(ns / 1_000_000_000).unwrap_or(i64::MAX),
            tv_nsec: i64::try_from(ns % 1_000_000_000).unwrap_or(0),
        };
        let mut fds = [rustix::event::PollFd::new(&self.servo, rustix::event::PollFlags::IN)];
        matches!(rustix::event::poll(&mut fds, Some(&timeout)), Ok(n) if n > 0)
    }

    fn run_real_time(&mut self, clock: &impl Clock) -> Result<(), VehicleError> {
        let period = self.settings.fdm_period_ns;
        let origin = clock.now_ns();
        let now = || clock.now_ns().saturating_sub(origin);
        let mut next_fdm_ns = 0u64;
        let mut last_fdm_ns = None::<u64>;
        let mut next_publish = 0u64;
        // When motor packets stop while state packets flow, the state packets pause for
        // RESYNC_PAUSE_NS: the firmware then takes its stale-state branch (500 ms), which resets
        // its clock estimate, and answers again.
        let mut last_servo_ns = 0u64;
        let mut paused_until = 0u64;
        let mut buf = [0u8; 512];
        self.servo.set_nonblocking(true).map_err(io("make the motor socket non-blocking"))?;
        while !self.stop.load(Ordering::Relaxed) {
            let t = now();
            if t >= next_fdm_ns && t.saturating_sub(last_servo_ns) > SILENCE_NS && t >= paused_until {
                self.stats.resyncs += 1;
                paused_until = t + RESYNC_PAUSE_NS;
                last_servo_ns = paused_until;
            }
            if t >= next_fdm_ns && t < paused_until {
                self.sim.advance_to(t)?;
                self.send_pose_if_due();
                next_fdm_ns = t + period;
            } else if t >= next_fdm_ns {
                self.sim.advance_to(t)?;
                self.send_state();
                last_fdm_ns = Some(t);
                self.send_pose_if_due();
                next_fdm_ns += period;
                if next_fdm_ns <= t {
                    self.stats.late_ticks += 1;
                    next_fdm_ns = t + period;
                }
                if t >= next_publish {
                    self.publish();
                    next_publish = t + PUBLISH_NS;
                }
            }
            let wait = next_fdm_ns.saturating_sub(now());
            if !self.wait_readable(wait) {
                continue;
            }
            match self.servo.recv(&mut buf) {
                Ok(n) => {
                    let t = now();
                    self.sim.advance_to(t)?;
                    if self.apply(&buf[..n]) {
                        last_servo_ns = t;
                        if let Some(sent) = last_fdm_ns.take() {
                            self.stats.latency.record(t - sent);
                        }
                    }
                }
                Err(e)
                    if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
                // ICMP errors from an earlier send surface on any socket op; not fatal.
                Err(_) => {}
            }
        }
        self.finish()
    }

    fn run_lockstep(&mut self, reply_timeout: Duration) -> Result<(), VehicleError> {
        let step = self.settings.fdm_period_ns;
        let wall = Instant::now;
        let mut buf = [0u8; 512];
        self.servo.set_read_timeout(Some(reply_timeout)).map_err(io("set the read timeout"))?;
        let mut next_publish = 0u64;
        while !self.stop.load(Ordering::Relaxed) {
            self.send_state();
            self.send_pose_if_due();
            let sent = wall();
            loop {
                match self.servo.recv(&mut buf) {
                    Ok(n) => {
                        if self.apply(&buf[..n]) {
                            self.stats
                                .latency
                                .record(u64::try_from(sent.elapsed().as_nanos()).unwrap_or(u64::MAX));
                            break;
                        }
                    }
                    Err(_) => {
                        self.stats.lockstep_timeouts += 1;
                        break;
                    }
                }
                if sent.elapsed() > reply_timeout {
                    self.stats.lockstep_timeouts += 1;
                    break;
                }
            }
            let t = self.sim.time_ns() + step;
            self.sim.advance_to(t)?;
            if t >= next_publish {
                self.publish();
                next_publish = t + PUBLISH_NS;
            }
        }
        self.finish()
    }
}
