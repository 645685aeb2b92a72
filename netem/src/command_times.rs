//! Lockstep: the plant time each command was sent at, so that netem can say how many commands
//! it drew a delay for before a given plant time (`NetemControl.CommandsSentBefore`).
//!
//! Why: an external controller steps on after its run has ended, until the bench stops it, so
//! netem's count of commands sent (`GetStats`) when the bench asks depends on the machine's
//! timing. The commands sent at plant times before the run's end do not: in lockstep plant time
//! moves only through netem, and a command sent at plant time `t` was drawn before netem moved
//! the plant past `t`, so every one of them was counted before the plant reached the end (and
//! before the bench saw it there), and none sent later is. Pure: the shell passes the times.

use std::collections::VecDeque;

/// Distinct plant times kept (16 bytes each: 1 MiB): a lockstep controller that sends a
/// command per 50 ms cycle is answered for the last hour of plant time. A time older than what
/// is kept gets no answer rather than a wrong one.
pub const KEPT_TIMES: usize = 1 << 16;

/// Commands counted by the plant time they were sent at.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct CommandTimes {
    /// `(plant time, commands sent at or before it)`, one per distinct time, oldest first.
    kept: VecDeque<(u64, u64)>,
    /// The newest entry dropped to keep [`KEPT_TIMES`].
    forgotten: Option<(u64, u64)>,
    sent: u64,
}

impl CommandTimes {
    /// A command sent at plant time `plant_time_ns` (not before the previous one's: plant time
    /// only moves on; the plant's reset starts a new count, [`CommandTimes::default`]).
    pub fn push(&mut self, plant_time_ns: u64) {
        self.sent += 1;
        match self.kept.back_mut() {
            Some((t, n)) if *t >= plant_time_ns => *n = self.sent,
            _ => {
                if self.kept.len() == KEPT_TIMES {
                    self.forgotten = self.kept.pop_front();
                }
                self.kept.push_back((plant_time_ns, self.sent));
            }
        }
    }

    /// Commands sent at plant times before `plant_time_ns`; `None` when that reaches into
    /// times no longer kept.
    pub fn before(&self, plant_time_ns: u64) -> Option<u64> {
        let i = self.kept.partition_point(|&(t, _)| t < plant_time_ns);
        if i > 0 {
            return Some(self.kept[i - 1].1);
        }
        match self.forgotten {
            None => Some(0),
            Some((t, n)) if t < plant_time_ns => Some(n),
            Some(_) => None,
        }
    }

    /// Every command counted.
    pub fn sent(&self) -> u64 {
        self.sent
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_are_counted_strictly_before_a_plant_time() {
        let mut c = CommandTimes::default();
        assert_eq!(c.before(0), Some(0));
        for t in [0, 0, 50, 100, 100, 100, 150] {
            c.push(t);
        }
        assert_eq!(c.sent(), 7);
        assert_eq!(c.before(0), Some(0));
        assert_eq!(c.before(1), Some(2));
        assert_eq!(c.before(50), Some(2));
        assert_eq!(c.before(51), Some(3));
        assert_eq!(c.before(100), Some(3));
        assert_eq!(c.before(150), Some(6));
        assert_eq!(c.before(u64::MAX), Some(7));
    }

    #[test]
    fn a_time_older_than_what_is_kept_has_no_answer_and_a_newer_one_stays_exact() {
        let mut c = CommandTimes::default();
        for k in 0..(KEPT_TIMES as u64 + 10) {
            c.push(k * 10);
        }
        // Times 0..=90 forgotten (ten entries), 100 the oldest kept.
        assert_eq!(c.before(100), Some(10), "the forgotten entry before it answers");
        assert_eq!(c.before(95), Some(10));
        assert_eq!(c.before(90), None);
        assert_eq!(c.before(0), None);
        assert_eq!(c.before(105), Some(11));
        assert_eq!(c.before(u64::MAX), Some(KEPT_TIMES as u64 + 10));
    }
}
