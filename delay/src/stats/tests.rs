use super::*;

#[test]
fn percentiles_are_nearest_rank() {
    let mut s = DirectionStats::new(10);
    assert_eq!(s.delay_percentiles(), None);
    for d in 1..=100 {
        s.record_delivered(d);
    }
    let p = s.delay_percentiles().unwrap_or_default();
    assert_eq!((p.p50_ns, p.p95_ns, p.p99_ns, p.max_ns), (50, 95, 99, 100));
    let (w, h) = s.histogram();
    assert_eq!(w, 10);
    assert_eq!(h.iter().sum::<u64>(), 100);
    assert_eq!(h[0], 9);
    assert_eq!(s.delivered, 100);
    s.reset();
    assert_eq!(s.delivered, 0);
}

#[test]
fn a_window_counts_every_push_and_keeps_the_maximum_of_all() {
    let mut w = Window::default();
    assert_eq!(w.percentiles(), None);
    for v in [5, 1, 9, 3] {
        w.push(v);
    }
    assert_eq!(w.count(), 4);
    let p = w.percentiles().unwrap_or_default();
    assert_eq!((p.p50_ns, p.max_ns), (3, 9));
}
