//! Falsification against random search on a scenario file's `[falsify]` spaces: each method
//! searches every space with the same budget from `--seeds` seeds (each seed also seeds the
//! families' processes), every run in process on `--jobs` threads, and the table gives the
//! falsification rate (searches that found a failure) and the median runs to the first failure
//! (a search that found none counts as more than the budget). `--dump` writes every run (its
//! point, score and closest approach's time) for a look at the score's landscape.

use std::path::PathBuf;

use anyhow::Context;
use std::time::Instant;

use falsify::in_process::{evaluate, par_map};
use falsify::{Method, SearchResult, SearchSettings, search};
use hilbench_scenario_file::ScenarioFile;
use hilbench_scenario_file::falsify_table;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The scenario file: its `[falsify]` table, `[sweep]` families and first controller.
    #[arg(long, env = "FILE", default_value = "scenarios/sweeps/paper-2-delays-plan-check.toml")]
    file: PathBuf,
    /// Search only these spaces (a family's name, or `signal`; comma-separated).
    #[arg(long, env = "SPACES", value_delimiter = ',')]
    spaces: Vec<String>,
    /// Runs per search (default: the file's).
    #[arg(long, env = "BUDGET")]
    budget: Option<u64>,
    /// Searches per method and space, seeds `first_seed..first_seed + seeds`.
    #[arg(long, env = "SEEDS", default_value_t = 10)]
    seeds: u64,
    #[arg(long, env = "FIRST_SEED", default_value_t = 1)]
    first_seed: u64,
    /// Threads flying a batch's runs.
    #[arg(long, env = "JOBS", default_value_t = 2)]
    jobs: usize,
    /// Methods compared.
    #[arg(long, env = "METHODS", value_delimiter = ',', default_value = "cmaes,random")]
    methods: Vec<String>,
    /// Search on after the first failure (the whole budget).
    #[arg(long, env = "WHOLE_BUDGET", value_parser = clap::builder::BoolishValueParser::new())]
    whole_budget: bool,
    /// CMA-ES's warm-up: random points flown before its first generation (default: the file's
    /// `falsify.warmup`, else the search's default).
    #[arg(long, env = "WARMUP")]
    warmup: Option<usize>,
    /// CMA-ES's first step, a fraction of each range (default: the file's `falsify.sigma0`).
    #[arg(long, env = "SIGMA0")]
    sigma0: Option<f64>,
    /// Write every run (space, method, seed, run, score, closest approach time, point) to this
    /// CSV file.
    #[arg(long, env = "DUMP")]
    dump: Option<PathBuf>,
    /// Print each search's convergence: the best score after each batch.
    #[arg(long, env = "VERBOSE", value_parser = clap::builder::BoolishValueParser::new())]
    verbose: bool,
}

fn method(name: &str) -> anyhow::Result<Method> {
    match name {
        "cmaes" => Ok(Method::Cmaes),
        "random" => Ok(Method::Random),
        other => anyhow::bail!("--methods: `{other}` is cmaes or random"),
    }
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let file = ScenarioFile::load(&args.file)?;
    file.nmpc_tuning(&args.file)?;
    let table =
        file.falsify.clone().ok_or_else(|| anyhow::anyhow!("{}: no [falsify] table", args.file.display()))?;
    // The dump's file is made before the searches, so a bad --dump is refused at once, not
    // after the campaign.
    let dump_file = match &args.dump {
        Some(path) => Some(
            std::fs::File::create(path)
                .with_context(|| format!("--dump: cannot write {}", path.display()))?,
        ),
        None => None,
    };
    let methods: Vec<Method> = args.methods.iter().map(|m| method(m)).collect::<Result<_, _>>()?;
    let mode = crate::mode(file.run.modes[0].name()).map_err(anyhow::Error::msg)?;
    let budget = args.budget.unwrap_or(table.budget_or_default());
    let names: Vec<String> =
        falsify_table::spaces(&table, file.sweep.as_ref(), 0).into_iter().map(|s| s.name).collect();
    if let Some(unknown) = args.spaces.iter().find(|s| !names.contains(s)) {
        anyhow::bail!("--spaces: `{unknown}` is none of the file's spaces ({})", names.join(", "));
    }
    println!(
        "{} ({}), property {}, budget {budget}, {} seeds from {}, {} threads",
        file.scenario.name,
        mode.name(),
        table.property.name(),
        args.seeds,
        args.first_seed,
        args.jobs
    );
    let mut dump: Vec<String> = vec!["space,method,seed,run,score_m,closest_s,point".into()];
    println!("space     method  found  rate   median runs to failure (all / found)  runs  wall [s]  s/run");
    for name in names.iter().filter(|n| args.spaces.is_empty() || args.spaces.contains(n)) {
        for &m in &methods {
            let started = Instant::now();
            let mut results: Vec<SearchResult> = Vec::new();
            for seed in args.first_seed..args.first_seed + args.seeds {
                let space = falsify_table::spaces(&table, file.sweep.as_ref(), seed)
                    .into_iter()
                    .find(|s| &s.name == name)
                    .ok_or_else(|| anyhow::anyhow!("space {name}"))?;
                let settings = SearchSettings {
                    stop_at_failure: !args.whole_budget,
                    population: table.population.map(|p| p as usize),
                    sigma0: args.sigma0.or(table.sigma0).unwrap_or(falsify::table::DEFAULT_SIGMA0),
                    ..SearchSettings::new(m, budget, seed)
                };
                let warmup = args.warmup.or(table.warmup.map(|w| w as usize)).unwrap_or(settings.warmup);
                let settings = SearchSettings { warmup, ..settings };
                let one = Instant::now();
                let mut flown = 0u64;
                let r = search(
                    &space.dims,
                    &settings,
                    |batch| {
                        let told = par_map(batch, args.jobs, |p| {
                            match evaluate(&space, &file.scenario, mode, table.property, p) {
                                Ok(e) => (e.score, e.closest_s),
                                Err(e) => {
                                    eprintln!("  {name} {} seed {seed}: {e}", m.name());
                                    (f64::NAN, None)
                                }
                            }
                        });
                        for (p, (score, closest_s)) in batch.iter().zip(&told) {
                            flown += 1;
                            let point: Vec<String> = p.iter().map(|v| format!("{v:.5}")).collect();
                            dump.push(format!(
                                "{name},{},{seed},{flown},{score},{},{}",
                                m.name(),
                                closest_s.map_or(String::new(), |c| format!("{c:.3}")),
                                point.join(";")
                            ));
                        }
                        told.into_iter().map(|(score, _)| score).collect()
                    },
                    |g| {
                        if args.verbose {
                            println!(
                                "    gen {:3} runs {:4} batch best {:+.4} best {:+.4} step {} pop {} restarts {}",
                                g.index,
                                g.runs,
                                g.batch_best,
                                g.best,
                                g.step.map_or("-".into(), |s| format!("{s:.3}")),
                                g.population,
                                g.restarts
                            );
                        }
                    },
                );
                let best = r.best.as_ref().expect("a run was flown");
                println!(
                    "  {name} {} seed {seed}: {} runs, first failure {}, best {:+.4} at [{}], {} restarts, {:.1} s",
                    m.name(),
                    r.runs,
                    r.runs_to_failure().map_or("none".into(), |n| format!("at run {n}")),
                    best.score,
                    best.point.iter().map(|v| format!("{v:.4}")).collect::<Vec<_>>().join(", "),
                    r.restarts,
                    one.elapsed().as_secs_f64()
                );
                results.push(r);
            }
            let wall = started.elapsed().as_secs_f64();
            let runs: u64 = results.iter().map(|r| r.runs).sum();
            let found: Vec<u64> = results.iter().filter_map(SearchResult::runs_to_failure).collect();
            // Misses rank above any budget.
            let all: Vec<u64> = results.iter().map(|r| r.runs_to_failure().unwrap_or(u64::MAX)).collect();
            let show = |v: Option<f64>| match v {
                Some(x) if x >= budget as f64 + 1.0 => format!(">{budget}"),
                Some(x) => format!("{x:.1}"),
                None => "-".into(),
            };
            println!(
                "{name:<9} {:<7} {:>2}/{:<2}  {:>4.0} %  {:>17} / {:<17}  {runs:>5}  {wall:>8.1}  {:.3}",
                m.name(),
                found.len(),
                results.len(),
                100.0 * found.len() as f64 / results.len().max(1) as f64,
                show(median(&all)),
                show(median(&found)),
                wall / runs.max(1) as f64,
            );
        }
    }
    if let (Some(mut f), Some(path)) = (dump_file, &args.dump) {
        use std::io::Write;
        f.write_all((dump.join("\n") + "\n").as_bytes())
            .with_context(|| format!("--dump: cannot write {}", path.display()))?;
    }
    Ok(())
}

/// The median (the mean of the middle two for an even count); `u64::MAX` counts as infinite.
fn median(v: &[u64]) -> Option<f64> {
    let mut v: Vec<f64> = v.iter().map(|&x| if x == u64::MAX { f64::INFINITY } else { x as f64 }).collect();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(v[n / 2]),
        _ => Some((v[n / 2 - 1] + v[n / 2]) / 2.0),
    }
}
