//! Run `i`'s delays, drawn from `(seed, i)` alone: its family (by weight), its parameters
//! (uniform in each range) and the seed of its delay process come from a ChaCha8 generator on
//! stream `i` of `seed`, so run `i` is the same whether it flies in a sweep of 10 or 10,000
//! runs, in any shard, or alone (`hilbench run FILE --sweep-run i`).
//!
//! The process is then drawn into a trace of as many delays as the run can have cycles (the
//! scenario's `max_duration_s` over `min_cycle_s`), from the same `delay::DelayLine` netem and
//! the in-process loop use, at the send times the closed loop will have (`t_{k+1} = t_k +
//! max(min_cycle_s, d_k)`, so a regime's dwell in seconds runs on the run's own clock), and
//! clipped at `max_delay_s`. A trace is what every transport replays to the bit, what a
//! failure is written as, and what `--shrink` shrinks.

use delay::{DelayLine, DelaysTable, Direction};
use hilbench_scenario_file::sweep_table::{self, Family, FamilyChoice, SweepSection};
use mav::Scenario;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// One run of a sweep: where its delays came from, and the delays.
#[derive(Debug, Clone, PartialEq)]
pub struct RunPlan {
    pub index: u64,
    pub family: String,
    /// The drawn values of the family's ranges, by key (`shape`, `states[1].delay_s`; a
    /// `traces` family's file index as `trace`).
    pub params: Vec<(String, f64)>,
    /// The seed of the delay process.
    pub delay_seed: u64,
    /// The file a `traces` family chose.
    pub trace_file: Option<String>,
    /// The round-trip delay of each cycle, s.
    pub delays_s: Vec<f64>,
}

impl RunPlan {
    /// `key=value;...` for runs.csv and the report, each value to 6 significant digits as
    /// `delay::Number` shows it (`trace=4`, `shape=1.53457`, not `trace=4.000000`).
    pub fn params_text(&self) -> String {
        let short = |v: f64| delay::Number(format!("{v:.5e}").parse().unwrap_or(v));
        let mut parts: Vec<String> = self.params.iter().map(|(k, v)| format!("{k}={}", short(*v))).collect();
        if let Some(f) = &self.trace_file {
            parts.push(format!("file={f}"));
        }
        parts.join(";")
    }

    /// `scenario` with this run's delays as its round trip (a trace, not looping).
    pub fn scenario(&self, scenario: &Scenario) -> Scenario {
        let mut s = scenario.clone();
        s.delays =
            Some(DelaysTable::trace(&format!("sweep-run-{}", self.index), self.delays_s.clone(), false));
        s
    }
}

/// The most cycles a run of `scenario` can have, plus 2 (`sweep_table::run_cycles`), capped at
/// `sweep_table::MAX_RUN_CYCLES`: a scenario file with a `[sweep]` table is refused beyond it,
/// and a scenario that did not come through the loader is not drawn past it.
pub fn max_cycles(scenario: &Scenario) -> usize {
    let cycles = sweep_table::run_cycles(scenario).min(sweep_table::MAX_RUN_CYCLES);
    usize::try_from(cycles).unwrap_or(usize::MAX)
}

/// Run `index` of a sweep of `scenario` with `seed`.
pub fn plan(sweep: &SweepSection, scenario: &Scenario, seed: u64, index: u64) -> Result<RunPlan, String> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(index);
    let total = sweep.total_weight();
    // Drawn in either case, so that the rest of run i's draws do not depend on the choice.
    let mut u = rng.random::<f64>() * total;
    let family = match sweep.family_choice {
        FamilyChoice::Weighted => sweep
            .families
            .iter()
            .find(|f| {
                if f.weight > 0.0 && u < f.weight {
                    return true;
                }
                u -= f.weight;
                false
            })
            .or_else(|| sweep.families.iter().rev().find(|f| f.weight > 0.0)),
        FamilyChoice::InTurn => {
            let positive: Vec<&Family> = sweep.families.iter().filter(|f| f.weight > 0.0).collect();
            usize::try_from(index % positive.len().max(1) as u64).ok().and_then(|k| positive.get(k).copied())
        }
    }
    .ok_or("no family has a positive weight")?;
    // A `traces` family's file: drawn before the parameters (the two closures below cannot
    // share the generator).
    let trace_u = rng.random::<f64>();
    let mut trace_index = None;
    let (table, params) = family.table(
        &mut |_, lo, hi| if hi > lo { lo + (hi - lo) * rng.random::<f64>() } else { lo },
        &mut |n| {
            let i = ((trace_u * n as f64) as usize).min(n.saturating_sub(1));
            trace_index = Some(i);
            i
        },
    );
    let delay_seed = rng.random::<u64>();
    let clip = sweep.max_delay_s.unwrap_or(delay::MAX_DELAY_S);
    let cycles = max_cycles(scenario);
    let delays_s: Vec<f64> = if family.kind == "traces" {
        let delays = table.delays_s.clone().unwrap_or_default();
        let looping = family.looping.unwrap_or(false);
        let n = if looping { cycles } else { delays.len() };
        delays.iter().cycle().take(n).map(|d| d.min(clip)).collect()
    } else {
        let network = table
            .to_network(delay_seed, &mut |f| Err(format!("{f}: a family names no file")))
            .map_err(|e| format!("family {}: {e}", family.name()))?;
        let mut line = DelayLine::new(Direction::ControllerToPlant, network.to_plant)
            .map_err(|e| format!("family {}: {e}", family.name()))?;
        let cycle_ns = delay::s_to_ns(scenario.min_cycle_s).unwrap_or(0);
        let mut t_ns = 0u64;
        (0..cycles)
            .map(|_| {
                let d = line.sample_delay_at(t_ns);
                let d = if d.is_nan() { 0.0 } else { d.clamp(0.0, clip) };
                t_ns = t_ns.saturating_add(cycle_ns.max(delay::delay_ns(d)));
                d
            })
            .collect()
    };
    let trace_file = trace_index.and_then(|i| family.traces.get(i)).map(|(name, _)| name.clone());
    Ok(RunPlan { index, family: family.name().to_string(), params, delay_seed, trace_file, delays_s })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sweep(text: &str) -> SweepSection {
        let s: SweepSection = toml::from_str(text).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(s.validate(), Ok(()));
        s
    }

    #[test]
    fn run_i_depends_on_the_seed_and_i_alone_and_families_follow_their_weights() {
        let s = sweep(
            "max_delay_s = 0.33\n[[families]]\nkind = \"gamma\"\nshape = [1.0, 30.0]\nscale_s = [0.002, 0.04]\n\
             [[families]]\nweight = 3\nkind = \"uniform\"\nmin_s = 0.0\nmax_s = 0.33\n",
        );
        let scenario = Scenario::paper_2();
        let a = plan(&s, &scenario, 7, 12).expect("a plan");
        assert_eq!(a, plan(&s, &scenario, 7, 12).expect("again"));
        assert_ne!(a.delays_s, plan(&s, &scenario, 8, 12).expect("another seed").delays_s);
        assert_ne!(a.delays_s, plan(&s, &scenario, 7, 13).expect("another run").delays_s);
        assert_eq!(a.delays_s.len(), max_cycles(&scenario));
        let plans: Vec<RunPlan> = (0..400).map(|i| plan(&s, &scenario, 7, i).expect("a plan")).collect();
        let uniform = plans.iter().filter(|p| p.family == "uniform").count();
        assert!((260..340).contains(&uniform), "{uniform} of 400 uniform runs, 300 expected");
        for p in &plans {
            assert!(p.delays_s.iter().all(|d| (0.0..=0.33).contains(d)), "run {}", p.index);
            if p.family == "gamma" {
                let (shape, scale) = (p.params[0].1, p.params[1].1);
                assert!((1.0..=30.0).contains(&shape) && (0.002..=0.04).contains(&scale), "{:?}", p.params);
            }
        }
        // Clipped at max_delay_s: the heaviest Gamma draws hit the clip.
        assert!(plans.iter().any(|p| p.delays_s.contains(&0.33)));
    }

    #[test]
    fn drawn_parameters_print_short_an_index_as_an_integer() {
        let plan = RunPlan {
            index: 0,
            family: "spiky".into(),
            params: vec![
                ("trace".into(), 4.0),
                ("shape".into(), 1.534_567_891),
                ("scale_s".into(), 0.012_345_678_9),
                ("states[1].delay_s".into(), 0.5),
            ],
            delay_seed: 1,
            trace_file: Some("a.csv".into()),
            delays_s: Vec::new(),
        };
        assert_eq!(
            plan.params_text(),
            "trace=4;shape=1.53457;scale_s=0.0123457;states[1].delay_s=0.5;file=a.csv"
        );
    }

    #[test]
    fn families_in_turn_give_run_i_the_family_i_mod_f_and_the_same_draws_otherwise() {
        let text = "[[families]]\nkind = \"gamma\"\nshape = [1.0, 30.0]\nscale_s = [0.002, 0.04]\n\
             [[families]]\nweight = 0\nkind = \"constant\"\ndelay_s = 0.1\n\
             [[families]]\nweight = 3\nkind = \"uniform\"\nmin_s = 0.0\nmax_s = 0.33\n";
        let weighted = sweep(text);
        let in_turn = sweep(&format!("family_choice = \"in_turn\"\n{text}"));
        let scenario = Scenario::paper_2();
        for i in 0..40 {
            let p = plan(&in_turn, &scenario, 7, i).expect("a plan");
            // The zero-weight family never flies.
            assert_eq!(p.family, if i % 2 == 0 { "gamma" } else { "uniform" }, "run {i}");
            let w = plan(&weighted, &scenario, 7, i).expect("a plan");
            if w.family == p.family {
                assert_eq!(w, p, "run {i}: only the choice of family differs");
            }
        }
    }
}
