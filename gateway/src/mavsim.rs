//! `mavsim`: the MAV model in real time behind the autopilot's side of MAVLink
//! ([`mavbridge::SimAutopilot`]: PX4's arming, OFFBOARD and offboard-loss failsafe, the same
//! frame and thrust conversions as the gateway's). A thread reads the link and a thread
//! integrates and sends the streams; the vehicle's boot clock is the time since start.

use crate::link::{Link, LinkError};
use mav::Scenario;
use mavbridge::{AutopilotSettings, SimAutopilot};
use std::sync::atomic::{AtomicBool, Ordering};
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
}

/// A running simulated vehicle; stopped when dropped.
pub struct Mavsim {
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
        let link = Link::open(&config.mavlink, 1, 1)?;
        let autopilot = Arc::new(Mutex::new(autopilot));
        let (stop, silent) = (Arc::new(AtomicBool::new(false)), Arc::new(AtomicBool::new(false)));
        let origin = Instant::now();
        let now_ns = move || u64::try_from(origin.elapsed().as_nanos()).unwrap_or(u64::MAX);
        let send_all = |link: &Link, out: &[mavbridge::mavlink::dialects::common::MavMessage]| {
            for m in out {
                if let Err(e) = link.send(m) {
                    tracing::debug!("mavsim cannot send: {e}");
                }
            }
        };
        let reader = {
            let (autopilot, stop, silent, link) =
                (autopilot.clone(), stop.clone(), silent.clone(), link.clone());
            std::thread::Builder::new().name("mavsim-recv".into()).spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    let Some((_, msg)) = link.recv() else { continue };
                    if silent.load(Ordering::Relaxed) {
                        continue;
                    }
                    let mut out = Vec::new();
                    autopilot.lock().unwrap_or_else(PoisonError::into_inner).on_message(
                        &msg,
                        now_ns(),
                        &mut out,
                    );
                    send_all(&link, &out);
                }
            })
        };
        let ticker = {
            let (autopilot, stop, silent) = (autopilot.clone(), stop.clone(), silent.clone());
            std::thread::Builder::new().name("mavsim-tick".into()).spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    let now = now_ns();
                    let mut out = Vec::new();
                    let next = {
                        let mut a = autopilot.lock().unwrap_or_else(PoisonError::into_inner);
                        a.poll(now, &mut out);
                        a.next_due_ns()
                    };
                    if !silent.load(Ordering::Relaxed) {
                        send_all(&link, &out);
                    }
                    // At least every millisecond: the model integrates at 1 kHz in real time.
                    std::thread::sleep(Duration::from_nanos(next.saturating_sub(now_ns()).min(1_000_000)));
                }
            })
        };
        let threads = [reader, ticker]
            .into_iter()
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| LinkError::Open { address: config.mavlink.clone(), source: e })?;
        tracing::info!(mavlink = %config.mavlink, scenario = %config.scenario.name, "mavsim running (PX4's side of MAVLink)");
        Ok(Self { autopilot, stop, silent, threads })
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
