use super::*;

#[test]
fn errors_name_the_line() {
    assert_eq!(
        parse_trace("0.1\n# c\nabc\n"),
        Err(TraceError::Line { line: 3, reason: "`abc` is not a number of seconds".into() })
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
