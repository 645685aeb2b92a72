//! `hilbench sweep-merge DIR...`: the shards of a sweep merged into the sweep.json of the whole.

use std::path::{Path, PathBuf};

use super::{Exit, Options};
use crate::cli::SweepMergeArgs;
use crate::output::out_dir::OutDir;

pub fn sweep_merge(args: SweepMergeArgs, opts: &Options) -> anyhow::Result<Exit> {
    // Before anything is touched: an --out among the inputs would be emptied by its claim, and a
    // shard that cannot be merged must not cost the directory a marker or a partial failures/.
    refuse_out_among_inputs(&args.out, &args.dirs)?;
    let shards = crate::sweep::output::read_shards(&args.dirs)?;
    let out = OutDir::claim(&args.out, "sweep-merge")?;
    let summary = crate::sweep::output::write_merged(shards, &args.out, opts.plots)?;
    out.finish()?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else if !opts.quiet {
        crate::output::terminal::print_sweep(&summary, &args.out);
    }
    Ok(Exit::Success)
}

/// Refuses an `--out` that is one of the shards, holds one, or lies inside one (compared as
/// absolute paths with links resolved, as far as they exist).
fn refuse_out_among_inputs(out: &Path, dirs: &[PathBuf]) -> anyhow::Result<()> {
    let out_abs = resolved(out);
    for dir in dirs {
        let dir_abs = resolved(dir);
        let relation = if out_abs == dir_abs {
            "is"
        } else if dir_abs.starts_with(&out_abs) {
            "holds"
        } else if out_abs.starts_with(&dir_abs) {
            "lies inside"
        } else {
            continue;
        };
        anyhow::bail!(
            "--out {}: {relation} the shard {} (the merge would replace the outputs it reads); give a \
             directory apart from every shard",
            out.display(),
            dir.display()
        );
    }
    Ok(())
}

/// `path` made absolute with its links resolved: the longest part that exists canonicalised,
/// the rest (not yet created) appended as it is, `.` and `..` folded.
fn resolved(path: &Path) -> PathBuf {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut existing = absolute.as_path();
    let mut rest = Vec::new();
    loop {
        if let Ok(real) = existing.canonicalize() {
            let mut out = real;
            for part in rest.iter().rev() {
                match part {
                    std::path::Component::ParentDir => {
                        out.pop();
                    }
                    std::path::Component::CurDir => {}
                    other => out.push(other),
                }
            }
            return out;
        }
        match (existing.parent(), existing.components().next_back()) {
            (Some(parent), Some(last)) => {
                rest.push(last);
                existing = parent;
            }
            _ => return absolute,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_out_that_is_holds_or_lies_inside_a_shard_is_refused_and_one_beside_is_not() {
        let base = std::env::temp_dir().join(format!("hilbench-merge-out-{}", std::process::id()));
        let shard = base.join("sh0");
        std::fs::create_dir_all(&shard).expect("dir");
        let dirs = [shard.clone(), base.join("sh1")];
        for (out, says) in [
            (shard.clone(), "is the shard"),
            (base.join("sh0/."), "is the shard"),
            (base.join("sh1/../sh0"), "is the shard"),
            (base.clone(), "holds the shard"),
            (shard.join("merged"), "lies inside the shard"),
            (base.join("sh1/not-yet/x"), "lies inside the shard"),
        ] {
            let e = refuse_out_among_inputs(&out, &dirs).expect_err("refused").to_string();
            assert!(e.contains(says), "{out:?}: {e}");
        }
        refuse_out_among_inputs(&base.join("merged"), &dirs).expect("beside the shards");
        let _ = std::fs::remove_dir_all(&base);
    }
}
