#!/usr/bin/env bash
# The Slurm check of .ci/run: a one-node Slurm cluster on loopback (munged, slurmctld and slurmd
# started here from check/slurm.conf.in, in a temporary directory), the sweep of submit.sh
# submitted to it (a 4-task job array of a small sweep, `--shard auto`, and the merge with
# --dependency=afterok), and a check that the merged sweep.json and runs.csv are one process's
# whole sweep of the same file, but for the wall-clock numbers. Installs Debian's slurm-wlm and
# munge when they are missing; skips with a message (exit 0) where it cannot run (not root, no
# apt-get, the install fails). Stops whatever it started, whatever happens.
#
#   deploy/slurm/check.sh            (from the repository; uses ${CARGO_TARGET_DIR:-target}/release/hilbench)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../.."
NAME=slurm-check
FILE=scenarios/sweeps/paper-2-gamma.toml
RUNS=8
SHARDS=4
TIMEOUT_S=${SLURM_CHECK_TIMEOUT_S:-600}
skip() { echo "$NAME: skipped: $*"; exit 0; }
fail() { echo "$NAME: FAILED: $*" >&2; exit 1; }

[ "$(id -u)" -eq 0 ] || skip "not root (slurmd and munged run as root here)"
daemons="munged slurmctld slurmd sbatch squeue scontrol"
missing() { for c in $daemons; do command -v "$c" >/dev/null 2>&1 || return 0; done; return 1; }
if missing; then
    command -v apt-get >/dev/null 2>&1 || skip "no slurm-wlm and munge, and no apt-get to install them"
    echo "$NAME: installing slurm-wlm and munge"
    export DEBIAN_FRONTEND=noninteractive
    apt-get install -y --no-install-recommends slurm-wlm munge >/dev/null \
        || { apt-get update >/dev/null && apt-get install -y --no-install-recommends slurm-wlm munge >/dev/null; } \
        || skip "apt-get install slurm-wlm munge failed"
    missing && skip "slurm-wlm and munge installed, but one of $daemons is not on PATH"
fi
hilbench="${CARGO_TARGET_DIR:-target}/release/hilbench"
[ -x "$hilbench" ] || cargo build --release -p hilbench
started=$SECONDS

dir=$(mktemp -d /tmp/hilbench-slurm.XXXXXX)
pids=()
array= merge=
stop() {
    local rc=$?
    # The jobs first (a job's processes outlive slurmd), then slurmd, slurmctld and munged.
    if [ -n "$array$merge" ]; then
        scancel $array $merge 2>/dev/null || true
        for _ in $(seq 50); do [ -z "$(squeue -h 2>/dev/null)" ] && break; sleep 0.2; done
    fi
    for pidfile in "$dir/slurmd.pid" "$dir/slurmctld.pid" "$dir/munge/munged.pid"; do
        [ -s "$pidfile" ] && kill "$(cat "$pidfile")" 2>/dev/null || true
    done
    for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
    for pid in "${pids[@]}"; do wait "$pid" 2>/dev/null || true; done
    if [ "$rc" -ne 0 ]; then
        for log in slurmctld.log slurmd.log out/logs/shard-0.out out/logs/merge.out; do
            [ -f "$dir/$log" ] && { echo "--- $log (end)"; tail -n 20 "$dir/$log"; } >&2
        done
    fi
    rm -rf "$dir"
    exit "$rc"
}
trap stop EXIT
trap 'exit 130' INT TERM

# munged: its own key, socket and files in $dir (never the machine's).
mkdir -p "$dir/munge" "$dir/state" "$dir/spool" "$dir/out"
chmod 755 "$dir/munge"
dd if=/dev/urandom of="$dir/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$dir/munge/munge.key"
munged --force --foreground --key-file="$dir/munge/munge.key" --socket="$dir/munge/munge.socket" \
    --pid-file="$dir/munge/munged.pid" --log-file="$dir/munge/munged.log" \
    --seed-file="$dir/munge/munged.seed" 2>"$dir/munge/munged.out" &
pids+=($!)
for _ in $(seq 50); do [ -S "$dir/munge/munge.socket" ] && break; sleep 0.1; done
[ -S "$dir/munge/munge.socket" ] || fail "munged did not start ($(tail -n 3 "$dir/munge/munged.out" 2>/dev/null))"

# slurm.conf: this node as `slurmd -C` sees it, on loopback ports that are free.
free_port() {
    python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}
node=$(slurmd -C | head -n 1)
host=$(printf '%s\n' "$node" | sed -n 's/^NodeName=\([^ ]*\).*/\1/p')
[ -n "$host" ] || fail "slurmd -C gave no NodeName: $node"
sed -e "s|@DIR@|$dir|g" -e "s|@HOST@|$host|g" -e "s|@NODE@|$node|" \
    -e "s|@CTLD_PORT@|$(free_port)|" -e "s|@SLURMD_PORT@|$(free_port)|" \
    deploy/slurm/check/slurm.conf.in >"$dir/slurm.conf"
export SLURM_CONF="$dir/slurm.conf"
slurmctld -D -i -f "$SLURM_CONF" >"$dir/slurmctld.out" 2>&1 &
pids+=($!)
slurmd -D -f "$SLURM_CONF" -N "$host" >"$dir/slurmd.out" 2>&1 &
pids+=($!)
up=
for _ in $(seq 100); do
    if sinfo -h -N -o '%T' 2>/dev/null | grep -Eq '^(idle|mixed|allocated)'; then up=1; break; fi
    sleep 0.3
done
[ -n "$up" ] || fail "the node did not come up: $(sinfo -N 2>&1 | tail -n 2)"
echo "$NAME: slurmctld and slurmd up on $host ($(sinfo -h -N -o '%c CPUs, %m MB'))"

# The sweep as a user submits it, one CPU per task so the four tasks share the two cores.
ids=$(CPUS=1 TIME=00:20:00 deploy/slurm/submit.sh "$FILE" "$RUNS" "$SHARDS" "$dir/out")
echo "$NAME: submitted: $ids"
array=$(printf '%s\n' "$ids" | sed -n 's/^array \([0-9]*\) merge \([0-9]*\)$/\1/p')
merge=$(printf '%s\n' "$ids" | sed -n 's/^array \([0-9]*\) merge \([0-9]*\)$/\2/p')
[ -n "$array" ] && [ -n "$merge" ] || fail "submit.sh printed no job ids: $ids"

# One process's whole sweep of the same file while the cluster works.
nice -n 5 "$hilbench" sweep "$(realpath "$FILE")" --runs "$RUNS" --jobs 1 --quiet --no-plots --out "$dir/whole" \
    || fail "the whole sweep failed"

state() { scontrol show job "$1" 2>/dev/null | sed -n 's/.*JobState=\([A-Z_]*\).*/\1/p' | sort -u | tr '\n' ' '; }
deadline=$((SECONDS + TIMEOUT_S))
while :; do
    s=$(state "$merge")
    case "$s" in
        "COMPLETED ") break ;;
        *FAILED*|*CANCELLED*|*TIMEOUT*|*NODE_FAIL*|*OUT_OF_MEMORY*)
            fail "the merge job $merge ended $s(the array: $(state "$array"))" ;;
    esac
    [ "$SECONDS" -lt "$deadline" ] || fail "not done in ${TIMEOUT_S} s: array $(state "$array"), merge $s"
    sleep 1
done
[ "$(state "$array")" = "COMPLETED " ] || fail "the array ended $(state "$array")"
summary="$dir/out/all/sweep.json"
[ -f "$summary" ] || fail "no $summary"

python3 - "$dir/out" "$dir/whole" "$RUNS" "$SHARDS" <<'PY' || fail "the merged sweep is not the whole sweep"
import csv, json, os, sys
out, whole, runs, shards = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
WALL = {"timing", "solve_ms", "shard", "shard_from"}
def strip(v):
    if isinstance(v, dict):
        return {k: strip(x) for k, x in v.items() if k not in WALL}
    if isinstance(v, list):
        return [strip(x) for x in v]
    return v
for i in range(shards):
    v = json.load(open(os.path.join(out, f"shard-{i}", "sweep.json")))
    assert v["shard"] == f"{i}/{shards}" and v["shard_from"] == "slurm", (v["shard"], v["shard_from"])
merged = json.load(open(os.path.join(out, "all", "sweep.json")))
one = json.load(open(os.path.join(whole, "sweep.json")))
assert merged["runs"] == runs and merged["timing"]["shards"] == shards, merged["timing"]
a, b = strip(merged), strip(one)
diff = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
assert not diff, f"sweep.json differs in {diff}"
WALL_COLUMNS = {"solve_ms_p50", "solve_ms_p99", "solve_ms_max", "solver_s", "wall_s"}
def rows(d):
    with open(os.path.join(d, "runs.csv")) as f:
        return [{k: x for k, x in r.items() if k not in WALL_COLUMNS} for r in csv.DictReader(f)]
assert rows(os.path.join(out, "all")) == rows(whole), "runs.csv differs"
print(f"merged sweep of {shards} array tasks = one process's sweep: {merged['runs']} runs, "
      f"{merged['reached']} reached, {merged['collided']} collided, {merged['missed']} missed, "
      f"{merged['errors']} errors")
PY
echo "$NAME: passed in $((SECONDS - started)) s"
