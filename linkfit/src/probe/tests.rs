use super::*;
use proptest::prelude::*;

#[test]
fn a_probe_and_its_reply_read_back_and_the_reply_is_as_long_as_the_probe() {
    let p = Probe { seq: 7, sent_ns: 123_456_789 };
    let mut buf = Vec::new();
    encode_probe(p, 64, &mut buf).expect("encoded");
    assert_eq!(buf.len(), 64);
    assert_eq!(decode(&buf), Ok(Packet::Probe(p)));
    let far = FarStamps { received_ns: 9, sent_ns: 11 };
    let mut reply = Vec::new();
    assert_eq!(encode_reply(&buf, far, &mut reply), Ok(p));
    assert_eq!(reply.len(), 64);
    assert_eq!(decode(&reply), Ok(Packet::Reply(p, far)));
    // The echo answers probes only: not a reply, not a stranger's datagram.
    assert_eq!(encode_reply(&reply, far, &mut Vec::new()), Err(ProbeError::Kind(2)));
    assert_eq!(decode(b"hello"), Err(ProbeError::Short(5)));
    assert_eq!(decode(&[0u8; 64]), Err(ProbeError::Magic));
    let mut v2 = buf.clone();
    v2[4] = 2;
    assert_eq!(decode(&v2), Err(ProbeError::Version(2)));
    assert_eq!(encode_probe(p, 39, &mut buf), Err(ProbeError::Size(39)));
    assert_eq!(encode_probe(p, 1473, &mut buf), Err(ProbeError::Size(1473)));
}

#[test]
fn probes_settle_in_send_order_as_answered_or_lost_and_stray_replies_are_counted() {
    let ms = 1_000_000;
    let mut l = Ledger::new(100 * ms);
    let a = l.send(0);
    let b = l.send(10 * ms);
    let c = l.send(20 * ms);
    // c answered first: nothing settles before a and b are.
    assert_eq!(l.answer(c.seq, 25 * ms, None), Matched::Answered(5 * ms));
    assert_eq!(l.settle(30 * ms), 0);
    assert_eq!(l.answer(a.seq, 40 * ms, None), Matched::Answered(40 * ms));
    assert_eq!(l.settle(41 * ms), 1);
    // b never answered: lost once its timeout passed, then c settles behind it.
    assert_eq!(l.settle(110 * ms), 1);
    assert_eq!(l.settle(111 * ms), 3);
    assert_eq!(l.answer(b.seq, 200 * ms, None), Matched::Late);
    assert_eq!(l.answer(a.seq, 200 * ms, None), Matched::Duplicate);
    assert_eq!(l.answer(99, 200 * ms, None), Matched::Unknown);
    let d = l.send(300 * ms);
    // A reply past the timeout, before the ledger settled the probe: late all the same.
    assert_eq!(l.answer(d.seq, 401 * ms, None), Matched::Late);
    let e = l.send(400 * ms);
    assert_eq!(l.waiting_sent_at(400 * ms), Some(e.seq));
    assert_eq!(l.waiting_sent_at(401 * ms), None);
    let (exchanges, counts, left_out) = l.finish(450 * ms);
    assert_eq!(left_out, 1, "e is within its timeout: neither answered nor lost");
    assert_eq!(round_trips_s(&exchanges), vec![0.04, LOST_S, 0.005, LOST_S]);
    assert_eq!(counts, Counts { sent: 5, answered: 2, lost: 2, late: 2, duplicates: 1, unknown: 1 });
}

#[test]
fn the_far_sides_holding_time_is_not_part_of_the_round_trip() {
    let e = Exchange {
        seq: 0,
        sent_ns: 1_000,
        outcome: Outcome::Answered {
            received_ns: 11_000,
            far: Some(FarStamps { received_ns: 50_000, sent_ns: 52_000 }),
        },
    };
    assert_eq!(e.round_trip_ns(), Some(8_000));
    assert!(!e.held_past_round_trip());
}

#[test]
fn a_far_side_claiming_a_hold_longer_than_the_round_trip_is_flagged_and_gives_zero() {
    let e = Exchange {
        seq: 0,
        sent_ns: 1_000,
        outcome: Outcome::Answered {
            received_ns: 11_000,
            far: Some(FarStamps { received_ns: 50_000, sent_ns: 70_000 }),
        },
    };
    assert_eq!(e.round_trip_ns(), Some(0));
    assert!(e.held_past_round_trip());
    let plain = Exchange { outcome: Outcome::Answered { received_ns: 11_000, far: None }, ..e };
    assert!(!plain.held_past_round_trip(), "a plain echo claims nothing");
}

/// A recording against a far clock 5 s ahead drifting 20 ppm, with legs of 2 ms up and 1 ms
/// down at best and extra delay on either: the directions come back to within a few µs.
#[test]
fn the_two_directions_come_back_through_a_drifting_clock_offset() {
    let ms = 1_000_000u64;
    let far_clock = |t: u64| -> u64 { (t as f64 * (1.0 + 20e-6)) as u64 + 5_000 * ms };
    let mut exchanges = Vec::new();
    let mut truth = Vec::new();
    for k in 0..3000u64 {
        let t1 = k * 100 * ms; // 10 Hz for 300 s
        // Every 20th probe has the shortest legs (1.5 ms each way), the others more.
        let (up, down) = if k % 20 == 0 {
            (1_500_000, 1_500_000)
        } else {
            (2 * ms + (k % 7) * ms, 1_600_000 + (k % 5) * ms)
        };
        let t2 = far_clock(t1 + up);
        let t3 = t2 + 10_000;
        let t4 = t1 + up + 10_000 + down;
        exchanges.push(Exchange {
            seq: k,
            sent_ns: t1,
            outcome: if k == 17 {
                Outcome::Lost
            } else {
                Outcome::Answered { received_ns: t4, far: Some(FarStamps { received_ns: t2, sent_ns: t3 }) }
            },
        });
        truth.push((up, down));
    }
    let d = directions(&exchanges, 10_000 * ms).expect("directions");
    assert_eq!(d.offsets.len(), 30);
    assert_eq!((d.up_s[17], d.down_s[17]), (LOST_S, LOST_S));
    let mut worst: f64 = 0.0;
    for (k, (up, down)) in truth.iter().enumerate() {
        if k == 17 {
            continue;
        }
        worst = worst.max((d.up_s[k] - *up as f64 * 1e-9).abs());
        worst = worst.max((d.down_s[k] - *down as f64 * 1e-9).abs());
        // The round trip is the legs' sum whatever the offset.
        assert!((d.up_s[k] + d.down_s[k] - (up + down) as f64 * 1e-9).abs() < 1e-8);
    }
    // Drift between two estimates 10 s apart: interpolated, not stepped.
    assert!(worst < 5e-6, "worst one-way error {worst} s");
    // Without the far side's times there is nothing to split.
    let plain: Vec<Exchange> = exchanges
        .iter()
        .map(|e| match e.outcome {
            Outcome::Answered { received_ns, .. } => {
                Exchange { outcome: Outcome::Answered { received_ns, far: None }, ..*e }
            }
            Outcome::Lost => *e,
        })
        .collect();
    assert_eq!(directions(&plain, 10_000 * ms), None);
}

#[test]
fn iso8601_is_utc_civil_time() {
    assert_eq!(iso8601_utc(1_795_833_460), "2026-11-28T02:37:40Z");
    assert_eq!(iso8601_utc(0), "1970-01-01T00:00:00Z");
    assert_eq!(iso8601_utc(951_782_400), "2000-02-29T00:00:00Z");
}

proptest! {
    #[test]
    fn any_probe_reads_back(seq in any::<u64>(), sent in any::<u64>(), bytes in HEADER_BYTES..=MAX_PROBE_BYTES,
                            r in any::<u64>(), s in any::<u64>()) {
        let p = Probe { seq, sent_ns: sent };
        let mut buf = Vec::new();
        encode_probe(p, bytes, &mut buf).expect("encoded");
        prop_assert_eq!(buf.len(), bytes);
        prop_assert_eq!(decode(&buf), Ok(Packet::Probe(p)));
        let far = FarStamps { received_ns: r, sent_ns: s };
        let mut reply = Vec::new();
        prop_assert_eq!(encode_reply(&buf, far, &mut reply), Ok(p));
        prop_assert_eq!(decode(&reply), Ok(Packet::Reply(p, far)));
    }

    /// Any replies in any order (some lost, some late, some twice): the probes settle in send
    /// order, each answered one with its own round trip, and the counts add up.
    #[test]
    fn any_replies_settle_in_order_with_their_round_trips(
        delays in proptest::collection::vec(proptest::option::of(0u64..300), 1..200),
        twice in proptest::collection::vec(any::<bool>(), 200),
    ) {
        let timeout = 200u64;
        let mut l = Ledger::new(timeout);
        let mut arrivals = Vec::new();
        for (k, d) in delays.iter().enumerate() {
            let p = l.send(k as u64 * 10);
            if let Some(d) = d {
                arrivals.push((p.sent_ns + d, p.seq));
                if twice[k] {
                    arrivals.push((p.sent_ns + d + 1, p.seq));
                }
            }
        }
        arrivals.sort_unstable();
        for &(t, seq) in &arrivals {
            l.settle(t);
            l.answer(seq, t, None);
        }
        let end = delays.len() as u64 * 10 + 10 * timeout;
        let (exchanges, counts, left_out) = l.finish(end);
        prop_assert_eq!(left_out, 0);
        prop_assert_eq!(exchanges.len(), delays.len());
        for (k, (e, d)) in exchanges.iter().zip(&delays).enumerate() {
            prop_assert_eq!(e.seq, k as u64);
            let want = d.filter(|d| *d <= timeout);
            prop_assert_eq!(e.round_trip_ns(), want);
        }
        prop_assert_eq!(counts.answered + counts.lost, counts.sent);
        let answered = delays.iter().filter(|d| d.is_some_and(|d| d <= timeout)).count() as u64;
        prop_assert_eq!(counts.answered, answered);
        // A second reply is a duplicate of an answered probe, late again for a late one.
        let (mut late, mut duplicates) = (0, 0);
        for (d, t) in delays.iter().zip(&twice) {
            let Some(d) = d else { continue };
            let copies = if *t { 2 } else { 1 };
            if *d > timeout { late += copies } else { duplicates += copies - 1 }
        }
        prop_assert_eq!((counts.late, counts.duplicates, counts.unknown), (late, duplicates, 0));
    }
}
