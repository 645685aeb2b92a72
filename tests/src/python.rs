//! The Python the tests check our wire protocols with (grpcio, mcap, pymavlink, ...): a venv in
//! `target/python-venv`, made on first use from `tests/python/requirements.txt`, so that
//! `cargo test` needs nothing but `python3` with its `venv` module (Debian: `python3-venv`) and
//! PyPI. `.ci/run` makes it ahead of the tests; `HILBENCH_PYTHON` names another interpreter
//! that already has the requirements.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// The requirements the venv is made from.
const REQUIREMENTS: &str = include_str!("../python/requirements.txt");

/// The directory of the Python test scripts (`tests/python/`).
pub fn scripts_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("python")
}

/// The interpreter of the test venv, made (once, across test processes) when missing or when
/// the requirements changed. Panics with what to install when it cannot be made.
pub fn python() -> PathBuf {
    if let Some(python) = std::env::var_os("HILBENCH_PYTHON") {
        return PathBuf::from(python);
    }
    let venv = target_dir().join("python-venv");
    let python = venv.join("bin").join("python");
    let stamp = venv.join("requirements.txt");
    if std::fs::read_to_string(&stamp).is_ok_and(|s| s == REQUIREMENTS) {
        return python;
    }
    let _lock = DirLock::acquire(&target_dir().join("python-venv.lock"));
    // Another test process may have made it while this one waited.
    if std::fs::read_to_string(&stamp).is_ok_and(|s| s == REQUIREMENTS) {
        return python;
    }
    run(
        Command::new("python3").args(["-m", "venv", "--clear"]).arg(&venv),
        "python3 -m venv (Debian: apt install python3-venv)",
    );
    let requirements = venv.join("requirements.in");
    std::fs::write(&requirements, REQUIREMENTS).expect("write the venv's requirements");
    run(
        Command::new(&python)
            .args(["-m", "pip", "install", "--quiet", "--disable-pip-version-check", "-r"])
            .arg(&requirements),
        "pip install -r tests/python/requirements.txt (needs PyPI)",
    );
    std::fs::write(&stamp, REQUIREMENTS).expect("write the venv's stamp");
    python
}

/// Runs `tests/python/<script>` with `args` under the venv's interpreter; panics with its
/// output when it fails, returns its stdout when it succeeds.
pub fn run_script(script: &str, args: &[&str]) -> String {
    let output = Command::new(python())
        .arg(scripts_dir().join(script))
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {script}: {e}"));
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    assert!(
        output.status.success(),
        "{script} {args:?} failed ({}):\n--- stdout\n{stdout}\n--- stderr\n{}",
        output.status,
        String::from_utf8_lossy(&output.stderr)
    );
    stdout
}

/// `target/` (the tests run as `target/<profile>/deps/<test>-<hash>`).
fn target_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("the test binary's path");
    exe.ancestors().nth(3).expect("the target directory").to_path_buf()
}

fn run(command: &mut Command, what: &str) {
    let status = command.status().unwrap_or_else(|e| panic!("cannot run {what}: {e}"));
    assert!(status.success(), "{what} failed ({status})");
}

/// A lock between processes: a directory only one can create (removed on drop; one older than
/// ten minutes is a crashed holder's and is taken over).
struct DirLock(PathBuf);

impl DirLock {
    fn acquire(path: &Path) -> Self {
        let started = Instant::now();
        loop {
            match std::fs::create_dir(path) {
                Ok(()) => return Self(path.to_path_buf()),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    let stale = std::fs::metadata(path)
                        .and_then(|m| m.modified())
                        .is_ok_and(|t| t.elapsed().unwrap_or_default() > Duration::from_secs(600));
                    if stale {
                        let _ = std::fs::remove_dir(path);
                    }
                    assert!(
                        started.elapsed() < Duration::from_secs(900),
                        "{} held for 15 min",
                        path.display()
                    );
                    std::thread::sleep(Duration::from_millis(200));
                }
                Err(e) => panic!("cannot create {}: {e}", path.display()),
            }
        }
    }
}

impl Drop for DirLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir(&self.0);
    }
}
