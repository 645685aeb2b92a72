//! `HILBENCH_COMMIT`: the commit the CLI was built from, for `summary.json` (an output directory
//! says which bench made it). From the environment variable of that name when set (a build
//! outside a checkout), else from git, with `-dirty` when the tree had changes; `unknown`
//! without either.

use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    out.status.success().then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

fn main() {
    println!("cargo:rerun-if-env-changed=HILBENCH_COMMIT");
    let commit = std::env::var("HILBENCH_COMMIT").ok().filter(|c| !c.is_empty()).or_else(|| {
        let head = git(&["rev-parse", "HEAD"])?;
        // Rebuilt when HEAD moves or the index changes (a commit, a checkout, a staged edit).
        // Only files that exist are watched: cargo reruns a build script on every command for
        // a watched path that is missing (a branch ref kept in packed-refs, a worktree's refs
        // in the common directory), which recompiled hilbench and every test linking it.
        let git_dir = git(&["rev-parse", "--absolute-git-dir"]);
        let common_dir = git(&["rev-parse", "--path-format=absolute", "--git-common-dir"]);
        let mut watched = Vec::new();
        if let Some(dir) = &git_dir {
            watched.push(format!("{dir}/HEAD"));
            watched.push(format!("{dir}/index"));
        }
        if let Some(dir) = common_dir.as_ref().or(git_dir.as_ref()) {
            watched.push(format!("{dir}/packed-refs"));
            if let Some(reference) = git(&["symbolic-ref", "-q", "HEAD"]) {
                watched.push(format!("{dir}/{reference}"));
            }
        }
        for path in watched.iter().filter(|p| std::path::Path::new(p).exists()) {
            println!("cargo:rerun-if-changed={path}");
        }
        let dirty = git(&["status", "--porcelain", "--untracked-files=no"]).is_some_and(|s| !s.is_empty());
        Some(if dirty { format!("{head}-dirty") } else { head })
    });
    println!("cargo:rustc-env=HILBENCH_COMMIT={}", commit.as_deref().unwrap_or("unknown"));
}
