//! A temporary directory that goes away with its guard, also when the test using it fails
//! (a panic unwinds through the guard's `Drop`).

use std::path::{Path, PathBuf};

/// A fresh directory under the system's temporary one, removed (with what it holds) on drop.
/// Declare it before the processes writing into it, so that they are dropped (killed) first.
#[derive(Debug)]
pub struct TempDir(PathBuf);

impl TempDir {
    /// `hilbench-{what}-{pid}` under `std::env::temp_dir()`, emptied if a killed run left it.
    pub fn new(what: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("hilbench-{what}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
        Self(dir)
    }

    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl std::ops::Deref for TempDir {
    type Target = Path;

    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for TempDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
