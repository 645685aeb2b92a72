use super::*;

#[test]
fn errors_name_the_line() {
    assert_eq!(
        parse_trace("0.1\n# c\nabc\n"),
        Err(TraceError::Line { line: 3, reason: "`abc` is not a number of seconds (nor `lost`)".into() })
    );
    assert!(matches!(parse_trace("0.1\r\n-0.2\r\n"), Err(TraceError::Line { line: 2, .. })));
    assert!(matches!(parse_trace("0.1\nNaN\n"), Err(TraceError::Line { line: 2, .. })));
    assert!(matches!(parse_trace("0.1\ninf\n"), Err(TraceError::Line { line: 2, .. })));
    assert!(matches!(parse_trace("0.1\n3601\n"), Err(TraceError::Line { line: 2, .. })));
    assert!(matches!(parse_trace("0.1, 0.2\n"), Err(TraceError::Line { line: 1, .. })));
    assert_eq!(parse_trace("# only a comment\n\n"), Err(TraceError::Empty));
    assert_eq!(parse_trace("delay_s\n"), Err(TraceError::Empty));
    assert_eq!(parse_trace("1e-3\r\n2.5e-2\n"), Ok(vec![0.001, 0.025]));
}

#[test]
fn the_header_is_allowed_only_as_the_first_line() {
    assert_eq!(parse_trace("delay_s\n0.1\n"), Ok(vec![0.1]));
    assert_eq!(parse_trace("# recorded\ndelay_s\n0.1\n"), Ok(vec![0.1]));
    assert!(matches!(parse_trace("0.1\ndelay_s\n"), Err(TraceError::Line { line: 2, .. })));
}

#[test]
fn each_end_gives_what_it_says_past_the_last_delay() {
    let d = [0.1, 0.2];
    let at = |t: &Trace| (0..5).map(|k| t.delay_of(k)).collect::<Vec<_>>();
    assert_eq!(at(&Trace::looping(d)), [Some(0.1), Some(0.2), Some(0.1), Some(0.2), Some(0.1)]);
    assert_eq!(at(&Trace::holding(d)), [Some(0.1), Some(0.2), Some(0.2), Some(0.2), Some(0.2)]);
    assert_eq!(at(&Trace::from_file("x.csv", d, false)), [Some(0.1), Some(0.2), None, None, None]);
    assert_eq!(Trace::from_file("x.csv", d, true).end, TraceEnd::Loop);
}

#[test]
fn a_lost_line_is_an_entry_in_its_place() {
    assert_eq!(parse_trace("delay_s\n0.1\nlost\nlost # timeout\n0.2\n"), Ok(vec![0.1, LOST_S, LOST_S, 0.2]));
    assert_eq!(parse_trace("lost\n"), Ok(vec![LOST_S]), "a trace of one loss holds an entry");
    assert!(matches!(parse_trace("0.1\nLOST\n"), Err(TraceError::Line { line: 2, .. })));
    assert!(
        matches!(parse_trace("0.1\n-1\n"), Err(TraceError::Line { line: 2, .. })),
        "-1 is no file's loss"
    );
    let t = Trace::looping(vec![0.1, LOST_S]);
    assert_eq!((t.losses(), t.delay_of(3)), (1, Some(LOST_S)));
}

#[test]
fn provenance_comments_before_the_first_delay_are_returned_and_prose_stays_a_comment() {
    let text = "# Recorded on the lab's Wi-Fi: two walls, one AP.\n# source: ap3\n# rate_hz: 20\n\
                # probe_bytes: 56\n# losses: 1\n# tool: ping -i 0.05 # iputils\n# operator: kim\ndelay_s\n\
                0.1\n# when: not provenance after the first delay\nlost\n";
    let f = parse_trace_file(text).expect("a trace");
    assert_eq!(f.delays_s, vec![0.1, LOST_S]);
    let p = &f.provenance;
    assert_eq!(p.source.as_deref(), Some("ap3"));
    assert_eq!((p.rate_hz, p.probe_bytes, p.losses), (Some(20.0), Some(56), Some(1)));
    assert_eq!(p.tool.as_deref(), Some("ping -i 0.05 # iputils"));
    assert_eq!(p.when, None);
    assert_eq!(p.other, vec![("operator".to_string(), "kim".to_string())]);
    assert_eq!((f.losses(), f.delivered().collect::<Vec<_>>()), (1, vec![0.1]));
}

#[test]
fn a_bad_provenance_value_or_a_repeated_key_names_its_line() {
    assert!(matches!(parse_trace_file("# rate_hz: fast\n0.1\n"), Err(TraceError::Line { line: 1, .. })));
    assert!(matches!(parse_trace_file("# rate_hz: 0\n0.1\n"), Err(TraceError::Line { line: 1, .. })));
    assert!(matches!(parse_trace_file("\n# losses: -2\n0.1\n"), Err(TraceError::Line { line: 2, .. })));
    let twice = parse_trace_file("# source: a\n# source: b\n0.1\n");
    assert_eq!(
        twice,
        Err(TraceError::Line {
            line: 2,
            reason: "provenance key `source` given twice (first on line 1)".into()
        })
    );
}

#[test]
fn what_write_trace_writes_reads_back_equal() {
    let delays = vec![0.0123, LOST_S, 1e-7, 0.1 + 0.2, 3600.0, 0.0];
    let provenance = Provenance {
        source: Some("127.0.0.1".into()),
        when: Some("2026-11-27T20:57:40Z".into()),
        rate_hz: Some(100.0),
        probe_bytes: Some(56),
        losses: Some(1),
        tool: Some("ping (iputils)".into()),
        other: vec![("note".into(), "loopback # with drops".into())],
    };
    let text = write_trace(&delays, &provenance).expect("writable");
    assert!(text.contains("\nlost\n") && text.starts_with("# source: 127.0.0.1\n"), "{text}");
    assert_eq!(parse_trace_file(&text), Ok(TraceFile { delays_s: delays, provenance }));
}

#[test]
fn write_trace_refuses_what_would_not_read_back() {
    let p = Provenance::default();
    assert_eq!(write_trace(&[], &p), Err(WriteError::Empty));
    assert!(matches!(write_trace(&[0.1, -0.5], &p), Err(WriteError::Delay { index: 1, .. })));
    assert!(matches!(write_trace(&[f64::NAN], &p), Err(WriteError::Delay { index: 0, .. })));
    let multi = Provenance { tool: Some("a\nb".into()), ..Provenance::default() };
    assert!(matches!(write_trace(&[0.1], &multi), Err(WriteError::Provenance { .. })));
    let known = Provenance { other: vec![("source".into(), "x".into())], ..Provenance::default() };
    assert!(matches!(write_trace(&[0.1], &known), Err(WriteError::Provenance { .. })));
    let bad_key = Provenance { other: vec![("two words".into(), "x".into())], ..Provenance::default() };
    assert!(matches!(write_trace(&[0.1], &bad_key), Err(WriteError::Provenance { .. })));
}
