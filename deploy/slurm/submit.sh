#!/usr/bin/env bash
# Submits a hilbench sweep to Slurm: a job array of SHARDS tasks (sweep.sbatch, one shard each,
# `hilbench sweep --shard auto`) and the merge (merge.sbatch) with --dependency=afterok on the
# array. Prints the two job ids; the merged sweep is then in OUT/all.
#
#   deploy/slurm/submit.sh FILE RUNS SHARDS OUT
#   PARTITION=short TIME=01:00:00 CPUS=8 deploy/slurm/submit.sh scenarios/sweeps/paper-2-gamma.toml 100000 50 /scratch/$USER/sweep
#
# Knobs (environment): PARTITION (default: the cluster's default partition), TIME (per task,
# default 02:00:00), CPUS (CPUs per task, which is `--jobs`, default 2), MEM_PER_CPU (default
# 1G), HILBENCH (the binary, default ${CARGO_TARGET_DIR:-target}/release/hilbench), SWEEP_ARGS (more flags of
# `hilbench sweep`), SBATCH_ARGS (more flags of both sbatch calls, e.g. "--account=lab").
# OUT and the binary must be on a file system every node sees.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
usage() { echo "usage: $0 FILE RUNS SHARDS OUT (see the comment at its top)" >&2; exit 2; }
[ $# -eq 4 ] || usage
file=$1 runs=$2 shards=$3 out=$4
[[ $runs =~ ^[1-9][0-9]*$ ]] || { echo "$0: RUNS must be a number of runs, got '$runs'" >&2; exit 2; }
[[ $shards =~ ^[1-9][0-9]*$ ]] || { echo "$0: SHARDS must be a number of shards, got '$shards'" >&2; exit 2; }
[ "$shards" -le "$runs" ] || { echo "$0: SHARDS ($shards) is more than RUNS ($runs)" >&2; exit 2; }
[ -f "$file" ] || { echo "$0: FILE '$file' is not a file" >&2; exit 2; }
hilbench=${HILBENCH:-${CARGO_TARGET_DIR:-target}/release/hilbench}
[ -x "$hilbench" ] || { echo "$0: $hilbench is not an executable (set HILBENCH)" >&2; exit 2; }
mkdir -p "$out/logs"
export HILBENCH SWEEP_FILE SWEEP_RUNS SWEEP_OUT SWEEP_ARGS
HILBENCH="$(realpath "$hilbench")" SWEEP_FILE="$(realpath "$file")" SWEEP_RUNS=$runs
SWEEP_OUT="$(realpath "$out")" SWEEP_ARGS=${SWEEP_ARGS:-}
common=(--parsable --export=ALL)
[ -n "${PARTITION:-}" ] && common+=(--partition="$PARTITION")
# shellcheck disable=SC2206 # SBATCH_ARGS is a list of flags
common+=(${SBATCH_ARGS:-})
array=$(sbatch "${common[@]}" --array="0-$((shards - 1))" --time="${TIME:-02:00:00}" \
    --cpus-per-task="${CPUS:-2}" --mem-per-cpu="${MEM_PER_CPU:-1G}" \
    --output="$SWEEP_OUT/logs/shard-%a.out" "$here/sweep.sbatch")
array=${array%%;*}
merge=$(sbatch "${common[@]}" --dependency="afterok:$array" --kill-on-invalid-dep=yes \
    --output="$SWEEP_OUT/logs/merge.out" "$here/merge.sbatch")
merge=${merge%%;*}
echo "array $array merge $merge"
echo "shards in $SWEEP_OUT/shard-*, the merged sweep in $SWEEP_OUT/all, logs in $SWEEP_OUT/logs"
