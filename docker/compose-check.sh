#!/usr/bin/env bash
# The compose check of .ci/run: builds the static binaries (docker/build.sh) and the images,
# runs compose.yaml (plant, netem, controller and `hilbench reproduce --scenario paper-2` against
# them, in lockstep) and checks runs/compose/summary.json: both controllers reached the goal
# without a collision and no plant link was lost. Skips with a message (exit 0) when there is no
# Docker engine or Compose tool; fails with the services' logs otherwise. Tears the project
# down (`down -v`) whatever happens.
set -euo pipefail
SCRIPT_NAME=compose-check
COMPOSE_FILES=()
# shellcheck source=docker/compose-lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/compose-lib.sh"

started=$SECONDS
echo "$SCRIPT_NAME: ${COMPOSE_TOOL[*]}; building static binaries and images"
docker/build.sh
compose build
rm -f runs/compose/summary.json
compose up --abort-on-container-exit --exit-code-from bench || fail "compose up failed (exit $?)"
check_summary runs/compose/summary.json --runs paper-2/nmpc paper-2/multistage
echo "$SCRIPT_NAME: passed in $((SECONDS - started)) s"
