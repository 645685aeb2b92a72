#!/usr/bin/env bash
# The firmware-in-the-loop checks: builds (or finds cached) Betaflight 4.6.0 SITL with
# scripts/betaflight-sitl.sh, then runs the tests that need the real firmware, each required
# (HILBENCH_REQUIRE_SITL=1): the MSP core against the firmware (msp), the Betaflight vehicle
# (bfsim: MSP and motor packets, a hover armed over MSP in ANGLE mode, no SITL left behind, the
# pose stream read by pymavlink) and the gateway's MSP side (arms on request, attitude, the
# watchdog). One SITL runs at a time (fixed ports; the tests take a lock). On a loaded 2-core
# machine the firmware misses RC and MSP deadlines (docs/betaflight.md): run it on a quiet one.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
binary="$(scripts/betaflight-sitl.sh)"
echo "betaflight-check: SITL at $binary"
export HILBENCH_REQUIRE_SITL=1 HILBENCH_BETAFLIGHT_SITL="$binary"
cargo test --workspace --release --test sitl --test betaflight_sitl -- --test-threads 1
echo "betaflight-check: passed"
