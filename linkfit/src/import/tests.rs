use super::*;

/// A fixture under `tests/data/` (recorded on this machine: see `tests/data/README.md`).
fn data(name: &str) -> String {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn lost_at(delays: &[f64]) -> Vec<usize> {
    delays.iter().enumerate().filter(|(_, d)| delay::is_lost(**d)).map(|(i, _)| i).collect()
}

#[test]
fn linux_ping_with_dropped_replies_gives_every_probe_in_order() {
    let got = import(&data("ping-linux-loopback.txt"), &ImportOptions::new(Format::Ping)).expect("imported");
    let d = &got.trace.delays_s;
    // 200 transmitted, 192 received; icmp_seq 1 is entry 0. The missing numbers, by hand.
    assert_eq!(d.len(), 200);
    assert_eq!(lost_at(d), vec![18, 34, 52, 53, 78, 98, 125, 175]);
    assert_eq!((d[0], d[4], d[17]), (0.133e-3, 0.047e-3, 0.049e-3));
    let p = &got.trace.provenance;
    assert_eq!((p.source.as_deref(), p.probe_bytes, p.losses), (Some("127.0.0.1"), Some(56), Some(8)));
    assert_eq!(p.tool.as_deref(), Some("ping (iputils)"));
    assert_eq!((got.skipped, got.duplicates), (0, 0));
}

#[test]
fn ping_dash_o_dash_d_loses_the_first_probe_and_strips_the_timestamps() {
    let got =
        import(&data("ping-linux-loopback-O-D.txt"), &ImportOptions::new(Format::Ping)).expect("imported");
    assert_eq!(got.trace.delays_s.len(), 60);
    assert_eq!(lost_at(&got.trace.delays_s), vec![0, 17], "icmp_seq 1 and 18 had no answer");
    assert_eq!(got.trace.delays_s[4], 0.037e-3);
}

#[test]
fn macos_ping_numbers_from_zero_and_counts_timeouts_and_a_lost_tail() {
    let text = "PING 10.0.0.1 (10.0.0.1): 56 data bytes\n\
                64 bytes from 10.0.0.1: icmp_seq=0 ttl=64 time=12.345 ms\n\
                Request timeout for icmp_seq 1\n\
                64 bytes from 10.0.0.1: icmp_seq=2 ttl=64 time=20.5 ms\n\
                64 bytes from 10.0.0.1: icmp_seq=2 ttl=64 time=25.1 ms (DUP!)\n\
                \n--- 10.0.0.1 ping statistics ---\n\
                5 packets transmitted, 2 packets received, +1 duplicates, 60.0% packet loss\n\
                round-trip min/avg/max/stddev = 12.345/16.422/20.500/4.077 ms\n";
    let got = import(text, &ImportOptions::new(Format::Ping)).expect("imported");
    assert_eq!(got.trace.delays_s, vec![0.012345, delay::LOST_S, 0.0205, delay::LOST_S, delay::LOST_S]);
    assert_eq!(got.duplicates, 1);
    assert_eq!(got.trace.provenance.tool.as_deref(), Some("ping (macOS)"));
    assert_eq!(got.trace.provenance.probe_bytes, Some(56));
}

#[test]
fn ping_sequence_numbers_unwrap_past_65535_and_late_replies_find_their_probe() {
    let mut text = String::from("PING h (127.0.0.1) 56(84) bytes of data.\n");
    let n = 70_000u64;
    for k in 1..=n {
        if k == 10 {
            continue; // its reply comes after probe 11's
        }
        text.push_str(&format!("64 bytes from h: icmp_seq={} ttl=64 time={}.5 ms\n", k % 65_536, k % 7));
        if k == 11 {
            text.push_str("64 bytes from h: icmp_seq=10 ttl=64 time=3.5 ms\n");
        }
    }
    text.push_str(&format!("{n} packets transmitted, {n} received, 0% packet loss, time 1ms\n"));
    let got = import(&text, &ImportOptions::new(Format::Ping)).expect("imported");
    assert_eq!(got.trace.delays_s.len(), n as usize);
    for (i, d) in got.trace.delays_s.iter().enumerate() {
        let k = i as u64 + 1;
        let want: f64 = format!("{}.5e-3", k % 7).parse().expect("a number");
        assert_eq!(*d, want, "probe {k}");
    }
}

#[test]
fn a_bad_ping_line_is_refused_with_its_number_or_skipped_and_counted() {
    let text = "PING h (127.0.0.1) 56(84) bytes of data.\n\
                64 bytes from h: icmp_seq=1 ttl=64 time=1.0 ms\n\
                garbage here\n\
                64 bytes from h: icmp_seq=2 ttl=64 time=abc ms\n\
                64 bytes from h: icmp_seq=3 ttl=64 time=3.0 ms\n";
    let err = import(text, &ImportOptions::new(Format::Ping));
    assert_eq!(
        err,
        Err(ImportError::Line { line: 3, reason: "not a line of ping's output: `garbage here`".into() })
    );
    let got = import(text, &ImportOptions { skip_bad: true, ..ImportOptions::new(Format::Ping) })
        .expect("imported");
    assert_eq!(got.skipped, 2);
    assert_eq!(got.skipped_first.iter().map(|s| s.line).collect::<Vec<_>>(), vec![3, 4]);
    assert_eq!(got.trace.delays_s, vec![1e-3, delay::LOST_S, 3e-3], "a skipped reply is a loss");
    assert!(
        import("hello\n", &ImportOptions { skip_bad: true, ..ImportOptions::new(Format::Ping) }).is_err()
    );
}

#[test]
fn irtt_json_gives_round_trips_losses_and_provenance() {
    let got = import(&data("irtt-loopback.json"), &ImportOptions::new(Format::Irtt)).expect("imported");
    let d = &got.trace.delays_s;
    // stats: packets_sent 199, packets_received 194; round trip 0's rtt is 119984 ns.
    assert_eq!((d.len(), got.trace.losses()), (199, 5));
    assert!(delay::is_lost(d[71]) && delay::is_lost(d[78]));
    assert_eq!(d[0], 119_984e-9);
    let p = &got.trace.provenance;
    assert_eq!(p.source.as_deref(), Some("127.0.0.1:2112"));
    assert_eq!((p.rate_hz, p.probe_bytes), (Some(100.0), Some(60)));
    assert_eq!(p.tool.as_deref(), Some("irtt 0.9.0"));
    assert_eq!(p.when.as_deref(), Some("2026-11-27T20:57:40.914902733Z"));
    let send = ImportOptions { irtt_delay: IrttDelay::Send, ..ImportOptions::new(Format::Irtt) };
    assert_eq!(import(&data("irtt-loopback.json"), &send).expect("imported").trace.delays_s[0], 40_081e-9);
}

#[test]
fn irtt_round_trip_without_its_delay_is_bad_and_not_json_is_refused() {
    let text = r#"{"round_trips":[{"seqno":0,"lost":"false","delay":{"rtt":1000000}},{"seqno":1,"lost":"false","delay":{}},{"seqno":2,"lost":"true_down"}]}"#;
    assert!(matches!(
        import(text, &ImportOptions::new(Format::Irtt)),
        Err(ImportError::Line { line: 2, .. })
    ));
    let skip = ImportOptions { skip_bad: true, ..ImportOptions::new(Format::Irtt) };
    let got = import(text, &skip).expect("imported");
    assert_eq!(got.trace.delays_s, vec![1e-3, delay::LOST_S, delay::LOST_S]);
    assert!(matches!(import("PING", &ImportOptions::new(Format::Irtt)), Err(ImportError::Text(_))));
}

#[test]
fn csv_takes_a_named_column_in_its_unit_and_empty_or_lost_cells_are_losses() {
    let text = "# exported\ntime,rtt_ms,host\n0,12.5,a\n1,,a\n2,lost,a\n3,\"7\",a\n";
    let opts = ImportOptions { column: Some("rtt_ms".into()), ..ImportOptions::new(Format::Csv) };
    let got = import(text, &opts).expect("imported");
    assert_eq!(got.trace.delays_s, vec![0.0125, delay::LOST_S, delay::LOST_S, 0.007]);
    let us = ImportOptions { unit: Some(Unit::Us), ..opts.clone() };
    assert!(matches!(import(text, &us), Err(ImportError::Text(m)) if m.contains("says ms")));
    assert!(
        matches!(import(text, &ImportOptions::new(Format::Csv)), Err(ImportError::Text(m)) if m.contains("--column"))
    );
    let one = ImportOptions { unit: Some(Unit::Us), ..ImportOptions::new(Format::Csv) };
    assert_eq!(import("1500\n250\n", &one).expect("imported").trace.delays_s, vec![0.0015, 0.00025]);
    assert_eq!(
        import("delay_s\n0.1\n", &ImportOptions::new(Format::Csv)).expect("ours").trace.delays_s,
        vec![0.1]
    );
}

#[test]
fn a_bad_csv_row_names_its_line() {
    let text = "rtt_ms\n1\n-2\nx\n3\n";
    assert!(matches!(import(text, &ImportOptions::new(Format::Csv)), Err(ImportError::Line { line: 3, .. })));
    let skip = ImportOptions { skip_bad: true, ..ImportOptions::new(Format::Csv) };
    let got = import(text, &skip).expect("imported");
    assert_eq!((got.trace.delays_s.clone(), got.skipped), (vec![0.001, 0.003], 2));
    let ragged = "a,b\n1,2\n3\n";
    let col = ImportOptions { column: Some("a".into()), ..ImportOptions::new(Format::Csv) };
    assert!(matches!(import(ragged, &col), Err(ImportError::Line { line: 3, .. })));
}

#[test]
fn an_imported_trace_writes_and_reads_back_equal() {
    let got = import(&data("ping-linux-loopback.txt"), &ImportOptions::new(Format::Ping)).expect("imported");
    let text = delay::write_trace(&got.trace.delays_s, &got.trace.provenance).expect("written");
    assert_eq!(delay::parse_trace_file(&text), Ok(got.trace));
}

#[test]
fn unit_and_column_apply_to_csv_only() {
    let o = ImportOptions { unit: Some(Unit::Ms), ..ImportOptions::new(Format::Ping) };
    assert!(matches!(import("", &o), Err(ImportError::Text(_))));
}

#[test]
fn a_log_claiming_more_probes_than_a_trace_holds_is_refused_naming_the_claim_before_allocating() {
    let ping = |text: &str| import(text, &ImportOptions::new(Format::Ping));
    // Three replies and a summary claiming 10^15 packets (an 8 PB allocation before).
    let claim = "64 bytes from h: icmp_seq=1 ttl=64 time=1.0 ms\n\
                 64 bytes from h: icmp_seq=2 ttl=64 time=1.0 ms\n\
                 1000000000000000 packets transmitted, 2 received, 0% packet loss\n";
    let e = ping(claim).expect_err("refused").to_string();
    assert!(
        e.contains("`1000000000000000 packets transmitted`") && e.contains("more than the 10000000"),
        "{e}"
    );
    // icmp_seq jumping by 32,767 a line: unwrapped, 65.5 M entries from a 100 kB log.
    let mut jumps = String::new();
    for k in 0..2_000u64 {
        jumps.push_str(&format!("64 bytes from h: icmp_seq={} ttl=64 time=1.0 ms\n", (k * 32_767) % 65_536));
    }
    let e = ping(&jumps).expect_err("refused").to_string();
    assert!(e.contains("icmp_seq up to") && e.contains("entries"), "{e}");
    // irtt's seqno of 10^15.
    let irtt = r#"{"round_trips":[{"seqno":0,"lost":"false","delay":{"rtt":1000000}},{"seqno":1000000000000000,"lost":"false","delay":{"rtt":1000000}}]}"#;
    let e = import(irtt, &ImportOptions::new(Format::Irtt)).expect_err("refused").to_string();
    assert!(e.contains("seqno 0 to 1000000000000000"), "{e}");
}

#[test]
fn ping_dash_d_stamps_give_the_rate_and_rate_hz_says_it_for_any_format_within_bounds() {
    let got =
        import(&data("ping-linux-loopback-O-D.txt"), &ImportOptions::new(Format::Ping)).expect("imported");
    // icmp_seq 2 to 60, stamped 1795813059.422189 to 1795813060.386145: 58 probes in 0.963956 s.
    assert_eq!(got.trace.provenance.rate_hz, Some(60.17));
    let plain =
        import(&data("ping-linux-loopback.txt"), &ImportOptions::new(Format::Ping)).expect("imported");
    assert_eq!(plain.trace.provenance.rate_hz, None, "no stamps, no rate");
    let said = ImportOptions { rate_hz: Some(100.0), ..ImportOptions::new(Format::Ping) };
    let got = import(&data("ping-linux-loopback-O-D.txt"), &said).expect("imported");
    assert_eq!(got.trace.provenance.rate_hz, Some(100.0), "--rate-hz over the stamps");
    let csv = ImportOptions { rate_hz: Some(20.0), ..ImportOptions::new(Format::Csv) };
    assert_eq!(import("delay_s\n0.1\n", &csv).expect("imported").trace.provenance.rate_hz, Some(20.0));
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e6] {
        let o = ImportOptions { rate_hz: Some(bad), ..ImportOptions::new(Format::Csv) };
        assert!(
            matches!(import("delay_s\n0.1\n", &o), Err(ImportError::Text(m)) if m.contains("--rate-hz")),
            "{bad}"
        );
    }
}

#[test]
fn a_byte_order_mark_is_no_part_of_the_first_value_or_header() {
    let csv = ImportOptions::new(Format::Csv);
    assert_eq!(import("\u{feff}0.1\n0.2\n", &csv).expect("imported").trace.delays_s, vec![0.1, 0.2]);
    let named = ImportOptions { column: Some("rtt_ms".into()), ..csv };
    assert_eq!(import("\u{feff}rtt_ms\n40\n", &named).expect("imported").trace.delays_s, vec![0.04]);
}

#[test]
fn milliseconds_in_a_column_that_names_no_unit_are_refused_asking_for_the_unit() {
    let text = "rtt\n40\n55\n69\n";
    let csv = ImportOptions::new(Format::Csv);
    let Err(ImportError::Text(m)) = import(text, &csv) else { panic!("40-69 s delays taken") };
    assert!(m.contains("column `rtt` names no unit") && m.contains("--unit"), "{m}");
    let ms = ImportOptions { unit: Some(Unit::Ms), ..csv.clone() };
    assert_eq!(import(text, &ms).expect("imported").trace.delays_s, vec![0.04, 0.055, 0.069]);
    let s = ImportOptions { unit: Some(Unit::S), ..csv.clone() };
    assert_eq!(import("rtt\n4\n", &s).expect("said: seconds").trace.delays_s, vec![4.0]);
    assert_eq!(import("rtt\n0.04\n0.5\n", &csv).expect("seconds").trace.delays_s, vec![0.04, 0.5]);
}

#[test]
fn a_refused_value_is_echoed_cut_to_a_few_dozen_characters() {
    let huge = "9".repeat(300);
    let text = format!("rtt_ms\n1\n{huge}\n");
    let Err(ImportError::Line { line: 3, reason }) = import(&text, &ImportOptions::new(Format::Csv)) else {
        panic!("a 300-digit delay taken")
    };
    assert!(reason.len() < 120 && reason.contains("..."), "{reason}");
    let header = format!("{}\n1\n", "x".repeat(10_000));
    let named = ImportOptions { column: Some("rtt".into()), ..ImportOptions::new(Format::Csv) };
    let Err(ImportError::Text(m)) = import(&header, &named) else { panic!("no such column") };
    assert!(m.len() < 200, "{m}");
}
