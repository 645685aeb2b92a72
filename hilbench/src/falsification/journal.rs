//! A falsification's runs kept as they finish ([`JOURNAL`], `crate::output::journal`), so that
//! one killed loses only the runs in flight. `hilbench falsify ... --resume` runs the same
//! searches again (the same seed asks the same points, bit for bit): a point the journal holds
//! for its (space, method, run) is taken from it instead of flown, so the resumed
//! falsification's outputs are those of one never stopped (but for wall times).

use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use falsify::Method;
use serde_json::{Value, json};

use super::Evaluation;
use crate::output::journal::{JournalFile, float, float_of};

/// The journal's file name in the falsification's directory (removed when it is written).
pub const JOURNAL: &str = ".falsify-journal.jsonl";

/// The open journal of a running falsification.
#[derive(Debug)]
pub struct Journal {
    file: JournalFile,
    /// The runs an earlier try finished, by (space, method, run).
    finished: HashMap<(String, String, u64), Evaluation>,
    /// A write failed (said once): from then on a kill loses the runs since.
    failed: AtomicBool,
}

impl Journal {
    /// Starts the journal of a new falsification in `dir` (claimed, empty).
    pub fn start(dir: &Path, identity: &Value) -> anyhow::Result<Self> {
        let file = JournalFile::start(&dir.join(JOURNAL), identity)?;
        Ok(Self { file, finished: HashMap::new(), failed: AtomicBool::new(false) })
    }

    /// Reopens the journal a killed falsification left in `dir`, with the runs it holds;
    /// refused when `identity` is not the one it was started with.
    pub fn resume(dir: &Path, identity: &Value) -> anyhow::Result<Self> {
        let (file, lines) = JournalFile::resume(&dir.join(JOURNAL), identity, "falsify")?;
        let mut finished = HashMap::new();
        for (k, line) in lines {
            let (key, evaluation) =
                from_line(&line).map_err(|e| anyhow::anyhow!("{}: line {k}: {e}", file.path().display()))?;
            finished.insert(key, evaluation);
        }
        Ok(Self { file, finished, failed: AtomicBool::new(false) })
    }

    /// Runs an earlier try finished.
    pub fn len(&self) -> usize {
        self.finished.len()
    }

    pub fn is_empty(&self) -> bool {
        self.finished.is_empty()
    }

    /// Run `run` of the search of `space` with `method`, if an earlier try finished it at this
    /// very `point` (to the bit).
    pub fn finished(&self, space: &str, method: Method, run: u64, point: &[f64]) -> Option<Evaluation> {
        let e = self.finished.get(&(space.to_string(), method.name().to_string(), run))?;
        let same = e.point.len() == point.len()
            && e.point.iter().zip(point).all(|(a, b)| a.to_bits() == b.to_bits());
        same.then(|| e.clone())
    }

    /// Appends a finished run. A failure to write is said once on stderr; the search goes on.
    pub fn record(&self, space: &str, method: Method, evaluation: &Evaluation) {
        if let Err(e) = self.file.append(&to_line(space, method, evaluation))
            && !self.failed.swap(true, Ordering::Relaxed)
        {
            eprintln!(
                "warning: cannot append to {} ({e}): a falsification killed from now on loses the runs that finish",
                self.file.path().display()
            );
        }
    }

    /// The falsification's outputs are written: the journal goes.
    pub fn finish(&self) -> anyhow::Result<()> {
        self.file.finish()
    }
}

fn to_line(space: &str, method: Method, e: &Evaluation) -> String {
    json!({
        "space": space,
        "method": method.name(),
        "run": e.run,
        "point": e.point.iter().map(|v| float(*v)).collect::<Vec<_>>(),
        "score": float(e.score),
        "outcome": e.outcome,
        "error": e.error,
        "cycles": e.cycles,
        "min_clearance_m": e.min_clearance_m.map(float),
        "end_time_s": e.end_time_s.map(float),
        "wall_s": float(e.wall_s),
    })
    .to_string()
}

type Key = (String, String, u64);

fn from_line(line: &str) -> Result<(Key, Evaluation), String> {
    let v: Value = serde_json::from_str(line).map_err(|e| e.to_string())?;
    let text = |key: &str| v[key].as_str().map(str::to_string).ok_or_else(|| format!("no `{key}`"));
    let count = |key: &str| v[key].as_u64().ok_or_else(|| format!("`{key}`: not a count"));
    let optional = |key: &str| match &v[key] {
        Value::Null => Ok(None),
        x => float_of(x, key).map(Some),
    };
    let point = v["point"]
        .as_array()
        .ok_or("no `point`")?
        .iter()
        .map(|x| float_of(x, "point"))
        .collect::<Result<Vec<f64>, String>>()?;
    let evaluation = Evaluation {
        run: count("run")?,
        point,
        score: float_of(&v["score"], "score")?,
        outcome: text("outcome")?.parse().map_err(|e| format!("`outcome`: {e}"))?,
        error: text("error")?,
        cycles: count("cycles")?,
        min_clearance_m: optional("min_clearance_m")?,
        end_time_s: optional("end_time_s")?,
        wall_s: float_of(&v["wall_s"], "wall_s")?,
    };
    Ok(((text("space")?, text("method")?, evaluation.run), evaluation))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run::{RunErrorKind, Verdict};

    fn evaluation(run: u64, score: f64, outcome: Verdict) -> Evaluation {
        Evaluation {
            run,
            point: vec![0.1 + 0.2, 1.0 / 3.0],
            score,
            outcome,
            error: if outcome.is_the_benchs() { "netem died".into() } else { String::new() },
            cycles: 17,
            min_clearance_m: Some(f64::INFINITY),
            end_time_s: None,
            wall_s: 0.25,
        }
    }

    #[test]
    fn a_falsifications_journal_gives_back_each_run_at_its_point_to_the_bit_and_no_other() {
        let dir = std::env::temp_dir().join(format!("hilbench-falsify-journal-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("dir");
        let identity = json!({"seed": 7});
        let journal = Journal::start(&dir, &identity).expect("start");
        let runs = [
            evaluation(1, -0.0125, Verdict::Collided),
            evaluation(2, f64::NEG_INFINITY, Verdict::Failed(RunErrorKind::Controller)),
            evaluation(3, f64::NAN, Verdict::Failed(RunErrorKind::Bench)),
        ];
        for e in &runs {
            journal.record("gamma", Method::Cmaes, e);
        }
        drop(journal);
        let journal = Journal::resume(&dir, &identity).expect("resume");
        assert_eq!(journal.len(), 3);
        for e in &runs {
            let back = journal.finished("gamma", Method::Cmaes, e.run, &e.point).expect("journaled");
            assert_eq!(format!("{back:?}"), format!("{e:?}"));
            assert_eq!(back.score.to_bits(), e.score.to_bits());
        }
        // Another search, or the same run asked at another point, is flown.
        assert!(journal.finished("gamma", Method::Random, 1, &runs[0].point).is_none());
        assert!(journal.finished("gamma", Method::Cmaes, 1, &[0.3, 1.0 / 3.0]).is_none());
        journal.finish().expect("finish");
        assert!(!dir.join(JOURNAL).exists());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
