#!/usr/bin/env bash
# README's two commands share one build: after `cargo test --workspace --release` has built,
# `cargo build --release -p hilbench` (what `cargo run --release -p hilbench` builds) must find
# every unit fresh. A unit it compiles again means a package build resolves some crate's cargo
# features differently from the workspace build (a feature of a workspace crate, or a
# third-party feature the workspace-hack crate does not pin): see docs/building.md.
#
# Usage: scripts/check-one-build.sh   (builds the test targets first when they are missing)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

cargo test --workspace --release --no-run --quiet
report="$(cargo build --release -p hilbench --message-format=json --quiet)"
stale="$(printf '%s\n' "$report" | python3 -c '
import json, sys
for line in sys.stdin:
    line = line.strip()
    if not line.startswith("{"):
        continue
    message = json.loads(line)
    if message.get("reason") == "compiler-artifact" and not message.get("fresh", True):
        target = message["target"]
        print(message["package_id"], "(" + ",".join(target["kind"]), target["name"] + ")")
')"
if [ -n "$stale" ]; then
    echo "check-one-build: \`cargo build --release -p hilbench\` after the workspace's test build compiled again:" >&2
    printf '%s\n' "$stale" | sed 's/^/  /' >&2
    echo "check-one-build: a package build resolves these crates' features unlike the workspace build (docs/building.md)" >&2
    exit 1
fi
echo "check-one-build: \`cargo build --release -p hilbench\` after the workspace's test build compiled nothing"
