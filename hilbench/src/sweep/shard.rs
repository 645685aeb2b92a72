//! A sweep's shard: `--shard I/K`, or `--shard auto` (`auto/K`), the shard a scheduler gives
//! its task in the environment: a Slurm job array (`SLURM_ARRAY_TASK_ID` with
//! `SLURM_ARRAY_TASK_COUNT` or `SLURM_ARRAY_TASK_MIN`/`_MAX`) or a Kubernetes Indexed Job
//! (`JOB_COMPLETION_INDEX`, with the completions count in [`COUNT_VAR`] or `auto/K`).
//!
//! [`from_env`] is pure: it takes the variables as a map; `commands::sweep` passes the
//! process's environment.

use std::collections::BTreeMap;

use crate::cli::ShardArg;

/// Slurm: the task's index in the array.
pub const SLURM_ID: &str = "SLURM_ARRAY_TASK_ID";
/// Slurm: the number of tasks in the array.
pub const SLURM_COUNT: &str = "SLURM_ARRAY_TASK_COUNT";
/// Slurm: the array's lowest index.
pub const SLURM_MIN: &str = "SLURM_ARRAY_TASK_MIN";
/// Slurm: the array's highest index.
pub const SLURM_MAX: &str = "SLURM_ARRAY_TASK_MAX";
/// Slurm: the step between indices (`--array=0-9:2`); a sweep's shards need 1.
pub const SLURM_STEP: &str = "SLURM_ARRAY_TASK_STEP";
/// Kubernetes Indexed Job: the pod's completion index.
pub const K8S_INDEX: &str = "JOB_COMPLETION_INDEX";
/// The number of shards where the scheduler does not say it (a Kubernetes Indexed Job's
/// `completions`): the manifest sets it.
pub const COUNT_VAR: &str = "HILBENCH_SHARD_COUNT";

/// Where a shard came from (`sweep.json`'s `shard_from`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShardFrom {
    Flag,
    Slurm,
    Kubernetes,
}

impl ShardFrom {
    pub fn name(self) -> &'static str {
        match self {
            ShardFrom::Flag => "flag",
            ShardFrom::Slurm => "slurm",
            ShardFrom::Kubernetes => "kubernetes",
        }
    }
}

/// A shard of a sweep: the `index`-th (from 0) of `count` contiguous slices of the runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: u64,
    pub count: u64,
    pub from: ShardFrom,
}

/// The shard `arg` names; for `auto`, the one `env` (the process's environment) gives.
/// Refused, naming the variables, when no scheduler's variables are set, when they are not
/// numbers, out of range, or disagree with each other, with [`COUNT_VAR`] or with `auto/K`.
pub fn resolve(arg: ShardArg, env: &BTreeMap<String, String>) -> Result<Shard, String> {
    match arg {
        ShardArg::Slice { index, count } => Ok(Shard { index, count, from: ShardFrom::Flag }),
        ShardArg::Auto { count } => from_env(count, env),
    }
}

/// `--shard auto` (`auto/K` passes K as `expected`): see [`resolve`].
pub fn from_env(expected: Option<u64>, env: &BTreeMap<String, String>) -> Result<Shard, String> {
    let number = |name: &str| -> Result<Option<u64>, String> {
        env.get(name)
            .map(|v| {
                v.trim().parse::<u64>().map_err(|_| format!("--shard auto: {name}={v:?} is not a number"))
            })
            .transpose()
    };
    let slurm = number(SLURM_ID)?;
    let k8s = number(K8S_INDEX)?;
    let (index, count, from) = match (slurm, k8s) {
        (None, None) => {
            return Err(format!(
                "--shard auto: no scheduler's shard in the environment: neither {SLURM_ID} (a Slurm job \
                 array, with {SLURM_COUNT} or {SLURM_MIN}/{SLURM_MAX}) nor {K8S_INDEX} (a Kubernetes \
                 Indexed Job, with {COUNT_VAR} or --shard auto/K) is set; give --shard I/K instead"
            ));
        }
        (Some(_), Some(_)) => {
            return Err(format!(
                "--shard auto: both {SLURM_ID} (Slurm) and {K8S_INDEX} (Kubernetes) are set: which \
                 scheduler runs this? give --shard I/K instead"
            ));
        }
        (Some(id), None) => {
            let (index, count) = slurm_shard(id, &number)?;
            (index, Some(count), ShardFrom::Slurm)
        }
        (None, Some(index)) => (index, None, ShardFrom::Kubernetes),
    };
    // Every count given must agree: the scheduler's, HILBENCH_SHARD_COUNT and auto/K.
    let mut counts: Vec<(String, u64)> = Vec::new();
    if let Some(c) = count {
        counts.push((count_source(from, env), c));
    }
    if let Some(c) = number(COUNT_VAR)? {
        counts.push((format!("{COUNT_VAR}={c}"), c));
    }
    if let Some(c) = expected {
        counts.push((format!("--shard auto/{c}"), c));
    }
    let Some((first, count)) = counts.first().cloned() else {
        return Err(format!(
            "--shard auto: {K8S_INDEX}={index} (Kubernetes) but no number of shards: set {COUNT_VAR} \
             to the Job's completions, or give --shard auto/K"
        ));
    };
    if let Some((other, _)) = counts.iter().find(|(_, c)| *c != count) {
        return Err(format!("--shard auto: {first} but {other}: the numbers of shards disagree"));
    }
    if count == 0 {
        return Err(format!("--shard auto: {first}: no shard"));
    }
    if index >= count {
        let index_var = if from == ShardFrom::Slurm { SLURM_ID } else { K8S_INDEX };
        return Err(format!(
            "--shard auto: shard {index} ({index_var}) of {count} ({first}): the index must be below \
             the number of shards"
        ));
    }
    Ok(Shard { index, count, from })
}

/// Slurm's shard: `ID - MIN` of `MAX - MIN + 1` (or of `COUNT` alone, the array from 0).
fn slurm_shard(id: u64, number: &dyn Fn(&str) -> Result<Option<u64>, String>) -> Result<(u64, u64), String> {
    if let Some(step) = number(SLURM_STEP)?
        && step != 1
    {
        return Err(format!(
            "--shard auto: {SLURM_STEP}={step}: the shards of a sweep are an array of consecutive \
             indices (--array=0-{{K-1}}, step 1)"
        ));
    }
    let count = number(SLURM_COUNT)?;
    let (index, range_count) = match (number(SLURM_MIN)?, number(SLURM_MAX)?) {
        (Some(min), Some(max)) => {
            if min > max || id < min || id > max {
                return Err(format!(
                    "--shard auto: {SLURM_ID}={id} is not in {SLURM_MIN}={min}..{SLURM_MAX}={max}"
                ));
            }
            (id - min, Some(max - min + 1))
        }
        (None, None) => (id, None),
        (Some(_), None) | (None, Some(_)) => {
            return Err(format!(
                "--shard auto: {SLURM_MIN} and {SLURM_MAX} go together: one of them is not set"
            ));
        }
    };
    match (count, range_count) {
        (Some(c), Some(r)) if c != r => Err(format!(
            "--shard auto: {SLURM_COUNT}={c} but {SLURM_MIN}..{SLURM_MAX} holds {r} indices: the array \
             has gaps; the shards of a sweep are an array of consecutive indices (--array=0-{{K-1}})"
        )),
        (Some(c), _) | (None, Some(c)) => Ok((index, c)),
        (None, None) => Err(format!(
            "--shard auto: {SLURM_ID}={id} but neither {SLURM_COUNT} nor {SLURM_MIN}/{SLURM_MAX} is set: \
             how many shards?"
        )),
    }
}

/// How the scheduler gave the count, for the messages.
fn count_source(from: ShardFrom, env: &BTreeMap<String, String>) -> String {
    match (from, env.get(SLURM_COUNT)) {
        (ShardFrom::Slurm, Some(c)) => format!("{SLURM_COUNT}={c}"),
        (ShardFrom::Slurm, None) => format!("{SLURM_MIN}..{SLURM_MAX}"),
        _ => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli::shard_arg;

    fn env(vars: &[(&str, &str)]) -> BTreeMap<String, String> {
        vars.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect()
    }

    fn auto(vars: &[(&str, &str)]) -> Result<Shard, String> {
        from_env(None, &env(vars))
    }

    fn shard(index: u64, count: u64, from: ShardFrom) -> Result<Shard, String> {
        Ok(Shard { index, count, from })
    }

    #[test]
    fn parse_reads_slices_auto_and_auto_with_a_count_and_names_what_is_wrong() {
        assert_eq!(shard_arg("1/4"), Ok(ShardArg::Slice { index: 1, count: 4 }));
        assert_eq!(shard_arg("auto"), Ok(ShardArg::Auto { count: None }));
        assert_eq!(shard_arg("auto/8"), Ok(ShardArg::Auto { count: Some(8) }));
        for (bad, says) in [
            ("3/2", "below K"),
            ("1", "I/K"),
            ("x/2", "shard number"),
            ("0/0", "at least 1"),
            ("auto/0", "at least 1"),
            ("auto/x", "number of shards"),
        ] {
            let e = shard_arg(bad).expect_err(bad);
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    #[test]
    fn a_slurm_array_gives_id_minus_min_of_the_tasks_by_count_or_by_min_and_max() {
        let id_count = [(SLURM_ID, "2"), (SLURM_COUNT, "4")];
        assert_eq!(auto(&id_count), shard(2, 4, ShardFrom::Slurm));
        // What Slurm sets for --array=1-4: index = ID - MIN.
        let all =
            [(SLURM_ID, "3"), (SLURM_COUNT, "4"), (SLURM_MIN, "1"), (SLURM_MAX, "4"), (SLURM_STEP, "1")];
        assert_eq!(auto(&all), shard(2, 4, ShardFrom::Slurm));
        let min_max = [(SLURM_ID, "10"), (SLURM_MIN, "10"), (SLURM_MAX, "12")];
        assert_eq!(auto(&min_max), shard(0, 3, ShardFrom::Slurm));
        // auto/K and HILBENCH_SHARD_COUNT check the count when they agree.
        assert_eq!(from_env(Some(4), &env(&id_count)), shard(2, 4, ShardFrom::Slurm));
    }

    #[test]
    fn a_kubernetes_indexed_job_gives_its_index_of_the_count_the_manifest_or_the_flag_passes() {
        assert_eq!(auto(&[(K8S_INDEX, "3"), (COUNT_VAR, "4")]), shard(3, 4, ShardFrom::Kubernetes));
        assert_eq!(from_env(Some(4), &env(&[(K8S_INDEX, "0")])), shard(0, 4, ShardFrom::Kubernetes));
        assert_eq!(
            from_env(Some(4), &env(&[(K8S_INDEX, "1"), (COUNT_VAR, "4")])),
            shard(1, 4, ShardFrom::Kubernetes)
        );
    }

    #[test]
    fn auto_is_refused_naming_the_variables_when_none_is_set_or_they_are_bad_or_disagree() {
        // (the variables, auto/K, what the message must name)
        type Case<'a> = (&'a [(&'a str, &'a str)], Option<u64>, &'a [&'a str]);
        let cases: &[Case] = &[
            (&[], None, &[SLURM_ID, K8S_INDEX, COUNT_VAR, "--shard I/K"]),
            (&[("SLURM_JOB_ID", "7")], None, &[SLURM_ID, K8S_INDEX]),
            (&[(SLURM_ID, "1")], None, &[SLURM_COUNT, SLURM_MIN]),
            (&[(SLURM_ID, "x"), (SLURM_COUNT, "4")], None, &[SLURM_ID, "not a number"]),
            (&[(SLURM_ID, ""), (SLURM_COUNT, "4")], None, &[SLURM_ID, "not a number"]),
            (&[(SLURM_ID, "1"), (SLURM_COUNT, "-4")], None, &[SLURM_COUNT, "not a number"]),
            (&[(SLURM_ID, "4"), (SLURM_COUNT, "4")], None, &[SLURM_ID, "below"]),
            (&[(SLURM_ID, "0"), (SLURM_COUNT, "0")], None, &[SLURM_COUNT, "no shard"]),
            (&[(SLURM_ID, "0"), (SLURM_MIN, "1"), (SLURM_MAX, "4")], None, &[SLURM_MIN, "not in"]),
            (&[(SLURM_ID, "2"), (SLURM_MIN, "0")], None, &[SLURM_MAX, "together"]),
            (
                &[(SLURM_ID, "2"), (SLURM_COUNT, "5"), (SLURM_MIN, "0"), (SLURM_MAX, "8")],
                None,
                &[SLURM_COUNT, "gaps"],
            ),
            (&[(SLURM_ID, "2"), (SLURM_COUNT, "5"), (SLURM_STEP, "2")], None, &[SLURM_STEP]),
            (&[(SLURM_ID, "1"), (SLURM_COUNT, "4")], Some(8), &[SLURM_COUNT, "auto/8", "disagree"]),
            (
                &[(SLURM_ID, "1"), (SLURM_COUNT, "4"), (COUNT_VAR, "2")],
                None,
                &[SLURM_COUNT, COUNT_VAR, "disagree"],
            ),
            (&[(K8S_INDEX, "1")], None, &[K8S_INDEX, COUNT_VAR, "auto/K"]),
            (&[(K8S_INDEX, "4"), (COUNT_VAR, "4")], None, &[K8S_INDEX, "below"]),
            (&[(K8S_INDEX, "1"), (COUNT_VAR, "four")], None, &[COUNT_VAR, "not a number"]),
            (&[(K8S_INDEX, "1"), (COUNT_VAR, "4")], Some(3), &[COUNT_VAR, "auto/3", "disagree"]),
            (&[(K8S_INDEX, "1"), (SLURM_ID, "1"), (SLURM_COUNT, "4")], None, &[SLURM_ID, K8S_INDEX, "both"]),
        ];
        for (vars, expected, says) in cases {
            let e = from_env(*expected, &env(vars)).expect_err(&format!("{vars:?}"));
            for word in *says {
                assert!(e.contains(word), "{vars:?}: {e:?} does not name {word}");
            }
        }
    }
}
