//! `mavsim`: the MAV model in real time behind the autopilot's side of MAVLink
//! ([`mavbridge::SimAutopilot`]: PX4's arming, OFFBOARD and offboard-loss failsafe, the same
//! frame and thrust conversions as the gateway's). A thread reads the link and a thread
//! integrates and sends the streams; the vehicle's boot clock is the time since start (or since
//! the last [`Mavsim::reboot`]).

use crate::link::{Frame, Link, LinkError};
use mav::Scenario;
use mavbridge::{AutopilotSettings, SimAutopilot};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Settings of one simulated vehicle.
#[derive(Debug, Clone, PartialEq)]
pub struct MavsimConfig {
    /// Where the gateway is: `udpout:127.0.0.1:14540` (PX4 SITL's offboard port) by default.
    pub mavlink: String,
    pub scenario: Scenario,
    pub autopilot: AutopilotSettings,
    /// MAVLink 2 signing: frames sent are signed, frames read unsigned or signed otherwise are
    /// dropped (`None`: neither).
    pub signing_key: Option<mavbridge::SigningKey>,
}

/// The vehicle's boot clock: the time since start, less the time of the last reboot.
#[derive(Clone)]
struct BootClock {
    origin: Instant,
    /// Time since start of the last reboot, ns.
    booted_ns: Arc<AtomicU64>,
}

impl BootClock {
    fn since_start_ns(&self) -> u64 {
        u64::try_from(self.origin.elapsed().as_nanos()).unwrap_or(u64::MAX)
    }

    /// The vehicle's clock (`time_boot_ms` in ns).
    fn now_ns(&self) -> u64 {
        self.since_start_ns().saturating_sub(self.booted_ns.load(Ordering::Relaxed))
    }
}

/// A running simulated vehicle; stopped when dropped.
pub struct Mavsim {
    config: MavsimConfig,
    clock: BootClock,
    autopilot: Arc<Mutex<SimAutopilot>>,
    stop: Arc<AtomicBool>,
    silent: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

impl Mavsim {
    /// Opens the link and starts the vehicle (disarmed, at the scenario's start).
    pub fn start(config: &MavsimConfig) -> Result<Self, LinkError> {
        let autopilot = SimAutopilot::new(&config.scenario, config.autopilot).map_err(|e| {
            LinkError::Address { address: config.mavlink.clone(), reason: format!("autopilot settings: {e}") }
        })?;
        let link = Link::open_signed(&config.mavlink, 1, 1, config.signing_key.clone())?;
        let autopilot = Arc::new(Mutex::new(autopilot));
        let (stop, silent) = (Arc::new(AtomicBool::new(false)), Arc::new(AtomicBool::new(false)));
        let clock = BootClock { origin: Instant::now(), booted_ns: Arc::new(AtomicU64::new(0)) };
        let send_all = |link: &Link, out: &[mavbridge::mavlink::dialects::common::MavMessage]| {
            for m in out {
                if let Err(e) = link.send(m) {
                    tracing::debug!("mavsim cannot send: {e}");
                }
            }
        };
        let reader = {
            let (autopilot, stop, silent, link, clock) =
                (autopilot.clone(), stop.clone(), silent.clone(), link.clone(), clock.clone());
            std::thread::Builder::new().name("mavsim-recv".into()).spawn(move || {
                let mut answering = false;
                while !stop.load(Ordering::Relaxed) {
                    let msg = match link.recv() {
                        Some(Frame::Message(peer, _, msg)) => {
                            // Listening (udpin): the vehicle answers the first that speaks to it.
                            if !answering {
                                link.answer(peer);
                                answering = true;
                            }
                            msg
                        }
                        Some(Frame::Refused(_, why)) => {
                            tracing::debug!("mavsim drops a frame: {why:?}");
                            continue;
                        }
                        None => continue,
                    };
                    if silent.load(Ordering::Relaxed) {
                        continue;
                    }
                    let mut out = Vec::new();
                    // The clock is read under the lock, so that a reboot is never half seen.
                    let mut a = autopilot.lock().unwrap_or_else(PoisonError::into_inner);
                    a.on_message(&msg, clock.now_ns(), &mut out);
                    drop(a);
                    send_all(&link, &out);
                }
            })
        };
        let ticker = {
            let (autopilot, stop, silent, clock) =
                (autopilot.clone(), stop.clone(), silent.clone(), clock.clone());
            std::thread::Builder::new().name("mavsim-tick".into()).spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    let mut out = Vec::new();
                    let next = {
                        let mut a = autopilot.lock().unwrap_or_else(PoisonError::into_inner);
                        a.poll(clock.now_ns(), &mut out);
                        a.next_due_ns()
                    };
                    if !silent.load(Ordering::Relaxed) {
                        send_all(&link, &out);
                    }
                    // At least every millisecond: the model integrates at 1 kHz in real time.
                    std::thread::sleep(Duration::from_nanos(
                        next.saturating_sub(clock.now_ns()).min(1_000_000),
                    ));
                }
            })
        };
        let threads = [reader, ticker]
            .into_iter()
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| LinkError::Open { address: config.mavlink.clone(), source: e })?;
        tracing::info!(mavlink = %config.mavlink, scenario = %config.scenario.name, firmware = ?config.autopilot.firmware, "mavsim running (the autopilot's side of MAVLink)");
        Ok(Self { config: config.clone(), clock, autopilot, stop, silent, threads })
    }

    /// The vehicle reboots, at once: its boot clock starts again at 0, and it is a fresh
    /// autopilot (disarmed, POSCTL) at the scenario's start. The link stays up (a real reboot
    /// also silences it for a few seconds; [`Mavsim::set_silent`] plays that part).
    pub fn reboot(&self) -> Result<(), mavbridge::thrust::ThrustError> {
        let fresh = SimAutopilot::new(&self.config.scenario, self.config.autopilot)?;
        let mut a = self.autopilot();
        self.clock.booted_ns.store(self.clock.since_start_ns(), Ordering::Relaxed);
        *a = fresh;
        tracing::info!("mavsim rebooted: boot clock at 0, disarmed in POSCTL");
        Ok(())
    }

    /// The simulated autopilot and its model (the truth, for tests).
    pub fn autopilot(&self) -> MutexGuard<'_, SimAutopilot> {
        self.autopilot.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Goes silent (sends nothing, hears nothing: a link cut) or talks again; the model flies on.
    pub fn set_silent(&self, silent: bool) {
        self.silent.store(silent, Ordering::Relaxed);
    }

    /// Stops the threads and waits for them.
    pub fn stop(mut self) {
        self.halt();
    }

    fn halt(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

impl Drop for Mavsim {
    fn drop(&mut self) {
        self.halt();
    }
}
