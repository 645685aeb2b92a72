#!/usr/bin/env bash
# The gateway check of .ci/run, under Compose (compose.yaml's profile `gateway`): a simulated PX4
# vehicle (mavsim) over MAVLink/UDP, the vehicle gateway, netem with the paper's delays and the
# controller; `vehiclectl arm-offboard` arms the vehicle and switches it to OFFBOARD (the
# gateway never does on its own), then `hilbench run` flies paper-2 with the standard NMPC in
# real time. Checks runs/compose-gateway/summary.json: the goal reached without a collision.
# Skips with a message (exit 0) when there is no Docker engine or Compose tool; fails with the
# services' logs otherwise.
set -euo pipefail
SCRIPT_NAME=gateway-check
COMPOSE_FILES=()
# Every Compose call here, the teardown's included, sees the profile's services.
export COMPOSE_PROFILES=gateway
# shellcheck source=docker/compose-lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/compose-lib.sh"

started=$SECONDS
echo "$SCRIPT_NAME: ${COMPOSE_TOOL[*]}; building static binaries and images"
docker/build.sh
compose build mavsim gateway gw-netem gw-controller gw-arm gw-bench
rm -f runs/compose-gateway/summary.json
compose up -d mavsim gateway gw-netem gw-controller
compose run --rm gw-arm || fail "arming and OFFBOARD through vehiclectl failed"
compose up --no-deps --exit-code-from gw-bench gw-bench || fail "the run failed (exit $?)"
check_summary runs/compose-gateway/summary.json --runs paper-2/nmpc --time-mode real-time
echo "$SCRIPT_NAME: passed in $((SECONDS - started)) s"
