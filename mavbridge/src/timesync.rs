//! The vehicle's clock seen from the gateway's: MAVLink `TIMESYNC` (a request carries the
//! sender's time in `ts1` and `tc1 = 0`; the answer carries the answerer's time in `tc1` and
//! echoes `ts1`). The offset of the exchange with the shortest round trip among the last few is
//! kept (a long round trip bounds the offset loosely).

/// Exchanges remembered.
const WINDOW: usize = 8;

/// The offset `vehicle - local` of the vehicle's clock, ns.
#[derive(Debug, Clone, Default)]
pub struct TimeSync {
    /// (round trip, offset) of the last exchanges, ns.
    exchanges: Vec<(u64, i64)>,
    next: usize,
    /// Vehicle time minus local arrival time of the latest state message: a bound used before
    /// the first exchange (it ignores the transport's latency).
    arrival_offset_ns: Option<i64>,
    /// Local time of the last [`TimeSync::restart`]: answers to earlier requests are ignored.
    since_ns: i64,
    /// `ts1` of the last requests sent and not answered yet: an answer must echo one.
    outstanding: Vec<i64>,
    /// `(ts1, tc1)` of the last answer taken: a later one must be newer in both clocks.
    last_answer: Option<(i64, i64)>,
}

impl TimeSync {
    /// The request to send at local time `now_ns`: `(tc1, ts1)`, remembered until answered.
    pub fn request(&mut self, now_ns: u64) -> (i64, i64) {
        if self.outstanding.len() == WINDOW {
            self.outstanding.remove(0);
        }
        self.outstanding.push(now_ns as i64);
        (0, now_ns as i64)
    }

    /// An answer `(tc1, ts1)` arrived at local time `now_ns`. Returns the exchange's round trip
    /// when it answers one of our outstanding requests (sent since the last restart) and goes
    /// forward in both clocks from the last answer taken; `None` otherwise (the caller counts
    /// it): an answer to someone else's request, a second answer, or a vehicle clock that went
    /// backwards, which would drag the offset that stamps the commands.
    pub fn on_answer(&mut self, tc1: i64, ts1: i64, now_ns: u64) -> Option<u64> {
        let now = now_ns as i64;
        if tc1 <= 0 || ts1 < self.since_ns || ts1 > now {
            return None;
        }
        let asked = self.outstanding.iter().position(|&t| t == ts1)?;
        if self.last_answer.is_some_and(|(last_ts1, last_tc1)| ts1 <= last_ts1 || tc1 <= last_tc1) {
            return None;
        }
        self.outstanding.remove(asked);
        self.last_answer = Some((ts1, tc1));
        let rtt = (now - ts1) as u64;
        let offset = tc1 - (ts1 + (now - ts1) / 2);
        if self.exchanges.len() < WINDOW {
            self.exchanges.push((rtt, offset));
        } else {
            self.exchanges[self.next] = (rtt, offset);
        }
        self.next = (self.next + 1) % WINDOW;
        Some(rtt)
    }

    /// The vehicle's clock restarted (it rebooted), noticed at local time `now_ns`: every
    /// estimate is forgotten, and answers to requests sent before now (which the vehicle may
    /// have stamped with its old clock) are ignored.
    pub fn restart(&mut self, now_ns: u64) {
        *self = Self { since_ns: now_ns as i64, ..Self::default() };
    }

    /// A state message stamped `vehicle_ns` arrived at local time `now_ns`.
    pub fn on_arrival(&mut self, vehicle_ns: u64, now_ns: u64) {
        self.arrival_offset_ns = Some(vehicle_ns as i64 - now_ns as i64);
    }

    /// The best estimate of `vehicle - local`, ns, and whether it comes from `TIMESYNC`.
    pub fn offset_ns(&self) -> Option<(i64, bool)> {
        match self.exchanges.iter().min_by_key(|(rtt, _)| *rtt) {
            Some(&(_, offset)) => Some((offset, true)),
            None => self.arrival_offset_ns.map(|o| (o, false)),
        }
    }

    /// The vehicle's clock at local time `now_ns`, ns (0 before any estimate).
    pub fn vehicle_ns(&self, now_ns: u64) -> Option<u64> {
        self.offset_ns().map(|(o, _)| (now_ns as i64).saturating_add(o).max(0) as u64)
    }

    /// The shortest round trip of the exchanges remembered, ns.
    pub fn best_round_trip_ns(&self) -> Option<u64> {
        self.exchanges.iter().map(|(rtt, _)| *rtt).min()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shortest_round_trip_gives_the_offset() {
        let mut t = TimeSync::default();
        assert_eq!(t.offset_ns(), None);
        t.on_arrival(5_000_000_000, 1_000_000_000);
        assert_eq!(t.offset_ns(), Some((4_000_000_000, false)));
        // Vehicle clock = local + 3 s. Exchange 1: sent at 10 ms, answered after 1 ms each
        // way... but the answer leg took 5 ms: a loose estimate.
        let (_, ts1) = t.request(10_000_000);
        let rtt = t.on_answer(3_011_000_000, ts1, 16_000_000);
        assert_eq!(rtt, Some(6_000_000));
        assert_eq!(t.offset_ns(), Some((3_011_000_000 - 13_000_000, true)));
        // Exchange 2: symmetric 0.1 ms legs: exact.
        let (_, ts1) = t.request(20_000_000);
        t.on_answer(3_020_100_000, ts1, 20_200_000);
        assert_eq!(t.offset_ns(), Some((3_000_000_000, true)));
        assert_eq!(t.vehicle_ns(1), Some(3_000_000_001));
        // A request from the vehicle (tc1 = 0) or a stamp from the future is not an answer.
        assert_eq!(t.on_answer(0, 5, 20_300_000), None);
        assert_eq!(t.on_answer(7, 30_000_000, 20_300_000), None);
    }

    #[test]
    fn a_restart_forgets_the_offset_and_ignores_answers_to_requests_sent_before_it() {
        let mut t = TimeSync::default();
        let (_, ts1) = t.request(10_000_000);
        t.on_answer(600_000_000_000, ts1, 10_200_000);
        t.on_arrival(600_000_000_000, 10_000_000);
        t.restart(20_000_000);
        assert_eq!(t.offset_ns(), None);
        // Sent before the restart, answered late with the old clock: not used.
        assert_eq!(t.on_answer(600_010_000_000, ts1, 20_100_000), None);
        assert_eq!(t.offset_ns(), None);
        // Sent after it: the new clock (booted 1 s ago).
        let (_, ts1) = t.request(20_000_000);
        t.on_answer(1_000_100_000, ts1, 20_200_000);
        assert_eq!(t.offset_ns(), Some((1_000_000_000 - 20_000_000, true)));
    }

    #[test]
    fn an_answer_must_echo_an_outstanding_request_once_and_go_forward_in_both_clocks() {
        let mut t = TimeSync::default();
        // Vehicle clock = local + 3 s.
        let (_, first) = t.request(10_000_000);
        let (_, second) = t.request(20_000_000);
        assert_eq!(t.on_answer(3_015_000_000, 15_000_000, 21_000_000), None, "never asked at 15 ms");
        assert!(t.on_answer(3_010_100_000, first, 10_200_000).is_some());
        assert_eq!(t.on_answer(3_010_100_000, first, 10_300_000), None, "answered already");
        // The second answer says the vehicle's clock went back by 2 s: refused, offset kept.
        assert_eq!(t.on_answer(1_020_100_000, second, 20_200_000), None);
        assert_eq!(t.offset_ns(), Some((3_000_000_000, true)));
        let (_, third) = t.request(30_000_000);
        assert!(t.on_answer(3_030_100_000, third, 30_200_000).is_some());
        assert_eq!(t.offset_ns(), Some((3_000_000_000, true)));
    }
}
