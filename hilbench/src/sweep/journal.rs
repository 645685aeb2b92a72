//! A sweep's runs kept as they finish, so that a sweep killed (`kill -9`, a node lost, a
//! scheduler's time limit) loses only the runs in flight: `runs.csv` grows a line per finished
//! run in the order they finish (sorted when the sweep ends), and [`JOURNAL`] keeps each run's
//! row and failure trace to the bit. `hilbench sweep ... --resume` reads the journal back and
//! flies only the (run, controller) pairs it lacks; run `i`'s delays are drawn from the seed
//! and `i` alone, so the resumed sweep's outputs are those of one that was never stopped
//! (but for its wall times).
//!
//! The journal's first line is the sweep's identity (file and its contents' hash, seed, runs,
//! controllers, shard, ...): a resume with other settings is refused, naming what differs.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;
use serde_json::{Value, json};

use super::Done;
use super::stats::{self, RunRow};
use crate::output::journal::JournalFile;
use crate::shrink::FailureTrace;

/// The journal's file name in the sweep's directory (removed when the sweep is written).
pub const JOURNAL: &str = ".sweep-journal.jsonl";

/// The runs a journal holds, by (run, controller).
pub type Finished = BTreeMap<(u64, String), Done>;

/// The open journal of a running sweep: lines appended by the worker threads.
#[derive(Debug)]
pub struct Journal {
    dir: PathBuf,
    journal: JournalFile,
    runs_csv: Mutex<File>,
    /// A write failed (said once): from then on a kill loses the runs since.
    failed: AtomicBool,
}

impl Journal {
    /// Starts the journal of a new sweep in `dir` (claimed, empty): the identity, and
    /// `runs.csv`'s header.
    pub fn start(dir: &Path, identity: &Value) -> anyhow::Result<Self> {
        let journal = JournalFile::start(&dir.join(JOURNAL), identity)?;
        let mut runs_csv = create(&dir.join("runs.csv"))?;
        writeln!(runs_csv, "{}", stats::CSV_HEADER)?;
        Ok(Self {
            dir: dir.to_path_buf(),
            journal,
            runs_csv: Mutex::new(runs_csv),
            failed: AtomicBool::new(false),
        })
    }

    /// Reopens the journal a killed sweep left in `dir`: refused when `identity` is not the
    /// one it was started with. Returns it with the runs it holds; `runs.csv` is written anew
    /// from them (a line cut by the kill is dropped from both).
    pub fn resume(dir: &Path, identity: &Value) -> anyhow::Result<(Self, Finished)> {
        let (journal, lines) = JournalFile::resume(&dir.join(JOURNAL), identity, "sweep")?;
        let mut finished = Finished::new();
        for (k, line) in lines {
            let done = from_line(&line)
                .map_err(|e| anyhow::anyhow!("{}: line {k}: {e}", journal.path().display()))?;
            finished.insert((done.row.run, done.row.controller.clone()), done);
        }
        let rows: Vec<&RunRow> = finished.values().map(|d| &d.row).collect();
        let runs_csv_path = dir.join("runs.csv");
        std::fs::write(&runs_csv_path, stats::to_csv(&rows))
            .with_context(|| format!("cannot write {}", runs_csv_path.display()))?;
        let runs_csv = File::options().append(true).open(&runs_csv_path)?;
        let journal = Self {
            dir: dir.to_path_buf(),
            journal,
            runs_csv: Mutex::new(runs_csv),
            failed: AtomicBool::new(false),
        };
        Ok((journal, finished))
    }

    /// Appends a finished run (its journal line, then its `runs.csv` line). A failure to
    /// write is said once on stderr; the sweep goes on.
    pub fn record(&self, done: &Done) {
        let written = self.journal.append(&to_line(done)).and_then(|()| {
            let mut runs_csv = self.runs_csv.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            writeln!(runs_csv, "{}", done.row.to_csv())
        });
        if let Err(e) = written
            && !self.failed.swap(true, Ordering::Relaxed)
        {
            eprintln!(
                "warning: cannot append to {}'s runs.csv and journal ({e}): a sweep killed from now on loses \
                 the runs that finish",
                self.dir.display()
            );
        }
    }

    /// The sweep's outputs are written: the journal goes.
    pub fn finish(&self) -> anyhow::Result<()> {
        self.journal.finish()
    }
}

fn create(path: &Path) -> anyhow::Result<File> {
    File::create(path).with_context(|| format!("cannot write {}", path.display()))
}

/// A finished run as a journal line: its `runs.csv` line, and its failure trace (delays to
/// the bit: serde_json's `float_roundtrip`).
fn to_line(done: &Done) -> String {
    let failure = done.failure.as_ref().map(|f| {
        json!({
            "delays_s": f.delays_s,
            "original_len": f.original_len,
            "shrink": f.shrink,
            "replay": f.replay,
        })
    });
    json!({ "row": done.row.to_csv(), "failure": failure }).to_string()
}

fn from_line(line: &str) -> Result<Done, String> {
    let v: Value = serde_json::from_str(line).map_err(|e| e.to_string())?;
    let row = RunRow::from_csv(v["row"].as_str().ok_or("no row")?, 1)?;
    let failure = match &v["failure"] {
        Value::Null => None,
        f => Some(FailureTrace {
            delays_s: serde_json::from_value(f["delays_s"].clone()).map_err(|e| format!("delays_s: {e}"))?,
            original_len: serde_json::from_value(f["original_len"].clone())
                .map_err(|e| format!("original_len: {e}"))?,
            shrink: serde_json::from_value(f["shrink"].clone()).map_err(|e| format!("shrink: {e}"))?,
            replay: serde_json::from_value(f["replay"].clone()).map_err(|e| format!("replay: {e}"))?,
        }),
    };
    Ok(Done { row, failure })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run::Verdict;
    use crate::shrink::Replay;

    fn temp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("hilbench-journal-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("dir");
        dir
    }

    fn done(run: u64, failed: bool) -> Done {
        let mut row = RunRow::of_error(run, "multistage", "gamma", "k=2", Verdict::Reached, "", 0.25);
        row.min_clearance_m = Some(0.1 + 1e-17 * run as f64);
        let failure = failed.then(|| FailureTrace {
            delays_s: vec![0.1, 1.0 / 3.0, 0.2 + f64::EPSILON],
            original_len: 3,
            shrink: None,
            replay: Some(Replay {
                outcome: Verdict::Collided,
                end_reason: "collided".into(),
                cycles: 7,
                min_clearance_m: -0.012_345_678_901_234_5,
                path_length_m: 2.0 / 7.0,
                end_time_s: 1.3,
            }),
        });
        if failed {
            row.outcome = Verdict::Collided;
        }
        Done { row, failure }
    }

    #[test]
    fn a_journal_reads_back_to_the_bit_and_drops_a_line_cut_by_a_kill() {
        let dir = temp("roundtrip");
        let identity = json!({"seed": 3, "runs": 10});
        let journal = Journal::start(&dir, &identity).expect("start");
        let (a, b) = (done(0, false), done(1, true));
        journal.record(&a);
        journal.record(&b);
        drop(journal);
        // A kill in the middle of a line.
        let path = dir.join(JOURNAL);
        let mut text = std::fs::read_to_string(&path).expect("journal");
        text.push_str("{\"row\": \"2,multi");
        std::fs::write(&path, text).expect("write");
        let (journal, finished) = Journal::resume(&dir, &identity).expect("resume");
        assert_eq!(finished.len(), 2);
        assert_eq!(finished[&(0, "multistage".to_string())].row, a.row);
        assert_eq!(finished[&(1, "multistage".to_string())].failure, b.failure);
        // runs.csv is written anew from the journal, and appended to after.
        journal.record(&done(2, false));
        drop(journal);
        let rows =
            stats::from_csv(&std::fs::read_to_string(dir.join("runs.csv")).expect("runs.csv")).expect("rows");
        assert_eq!(rows.iter().map(|r| r.run).collect::<Vec<_>>(), [0, 1, 2]);
        let (journal, finished) = Journal::resume(&dir, &identity).expect("resume again");
        assert_eq!(finished.len(), 3);
        journal.finish().expect("finish");
        assert!(!path.exists());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_resume_with_other_settings_is_refused_naming_what_differs() {
        let dir = temp("identity");
        drop(Journal::start(&dir, &json!({"seed": 3, "runs": 10, "shard": null})).expect("start"));
        let e =
            Journal::resume(&dir, &json!({"seed": 4, "runs": 10, "shard": null})).expect_err("other seed");
        assert!(e.to_string().contains("seed: 3 then, 4 now"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
