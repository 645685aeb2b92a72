//! One line of a delivery trace: what the network did to one copy of one message.

use crate::profile::Direction;

/// What happened to one copy of a message (or to a message that was lost).
#[derive(Debug, Clone, PartialEq)]
pub struct Record {
    pub direction: Direction,
    /// Number of the message on its delay line.
    pub message_seq: u64,
    /// The message's own number (a state sample's `seq`, a command's `command_seq`).
    pub payload_seq: u64,
    pub send_time_ns: u64,
    /// Scheduled release time, ns (for a lost message, when it would have arrived).
    pub release_time_ns: u64,
    /// The delay the copy actually got, s (release minus send, plus the release error).
    pub injected_delay_s: f64,
    pub dropped: bool,
    pub duplicate: bool,
    /// Why a dropped copy was dropped; empty when delivered.
    pub drop_reason: String,
    /// Real time: actual minus scheduled release, ns; 0 in lockstep.
    pub release_error_ns: i64,
}
