//! The QP fallback on the problems of the paper closed loops (multi-stage, M = 5, N = 40):
//! for every cycle of paper-1/2/3, the QP the safety layer would solve there (the cycle's state,
//! the previous command, the cycle's weights, the previous plan shifted as nominal), timed as
//! build + clarabel solve. Prints the distribution per scenario. Each problem is also solved
//! with elastic rows (`QpSettings::elastic_penalty_per_m`) for comparison (not timed).
use mpc::{ControllerMode, MpcSettings, OcpDefinition, QpBudget, QpFallback, QpSettings, QpStatus, accuracy};
use std::time::Instant;

use crate::settings::QpFlags;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Repetitions per problem (the fastest counts).
    #[arg(default_value_t = 3, value_parser = clap::value_parser!(u64).range(1..))]
    repetitions: u64,
    /// List the problems where both were solved with elastic rows present.
    #[arg(long, env = "QP_SHOW", value_parser = clap::builder::BoolishValueParser::new())]
    show: bool,
    /// List the problems over 3 ms.
    #[arg(long, env = "QP_SLOW", value_parser = clap::builder::BoolishValueParser::new())]
    slow: bool,
    #[command(flatten)]
    qp: QpFlags,
}

#[derive(Default)]
struct Tally {
    solved: usize,
    clear: usize,
    elastic_status: usize,
}

impl Tally {
    fn add(&mut self, r: &mpc::QpReport) {
        self.solved += usize::from(r.status.has_solution());
        self.clear += usize::from(r.status.has_solution() && r.min_clearance_m >= 0.0);
        self.elastic_status += usize::from(r.status == QpStatus::SolvedElastic);
    }
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let (reps, show) = (args.repetitions, args.show);
    let mut all = Vec::new();
    let base = args.qp.settings();
    let mpc_settings = MpcSettings::default();
    for scenario in [mav::Scenario::paper_1(), mav::Scenario::paper_2(), mav::Scenario::paper_3()] {
        let loop_solves = accuracy::loop_solves(&scenario, ControllerMode::Multistage, &mpc_settings)?;
        let def = OcpDefinition::from_scenario(
            &scenario,
            ControllerMode::Multistage,
            mpc_settings.obstacle_margin_m,
            mpc_settings.formulation,
        );
        let mut qp = QpFallback::new(&def, base)?;
        let elastic = QpSettings { elastic_penalty_per_m: Some(1e5), ..base };
        let mut qp_elastic = QpFallback::new(&def, elastic)?;
        let mut times = Vec::new();
        let (mut iterations, mut solves, mut rows) = (0u64, 0u64, 0u64);
        let (mut hard, mut soft, mut same_worst) = (Tally::default(), Tally::default(), 0.0f64);
        for (cycle, ls) in loop_solves.iter().enumerate().skip(1) {
            let (x0, u_prev, w) = (&ls.instance.x0, &ls.instance.u_prev, &ls.instance.weights);
            let nominal = &ls.instance.warm_start;
            let mut best = f64::INFINITY;
            let mut last = None;
            for _ in 0..reps {
                let t = Instant::now();
                let r = qp.solve(x0, u_prev, w, Some(nominal), &QpBudget::default())?;
                best = best.min(t.elapsed().as_secs_f64() * 1e3);
                last = Some(r);
            }
            times.push(best);
            // Deterministic: every repetition reports the same (`reps` is at least 1).
            let Some(r) = last else { unreachable!("at least one repetition") };
            if args.slow && best > 3.0 {
                println!(
                    "    slow: cycle {} {best:.2} ms, {:?}, iterations {}, clarabel solves {}, rows {}, half-planes {}",
                    cycle, r.status, r.iterations, r.clarabel_solves, r.num_clarabel_rows, r.num_half_planes
                );
            }
            iterations += u64::from(r.iterations);
            solves += r.clarabel_solves as u64;
            rows += r.num_clarabel_rows as u64;
            hard.add(&r);
            let re = qp_elastic.solve(x0, u_prev, w, Some(nominal), &QpBudget::default())?;
            soft.add(&re);
            if r.status == QpStatus::Solved && re.status == QpStatus::Solved && re.num_elastic_rows > 0 {
                let (a, b) = (qp.solution().expect("solved"), qp_elastic.solution().expect("solved"));
                let d = a.iter().zip(b).fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
                same_worst = same_worst.max(d);
                if show {
                    println!(
                        "    cycle {} state {:?} u_prev {:?} elastic rows {} input difference {d:.2e}",
                        cycle, x0, u_prev, re.num_elastic_rows
                    );
                }
            }
        }
        let n = times.len();
        print_distribution(&scenario.name, &mut times.clone());
        println!(
            "    {n} problems, solved {} (true clearance >= 0: {}), mean clarabel iterations {:.1}, solves {:.2}, rows {:.0}",
            hard.solved,
            hard.clear,
            iterations as f64 / n as f64,
            solves as f64 / n as f64,
            rows as f64 / n as f64
        );
        println!(
            "    elastic rows: solved {} (true clearance >= 0: {}), of which solved_elastic {}; where both solved and rows were elastic, largest input difference {same_worst:.2e}",
            soft.solved, soft.clear, soft.elastic_status
        );
        all.extend(times);
    }
    print_distribution("all", &mut all);
    Ok(())
}

fn print_distribution(name: &str, t: &mut [f64]) {
    t.sort_by(f64::total_cmp);
    let q = |p: f64| t[((t.len() - 1) as f64 * p).round() as usize];
    println!("{name}: median {:.3} ms, p95 {:.3} ms, max {:.3} ms", q(0.5), q(0.95), q(1.0));
}
