//! What the vehicle counts on its link to the firmware: packets each way, bad packets, and the
//! latency from the last state packet sent to each motor packet received ([`Latency`]).

use std::fmt;

pub use mav::latency::Latency;

/// Counters of the vehicle's link to the firmware.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LinkStats {
    /// State packets (`fdm_packet`) sent.
    pub fdm_sent: u64,
    /// State packets the socket refused.
    pub fdm_send_errors: u64,
    /// Motor packets (`servo_packet`) received and applied.
    pub servo_received: u64,
    /// Datagrams on the motor port that were not motor packets (size, non-finite values).
    pub bad_packets: u64,
    /// Motor outputs clamped or replaced by the sanitiser (`quad::motors`).
    pub sanitised: u64,
    /// Pose frames (ODOMETRY) sent.
    pub pose_sent: u64,
    /// Ticks that started late by more than one state period (the loop fell behind).
    pub late_ticks: u64,
    /// Pauses of the state packets after the motor packets stopped (`vehicle`'s resync).
    pub resyncs: u64,
    /// In lockstep: state packets that got no answer in time (and were sent again).
    pub lockstep_timeouts: u64,
    /// From the last state packet sent to each motor packet received.
    pub latency: Latency,
}

fn ms(ns: Option<u64>) -> String {
    ns.map_or_else(|| "-".into(), |v| format!("{:.3}", v as f64 / 1e6))
}

impl fmt::Display for LinkStats {
    /// One line of `key=value` pairs (latencies in ms), for logs and tests.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let l = &self.latency;
        write!(
            f,
            "fdm_sent={} servo_received={} bad_packets={} sanitised={} pose_sent={} late_ticks={} resyncs={} \
             lockstep_timeouts={} fdm_send_errors={} latency_ms_min={} latency_ms_median={} latency_ms_p99={} \
             latency_ms_max={} latency_ms_mean={}",
            self.fdm_sent,
            self.servo_received,
            self.bad_packets,
            self.sanitised,
            self.pose_sent,
            self.late_ticks,
            self.resyncs,
            self.lockstep_timeouts,
            self.fdm_send_errors,
            ms(l.min_ns()),
            ms(l.quantile_ns(0.5)),
            ms(l.quantile_ns(0.99)),
            ms(l.max_ns()),
            ms(l.mean_ns()),
        )
    }
}
