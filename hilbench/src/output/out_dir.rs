//! The directory a command writes its outputs into (`--out`): its own for the command's life.
//!
//! A command claims its directory before it flies anything: a new or empty one, or one that
//! holds exactly the outputs of an earlier command that finished (listed in [`OUTPUTS`]), which
//! are removed first: outputs never mix (two sweeps' failure traces in one directory, a
//! smaller sweep leaving a larger one's traces, one scenario's CSV beside another's summary).
//! A directory with anything else in it (a file hilbench did not write) is refused untouched,
//! naming what is there, and a refusal costs nothing. The claim is a marker file,
//! [`IN_PROGRESS`], created exclusively and locked (`flock`) while the command runs; when the
//! outputs are complete it gives way to the list of outputs. A marker left behind is a command
//! that was killed (the lock went with its process): `hilbench sweep --resume` and `hilbench
//! falsify --resume` take such a directory back and fly the runs it lacks; other commands
//! refuse it, saying so.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;

/// The claim's marker, in the directory while its command runs.
pub const IN_PROGRESS: &str = ".hilbench-in-progress";
/// The list of a finished command's outputs (JSON), what the next claim may remove.
pub const OUTPUTS: &str = ".hilbench-outputs";

/// A claimed output directory. Dropping it without [`OutDir::finish`] leaves the marker: the
/// outputs are not complete (an error, a panic), which the next command is told.
#[derive(Debug)]
pub struct OutDir {
    path: PathBuf,
    command: String,
    /// The marker, open and locked for the claim's life.
    _marker: File,
}

/// What the marker says: which command claimed the directory.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Claim {
    /// `run`, `reproduce`, `sweep`, `falsify` or `sweep-merge`.
    pub command: String,
    pub pid: u32,
}

impl OutDir {
    /// Claims `dir` for `command`, creating it when missing: refused when it holds anything
    /// but an earlier command's outputs, which go.
    pub fn claim(dir: &Path, command: &str) -> anyhow::Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("--out {}: cannot create it", dir.display()))?;
        let entries = entries(dir)?;
        if entries.iter().any(|e| e == IN_PROGRESS) {
            return Err(in_progress(dir));
        }
        if !entries.is_empty() {
            clear_outputs(dir)?;
        }
        let path = dir.join(IN_PROGRESS);
        let marker = match File::options().write(true).create_new(true).open(&path) {
            Ok(file) => file,
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => return Err(in_progress(dir)),
            Err(e) => return Err(e).with_context(|| format!("--out {}: cannot write in it", dir.display())),
        };
        Self::hold(dir, marker, command)
    }

    /// Claims a new directory `runs/<prefix><unix time>` (`-2`, `-3`, ... when that is taken):
    /// where a command writes without `--out`.
    pub fn claim_new(prefix: &str, command: &str) -> anyhow::Result<Self> {
        let secs = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0);
        let runs = Path::new("runs");
        std::fs::create_dir_all(runs).with_context(|| format!("cannot create {}", runs.display()))?;
        for k in 1..1000 {
            let name = if k == 1 { format!("{prefix}{secs}") } else { format!("{prefix}{secs}-{k}") };
            let dir = runs.join(name);
            match std::fs::create_dir(&dir) {
                // Made by this process: nobody else writes into it.
                Ok(()) => return Self::claim(&dir, command),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => return Err(e).with_context(|| format!("cannot create {}", dir.display())),
            }
        }
        anyhow::bail!("runs/{prefix}{secs}: a thousand directories of that name exist; give --out")
    }

    /// Claims `dir` when given, else a new directory under `runs/` named with `prefix`.
    pub fn claim_or_new(dir: Option<&Path>, prefix: &str, command: &str) -> anyhow::Result<Self> {
        match dir {
            Some(dir) => Self::claim(dir, command),
            None => Self::claim_new(prefix, command),
        }
    }

    /// Takes back a directory whose command was killed (its marker left, unlocked) for
    /// `command`: `--resume`. Returns the claim and what the marker said.
    pub fn reclaim(dir: &Path, command: &str) -> anyhow::Result<(Self, Claim)> {
        let path = dir.join(IN_PROGRESS);
        let marker = File::options().read(true).write(true).open(&path).map_err(|e| {
            anyhow::anyhow!(
                "--resume: {} holds no unfinished command's outputs ({}: {e})",
                dir.display(),
                IN_PROGRESS
            )
        })?;
        let text = std::fs::read_to_string(&path).with_context(|| format!("{}", path.display()))?;
        let before: Claim = serde_json::from_str(&text)
            .with_context(|| format!("{}: not a claim hilbench wrote", path.display()))?;
        anyhow::ensure!(
            before.command == command,
            "--resume: {} holds an unfinished `hilbench {}`, not a {command}",
            dir.display(),
            before.command
        );
        Ok((Self::hold(dir, marker, command)?, before))
    }

    /// Locks `marker` and writes the claim into it.
    fn hold(dir: &Path, mut marker: File, command: &str) -> anyhow::Result<Self> {
        match marker.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => return Err(in_progress(dir)),
            Err(std::fs::TryLockError::Error(e)) => {
                return Err(e).with_context(|| format!("--out {}: cannot lock its marker", dir.display()));
            }
        }
        let claim = Claim { command: command.to_string(), pid: std::process::id() };
        marker.set_len(0)?;
        marker
            .write_all(serde_json::to_string(&claim)?.as_bytes())
            .with_context(|| format!("--out {}: cannot write in it", dir.display()))?;
        Ok(Self { path: dir.to_path_buf(), command: command.to_string(), _marker: marker })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The outputs are complete (all of what finished, after Ctrl-C too): the marker gives way
    /// to the list of them (everything in the directory: it held nothing else at the claim).
    pub fn finish(self) -> anyhow::Result<()> {
        let mut files = Vec::new();
        walk(&self.path, Path::new(""), &mut files)?;
        files.retain(|f| f != Path::new(IN_PROGRESS) && f != Path::new(OUTPUTS));
        let names: Vec<String> = files.iter().map(|f| f.to_string_lossy().into_owned()).collect();
        let list = serde_json::json!({ "command": self.command, "files": names });
        let path = self.path.join(OUTPUTS);
        std::fs::write(&path, serde_json::to_string_pretty(&list)?)
            .with_context(|| format!("cannot write {}", path.display()))?;
        let marker = self.path.join(IN_PROGRESS);
        std::fs::remove_file(&marker).with_context(|| format!("cannot remove {}", marker.display()))
    }
}

/// Removes the outputs an earlier command listed in `dir`'s [`OUTPUTS`], and the folders they
/// leave empty; refused, touching nothing, when `dir` holds anything else.
fn clear_outputs(dir: &Path) -> anyhow::Result<()> {
    let list_path = dir.join(OUTPUTS);
    let listed: Vec<PathBuf> = match std::fs::read_to_string(&list_path) {
        Ok(text) => {
            let v: serde_json::Value = serde_json::from_str(&text)
                .with_context(|| format!("{}: not a list hilbench wrote", list_path.display()))?;
            v["files"]
                .as_array()
                .into_iter()
                .flatten()
                .filter_map(|f| f.as_str())
                .map(PathBuf::from)
                .collect()
        }
        Err(_) => Vec::new(),
    };
    let mut present = Vec::new();
    walk(dir, Path::new(""), &mut present)?;
    let foreign: Vec<String> = present
        .iter()
        .filter(|f| *f != Path::new(OUTPUTS) && !listed.contains(f))
        .map(|f| f.to_string_lossy().into_owned())
        .collect();
    if !foreign.is_empty() {
        let shown: Vec<&str> = foreign.iter().take(3).map(String::as_str).collect();
        anyhow::bail!(
            "--out {}: holds {} file(s) hilbench did not write ({}{}); hilbench writes into a new or empty \
             directory, or one holding only an earlier run's outputs (which it replaces), so that no \
             outputs mix: remove them or give another --out",
            dir.display(),
            foreign.len(),
            shown.join(", "),
            if foreign.len() > shown.len() { ", ..." } else { "" }
        );
    }
    for file in present.iter().filter(|f| listed.contains(f)) {
        let path = dir.join(file);
        let removed = if path.is_dir() { std::fs::remove_dir(&path) } else { std::fs::remove_file(&path) };
        removed.with_context(|| format!("--out: cannot remove {}", path.display()))?;
        // The folders it leaves empty (plots/, failures/), up to the directory.
        let mut parent = file.parent();
        while let Some(p) = parent.filter(|p| !p.as_os_str().is_empty()) {
            if std::fs::remove_dir(dir.join(p)).is_err() {
                break;
            }
            parent = p.parent();
        }
    }
    let _ = std::fs::remove_file(&list_path);
    Ok(())
}

/// The files below `dir/at`, as paths relative to `dir` (symbolic links as files, not
/// followed); an empty folder is not listed.
fn walk(dir: &Path, at: &Path, files: &mut Vec<PathBuf>) -> anyhow::Result<()> {
    let here = dir.join(at);
    for entry in std::fs::read_dir(&here).with_context(|| format!("cannot read {}", here.display()))? {
        let entry = entry?;
        let relative = at.join(entry.file_name());
        if entry.file_type()?.is_dir() {
            let before = files.len();
            walk(dir, &relative, files)?;
            if files.len() == before {
                // An empty folder is the user's: listed so that it is not removed unseen.
                files.push(relative);
            }
        } else {
            files.push(relative);
        }
    }
    Ok(())
}

/// Whether `dir` holds a command's unfinished outputs (its marker).
pub fn unfinished(dir: &Path) -> bool {
    dir.join(IN_PROGRESS).exists()
}

/// The names in `dir`, sorted.
fn entries(dir: &Path) -> anyhow::Result<Vec<String>> {
    let mut names = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("--out {}: cannot read it", dir.display()))? {
        names.push(entry?.file_name().to_string_lossy().into_owned());
    }
    names.sort();
    Ok(names)
}

/// The refusal of a directory with a marker: another command writes into it, or one was
/// killed there.
fn in_progress(dir: &Path) -> anyhow::Error {
    let path = dir.join(IN_PROGRESS);
    let claim = std::fs::read_to_string(&path).ok().and_then(|t| serde_json::from_str::<Claim>(&t).ok());
    let running =
        File::open(&path).is_ok_and(|f| matches!(f.try_lock(), Err(std::fs::TryLockError::WouldBlock)));
    match (claim, running) {
        (Some(c), true) => anyhow::anyhow!(
            "--out {}: `hilbench {}` (pid {}) is writing into it; give another --out",
            dir.display(),
            c.command,
            c.pid
        ),
        (_, true) => anyhow::anyhow!("--out {}: another hilbench is writing into it", dir.display()),
        (Some(c), false) if c.command == "sweep" || c.command == "falsify" => anyhow::anyhow!(
            "--out {}: holds the outputs of a `hilbench {}` that did not finish (killed): give the same \
             command with --resume to fly the runs it lacks, or give another --out",
            dir.display(),
            c.command
        ),
        (c, false) => anyhow::anyhow!(
            "--out {}: holds the outputs of a `hilbench {}` that did not finish (killed); remove it or give \
             another --out",
            dir.display(),
            c.map_or_else(|| "command".to_string(), |c| c.command)
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("hilbench-out-dir-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn a_finished_claim_lists_its_outputs_and_the_next_claim_replaces_them() {
        let dir = temp("new");
        let out = OutDir::claim(&dir, "sweep").expect("a new directory");
        assert!(unfinished(&dir));
        std::fs::write(dir.join("summary.json"), "{}").expect("write");
        std::fs::create_dir_all(dir.join("failures")).expect("dir");
        std::fs::write(dir.join("failures/3.csv"), "0.1").expect("write");
        out.finish().expect("finish");
        assert!(!unfinished(&dir));
        assert_eq!(entries(&dir).expect("entries"), [OUTPUTS, "failures", "summary.json"]);
        // A second command into it: the first one's outputs go, folders and all.
        let out = OutDir::claim(&dir, "run").expect("an earlier command's outputs");
        assert_eq!(entries(&dir).expect("entries"), [IN_PROGRESS]);
        out.finish().expect("finish");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_directory_with_a_file_hilbench_did_not_write_is_refused_naming_it_and_left_as_it_was() {
        let dir = temp("full");
        std::fs::create_dir_all(&dir).expect("dir");
        std::fs::write(dir.join("notes.txt"), "mine").expect("write");
        let e = OutDir::claim(&dir, "sweep").expect_err("not empty").to_string();
        assert!(e.contains("holds 1 file(s) hilbench did not write (notes.txt)"), "{e}");
        assert_eq!(entries(&dir).expect("entries"), ["notes.txt"]);
        // Beside an earlier command's outputs too: nothing is removed.
        std::fs::remove_file(dir.join("notes.txt")).expect("rm");
        let out = OutDir::claim(&dir, "run").expect("empty");
        std::fs::write(dir.join("summary.json"), "{}").expect("write");
        out.finish().expect("finish");
        std::fs::create_dir_all(dir.join("plots")).expect("dir");
        std::fs::write(dir.join("plots/mine.png"), "mine").expect("write");
        let e = OutDir::claim(&dir, "run").expect_err("a foreign file").to_string();
        assert!(e.contains("(plots/mine.png)"), "{e}");
        assert_eq!(entries(&dir).expect("entries"), [OUTPUTS, "plots", "summary.json"]);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_claimed_directory_is_refused_while_its_claim_lives_and_named_killed_after() {
        let dir = temp("busy");
        let out = OutDir::claim(&dir, "sweep").expect("claimed");
        let e = OutDir::claim(&dir, "sweep").expect_err("busy").to_string();
        assert!(
            e.contains(&format!("`hilbench sweep` (pid {}) is writing into it", std::process::id())),
            "{e}"
        );
        let e = OutDir::reclaim(&dir, "sweep").expect_err("still locked").to_string();
        assert!(e.contains("is writing into it"), "{e}");
        // Dropped without finish: as a killed command leaves it.
        drop(out);
        let e = OutDir::claim(&dir, "sweep").expect_err("killed").to_string();
        assert!(e.contains("did not finish (killed)") && e.contains("--resume"), "{e}");
        let e = OutDir::reclaim(&dir, "falsify").expect_err("another command").to_string();
        assert!(e.contains("an unfinished `hilbench sweep`, not a falsify"), "{e}");
        let (out, before) = OutDir::reclaim(&dir, "sweep").expect("taken back");
        assert_eq!(before.command, "sweep");
        out.finish().expect("finish");
        let e = OutDir::reclaim(&dir, "sweep").expect_err("nothing unfinished").to_string();
        assert!(e.contains("holds no unfinished command's outputs"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
