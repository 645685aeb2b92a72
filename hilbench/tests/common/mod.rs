//! What the CLI tests share: a variant of a shipped scenario file.

use std::path::{Path, PathBuf};

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
