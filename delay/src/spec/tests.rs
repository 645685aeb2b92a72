use super::*;
use crate::TraceEnd;

fn parse(text: &str) -> DelaysTable {
    match toml::from_str(text) {
        Ok(t) => t,
        Err(e) => panic!("{e}"),
    }
}

fn network(text: &str) -> Result<NetworkProfile, SpecError> {
    parse(text).to_network(7, &mut |file| match file {
        "wifi.csv" => Ok(vec![0.01, 0.02, 0.03]),
        other => Err(format!("cannot read {other}")),
    })
}

fn field_of(text: &str) -> String {
    match network(text) {
        Ok(n) => panic!("accepted: {n:?}"),
        Err(e) => e.field,
    }
}

#[test]
fn a_round_trip_is_on_commands_and_every_kind_is_read() -> Result<(), SpecError> {
    let n = network("kind = \"gamma\"\nshape = 12.0\nscale_s = 0.015\n")?;
    assert_eq!(n, crate::preset("paper", 7).map_err(|e| err(e.field, e.reason))?);
    let cases = [
        ("kind = \"none\"", Distribution::Constant { delay_s: 0.0 }),
        ("kind = \"constant\"\ndelay_s = 0.1", Distribution::Constant { delay_s: 0.1 }),
        ("kind = \"uniform\"\nmin_s = 0.1\nmax_s = 0.2", Distribution::Uniform { min_s: 0.1, max_s: 0.2 }),
        ("kind = \"normal\"\nmean_s = 0.1\nstd_s = 0.02", Distribution::Normal { mean_s: 0.1, std_s: 0.02 }),
        (
            "kind = \"gamma\"\nmean_s = 0.1\nstd_s = 0.02",
            Distribution::GammaMoments { mean_s: 0.1, std_s: 0.02 },
        ),
        (
            "kind = \"gamma_moments\"\nmean_s = 0.1\nstd_s = 0.02",
            Distribution::GammaMoments { mean_s: 0.1, std_s: 0.02 },
        ),
        (
            "kind = \"lognormal\"\nmean_s = 0.1\nstd_s = 0.02",
            Distribution::LognormalMoments { mean_s: 0.1, std_s: 0.02 },
        ),
        ("kind = \"lognormal\"\nmu = -2.0\nsigma = 0.5", Distribution::Lognormal { mu: -2.0, sigma: 0.5 }),
        (
            "kind = \"pareto\"\nscale_s = 0.01\nshape = 3.0",
            Distribution::Pareto { scale_s: 0.01, shape: 3.0 },
        ),
        (
            "kind = \"trace\"\nfile = \"wifi.csv\"",
            Distribution::Trace(Trace::from_file("wifi.csv", vec![0.01, 0.02, 0.03], false)),
        ),
    ];
    for (text, want) in cases {
        let n = network(text)?;
        assert_eq!(n.to_plant.delay, want, "{text}");
        assert!(n.to_controller.delay.is_zero());
        assert_eq!((n.to_plant.seed, n.to_controller.seed), (7, 7));
    }
    let n = network("kind = \"trace\"\nfile = \"wifi.csv\"\nlooping = true")?;
    assert!(matches!(n.to_plant.delay, Distribution::Trace(Trace { end: TraceEnd::Loop, .. })));
    Ok(())
}

#[test]
fn each_direction_in_its_own_table_with_loss_duplication_and_ordering() -> Result<(), SpecError> {
    let n = network(
        "[to_plant]\nkind = \"constant\"\ndelay_s = 0.05\nloss_probability = 0.1\n\
         [to_controller]\nkind = \"uniform\"\nmin_s = 0.0\nmax_s = 0.02\nduplicate_probability = 0.2\nordering = \"independent\"\n",
    )?;
    assert_eq!(n.to_plant.delay, Distribution::Constant { delay_s: 0.05 });
    assert_eq!((n.to_plant.loss_probability, n.to_plant.ordering), (0.1, Ordering::Fifo));
    assert_eq!(n.to_controller.duplicate_probability, 0.2);
    assert_eq!(n.to_controller.ordering, Ordering::Independent);
    let only = network("[to_controller]\nkind = \"constant\"\ndelay_s = 0.05\n")?;
    assert!(only.to_plant.delay.is_zero());
    Ok(())
}

#[test]
fn a_regime_reads_its_states_with_their_dwells() -> Result<(), SpecError> {
    let n = network(
        "kind = \"regime\"\n\
         [[states]]\nkind = \"gamma\"\nshape = 8.0\nscale_s = 0.005\nmean_dwell_messages = 50\n\
         [[states]]\nkind = \"uniform\"\nmin_s = 0.2\nmax_s = 0.4\nmean_dwell_s = 1.5\n",
    )?;
    let Distribution::Regime { states } = &n.to_plant.delay else { panic!("{n:?}") };
    assert_eq!(states.len(), 2);
    assert_eq!(states[0].mean_dwell, Dwell::Messages(50.0));
    assert_eq!(states[1].delay, Distribution::Uniform { min_s: 0.2, max_s: 0.4 });
    assert_eq!(states[1].mean_dwell, Dwell::Seconds(1.5));
    assert_eq!((states[0].loss_probability, states[1].loss_probability), (None, None));
    Ok(())
}

#[test]
fn a_regime_state_may_have_a_loss_of_its_own_beside_the_directions() -> Result<(), SpecError> {
    let n = network(
        "kind = \"regime\"\nloss_probability = 0.002\n\
         [[states]]\nkind = \"constant\"\ndelay_s = 0.02\nmean_dwell_messages = 50\n\
         [[states]]\nkind = \"constant\"\ndelay_s = 0.3\nmean_dwell_s = 1.5\nloss_probability = 0.08\n",
    )?;
    let Distribution::Regime { states } = &n.to_plant.delay else { panic!("{n:?}") };
    assert_eq!(n.to_plant.loss_probability, 0.002);
    assert_eq!((states[0].loss_probability, states[1].loss_probability), (None, Some(0.08)));
    Ok(())
}

#[test]
fn every_bad_table_names_its_key() {
    assert_eq!(field_of("kind = \"lognormall\""), "kind");
    assert_eq!(field_of("shape = 1.0"), "kind");
    assert_eq!(field_of("kind = \"gamma\"\nshape = 1.0"), "scale_s");
    assert_eq!(field_of("kind = \"gamma\"\nshape = 1.0\nscale_s = 0.1\nmu = 1.0"), "mu");
    assert_eq!(field_of("kind = \"constant\"\ndelay_s = -0.1"), "delay_s");
    assert_eq!(field_of("kind = \"constant\"\ndelay_s = nan"), "delay_s");
    assert_eq!(field_of("kind = \"constant\"\ndelay_s = 3601.0"), "delay_s");
    assert_eq!(field_of("kind = \"uniform\"\nmin_s = 0.2\nmax_s = 0.1"), "max_s");
    assert_eq!(field_of("kind = \"gamma\"\nmean_s = 0.1\nstd_s = 0.0"), "std_s");
    assert_eq!(field_of("kind = \"none\"\nloss_probability = 1.5"), "loss_probability");
    assert_eq!(field_of("kind = \"none\"\nduplicate_probability = -0.1"), "duplicate_probability");
    assert_eq!(field_of("kind = \"trace\"\nfile = \"gone.csv\""), "file");
    assert_eq!(field_of("kind = \"none\"\nmean_dwell_s = 1.0"), "mean_dwell_s");
    assert_eq!(field_of("kind = \"none\"\n[to_plant]\nkind = \"none\""), "kind");
    assert_eq!(
        field_of("[to_plant]\nkind = \"none\"\n[to_plant.to_controller]\nkind = \"none\""),
        "to_plant.to_controller"
    );
    assert_eq!(
        field_of("[to_controller]\nkind = \"pareto\"\nscale_s = 0.0\nshape = 2.0"),
        "to_controller.scale_s"
    );
    assert_eq!(field_of("kind = \"regime\"\nstates = []"), "states");
    let regime = |state: &str| {
        field_of(&format!(
            "kind = \"regime\"\n[[states]]\nkind = \"none\"\nmean_dwell_s = 1.0\n[[states]]\n{state}"
        ))
    };
    assert_eq!(regime("kind = \"constant\"\ndelay_s = 0.1"), "states[1].mean_dwell_s");
    assert_eq!(regime("kind = \"constant\"\ndelay_s = 0.1\nmean_dwell_s = 0.0"), "states[1].mean_dwell_s");
    assert_eq!(
        regime("kind = \"constant\"\ndelay_s = 0.1\nmean_dwell_messages = 0.5"),
        "states[1].mean_dwell_messages"
    );
    assert_eq!(regime("kind = \"constant\"\ndelay_s = -1.0\nmean_dwell_s = 1.0"), "states[1].delay_s");
    assert_eq!(regime("kind = \"trace\"\nfile = \"wifi.csv\"\nmean_dwell_s = 1.0"), "states[1].kind");
    assert_eq!(
        regime("kind = \"none\"\nmean_dwell_s = 1.0\nloss_probability = 1.1"),
        "states[1].loss_probability"
    );
    assert_eq!(
        regime("kind = \"none\"\nmean_dwell_s = 1.0\nduplicate_probability = 0.1"),
        "states[1].duplicate_probability"
    );
    // Unknown keys are serde's, with the key named.
    let e =
        toml::from_str::<DelaysTable>("kind = \"none\"\nshap = 1.0").map(|_| ()).map_err(|e| e.to_string());
    assert!(e.as_ref().is_err_and(|m| m.contains("unknown field `shap`")), "{e:?}");
    let e = toml::from_str::<DelaysTable>("ordering = \"lifo\"").map(|_| ()).map_err(|e| e.to_string());
    assert!(e.is_err(), "{e:?}");
}

#[test]
fn profile_paths_become_table_keys() {
    assert_eq!(file_field("delay.gamma.shape"), "shape");
    assert_eq!(file_field("delay.gamma_moments.std_s"), "std_s");
    assert_eq!(file_field("loss_probability"), "loss_probability");
    assert_eq!(file_field("delay.trace.delays_s[4]"), "file");
    assert_eq!(file_field("delay.regime.states"), "states");
    assert_eq!(file_field("delay.regime.states[2].delay.uniform.max_s"), "states[2].max_s");
    assert_eq!(file_field("delay.regime.states[2].delay"), "states[2].kind");
    assert_eq!(file_field("delay.regime.states[0].mean_dwell_s"), "states[0].mean_dwell_s");
}

#[test]
fn every_network_a_table_describes_comes_back_from_its_own_table() -> Result<(), SpecError> {
    let texts = [
        "kind = \"none\"",
        "kind = \"constant\"\ndelay_s = 0.1\nloss_probability = 0.2",
        "kind = \"uniform\"\nmin_s = 0.1\nmax_s = 0.2\nordering = \"independent\"",
        "kind = \"normal\"\nmean_s = 0.1\nstd_s = 0.02\nduplicate_probability = 0.1",
        "kind = \"gamma\"\nshape = 12.0\nscale_s = 0.015",
        "kind = \"gamma\"\nmean_s = 0.1\nstd_s = 0.02",
        "kind = \"lognormal\"\nmean_s = 0.1\nstd_s = 0.02",
        "kind = \"lognormal\"\nmu = -2.0\nsigma = 0.5",
        "kind = \"pareto\"\nscale_s = 0.05\nshape = 2.5",
        "kind = \"trace\"\nfile = \"wifi.csv\"",
        "kind = \"trace\"\nfile = \"wifi.csv\"\nlooping = true",
        "kind = \"trace\"\ndelays_s = [0.1, 0.3]",
        "kind = \"regime\"\n[[states]]\nkind = \"constant\"\ndelay_s = 0.02\nmean_dwell_messages = 20.0\n[[states]]\nkind = \"uniform\"\nmin_s = 0.1\nmax_s = 0.3\nmean_dwell_s = 1.5",
        "kind = \"regime\"\n[[states]]\nkind = \"constant\"\ndelay_s = 0.02\nmean_dwell_messages = 20.0\nloss_probability = 0.0\n[[states]]\nkind = \"constant\"\ndelay_s = 0.3\nmean_dwell_s = 1.5\nloss_probability = 0.08",
        "[to_plant]\nkind = \"constant\"\ndelay_s = 0.1\n[to_controller]\nkind = \"gamma\"\nshape = 2.0\nscale_s = 0.01",
    ];
    for text in texts {
        let n = network(text)?;
        let back = DelaysTable::from_network(&n);
        let again = back.to_network(7, &mut |f| Err(format!("{f} read twice")))?;
        assert_eq!(again, n, "{text}");
    }
    Ok(())
}

#[test]
fn loading_traces_inlines_their_delays_and_keeps_the_file_as_the_name() -> Result<(), SpecError> {
    let mut t = parse("[to_plant]\nkind = \"trace\"\nfile = \"wifi.csv\"\n[to_controller]\nkind = \"none\"");
    t.load_traces(&mut |f| if f == "wifi.csv" { Ok(vec![0.5, 0.25]) } else { Err(f.to_string()) })?;
    let inline = t.to_plant.as_ref().and_then(|p| p.delays_s.clone());
    assert_eq!(inline, Some(vec![0.5, 0.25]));
    let n = t.to_network(1, &mut |f| Err(format!("{f} read again")))?;
    let Distribution::Trace(trace) = &n.to_plant.delay else { panic!("{n:?}") };
    assert_eq!((&*trace.name, trace.end), ("wifi.csv", crate::TraceEnd::Stop));
    let mut missing = parse("kind = \"trace\"\nfile = \"gone.csv\"");
    let e = missing.load_traces(&mut |f| Err(format!("cannot read {f}")));
    assert_eq!(e.map_err(|e| e.field), Err("file".to_string()));
    Ok(())
}
