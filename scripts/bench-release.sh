#!/usr/bin/env bash
# Release precision, side by side on this machine (BENCHMARKS.md, "Release precision"):
#   1. the machine's floor, bare clock_nanosleep wake-ups at netem's own release deadlines,
#   2. netem's release error in its gRPC path and in its UDP path (--udp-listen) at each rate,
#      constant and Gamma delays,
#   3. Linux `tc netem` on a veth pair between two network namespaces, where the kernel has
#      sch_netem (constant delay, ping at the rate: round trip minus the delay and the pair's
#      own round trip without netem),
# and the plant's real-time step jitter at 1 kHz; idle, then with another process holding one
# core (a shell busy loop). Run as root (SCHED_FIFO, network namespaces).
#
#   scripts/bench-release.sh [SECONDS]        (default 20 s per measurement)
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_EACH=${1:-20}
RATES=50,1000
DELAY_MS=20

nice -n 5 cargo build --release -p lab
LAB="${CARGO_TARGET_DIR:-target}"/release/lab

echo "machine: $(lscpu | sed -n 's/^Model name:[[:space:]]*//p' | head -1), $(nproc) cores, kernel $(uname -r)"
echo

# --- tc netem ------------------------------------------------------------------------------
A=hb-rel-a
B=hb-rel-b
cleanup_ns() {
    ip netns del "$A" 2>/dev/null || true
    ip netns del "$B" 2>/dev/null || true
}
HOG=
cleanup() {
    cleanup_ns
    if [[ -n "$HOG" ]]; then kill "$HOG" 2>/dev/null || true; fi
}
trap cleanup EXIT

# Percentiles (p50 p99 max, µs) of the round trips ping printed (ms), less $1 ms.
ping_lateness() {
    sed -n 's/.*time=\([0-9.]*\) ms.*/\1/p' | awk -v off="$1" '{ v[NR] = ($1 - off) * 1000 }
        END { n = asort(v); if (n == 0) { print "no replies"; exit }
              i50 = int(0.50 * n + 0.999); i99 = int(0.99 * n + 0.999);
              printf "n %d | p50 %.1f | p99 %.1f | max %.1f µs\n", n, v[i50], v[i99], v[n] }'
}

tc_netem() {
    local label=$1
    if ! command -v tc >/dev/null || ! command -v ip >/dev/null; then
        echo "tc netem ($label): not measured: tc or ip is missing (apt-get install iproute2)"
        return
    fi
    cleanup_ns
    if ! { ip netns add "$A" && ip netns add "$B" &&
        ip link add veth-a netns "$A" type veth peer name veth-b netns "$B" &&
        ip -n "$A" addr add 10.99.0.1/24 dev veth-a && ip -n "$B" addr add 10.99.0.2/24 dev veth-b &&
        ip -n "$A" link set veth-a up && ip -n "$B" link set veth-b up; } 2>/tmp/bench-release-ns.err; then
        echo "tc netem ($label): not measured: no network namespaces or veth here ($(tr '\n' ' ' </tmp/bench-release-ns.err))"
        cleanup_ns
        return
    fi
    if ! ip netns exec "$A" tc qdisc add dev veth-a root netem delay "${DELAY_MS}ms" 2>/tmp/bench-release-tc.err; then
        echo "tc netem ($label): not measured: this kernel has no sch_netem ($(tr '\n' ' ' </tmp/bench-release-tc.err | sed 's/ *$//'))"
        cleanup_ns
        return
    fi
    if ! command -v ping >/dev/null; then
        echo "tc netem ($label): not measured: ping is missing (apt-get install iputils-ping)"
        cleanup_ns
        return
    fi
    ip netns exec "$A" tc qdisc del dev veth-a root
    local base
    base=$(ip netns exec "$A" ping -q -c 200 -i 0.005 10.99.0.2 | sed -n 's|.*= [0-9.]*/\([0-9.]*\)/.*|\1|p')
    ip netns exec "$A" tc qdisc add dev veth-a root netem delay "${DELAY_MS}ms"
    for rate in ${RATES//,/ }; do
        local count interval
        count=$(awk -v r="$rate" -v s="$SECONDS_EACH" 'BEGIN { printf "%d", r * s }')
        interval=$(awk -v r="$rate" 'BEGIN { printf "%.4f", 1 / r }')
        echo -n "tc netem ($label), $rate Hz, constant $DELAY_MS ms (round trip less $DELAY_MS ms and the $base ms without netem): "
        ip netns exec "$A" ping -c "$count" -i "$interval" 10.99.0.2 | ping_lateness "$(awk -v d="$DELAY_MS" -v b="$base" 'BEGIN { print d + b }')"
    done
    echo "tc netem ($label): Gamma not measured: tc netem has no Gamma law (only its normal, pareto and paretonormal tables)"
    cleanup_ns
}

# --- idle, then with a core held -----------------------------------------------------------
for label in idle "one core held by a busy loop"; do
    if [[ $label != idle ]]; then
        sh -c 'while :; do :; done' &
        HOG=$!
    fi
    echo "=== $label ==="
    tc_netem "$label"
    "$LAB" load release --seconds "$SECONDS_EACH" --rates-hz "$RATES" --delay-ms "$DELAY_MS"
    echo
    if [[ -n "$HOG" ]]; then
        kill "$HOG"
        wait "$HOG" 2>/dev/null || true
        HOG=
    fi
done
