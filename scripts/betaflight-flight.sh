#!/usr/bin/env bash
# Real flight firmware in the bench's loop, end to end: hilbench run -> netem -> gateway --msp
# -> Betaflight 4.6.0 SITL (the real firmware) -> bfsim's rigid-body quadrotor, in real time.
#
#   scripts/betaflight-flight.sh [--kill-firmware] [--mode nmpc|multistage] [--attitude-from firmware|pose]
#                                [--hover-throttle-us US] [SCENARIO.toml] [OUT_DIR]
#
# 1. Builds (or finds cached) the SITL with scripts/betaflight-sitl.sh and builds bfsim, the
#    gateway, vehiclectl and hilbench (release).
# 2. Starts bfsim at the scenario's start and the gateway on the firmware's MSP port, arms the
#    firmware (`vehiclectl arm-offboard`, retried while it is in boot grace or calibration) and
#    flies the scenario (default scenarios/fields/paper-2-field.toml: paper-2 with the bench's
#    defaults for files) with the file's controllers (or --mode's), the file's delays between
#    the controller and the gateway; prints the run's summary. Whether it
#    reaches the goal is the finding, printed, not the check's verdict: the check fails when the
#    chain does not fly (no summary, no cycles, a plant that does not name the firmware).
# 3. With --kill-firmware, instead: kills the firmware (the SITL process) 3 s into the run; the
#    run must end within seconds with an error, not fly on: the firmware was really in the loop.
#
# One vehicle per invocation: a SITL started again within a minute of the last one's end was
# seen stuck in BOOTGRACE, answering no state packet (3 of 3 tries here; docs/betaflight.md).
#
# The hover throttle passed to the gateway is the one measured on this vehicle (bfsim's rigid
# body under the firmware's ANGLE mode: docs/betaflight.md, section 7).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

kill_firmware=false
mode_args=()
attitude_from=firmware
# Measured on this vehicle (bfsim's rigid body under the firmware's ANGLE mode: docs/betaflight.md,
# section 7).
hover_throttle_us=1576
while [ $# -gt 0 ]; do
    case "$1" in
        --kill-firmware) kill_firmware=true; shift ;;
        --mode) mode_args=(--mode "$2"); shift 2 ;;
        --attitude-from) attitude_from="$2"; shift 2 ;;
        --hover-throttle-us) hover_throttle_us="$2"; shift 2 ;;
        --*) echo "betaflight-flight: unknown option $1" >&2; exit 2 ;;
        *) break ;;
    esac
done
scenario="${1:-scenarios/fields/paper-2-field.toml}"
out="${2:-$(mktemp -d -t hilbench-betaflight-XXXXXX)}"
target="${CARGO_TARGET_DIR:-target}/release"
readonly GATEWAY=127.0.0.1:50054

sitl="$(scripts/betaflight-sitl.sh)"
cargo build --release --quiet -p bfsim -p gateway -p hilbench
mkdir -p "$out"
pids=()
cleanup() {
    for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
    wait 2>/dev/null || true
}
trap cleanup EXIT

# Starts bfsim and the gateway, and arms the firmware; `log` names the logs' prefix.
start_vehicle() {
    local log="$1"
    "$target/bfsim" --sitl "$sitl" --scenario "$scenario" >"$out/$log-bfsim.log" 2>&1 &
    pids+=("$!")
    for _ in $(seq 100); do
        grep -q "bfsim: up" "$out/$log-bfsim.log" 2>/dev/null && break
        sleep 0.2
    done
    grep -q "bfsim: up" "$out/$log-bfsim.log" || { cat "$out/$log-bfsim.log" >&2; echo "betaflight-flight: bfsim did not come up" >&2; exit 1; }
    "$target/gateway" --msp tcp:127.0.0.1:5761 --pose-in 127.0.0.1:14560 --scenario "$scenario" \
        --hover-throttle-us "$hover_throttle_us" --attitude-from "$attitude_from" --listen "$GATEWAY" >"$out/$log-gateway.log" 2>&1 &
    pids+=("$!")
    local armed=false
    for _ in $(seq 8); do
        if "$target/vehiclectl" --gateway "$GATEWAY" --wait-s 10 arm-offboard >>"$out/$log-arm.log" 2>&1; then
            armed=true
            break
        fi
        sleep 1
    done
    $armed || { cat "$out/$log-arm.log" >&2; echo "betaflight-flight: the firmware would not arm" >&2; exit 1; }
}

stop_vehicle() {
    cleanup
    pids=()
}

if ! $kill_firmware; then
# 2. A flight.
start_vehicle flight
set +e
"$target/hilbench" run "$scenario" "${mode_args[@]}" --time-mode real-time --plant "$GATEWAY" \
    --start-from-vehicle --out "$out/flight" --no-plots
status=$?
set -e
stop_vehicle
[ -f "$out/flight/summary.json" ] || { echo "betaflight-flight: no summary.json (exit $status)" >&2; exit 1; }
python3 - "$out/flight/summary.json" <<'EOF'
import json, sys
summary = json.load(open(sys.argv[1]))
for run in summary["runs"]:
    print(f"betaflight-flight: plant: {run['plant']}")
    print(f"betaflight-flight: {run['scenario']} {run['controller']}: reached {run['reached']}, collided {run['collided']}, "
          f"end {run['end_reason']}, path {run['path_length_m']:.2f} m, min clearance {run['min_clearance_m']:+.3f} m, "
          f"{run['cycles']} cycles, round trip median {run['end_to_end_latency_ms']['median']:.0f} ms")
    for line in run["explanation"]:
        print(f"betaflight-flight:   {line}")
    if "BTFL 4.6.0" not in run["plant"]:
        sys.exit("betaflight-flight: the run's plant does not name the firmware")
    if run["cycles"] < 20:
        sys.exit(f"betaflight-flight: only {run['cycles']} cycles flew")
EOF
# The command's path by hop, from the run's cycle logs and the two logs' latency lines.
python3 - "$out/flight" "$out/flight-gateway.log" "$out/flight-bfsim.log" <<'EOF'
import csv, glob, re, statistics, sys
flight, gateway_log, bfsim_log = sys.argv[1:4]
rows = [r for f in sorted(glob.glob(f"{flight}/*.csv")) for r in csv.DictReader(open(f))]
def med(xs):
    return f"{statistics.median(xs):.2f}" if xs else "-"
solve = [float(r["solve_ms"]) for r in rows]
netem = [float(r["injected_delay_s"]) * 1e3 for r in rows if r["injected_delay_s"]]
def line(path, prefix):
    hits = [l for l in open(path) if prefix in l]
    return hits[-1] if hits else ""
hold = dict(re.findall(r"hold_ms_(\w+)=([\d.]+|-)", line(gateway_log, "command to RC frame")))
motor = dict(re.findall(r"latency_ms_(\w+)=([\d.]+|-)", line(bfsim_log, "bfsim: shutdown")))
print("betaflight-flight: the command's path by hop (median ms): "
      f"controller solve {med(solve)}; netem {med(netem)}; gateway, command to RC frame {hold.get('median', '-')} "
      f"(p99 {hold.get('p99', '-')}); firmware, state packet to motor packet {motor.get('median', '-')} (p99 {motor.get('p99', '-')})")
EOF
echo "betaflight-flight: passed (outputs in $out)"
exit 0
fi

# 3. The firmware killed mid-run.
start_vehicle kill
"$target/hilbench" run "$scenario" "${mode_args[@]}" --time-mode real-time --plant "$GATEWAY" \
    --start-from-vehicle --out "$out/killed" --no-plots --quiet &
run_pid=$!
sleep 3
if ! kill -0 "$run_pid" 2>/dev/null; then
    wait "$run_pid" || true
    echo "betaflight-flight: the run ended before the firmware was killed (see $out/killed/summary.json)" >&2
    exit 1
fi
sitl_pid="$(grep -o 'sitl_pid=[0-9]*' "$out/kill-bfsim.log" | head -1 | cut -d= -f2)"
[ -n "$sitl_pid" ] && kill -KILL "$sitl_pid" || { echo "betaflight-flight: no SITL process to kill" >&2; exit 1; }
killed_at=$(date +%s)
set +e
wait "$run_pid"
status=$?
set -e
ended_after=$(( $(date +%s) - killed_at ))
stop_vehicle
error="$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["error"])' "$out/killed/summary.json" 2>/dev/null || echo "no summary.json")"
echo "betaflight-flight: firmware killed 3 s into the run: hilbench exited $status after ${ended_after} s: $error"
if [ "$status" -eq 0 ] || [ "$ended_after" -gt 30 ]; then
    echo "betaflight-flight: the run did not end with an error soon after the firmware died" >&2
    exit 1
fi
echo "betaflight-flight: passed (outputs in $out)"
