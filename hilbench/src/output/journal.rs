//! A command's finished work kept line by line as it finishes, so that the command killed
//! (`kill -9`, a node lost, a scheduler's time limit) loses only what was in flight: a JSON
//! Lines file whose first line is the command's identity (file, seed, settings) and each later
//! line one finished item, appended and flushed as it finishes. `--resume` reads it back
//! ([`JournalFile::resume`]): refused when the identity differs, naming what differs; a last
//! line cut by the kill (no newline) is dropped. `sweep` and `falsify` keep one each
//! (`crate::sweep::journal`, `crate::falsification::journal`), in the directory they claim.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use anyhow::Context;
use serde_json::Value;

/// An open journal: lines appended from any thread.
#[derive(Debug)]
pub struct JournalFile {
    path: PathBuf,
    file: Mutex<File>,
}

impl JournalFile {
    /// Starts the journal `path` anew with `identity` as its first line.
    pub fn start(path: &Path, identity: &Value) -> anyhow::Result<Self> {
        let mut file = File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
        writeln!(file, "{}", serde_json::to_string(identity)?)
            .with_context(|| format!("cannot write {}", path.display()))?;
        Ok(Self { path: path.to_path_buf(), file: Mutex::new(file) })
    }

    /// Reopens the journal a killed `command` left at `path`: refused when `identity` is not
    /// the one it was started with. Returns it, cut to its whole lines, with those lines after
    /// the identity (numbered from 2, for errors) to be read by the caller.
    pub fn resume(
        path: &Path,
        identity: &Value,
        command: &str,
    ) -> anyhow::Result<(Self, Vec<(usize, String)>)> {
        let dir = path.parent().unwrap_or(Path::new("."));
        let text = std::fs::read_to_string(path).with_context(|| {
            format!("--resume: {} has no journal of a {command} ({})", dir.display(), path.display())
        })?;
        let mut lines = text.split_inclusive('\n');
        let first = lines.next().unwrap_or_default();
        let before: Value = serde_json::from_str(first.trim_end())
            .with_context(|| format!("{}: line 1 is not a {command}'s identity", path.display()))?;
        let differ = differences(&before, identity);
        anyhow::ensure!(
            differ.is_empty(),
            "--resume: this is not the {command} {} was started with: {}",
            dir.display(),
            differ.join("; ")
        );
        let mut kept = first.len();
        let mut whole = Vec::new();
        for (k, line) in lines.enumerate() {
            // The last line may have been cut by the kill: it has no newline, and goes.
            if !line.ends_with('\n') {
                break;
            }
            whole.push((k + 2, line.trim_end().to_string()));
            kept += line.len();
        }
        let file = File::options().write(true).open(path)?;
        file.set_len(kept as u64)?;
        let file = File::options().append(true).open(path)?;
        Ok((Self { path: path.to_path_buf(), file: Mutex::new(file) }, whole))
    }

    /// Appends one line (a write of its own, so that a kill cuts at most this line).
    pub fn append(&self, line: &str) -> std::io::Result<()> {
        let mut file = self.file.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        file.write_all(format!("{line}\n").as_bytes())
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The command's outputs are written: the journal goes.
    pub fn finish(&self) -> anyhow::Result<()> {
        std::fs::remove_file(&self.path).with_context(|| format!("cannot remove {}", self.path.display()))
    }
}

/// The keys of `identity` whose values differ in `before`, as `key: before vs now`.
fn differences(before: &Value, identity: &Value) -> Vec<String> {
    let (Some(a), Some(b)) = (before.as_object(), identity.as_object()) else {
        return vec!["the journal's identity is not an object".into()];
    };
    let mut keys: Vec<&String> = a.keys().chain(b.keys()).collect();
    keys.sort();
    keys.dedup();
    keys.into_iter()
        .filter(|k| a.get(*k) != b.get(*k))
        .map(|k| format!("{k}: {} then, {} now", show(a.get(k)), show(b.get(k))))
        .collect()
}

fn show(v: Option<&Value>) -> String {
    v.map_or_else(|| "none".to_string(), Value::to_string)
}

/// A float of a journal line, to the bit: a JSON number when finite (serde_json's
/// `float_roundtrip` reads it back exactly), else `"inf"`, `"-inf"` or `"nan"`, which JSON
/// has no number for.
pub fn float(v: f64) -> Value {
    if v.is_finite() {
        Value::from(v)
    } else if v.is_nan() {
        Value::from("nan")
    } else if v > 0.0 {
        Value::from("inf")
    } else {
        Value::from("-inf")
    }
}

/// [`float`] back; `key` names it in the error.
pub fn float_of(v: &Value, key: &str) -> Result<f64, String> {
    match v {
        Value::Number(n) => n.as_f64().ok_or_else(|| format!("`{key}`: {n} is not a float")),
        Value::String(s) if s == "nan" => Ok(f64::NAN),
        Value::String(s) if s == "inf" => Ok(f64::INFINITY),
        Value::String(s) if s == "-inf" => Ok(f64::NEG_INFINITY),
        other => Err(format!("`{key}`: {other} is not a float")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn every_float_reads_back_to_the_bit_infinities_and_nan_included() {
        for v in [0.1 + 0.2, -1e-300, f64::MIN_POSITIVE, 1.0 / 3.0, f64::INFINITY, f64::NEG_INFINITY] {
            let text = serde_json::to_string(&float(v)).expect("JSON");
            let back = float_of(&serde_json::from_str(&text).expect("JSON"), "x").expect("a float");
            assert_eq!(back.to_bits(), v.to_bits(), "{v} as {text}");
        }
        assert!(float_of(&float(f64::NAN), "x").expect("NaN").is_nan());
        assert_eq!(float_of(&json!("fast"), "score"), Err("`score`: \"fast\" is not a float".into()));
    }

    #[test]
    fn a_resumed_journal_keeps_its_whole_lines_drops_one_cut_and_refuses_another_identity() {
        let dir = std::env::temp_dir().join(format!("hilbench-journal-file-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("dir");
        let path = dir.join(".journal.jsonl");
        let identity = json!({"seed": 3, "budget": 10});
        let journal = JournalFile::start(&path, &identity).expect("start");
        journal.append("{\"a\": 1}").expect("append");
        drop(journal);
        let mut text = std::fs::read_to_string(&path).expect("journal");
        text.push_str("{\"a\": 2"); // a kill in the middle of a line
        std::fs::write(&path, text).expect("write");
        let (journal, lines) = JournalFile::resume(&path, &identity, "falsify").expect("resume");
        assert_eq!(lines, [(2, "{\"a\": 1}".to_string())]);
        journal.append("{\"a\": 3}").expect("append");
        drop(journal);
        let (journal, lines) = JournalFile::resume(&path, &identity, "falsify").expect("resume again");
        assert_eq!(lines.iter().map(|(k, _)| *k).collect::<Vec<_>>(), [2, 3]);
        drop(journal);
        let e =
            JournalFile::resume(&path, &json!({"seed": 4, "budget": 10}), "falsify").expect_err("other seed");
        assert!(
            e.to_string().contains("not the falsify") && e.to_string().contains("seed: 3 then, 4 now"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
