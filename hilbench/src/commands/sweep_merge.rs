//! `hilbench sweep-merge DIR...`: the shards of a sweep merged into the sweep.json of the whole.

use super::{Exit, Options};
use crate::cli::SweepMergeArgs;
use crate::output::out_dir::OutDir;

pub fn sweep_merge(args: SweepMergeArgs, opts: &Options) -> anyhow::Result<Exit> {
    let out = OutDir::claim(&args.out, "sweep-merge")?;
    let summary = crate::sweep::output::merge(&args.dirs, &args.out, opts.plots)?;
    out.finish()?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else if !opts.quiet {
        crate::output::terminal::print_sweep(&summary, &args.out);
    }
    Ok(Exit::Success)
}
