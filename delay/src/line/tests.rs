use super::*;

fn line(delay: Distribution) -> Result<DelayLine, ProfileError> {
    DelayLine::new(Direction::ControllerToPlant, DirectionProfile::with_delay(delay, 9))
}

#[test]
fn fifo_queues_behind_a_slow_message_and_independent_reorders() -> Result<(), ProfileError> {
    let trace = Distribution::Trace(Trace::holding(vec![0.5, 0.1]));
    let mut fifo = line(trace.clone())?;
    let a = fifo.send(0);
    let b = fifo.send(1_000);
    let rel = |d: Decision| d.releases().next().map(|r| r.release_time_ns);
    assert_eq!(rel(a), Some(500_000_000));
    assert_eq!(rel(b), Some(500_000_000), "FIFO: the second waits for the first");
    let mut indep = line(trace)?;
    let mut p = indep.profile().clone();
    p.ordering = Ordering::Independent;
    indep.set_profile(p)?;
    let a = indep.send(0);
    let b = indep.send(1_000);
    assert_eq!(rel(a), Some(500_000_000));
    assert_eq!(rel(b), Some(100_001_000), "independent: the second overtakes");
    Ok(())
}

#[test]
fn invalid_profile_change_keeps_the_running_one() -> Result<(), ProfileError> {
    let mut l = line(Distribution::Constant { delay_s: 0.02 })?;
    let before = l.profile().clone();
    let bad = DirectionProfile::with_delay(Distribution::Gamma { shape: -1.0, scale_s: 0.01 }, 1);
    assert_eq!(l.set_profile(bad).map_err(|e| e.field), Err("delay.gamma.shape".to_string()));
    assert_eq!(l.profile(), &before);
    assert_eq!(l.send(0).releases().next().map(|r| r.delay_ns), Some(20_000_000));
    Ok(())
}

#[test]
fn non_looping_trace_holds_its_last_delay() -> Result<(), ProfileError> {
    let mut l = line(Distribution::Trace(Trace::holding(vec![0.001, 0.002])))?;
    let d: Vec<f64> = (0..4).map(|_| l.sample_delay_s()).collect();
    assert_eq!(d, vec![0.001, 0.002, 0.002, 0.002]);
    assert!(l.trace_exhausted());
    assert_eq!(l.check_next(), Ok(()));
    Ok(())
}

#[test]
fn a_stopping_trace_gives_no_delay_past_its_end_and_says_so_before() -> Result<(), ProfileError> {
    let mut l = line(Distribution::Trace(Trace::from_file("wifi.csv", vec![0.001, 0.002], false)))?;
    for k in 0..2u64 {
        assert_eq!(l.check_next(), Ok(()));
        assert!(!l.send(k).trace_ended);
    }
    let ended = TraceEnded { name: "wifi.csv".into(), delays: 2, message: 2 };
    assert_eq!(l.check_next(), Err(ended));
    let d = l.send(2);
    assert!(d.trace_ended && d.fate == Fate::Dropped && d.sampled_delay_s.is_nan());
    assert!(l.check_next().is_err(), "it stays ended");
    l.reset();
    assert_eq!(l.check_next(), Ok(()));
    Ok(())
}

#[test]
fn loss_one_drops_everything_and_duplicate_one_doubles() -> Result<(), ProfileError> {
    let mut p = DirectionProfile::with_delay(Distribution::Constant { delay_s: 0.01 }, 3);
    p.loss_probability = 1.0;
    let mut l = DelayLine::new(Direction::PlantToController, p.clone())?;
    assert!((0..100).all(|i| l.send(i).fate == Fate::Dropped));
    p.loss_probability = 0.0;
    p.duplicate_probability = 1.0;
    let mut l = DelayLine::new(Direction::PlantToController, p)?;
    assert!((0..100).all(|i| l.send(i).releases().count() == 2));
    Ok(())
}

#[test]
fn a_traces_lost_entry_drops_that_message_and_counts_as_a_loss() -> Result<(), ProfileError> {
    let trace = Trace::from_file("link.csv", vec![0.01, crate::LOST_S, 0.02], false);
    let mut l = line(Distribution::Trace(trace))?;
    let mut stats = crate::DirectionStats::default();
    let decisions: Vec<Decision> = (0..3u64).map(|k| l.send(k * 50_000_000)).collect();
    for d in &decisions {
        stats.record_decision(d);
        for r in d.releases() {
            stats.record_delivered(r.delay_ns);
        }
    }
    assert_eq!(decisions[1].fate, Fate::Dropped);
    assert!(decisions[1].sampled_delay_s.is_nan() && !decisions[1].trace_ended);
    let delays: Vec<Option<u64>> =
        decisions.iter().map(|d| d.releases().next().map(|r| r.delay_ns)).collect();
    assert_eq!(delays, vec![Some(10_000_000), None, Some(20_000_000)], "the loss is not skipped");
    assert_eq!((stats.sent, stats.dropped, stats.delivered), (3, 1, 2));
    Ok(())
}

#[test]
fn a_trace_with_losses_validates_and_other_negatives_do_not() {
    let ok = DirectionProfile::with_delay(Distribution::Trace(Trace::looping(vec![crate::LOST_S, 0.1])), 1);
    assert_eq!(ok.validate(), Ok(()));
    let bad = DirectionProfile::with_delay(Distribution::Trace(Trace::looping(vec![0.1, -0.5])), 1);
    assert_eq!(bad.validate().map_err(|e| e.field), Err("delay.trace.delays_s[1]".to_string()));
}
