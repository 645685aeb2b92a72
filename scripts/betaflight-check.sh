#!/usr/bin/env bash
# The firmware-in-the-loop checks (run by .ci/run): builds (or finds cached) Betaflight 4.6.0
# SITL with scripts/betaflight-sitl.sh, then
# 1. the tests that need the real firmware, each required (HILBENCH_REQUIRE_SITL=1): the MSP
#    core against the firmware (msp), the Betaflight vehicle (bfsim: MSP and motor packets, a
#    hover armed over MSP in ANGLE mode with the stick's tilt, no SITL left behind, the pose
#    stream read by pymavlink) and the gateway's MSP side (arms on request, attitude, the
#    watchdog);
# 2. a flight end to end (scripts/betaflight-flight.sh): hilbench run -> netem -> gateway --msp
#    -> the firmware -> bfsim's rigid body, scenarios/fields/paper-2-field.toml in real time; it
#    prints the summary (vehicle, firmware, reached or not) and fails when the chain does not
#    fly;
# 3. the firmware killed mid-run (betaflight-flight.sh --kill-firmware): the run must end with an
#    error naming the lost vehicle within 30 s.
# One SITL runs at a time (fixed ports; the tests take a lock).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
binary="$(scripts/betaflight-sitl.sh)"
echo "betaflight-check: SITL at $binary"
export HILBENCH_REQUIRE_SITL=1 HILBENCH_BETAFLIGHT_SITL="$binary"
cargo test --workspace --release --test sitl --test betaflight_sitl -- --test-threads 1
scripts/betaflight-flight.sh
scripts/betaflight-flight.sh --kill-firmware
echo "betaflight-check: passed"
