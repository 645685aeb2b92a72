//! Run `i`'s delays, drawn from `(seed, i)` alone: its family (by weight), its parameters
//! (uniform in each range) and the seed of its delay process come from a ChaCha8 generator on
//! stream `i` of `seed`, so run `i` is the same whether it flies in a sweep of 10 or 10,000
//! runs, in any shard, or alone (`hilbench run FILE --sweep-run i`).
//!
//! The process is then drawn into a trace of as many delays as the run can have cycles (the
//! scenario's `max_duration_s` over `min_cycle_s`), from the same `delay::DelayLine` netem and
//! the in-process loop use, at the send times the closed loop will have (`t_{k+1} = t_k +
//! max(min_cycle_s, d_k)`, so a regime's dwell in seconds runs on the run's own clock), and
//! clipped at `max_delay_s`; the family's `loss` is the line's loss probability, and a message
//! it loses is a `lost` entry ([`delay::LOST_S`]), which every transport drops. A trace is what
//! every transport replays to the bit, what a failure is written as, and what `--shrink`
//! shrinks.

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
    // A `traces` family's file replays as it is (as often as the run can need when it loops);
    // the other kinds are drawn at the closed loop's send times. Through the table's delay
    // line both ways, so that the family's `loss` (the line's loss probability) applies to
    // either; a message the line loses (or the file records as lost) is a `lost` entry.
    let entries = if family.kind == "traces" && !family.looping.unwrap_or(false) {
        table.delays_s.as_ref().map_or(0, Vec::len)
    } else {
        cycles
    };
    let network = table
        .to_network(delay_seed, &mut |f| Err(format!("{f}: a family names no file")))
        .map_err(|e| format!("family {}: {e}", family.name()))?;
    let mut line = DelayLine::new(Direction::ControllerToPlant, network.to_plant)
        .map_err(|e| format!("family {}: {e}", family.name()))?;
    let cycle_ns = delay::s_to_ns(scenario.min_cycle_s).unwrap_or(0);
    let mut t_ns = 0u64;
    let delays_s: Vec<f64> = (0..entries)
        .map(|_| {
            let draw = line.draw(t_ns);
            let d = if draw.lost && !draw.trace_ended {
                delay::LOST_S
            } else if draw.sampled_delay_s.is_nan() {
                0.0
            } else {
                draw.sampled_delay_s.clamp(0.0, clip)
            };
            t_ns = t_ns.saturating_add(cycle_ns.max(delay::delay_ns(d)));
            d
        })
        .collect();
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
    fn a_familys_loss_loses_its_share_of_the_runs_commands_and_moves_no_delay() {
        let lossless = "[[families]]\nkind = \"gamma\"\nshape = 4.0\nscale_s = 0.01\n";
        let lossy = sweep(&format!("{lossless}loss = [0.1, 0.3]\n"));
        let fixed = sweep(&format!("{lossless}loss = 0.2\n"));
        let lossless = sweep(lossless);
        let scenario = Scenario::paper_2();
        for i in 0..5 {
            let a = plan(&lossy, &scenario, 7, i).expect("a plan");
            let (key, loss) = a.params.last().cloned().expect("the loss drawn");
            assert!(key == "loss" && (0.1..=0.3).contains(&loss), "{:?}", a.params);
            assert!(a.params_text().contains("loss="), "{}", a.params_text());
            let n = a.delays_s.len() as f64;
            let lost = a.delays_s.iter().filter(|d| delay::is_lost(**d)).count() as f64;
            // Within 5 standard deviations of the binomial.
            let sd = (n * loss * (1.0 - loss)).sqrt();
            assert!((lost - n * loss).abs() < 5.0 * sd, "run {i}: {lost} of {n} lost, p = {loss}");
            // A fixed loss draws nothing from the run's generator: the commands that get through
            // keep the delays of the run without loss (the loss has its own stream), whatever
            // the send times a loss moves (a Gamma's draws do not depend on them).
            let (f, b) = (
                plan(&fixed, &scenario, 7, i).expect("a plan"),
                plan(&lossless, &scenario, 7, i).expect("a plan"),
            );
            assert_eq!((f.delay_seed, f.delays_s.len()), (b.delay_seed, b.delays_s.len()));
            assert!(f.params.is_empty(), "{:?}", f.params);
            for (x, y) in f.delays_s.iter().zip(&b.delays_s) {
                assert!(delay::is_lost(*x) || x == y, "run {i}: {x} vs {y}");
            }
            assert!(
                f.delays_s.iter().any(|d| delay::is_lost(*d))
                    && !b.delays_s.iter().any(|d| delay::is_lost(*d))
            );
        }
        // A traces family: the file's own losses stay, the family's loss adds its share.
        let mut traces = sweep("[[families]]\nkind = \"traces\"\ndir = \"t\"\nloss = 0.5\n");
        let file: Vec<f64> = (0..2000).map(|k| if k % 10 == 0 { delay::LOST_S } else { 0.05 }).collect();
        traces.families[0].traces = vec![("a.csv".into(), file.clone())];
        let p = plan(&traces, &scenario, 7, 0).expect("a plan");
        assert_eq!(p.delays_s.len(), file.len());
        for (x, y) in p.delays_s.iter().zip(&file) {
            assert!(delay::is_lost(*x) || x == y);
            assert!(!delay::is_lost(*y) || delay::is_lost(*x), "a recorded loss stays");
        }
        let lost = p.delays_s.iter().filter(|d| delay::is_lost(**d)).count();
        assert!((1000..1200).contains(&lost), "{lost} of 2000 lost: 200 recorded, half of the rest drawn");
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
