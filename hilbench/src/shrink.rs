//! A failing run's delays as a trace that replays the failure (`hilbench run FILE
//! --delay-trace failures/<run>.csv`), and shrinking: the trace made smaller while the run
//! still fails the same way, as proptest shrinks a failing case. `hilbench sweep --shrink`
//! shrinks each failure, `hilbench falsify` the worst run it found.
//!
//! The trace of a failure is the delays of the cycles it flew (the rest were never used), so
//! replaying it flies the same run to the bit. Shrinking then tries, in this order, each within
//! a budget of reruns (and of wall time, when given): setting chunks to zero (halves, quarters,
//! ... single delays: fewer bursts), flattening chunks to their smallest delay (smaller
//! spikes), deleting chunks (a shorter trace), and rounding every delay to the millisecond.
//! Deletion comes last: it moves every later delay to an earlier cycle, so a failure tied to
//! when a spike comes survives no deletion before the spike, while zeroing and flattening
//! keep every delay at its cycle. A candidate is kept when its run still fails (the caller says what failing
//! is: the same outcome for a sweep, the property for a falsifier); a candidate the run
//! outlasts ends in an error and is not kept. After each kept candidate the trace is cut to the
//! cycles that run flew. The result is the trace of the last kept run, so its replay is that
//! run.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use mav::Scenario;

use crate::drive::Driver;
use crate::fly::{Flight, RunFate, fly_one};
use crate::run::{Controller, Job, Verdict};

/// A failure's trace, and the numbers its replay gives.
#[derive(Debug, Clone, PartialEq)]
pub struct FailureTrace {
    pub delays_s: Vec<f64>,
    /// Delays of the failing run as flown (before shrinking).
    pub original_len: usize,
    /// `Some` after shrinking: reruns spent, and whether shrinking ran to its end (rather than
    /// to its budget).
    pub shrink: Option<(u64, bool)>,
    /// What replaying the trace gives (`None` for an error or a time-out: the whole trace the
    /// run had is written, it is not a replay of a finished run).
    pub replay: Option<Replay>,
}

/// The numbers of a replayed failure, as `summary.json` has them.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Replay {
    pub outcome: Verdict,
    pub end_reason: String,
    pub cycles: u64,
    pub min_clearance_m: f64,
    pub path_length_m: f64,
    pub end_time_s: f64,
}

impl Replay {
    pub fn of(flown: &Flight) -> Self {
        let s = &flown.summary;
        Self {
            outcome: s.outcome().into(),
            end_reason: s.end_reason.name().to_string(),
            cycles: s.cycles,
            min_clearance_m: s.min_clearance_m,
            path_length_m: s.path_length_m,
            end_time_s: s.end_time_s,
        }
    }
}

impl FailureTrace {
    /// The delays (of `delays_s`, the run's trace) a failed run drew.
    pub fn unshrunk(delays_s: &[f64], flown: &Flight) -> Self {
        let n = flown.delays_needed(delays_s.len());
        Self {
            delays_s: delays_s[..n].to_vec(),
            original_len: n,
            shrink: None,
            replay: Some(Replay::of(flown)),
        }
    }

    /// Every delay a run had (one that stopped with an error or timed out).
    pub fn whole(delays_s: &[f64]) -> Self {
        Self { delays_s: delays_s.to_vec(), original_len: delays_s.len(), shrink: None, replay: None }
    }

    /// The lines of a trace file's header that say what the trace is (whole, cut or shrunk)
    /// and what its replay gives, then the command `replay` that replays it.
    pub fn provenance(&self, replay: &str) -> Vec<String> {
        let mut lines = vec![match (self.shrink, &self.replay) {
            (Some((reruns, complete)), _) => format!(
                "shrunk from {} delays to {} ({} not zero) in {reruns} reruns{}",
                self.original_len,
                self.delays_s.len(),
                self.delays_s.iter().filter(|d| **d != 0.0).count(),
                if complete { "" } else { " (its budget of reruns or wall time used up, or interrupted)" }
            ),
            (None, Some(_)) => "the delays the run drew up to its end".into(),
            (None, None) => "every delay the run had".into(),
        }];
        if let Some(r) = &self.replay {
            lines.push(format!(
                "its replay: {} ({}) after {} cycles at {:.3} s, min clearance {:+}",
                r.outcome,
                r.end_reason,
                r.cycles,
                r.end_time_s,
                mpc::record::Millimetres(r.min_clearance_m)
            ));
        }
        lines.push(format!("replay: {replay}"));
        lines
    }

    /// The trace file's text (`delay::parse_trace`'s format), `header` as comment lines.
    pub fn to_text(&self, header: &[String]) -> String {
        let mut out = String::with_capacity(24 * self.delays_s.len() + 200);
        for h in header {
            out.push_str(&format!("# {h}\n"));
        }
        out.push_str("delay_s\n");
        for d in &self.delays_s {
            // A lost command is `lost`, as the parser reads it (`-1.0` would be refused).
            if delay::is_lost(*d) {
                out.push_str("lost\n");
            } else {
                out.push_str(&format!("{d:?}\n"));
            }
        }
        out
    }
}

/// The command that flies `file` again with the trace `trace`: with the external controller
/// `controller_cmd` when there is one, else the bench's controller `mode` (its name).
///
/// The scenario file is named by its absolute path (relative paths are of the directory the
/// command ran in), so that the line pasted anywhere replays; the caller names the trace the
/// same way (or `<this file>`). Both are quoted for a POSIX shell when they need it.
pub fn replay_command(file: &str, controller_cmd: Option<&str>, mode: &str, trace: &str) -> String {
    let who = match controller_cmd {
        Some(cmd) => format!("--controller-cmd {}", shell_quote(cmd)),
        None => format!("--mode {mode}"),
    };
    let file = shell_word(&absolute(Path::new(file)));
    let trace = if trace == "<this file>" { trace.to_string() } else { shell_word(trace) };
    format!("hilbench run {file} {who} --delay-trace {trace}")
}

/// `path` made absolute against the current directory (as it is, when that cannot be read).
pub fn absolute(path: &Path) -> String {
    std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf()).display().to_string()
}

/// `text` as it is when a shell reads it as one word, else quoted.
fn shell_word(text: &str) -> String {
    let plain = !text.is_empty()
        && text
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '/' | '.' | '-' | '_' | ':' | '+' | ','));
    if plain { text.to_string() } else { shell_quote(text) }
}

/// `text` as one word for a POSIX shell.
pub fn shell_quote(text: &str) -> String {
    format!("'{}'", text.replace('\'', r"'\''"))
}

/// How a candidate trace is flown: `scenario` with the trace (named `trace_name`) as its round
/// trip, by `controller`, through `driver`, each rerun within `timeout`; none once `stop` is
/// set (Ctrl-C: shrinking ends within a run, keeping what it had).
pub struct Rerun<'a> {
    pub scenario: &'a Scenario,
    pub trace_name: String,
    pub controller: &'a Controller,
    pub driver: &'a Driver,
    pub timeout: Duration,
    pub stop: &'a AtomicBool,
    /// No rerun starts after this (a wall-time budget of the shrinking, `--shrink-wall-s`).
    pub deadline: Option<Instant>,
}

impl Rerun<'_> {
    /// The scenario flown with `delays_s` as its round trip (not looping).
    pub fn scenario_with(&self, delays_s: Vec<f64>) -> Scenario {
        let mut s = self.scenario.clone();
        s.delays = Some(delay::DelaysTable::trace(&self.trace_name, delays_s, false));
        s
    }
}

/// Which passes shrinking tries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Passes {
    /// Delete, zero, round.
    All,
    /// Zero and round only: for a run that missed its goal at its time limit, which drew a
    /// delay for every cycle up to it, a shorter trace runs out before the limit (an error,
    /// never kept), so each deletion would cost a whole run for nothing.
    KeepLength,
}

impl Passes {
    /// The passes for a failure of verdict `outcome`.
    pub fn for_outcome(outcome: Verdict) -> Self {
        if outcome == Verdict::Missed { Passes::KeepLength } else { Passes::All }
    }
}

/// Shrinks `failure` (a failed run's [`FailureTrace::unshrunk`]) within `budget` reruns; a
/// candidate is kept when its run `fails`.
pub fn shrink(
    rerun: &Rerun<'_>,
    budget: u64,
    failure: FailureTrace,
    passes: Passes,
    fails: &dyn Fn(&Flight) -> bool,
) -> FailureTrace {
    let mut best = failure;
    let mut reruns = 0u64;
    // The candidate's run if it still fails, and the trace cut to what it flew.
    let mut attempt = |delays: Vec<f64>, reruns: &mut u64| -> Tried {
        if rerun.stop.load(Ordering::Relaxed) {
            return Tried::Stop;
        }
        if rerun.deadline.is_some_and(|d| Instant::now() >= d) {
            return Tried::Stop;
        }
        *reruns += 1;
        // Flown with zeros after it: a candidate whose run lasts longer than the trace (smaller
        // delays can move the failure later, and an external controller sends commands at its
        // own rate) finds a delay for every command instead of running out, which would reject
        // every such candidate; the kept trace is cut to what its run drew.
        let mut padded = delays;
        padded.resize(padded.len() + padded.len().max(MIN_PADDING), 0.0);
        let job = Job { scenario: rerun.scenario_with(padded.clone()), controller: rerun.controller.clone() };
        match fly_one(&job, rerun.driver, rerun.timeout) {
            RunFate::Flown(f) if fails(&f) => {
                padded.truncate(f.delays_needed(padded.len()));
                Tried::Fails(padded, Box::new(*f))
            }
            _ => Tried::Passes,
        }
    };
    let complete = shrink_with(&mut best, budget, passes, &mut reruns, &mut attempt)
        && !rerun.stop.load(Ordering::Relaxed);
    best.shrink = Some((reruns, complete));
    best
}

/// Whether trace `a` is smaller than `b`: fewer non-zero delays (a lost command counts as
/// one), else a smaller sum of the delivered delays, else fewer delays. Zeroing, flattening and deleting each make a trace smaller, unless the run
/// that flies it needs more delays than before.
fn smaller(a: &[f64], b: &[f64]) -> bool {
    let key = |t: &[f64]| {
        let sum: f64 = t.iter().filter(|d| !delay::is_lost(**d)).sum();
        (t.iter().filter(|d| **d != 0.0).count(), sum, t.len())
    };
    let (ka, kb) = (key(a), key(b));
    ka.0 < kb.0 || (ka.0 == kb.0 && (ka.1 < kb.1 || (ka.1 == kb.1 && ka.2 < kb.2)))
}

/// The fewest zero delays a candidate is flown with after its own (it gets as many as it has,
/// at least these).
const MIN_PADDING: usize = 16;

/// What a candidate trace's rerun gave.
enum Tried {
    /// It fails as the original did: the trace cut to what its run flew, and the run.
    Fails(Vec<f64>, Box<Flight>),
    /// It does not (or the run ended in an error).
    Passes,
    /// Not flown: Ctrl-C, or the wall-time budget is spent.
    Stop,
}

/// Flies a candidate trace, counting the rerun.
type Attempt<'a> = dyn FnMut(Vec<f64>, &mut u64) -> Tried + 'a;

/// The passes of [`shrink`] over `best` (kept up to date), at most `budget` attempts; true when
/// they ran to their end.
fn shrink_with(
    best: &mut FailureTrace,
    budget: u64,
    passes: Passes,
    reruns: &mut u64,
    attempt: &mut Attempt<'_>,
) -> bool {
    // A failing candidate is kept when its trace, as its run cut it, is smaller than the best
    // ([`smaller`]; the rounding is kept whenever it still fails): a deletion that the cut
    // grows back to the same trace is no progress, and would be tried forever.
    let mut keep_if = |best: &mut FailureTrace, candidate: Vec<f64>, reruns: &mut u64, any: bool| {
        if *reruns >= budget {
            return None;
        }
        match attempt(candidate, reruns) {
            Tried::Fails(delays, flown) if any || smaller(&delays, &best.delays_s) => {
                best.delays_s = delays;
                best.replay = Some(Replay::of(&flown));
                Some(true)
            }
            Tried::Fails(..) | Tried::Passes => Some(false),
            Tried::Stop => None,
        }
    };
    let mut keep = |best: &mut FailureTrace, candidate: Vec<f64>, reruns: &mut u64| -> Option<bool> {
        keep_if(best, candidate, reruns, false)
    };
    // Fewer bursts: zero chunks (a lost command becomes a delivered one); then smaller
    // spikes: each chunk's delays flattened to its smallest (lost commands stay lost). Every
    // delay stays at its cycle.
    for flatten in [false, true] {
        let mut size = best.delays_s.len() / 2;
        while size >= 1 {
            let mut i = 0;
            while i < best.delays_s.len() {
                let end = (i + size).min(best.delays_s.len());
                let chunk = &best.delays_s[i..end];
                let delivered = || chunk.iter().copied().filter(|d| !delay::is_lost(*d));
                let to = if flatten { delivered().fold(f64::INFINITY, f64::min) } else { 0.0 };
                let changes = |d: &f64| !(flatten && delay::is_lost(*d)) && *d != to;
                if !to.is_finite() || !chunk.iter().any(changes) {
                    i += size;
                    continue;
                }
                let mut candidate = best.delays_s.clone();
                candidate[i..end]
                    .iter_mut()
                    .filter(|d| !(flatten && delay::is_lost(**d)))
                    .for_each(|d| *d = to);
                match keep(best, candidate, reruns) {
                    None => return false,
                    Some(_) => i += size,
                }
            }
            size /= 2;
        }
    }
    // Shorter: delete chunks.
    let mut size = if passes == Passes::All { best.delays_s.len() / 2 } else { 0 };
    while size >= 1 {
        let mut i = 0;
        while i < best.delays_s.len() {
            let mut candidate = best.delays_s[..i].to_vec();
            candidate.extend_from_slice(&best.delays_s[(i + size).min(best.delays_s.len())..]);
            match keep(best, candidate, reruns) {
                None => return false,
                Some(true) => {}
                Some(false) => i += size,
            }
        }
        size /= 2;
    }
    // Round numbers: every delay to the millisecond.
    let rounded: Vec<f64> = best.delays_s.iter().map(|d| (d * 1e3).round() / 1e3).collect();
    if rounded != best.delays_s && keep_if(best, rounded, reruns, true).is_none() {
        return false;
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flown(cycles: usize, collided: bool) -> Flight {
        let scenario = mav::Scenario::paper_2();
        let sim = mav::PlantSim::new(&scenario, mav::SimSettings::default()).expect("a plant");
        let mut summary = mpc::summarize(
            "x",
            mpc::ControllerMode::Multistage.name(),
            &[],
            &sim.peek(),
            mpc::RunEnd::TimeLimit,
        );
        summary.collided = collided;
        summary.cycles = cycles as u64;
        let row = crate::run::CycleRow {
            cycle: 0,
            t_s: 0.0,
            state: [0.0; 8],
            command: [0.0; 3],
            command_seq: 0,
            known_delay_s: 0.0,
            injected_delay_s: None,
            weights: vec![],
            status: String::new(),
            iterations: 0,
            solve_ms: 0.0,
            cost: 0.0,
            constraint_violation: 0.0,
            predicted_clearance_m: 0.0,
            decision: String::new(),
            reason: String::new(),
            cost_gap: None,
        };
        Flight { summary, rows: vec![row; cycles], delays_drawn: Some(cycles) }
    }

    /// A stand-in for the closed loop: the run "collides" at the first cycle after two delays
    /// of at least 0.3 s in a row, and flies on (to a time limit) otherwise.
    fn model(delays: &[f64]) -> Option<(Vec<f64>, Flight)> {
        let at = delays.windows(2).position(|w| w[0] >= 0.3 && w[1] >= 0.3)?;
        let cycles = at + 2;
        Some((delays[..cycles].to_vec(), flown(cycles, true)))
    }

    fn tried(run: Option<(Vec<f64>, Flight)>) -> Tried {
        run.map_or(Tried::Passes, |(d, f)| Tried::Fails(d, Box::new(f)))
    }

    #[test]
    fn a_failure_tied_to_when_its_spike_comes_keeps_the_spike_at_its_cycle_and_loses_every_other_delay() {
        // A stand-in for a failure that needs a spike at cycle 60 (deleting any delay before it
        // moves the spike, and the run passes); it flies 61 cycles.
        let model = |d: &[f64]| (d.len() > 60 && d[60] >= 0.3).then(|| (d[..61].to_vec(), flown(61, true)));
        let delays: Vec<f64> =
            (0..103).map(|k| if k == 60 { 0.35 } else { 0.01 + 0.02 * (k % 5) as f64 }).collect();
        let (cut, f) = model(&delays).expect("fails");
        let mut best =
            FailureTrace { delays_s: cut, original_len: 103, shrink: None, replay: Some(Replay::of(&f)) };
        let mut reruns = 0;
        // Zeroing first: about 2 log2(61) reruns to clear everything but the spike.
        let complete = shrink_with(&mut best, 40, Passes::All, &mut reruns, &mut |d, r| {
            *r += 1;
            tried(model(&d))
        });
        assert!(!complete, "the deletions after it spend the rest of the budget");
        let mut want = vec![0.0; 61];
        want[60] = 0.35;
        assert_eq!(best.delays_s, want, "after {reruns} reruns");
    }

    #[test]
    fn a_stop_ends_the_shrinking_at_once_keeping_what_was_shrunk() {
        let mut delays: Vec<f64> = (0..120).map(|k| 0.0123 * (k % 7) as f64).collect();
        delays[50] = 0.3123;
        delays[51] = 0.33;
        let (cut, f) = model(&delays).expect("fails");
        let mut best = FailureTrace {
            delays_s: cut.clone(),
            original_len: 52,
            shrink: None,
            replay: Some(Replay::of(&f)),
        };
        let mut reruns = 0;
        let complete = shrink_with(&mut best, 1000, Passes::All, &mut reruns, &mut |d, r| {
            if *r >= 3 {
                return Tried::Stop;
            }
            *r += 1;
            tried(model(&d))
        });
        assert!(!complete);
        assert_eq!(reruns, 3);
        assert!(model(&best.delays_s).is_some(), "still fails");
    }

    #[test]
    fn shrinking_keeps_the_failure_and_leaves_the_smallest_trace_that_fails() {
        let mut delays: Vec<f64> = (0..120).map(|k| 0.0123 * (k % 7) as f64).collect();
        delays[50] = 0.3123;
        delays[51] = 0.33;
        delays[80] = 0.31;
        let (cut, f) = model(&delays).expect("fails");
        let mut best =
            FailureTrace { delays_s: cut, original_len: 52, shrink: None, replay: Some(Replay::of(&f)) };
        let mut reruns = 0;
        let complete = shrink_with(&mut best, 1000, Passes::All, &mut reruns, &mut |d, r| {
            *r += 1;
            tried(model(&d))
        });
        assert!(complete);
        assert_eq!(best.delays_s, vec![0.312, 0.33], "after {reruns} reruns");
        assert!(model(&best.delays_s).is_some());
        // A budget stops it early, with a trace that still fails.
        let (cut, f) = model(&delays).expect("fails");
        let mut early =
            FailureTrace { delays_s: cut, original_len: 52, shrink: None, replay: Some(Replay::of(&f)) };
        let mut reruns = 0;
        assert!(!shrink_with(&mut early, 5, Passes::All, &mut reruns, &mut |d, r| {
            *r += 1;
            tried(model(&d))
        }));
        assert_eq!(reruns, 5);
        assert!(model(&early.delays_s).is_some() && early.delays_s.len() <= 52);
    }

    #[test]
    fn a_missed_run_is_shrunk_without_deleting_delays() {
        // A stand-in for a run that misses its goal at its time limit: it needs all 40 delays
        // (a shorter trace runs out first) and misses while any delay is at least 0.2 s.
        let model = |d: &[f64]| {
            (d.len() == 40 && d.iter().any(|x| *x >= 0.2)).then(|| (d.to_vec(), flown(40, false)))
        };
        let mut delays: Vec<f64> = (0..40).map(|k| 0.05 + 0.001 * k as f64).collect();
        delays[17] = 0.25;
        let (_, f) = model(&delays).expect("misses");
        let mut best =
            FailureTrace { delays_s: delays, original_len: 40, shrink: None, replay: Some(Replay::of(&f)) };
        let mut lengths = Vec::new();
        let complete = shrink_with(&mut best, 1000, Passes::KeepLength, &mut 0, &mut |d, r| {
            *r += 1;
            lengths.push(d.len());
            tried(model(&d))
        });
        assert!(complete);
        assert!(lengths.iter().all(|n| *n == 40), "a candidate was shortened: {lengths:?}");
        let mut want = vec![0.0; 40];
        want[17] = 0.25;
        assert_eq!(best.delays_s, want);
    }

    #[test]
    fn a_failure_trace_keeps_the_delays_an_external_run_drew_beyond_its_applied_commands() {
        // An external controller's run: 5 commands applied, 7 delayed by netem by the end (two
        // in flight): the trace keeps 7, or the replay would run out before the end.
        let mut f = flown(5, true);
        f.delays_drawn = Some(7);
        let delays: Vec<f64> = (0..20).map(|k| 0.01 * k as f64).collect();
        assert_eq!(FailureTrace::unshrunk(&delays, &f).delays_s, delays[..7].to_vec());
        f.delays_drawn = None;
        assert_eq!(FailureTrace::unshrunk(&delays, &f).delays_s.len(), 20, "unknown: every delay");
    }

    #[test]
    fn a_failure_trace_with_a_lost_command_writes_it_as_lost_and_parses_back() {
        let delays = vec![0.05, delay::LOST_S, 0.25];
        let text = FailureTrace::whole(&delays).to_text(&["run 3".into()]);
        assert!(text.contains("\nlost\n"), "{text}");
        assert_eq!(delay::parse_trace(&text).expect("a trace file"), delays);
    }
}
