#!/usr/bin/env python3
"""Checks a hilbench summary.json written by a run under Compose (docker/compose-check.sh,
docker/fault-test.sh): the runs are exactly the expected (scenario, controller) pairs, over gRPC
in the expected time mode, each reached the goal without a collision, and, with --fault, each
run recorded exactly one lost plant link that was held by the plant's watchdog. With
--collisions-from-s T, collisions at T s of plant time or later are listed but not failures: a
fault test injects its fault at T, after which the vehicle coasts under the plant's hover and
what it hits is the fault's outcome, not the link handling this check is about.

    check-summary.py runs/compose/summary.json --runs paper-2/nmpc paper-2/multistage
    check-summary.py runs/compose-fault/summary.json --runs paper-2/multistage \\
        --time-mode real-time --fault --min-outage-s 1.0

Exit code 0 when every check passes, 1 with one line per failed check otherwise.
"""

import argparse
import json
import sys


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("summary")
    parser.add_argument("--runs", nargs="+", required=True, help="scenario/controller, in order")
    parser.add_argument("--time-mode", default="lockstep")
    parser.add_argument("--fault", action="store_true", help="expect one recorded link fault per run")
    parser.add_argument("--min-outage-s", type=float, default=0.0)
    parser.add_argument(
        "--collisions-from-s",
        type=float,
        default=None,
        help="tolerate (and list) collisions at this plant time or later",
    )
    args = parser.parse_args()

    try:
        with open(args.summary, encoding="utf-8") as f:
            summary = json.load(f)
    except (OSError, ValueError) as e:
        print(f"{args.summary}: cannot read: {e}", file=sys.stderr)
        return 1

    problems = []
    runs = summary.get("runs") if isinstance(summary, dict) else None
    if not isinstance(runs, list):
        print(f"{args.summary}: no list of runs", file=sys.stderr)
        return 1
    got = [f"{r.get('scenario')}/{r.get('controller')}" for r in runs]
    if got != args.runs:
        problems.append(f"runs {got}, expected {args.runs}")
    if summary.get("transport") != "grpc":
        problems.append(f"transport {summary.get('transport')!r}, expected 'grpc'")
    if summary.get("time_mode") != args.time_mode:
        problems.append(f"time_mode {summary.get('time_mode')!r}, expected {args.time_mode!r}")
    for r in runs:
        name = f"{r.get('scenario')}/{r.get('controller')}"
        if r.get("reached") is not True:
            problems.append(f"{name}: did not reach the goal (time_to_goal_s {r.get('time_to_goal_s')})")
        if r.get("collided") is not False:
            collisions = r.get("collisions") if isinstance(r.get("collisions"), list) else []
            late = [
                c
                for c in collisions
                if args.collisions_from_s is not None
                and isinstance(c, dict)
                and isinstance(c.get("time_s"), (int, float))
                and c["time_s"] >= args.collisions_from_s
            ]
            if collisions and len(late) == len(collisions):
                print(f"  {name}: collided after the fault (tolerated): {collisions}")
            else:
                problems.append(f"{name}: collided: {r.get('collisions')}")
        losses = r.get("link_losses")
        down = r.get("longest_link_down_s")
        watchdog = r.get("watchdog_cycles")
        if args.fault:
            if losses != 1:
                problems.append(f"{name}: link_losses {losses}, expected 1")
            if not isinstance(down, (int, float)) or down < args.min_outage_s:
                problems.append(f"{name}: longest_link_down_s {down}, expected >= {args.min_outage_s}")
            if not isinstance(watchdog, int) or watchdog < 1:
                problems.append(f"{name}: watchdog_cycles {watchdog}, expected >= 1 (the plant held hover)")
        elif losses != 0:
            problems.append(f"{name}: link_losses {losses}, expected 0")
        print(
            f"  {name}: reached in {r.get('time_to_goal_s')} s, path {r.get('path_length_m')} m, "
            f"clearance {r.get('min_clearance_m')} m, link_losses {losses}, "
            f"link_down_s {r.get('link_down_s')}, watchdog_cycles {watchdog}"
        )
    for p in problems:
        print(f"{args.summary}: {p}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
