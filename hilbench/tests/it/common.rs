//! What the CLI tests share: a variant of a shipped scenario file, a CSV without its wall-clock
//! column.

// Each test module uses some of it.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Writes `dir/<name>.toml`: `scenarios/paper-2.toml` with each `(from, to)` replaced (each must
/// occur, so that a changed shipped file fails the test instead of silently flying paper-2).
pub fn paper_2_variant(dir: &Path, name: &str, replacements: &[(&str, &str)]) -> PathBuf {
    let paper_2 =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/paper-2.toml"))
            .expect("scenarios/paper-2.toml");
    let mut text = paper_2.replace("name = \"paper-2\"", &format!("name = \"{name}\""));
    for (from, to) in replacements {
        assert!(text.contains(from), "scenarios/paper-2.toml no longer holds {from:?}");
        text = text.replace(from, to);
    }
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text).expect("write the scenario");
    path
}

/// The per-cycle CSV without its solve_ms column (a wall-clock time): what two runs of the
/// same flight must share.
pub fn csv_without_solve_times(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let column =
        text.lines().next().and_then(|h| h.split(',').position(|c| c == "solve_ms")).expect("solve_ms");
    text.lines()
        .map(|l| {
            l.split(',')
                .enumerate()
                .filter(|(i, _)| *i != column)
                .map(|(_, c)| c)
                .collect::<Vec<_>>()
                .join(",")
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// `hilbench ARGS` to its end.
pub fn hilbench(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hilbench")).args(args).output().expect("hilbench runs")
}

/// A path of the repository, as text.
pub fn repo(path: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path).display().to_string()
}

/// An emptied directory `name` under the tests' temporary directory.
pub fn out_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// A path as a flag's text.
pub fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8")
}

/// The JSON file at `path`.
pub fn json_of(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())))
        .expect("JSON")
}
