#!/usr/bin/env bash
# `hilbench trace record` at 1 kHz on loopback (BENCHMARKS.md, "Recording at 1 kHz on
# loopback"; the issue's target: no probe lost): `trace echo` and `trace record` for SECONDS,
#   1. straight to the echo,
#   2. through netem's UDP proxy with a constant delay on the way to the echo (DELAY_MS) and
#      none back, each datagram on its own (`ordering = "independent"`),
# and for each the probes, losses, late and duplicate replies, the round trip's p50 / p99 /
# p99.9 / max, and the ticks the sender skipped (it skips, rather than bursts, a tick it
# woke more than a period late for). Prints the machine and its load (`uptime`) first.
#
#   scripts/bench-record.sh [SECONDS] [RATE_HZ]     (default 30 s at 1000 Hz)
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_EACH=${1:-30}
RATE=${2:-1000}
DELAY_MS=10

nice -n 5 cargo build --release -p hilbench -p netem
HB="${CARGO_TARGET_DIR:-target}"/release/hilbench
NETEM="${CARGO_TARGET_DIR:-target}"/release/netem
WORK=$(mktemp -d /tmp/bench-record.XXXXXX)
PIDS=()
cleanup() {
    for pid in "${PIDS[@]}"; do kill "$pid" 2>/dev/null || true; done
    rm -rf "$WORK"
}
trap cleanup EXIT

echo "machine: $(lscpu | sed -n 's/^Model name:[[:space:]]*//p' | head -1), $(nproc) cores, kernel $(uname -r)"
echo "load: $(uptime)"
echo "recording $SECONDS_EACH s at $RATE Hz"
echo

# A loopback UDP port nobody holds (the kernel's pick, let go).
free_port() {
    python3 -c 'import socket; s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# The provenance key $2 of trace file $1.
provenance() {
    sed -n "s/^# $2: //p" "$1" | head -1
}

# One line of numbers for trace file $1 (round trips less $2 ms).
summary() {
    local file=$1 less_ms=$2 stats
    stats=$("$HB" trace stats "$file" --json)
    jq -r --arg off "$less_ms" --arg late "$(provenance "$file" late)" \
        --arg dup "$(provenance "$file" duplicates)" --arg skipped "$(provenance "$file" ticks_skipped)" '
        def ms: (. * 1000 - ($off | tonumber)) * 1000 | round / 1000;
        "probes \(.count), lost \(.losses), late \($late), duplicates \($dup) | round trip" +
        (if ($off | tonumber) > 0 then " less \($off) ms" else "" end) +
        ": p50 \(.median_s | ms) ms, p99 \(.p99_s | ms) ms, p99.9 \(.p999_s | ms) ms, max \(.max_s | ms) ms" +
        " | ticks skipped \(if $skipped == "" then 0 else $skipped end)"' <<<"$stats"
}

ECHO_ADDR=127.0.0.1:$(free_port)
"$HB" --quiet trace echo --listen "$ECHO_ADDR" &
PIDS+=($!)
sleep 0.5

echo -n "straight to the echo: "
"$HB" --quiet trace record --target "$ECHO_ADDR" --rate-hz "$RATE" --duration-s "$SECONDS_EACH" \
    --out "$WORK/direct.csv"
summary "$WORK/direct.csv" 0

cat >"$WORK/link.toml" <<EOF
kind = "constant"
delay_s = $(awk -v d="$DELAY_MS" 'BEGIN { print d / 1000 }')
ordering = "independent"
EOF
UDP_ADDR=127.0.0.1:$(free_port)
CONTROL_ADDR=127.0.0.1:$(free_port)
"$NETEM" --listen "$CONTROL_ADDR" --udp-listen "$UDP_ADDR" --udp-forward "$ECHO_ADDR" \
    --udp-plant-side forward --profile-file "$WORK/link.toml" >"$WORK/netem.log" 2>&1 &
PIDS+=($!)
sleep 1

echo -n "through netem's UDP proxy, constant $DELAY_MS ms on the way out: "
"$HB" --quiet trace record --target "$UDP_ADDR" --rate-hz "$RATE" --duration-s "$SECONDS_EACH" \
    --out "$WORK/netem.csv"
summary "$WORK/netem.csv" "$DELAY_MS"
echo
echo "load after: $(uptime)"
