//! A point flown in process: the space's scenario for the point, `mpc::run_closed_loop` (the
//! same loop `hilbench run --in-process` flies, lockstep and deterministic), and its score.

use mav::Scenario;
use mpc::{ClosedLoopSettings, ControllerMode, RunSummary, run_closed_loop};

use crate::score::{RunFacts, closest_approach_s};
use crate::space::Space;
use crate::table::Property;

/// One flown point.
#[derive(Debug, Clone)]
pub struct Evaluation {
    pub score: f64,
    pub facts: RunFacts,
    pub summary: RunSummary,
    /// When the run came closest to a cylinder ([`crate::score::closest_approach_s`]), s.
    pub closest_s: Option<f64>,
    /// The scenario flown (the point's delays as its trace).
    pub scenario: Scenario,
}

/// Flies `point` of `space` on `scenario` with the controller `mode` and scores it for
/// `property`. Errors (a point the space cannot turn into delays, a run that stops with an
/// error) name the point's space.
pub fn evaluate(
    space: &Space,
    scenario: &Scenario,
    mode: ControllerMode,
    property: Property,
    point: &[f64],
) -> Result<Evaluation, String> {
    let flown = space.scenario(scenario, point, &format!("falsify-{}", space.name))?;
    let (summary, traces) = run_closed_loop(&flown, &ClosedLoopSettings::paper(mode))
        .map_err(|e| format!("{}: the run failed: {e}", space.name))?;
    let facts = RunFacts::of(&summary, &flown);
    let closest_s = closest_approach_s(
        &flown.obstacles,
        traces.iter().map(|t| {
            let [x, y, z, ..] = t.record.state;
            (mav::ns_to_s(t.record.sample_time_ns), [x, y, z])
        }),
    );
    Ok(Evaluation { score: property.robustness(&facts), facts, summary, closest_s, scenario: flown })
}

/// `f` of every item on up to `jobs` threads, in the items' order.
pub fn par_map<T: Sync, R: Send>(items: &[T], jobs: usize, f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let jobs = jobs.clamp(1, items.len().max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut out: Vec<(usize, R)> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..jobs)
            .map(|_| {
                scope.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(item) = items.get(i) else { break };
                        mine.push((i, f(item)));
                    }
                    mine
                })
            })
            .collect();
        workers.into_iter().flat_map(|w| w.join().unwrap_or_else(|p| std::panic::resume_unwind(p))).collect()
    });
    out.sort_by_key(|(i, _)| *i);
    out.into_iter().map(|(_, r)| r).collect()
}
