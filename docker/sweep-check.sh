#!/usr/bin/env bash
# The sweep check of .ci/run: a small sweep scaled out with Compose (compose.sweep.yaml: two
# shards in two containers, then sweep-merge), and a check of the merged sweep.json: every run
# of the sweep is in it once, counted in one outcome. Skips with a message (exit 0) when there
# is no Docker engine or Compose tool. Tears the project down whatever happens.
set -euo pipefail
SCRIPT_NAME=sweep-check
COMPOSE_PROJECT=hilbench-sweep
# shellcheck source=docker/compose-lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/compose-lib.sh"
# This project is compose.sweep.yaml alone.
compose() {
    "${COMPOSE_TOOL[@]}" -p "$COMPOSE_PROJECT" -f compose.sweep.yaml "$@"
}

export SWEEP_RUNS=6
started=$SECONDS
echo "$SCRIPT_NAME: ${COMPOSE_TOOL[*]}; building static binaries and the image"
docker/build.sh
compose build merge
rm -rf runs/compose-sweep
compose up merge || fail "compose up failed (exit $?)"
summary=runs/compose-sweep/all/sweep.json
[ -f "$summary" ] || fail "no $summary: a shard or the merge failed"
python3 - "$summary" "$SWEEP_RUNS" <<'PY' || fail "the merged sweep.json is not the whole sweep"
import json, sys
v = json.load(open(sys.argv[1]))
runs = int(sys.argv[2])
assert v["runs"] == runs and v["runs_planned"] == runs, v
assert v["shard"] is None and v["timing"]["shards"] == 2, v["timing"]
assert v["reached"] + v["collided"] + v["missed"] + v["errors"] == runs, v
print(f"merged sweep: {v['runs']} runs, {v['reached']} reached, {v['collided']} collided, "
      f"{v['missed']} missed, {v['errors']} errors")
PY
echo "$SCRIPT_NAME: passed in $((SECONDS - started)) s"
