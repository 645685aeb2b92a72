//! Profiling target for the QP fallback: the two problems of `mpc/benches/qp.rs`
//! (`mpc::fixtures::qp_cases`), solved repeatedly, for instruction counts under callgrind
//! (they do not depend on the load of the machine, unlike wall times).
use mpc::fixtures::{U_PREV, W5, qp_cases};
use mpc::{QpBudget, QpFallback};

use crate::settings::QpFlags;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Solves per problem.
    #[arg(default_value_t = 100)]
    repetitions: usize,
    /// One problem alone (`start` or `between_cylinders`).
    #[arg(long, env = "QP_ONLY")]
    only: Option<String>,
    #[command(flatten)]
    pub(crate) qp: QpFlags,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let reps = args.repetitions;
    let settings = args.qp.settings();
    let (def, cases) = qp_cases();
    if let Some(o) = &args.only
        && !cases.iter().any(|c| c.name == o)
    {
        anyhow::bail!("--only {o}: not one of the problems (start, between_cylinders)");
    }
    for case in cases.iter().filter(|c| args.only.as_ref().is_none_or(|o| o == c.name)) {
        let mut qp = QpFallback::new(&def, settings)?;
        let t = std::time::Instant::now();
        let mut last = None;
        for _ in 0..reps {
            last = Some(qp.solve(&case.x0, &U_PREV, &W5, Some(&case.nominal), &QpBudget::default())?);
        }
        let per_ms = t.elapsed().as_secs_f64() * 1e3 / reps.max(1) as f64;
        if let Some(r) = last {
            println!(
                "{}: {per_ms:.3} ms/solve, status {:?}, iterations {}, clarabel solves {}, rows {}, cost {:.4}, clearance {:.4}",
                case.name,
                r.status,
                r.iterations,
                r.clarabel_solves,
                r.num_clarabel_rows,
                r.cost,
                r.min_clearance_m
            );
        }
    }
    Ok(())
}
