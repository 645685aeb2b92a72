use super::*;

fn field_of(p: DirectionProfile) -> String {
    p.validate().map_err(|e| e.field).err().unwrap_or_default()
}

#[test]
fn bad_parameters_name_their_field() {
    let with = |delay| DirectionProfile::with_delay(delay, 1);
    assert_eq!(field_of(with(Distribution::Constant { delay_s: -1.0 })), "delay.constant.delay_s");
    assert_eq!(field_of(with(Distribution::Gamma { shape: 0.0, scale_s: 1.0 })), "delay.gamma.shape");
    assert_eq!(field_of(with(Distribution::Gamma { shape: 2.0, scale_s: f64::NAN })), "delay.gamma.scale_s");
    assert_eq!(field_of(with(Distribution::Uniform { min_s: 0.2, max_s: 0.1 })), "delay.uniform.max_s");
    assert_eq!(
        field_of(with(Distribution::Normal { mean_s: 0.1, std_s: f64::INFINITY })),
        "delay.normal.std_s"
    );
    assert_eq!(
        field_of(with(Distribution::GammaMoments { mean_s: 0.0, std_s: 0.1 })),
        "delay.gamma_moments.mean_s"
    );
    assert_eq!(field_of(with(Distribution::Lognormal { mu: -3.0, sigma: -0.1 })), "delay.lognormal.sigma");
    assert_eq!(field_of(with(Distribution::Pareto { scale_s: 0.01, shape: 0.0 })), "delay.pareto.shape");
    assert_eq!(field_of(with(Distribution::Trace(Trace::holding(vec![])))), "delay.trace.delays_s");
    assert_eq!(
        field_of(with(Distribution::Trace(Trace::looping(vec![0.1, -0.1])))),
        "delay.trace.delays_s[1]"
    );
    assert_eq!(
        field_of(with(Distribution::LognormalMoments { mean_s: 0.0, std_s: 0.1 })),
        "delay.lognormal_moments.mean_s"
    );
    let state = RegimeState::new;
    let regime = |states: Vec<RegimeState>| with(Distribution::Regime { states: states.into() });
    let fast = Distribution::Constant { delay_s: 0.01 };
    assert_eq!(field_of(regime(vec![])), "delay.regime.states");
    assert_eq!(
        field_of(regime(vec![
            state(fast.clone(), Dwell::Messages(5.0)),
            state(Distribution::Gamma { shape: -1.0, scale_s: 0.1 }, Dwell::Seconds(1.0)),
        ])),
        "delay.regime.states[1].delay.gamma.shape"
    );
    assert_eq!(
        field_of(regime(vec![state(fast.clone(), Dwell::Messages(0.5))])),
        "delay.regime.states[0].mean_dwell_messages"
    );
    assert_eq!(
        field_of(regime(vec![state(fast.clone(), Dwell::Seconds(0.0))])),
        "delay.regime.states[0].mean_dwell_s"
    );
    assert_eq!(
        field_of(regime(vec![state(Distribution::Trace(Trace::looping(vec![0.1])), Dwell::Seconds(1.0))])),
        "delay.regime.states[0].delay"
    );
    assert_eq!(field_of(regime(vec![state(fast, Dwell::Messages(1.0))])), "");
    let mut p = DirectionProfile { loss_probability: 1.5, ..DirectionProfile::default() };
    assert_eq!(field_of(p.clone()), "loss_probability");
    p.loss_probability = 0.5;
    p.duplicate_probability = f64::NAN;
    assert_eq!(field_of(p), "duplicate_probability");
    assert!(DirectionProfile::default().validate().is_ok());
}

#[test]
fn paper_preset_is_the_spec_round_trip_on_commands() -> Result<(), ProfileError> {
    let p = preset("paper", 42)?;
    assert_eq!(p.to_plant.delay, Distribution::Gamma { shape: 12.0, scale_s: 0.015 });
    assert_eq!(p.to_controller.delay, Distribution::Constant { delay_s: 0.0 });
    assert_eq!(p.to_plant.seed, 42);
    assert!(p.has_delays());
    assert!(!preset("none", 1)?.has_delays());
    let split = preset("paper-split", 7)?;
    assert_eq!(
        split.get(Direction::PlantToController).delay,
        Distribution::Gamma { shape: 6.0, scale_s: 0.015 }
    );
    assert_eq!(preset("nope", 1).map_err(|e| e.field), Err("preset".to_string()));
    for (name, _) in PRESETS {
        let p = preset(name, 3)?;
        p.validate()?;
    }
    Ok(())
}
