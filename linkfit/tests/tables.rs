//! The tables a fit writes load where the bench reads them: the scenario file loader
//! (`hilbench_scenario_file`, which checks `[scenario.delays]` through
//! `delay::DelaysTable::to_network`) and its `[sweep]` table (`sweep_table`, every corner of
//! the ranges checked the same way).

use std::path::Path;

use delay::{DelayLine, Direction, DirectionProfile, Distribution, Dwell, RegimeState};
use hilbench_scenario_file::ScenarioFile;
use hilbench_scenario_file::sweep_table::Param;
use linkfit::{FitOptions, Format, ImportOptions, Kind, fit, import};

/// paper-2's scenario file, renamed, with its `[scenario.delays]` replaced by `tables`.
fn scenario_with(tables: &str) -> Result<ScenarioFile, String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let text = std::fs::read_to_string(root.join("scenarios/paper-2.toml")).map_err(|e| e.to_string())?;
    let cut = text.find("[scenario.delays]").ok_or("paper-2 has a [scenario.delays] table")?;
    let head = text[..cut].replace("name = \"paper-2\"", "name = \"paper-2-fitted-link\"");
    let file = format!("{head}{tables}");
    ScenarioFile::parse(&root.join("scenarios/fitted.toml"), &file).map_err(|e| format!("{e}\n{file}"))
}

fn both(report: &linkfit::FitReport) -> String {
    format!("{}\n{}", report.scenario_toml().expect("scenario"), report.sweep_toml().expect("sweep"))
}

fn draws(d: Distribution, n: usize) -> Vec<f64> {
    let mut line = DelayLine::new(Direction::ControllerToPlant, DirectionProfile::with_delay(d, 5))
        .expect("a valid profile");
    (0..n).map(|k| line.sample_delay_at(k as u64 * 50_000_000)).collect()
}

#[test]
fn each_replayable_kind_loads_as_a_scenario_and_a_sweep_family() {
    let regime = Distribution::Regime {
        states: vec![
            RegimeState::new(Distribution::Lognormal { mu: -3.5, sigma: 0.2 }, Dwell::Messages(80.0)),
            RegimeState::new(Distribution::Uniform { min_s: 0.08, max_s: 0.3 }, Dwell::Messages(20.0)),
        ]
        .into(),
    };
    for (truth, kind) in [
        (Distribution::Gamma { shape: 8.0, scale_s: 0.02 }, Kind::Gamma),
        (Distribution::Lognormal { mu: -3.0, sigma: 0.4 }, Kind::Lognormal),
        (Distribution::Pareto { scale_s: 0.02, shape: 2.5 }, Kind::Pareto),
        (regime, Kind::Regime),
    ] {
        let x = draws(truth, 5000);
        let options = FitOptions { kinds: vec![kind], ..FitOptions::default() };
        let report = fit(&x, &options).expect("a fit");
        let tables = both(&report);
        let file = scenario_with(&tables).unwrap_or_else(|e| panic!("{kind:?}: {e}"));
        let delays = file.scenario.delays.as_ref().expect("delays");
        assert_eq!(delays.kind.as_deref(), Some(kind.name()), "{tables}");
        let sweep = file.sweep.as_ref().expect("a sweep");
        assert_eq!(sweep.families[0].kind, kind.name());
        assert_eq!(sweep.families[0].name(), format!("fit-{}", kind.name()));
        assert_eq!(sweep.families[0].loss, None, "nothing lost, no loss key");
    }
}

#[test]
fn a_recorded_irtt_trace_imports_fits_and_loads_with_its_losses_and_dwell_in_seconds() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/irtt-loopback.json");
    let text = std::fs::read_to_string(&path).expect("the fixture");
    let trace = import(&text, &ImportOptions::new(Format::Irtt)).expect("imported").trace;
    let options = FitOptions { rate_hz: trace.provenance.rate_hz, ..FitOptions::default() };
    let report = fit(&trace.delays_s, &options).expect("a fit");
    let file = scenario_with(&both(&report)).unwrap_or_else(|e| panic!("{e}"));
    let delays = file.scenario.delays.expect("delays");
    // Five losses do not tell two states' shares apart: the trace's one share.
    assert_eq!(delays.loss_probability, Some(5.0 / 199.0));
    // The sweep family's loss: the loss share's Clopper–Pearson 95 % interval.
    let family = &file.sweep.as_ref().expect("a sweep").families[0];
    let want = linkfit::clopper_pearson(5, 199, 0.95).expect("an interval");
    assert_eq!(family.loss, Some(Param::Range(want.lower, want.upper)));
    assert!(want.lower < 5.0 / 199.0 && 5.0 / 199.0 < want.upper && want.upper < 0.07, "{want:?}");
    if let Some(states) = delays.states {
        assert!(states.iter().all(|s| s.mean_dwell_s.is_some() && s.mean_dwell_messages.is_none()));
    }
}

#[test]
fn a_widened_family_holds_a_factor_either_side_of_each_estimate_and_still_loads() {
    let x = draws(Distribution::Lognormal { mu: -3.9, sigma: 0.3 }, 6000);
    let options = FitOptions { kinds: vec![Kind::Lognormal], ..FitOptions::default() };
    let report = fit(&x, &options).expect("a fit");
    let estimate = |name: &str| {
        report.candidates[0].params.iter().find(|p| p.name == name).map(|p| p.value).expect("a parameter")
    };
    let (mu, sigma) = (estimate("mu"), estimate("sigma"));
    let range = |file: &ScenarioFile, name: &str| {
        let family = &file.sweep.as_ref().expect("a sweep").families[0];
        match if name == "mu" { &family.mu } else { &family.sigma } {
            Some(Param::Range(lo, hi)) => (*lo, *hi),
            other => panic!("{name}: {other:?}"),
        }
    };
    let tight = scenario_with(&both(&report)).unwrap_or_else(|e| panic!("{e}"));
    let (lo, hi) = range(&tight, "mu");
    assert!(hi - lo < 0.05, "6,000 probes pin the location: [{lo}, {hi}]");
    let sweep = report.sweep_toml_widened(2.0).expect("widened");
    assert!(sweep.contains("widened to a factor of 2"), "{sweep}");
    let file = scenario_with(&format!("{}\n{sweep}", report.scenario_toml().expect("scenario")))
        .unwrap_or_else(|e| panic!("{e}"));
    let (lo, hi) = range(&file, "mu");
    assert!(lo <= mu - 2f64.ln() && hi >= mu + 2f64.ln(), "the level within a factor 2: [{lo}, {hi}]");
    let (lo, hi) = range(&file, "sigma");
    assert!(lo <= sigma / 2.0 && hi >= sigma * 2.0, "[{lo}, {hi}] around {sigma}");
    for bad in [0.5, f64::NAN, 1e3] {
        assert!(report.sweep_toml_widened(bad).is_err(), "{bad}");
    }
}

#[test]
fn a_regime_losing_in_its_spikes_loads_with_a_loss_per_state_as_a_scenario_and_a_sweep_family() {
    let state =
        |delay, dwell, loss| RegimeState { loss_probability: Some(loss), ..RegimeState::new(delay, dwell) };
    let truth = Distribution::Regime {
        states: vec![
            state(Distribution::Lognormal { mu: -3.5, sigma: 0.2 }, Dwell::Messages(80.0), 0.002),
            state(Distribution::Lognormal { mu: -1.9, sigma: 0.3 }, Dwell::Messages(20.0), 0.1),
        ]
        .into(),
    };
    let mut line = DelayLine::new(Direction::ControllerToPlant, DirectionProfile::with_delay(truth, 5))
        .expect("a valid profile");
    let x: Vec<f64> = (0..30_000)
        .map(|k| {
            let d = line.send(k as u64 * 50_000_000);
            if matches!(d.fate, delay::Fate::Dropped) { delay::LOST_S } else { d.sampled_delay_s }
        })
        .collect();
    let report = fit(&x, &FitOptions::default()).expect("a fit");
    let file = scenario_with(&both(&report)).unwrap_or_else(|e| panic!("{e}"));
    let delays = file.scenario.delays.as_ref().expect("delays");
    assert_eq!(delays.loss_probability, None, "the states carry the losses");
    let network = delays.to_network(1, &mut |f| Err(format!("{f}: no file"))).expect("a network");
    let Distribution::Regime { states } = &network.to_plant.delay else { panic!("{network:?}") };
    let shares: Vec<f64> = states.iter().filter_map(|s| s.loss_probability).collect();
    assert!(shares.len() == 2 && shares[0] < 0.01 && (0.07..0.13).contains(&shares[1]), "{shares:?}");
    let family = &file.sweep.as_ref().expect("a sweep").families[0];
    assert_eq!(family.loss, None, "the states carry the losses");
    for s in family.states.as_ref().expect("states") {
        assert!(matches!(s.loss, Some(Param::Range(lo, hi)) if lo < hi && hi < 1.0), "{s:?}");
    }
}
