#!/usr/bin/env bash
# The fail-safe check's lost time (issue 39; docs/robustness.md, "Where that time goes";
# BENCHMARKS.md's target row): the same runs flown with the fail-safe check and with the plan
# check, in process, compared run by run where both reached the goal without a collision:
#   1. the survey, scenarios/sweeps/paper-2-delays.toml and its -plan-check twin (120 runs);
#   2. each field of scenarios/fields/ (paper-2-field first) and the same file with
#      `fail_safe = false` (RUNS runs each; FIELDS="paper-2-field ..." picks some).
# Prints per campaign each side's collisions, overrides (fallback cycles) per run, best-effort
# cycles, worst clearance, and the median time-to-goal and path-length ratios (fail-safe /
# plan check) with their 10th and 90th percentiles and a 95 % bootstrap interval of each median
# (2,000 resamples of the runs, seeded: the median of a few hundred chaotic runs moves by a
# few percent, which is the size of the target), the time ratio per delay family, and both
# ratios by how near the plan check's run came to a cylinder (its min_clearance_m).
# Lockstep runs are deterministic: the same commit prints the same numbers on any machine.
#
#   scripts/bench-lost-time.sh [RUNS] [JOBS]     (default 250 field runs, 2 at once)
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS=${1:-250}
JOBS=${2:-2}

nice -n 5 cargo build --release -p hilbench
HB="${CARGO_TARGET_DIR:-target}"/release/hilbench
WORK=$(mktemp -d /tmp/bench-lost-time.XXXXXX)
trap 'rm -rf "$WORK"' EXIT
echo "commit: $(git rev-parse --short HEAD 2>/dev/null || echo unknown)"

FIELDS=${FIELDS:-paper-2-field paper-1-field staggered-slalom narrow-gap asymmetric-single}
for field in $FIELDS; do
    sed 's/^fail_safe = true$/fail_safe = false/' "scenarios/fields/$field.toml" > "$WORK/$field-plan-check.toml"
    grep -q '^fail_safe = false$' "$WORK/$field-plan-check.toml" || { echo "$field.toml: no 'fail_safe = true' line to turn off" >&2; exit 1; }
done

sweep() { "$HB" sweep "$1" --jobs "$JOBS" --no-plots --quiet --out "$2" "${@:3}"; }
sweep scenarios/sweeps/paper-2-delays.toml "$WORK/survey-fail-safe"
sweep scenarios/sweeps/paper-2-delays-plan-check.toml "$WORK/survey-plan-check"
for field in $FIELDS; do
    sweep "scenarios/fields/$field.toml" "$WORK/$field-fail-safe" --runs "$RUNS"
    sweep "$WORK/$field-plan-check.toml" "$WORK/$field-plan-check" --runs "$RUNS"
done

compare() {
    python3 - "$1" "$2" "$3" <<'PY'
import csv, random, statistics, sys

name, fail_safe_dir, plan_check_dir = sys.argv[1:4]
def runs(d):
    with open(d + "/runs.csv") as f:
        return {r["run"]: r for r in csv.DictReader(f)}
fs, pc = runs(fail_safe_dir), runs(plan_check_dir)
def clear(r):
    return r["outcome"] == "reached" and float(r["min_clearance_m"]) > 0
def quantile(v, q):
    v = sorted(v)
    return v[int(q * (len(v) - 1))]
def median_interval(v):
    # The 95 % percentile-bootstrap interval of the median, seeded so that the same runs print
    # the same interval.
    rng = random.Random(0)
    medians = sorted(statistics.median(rng.choices(v, k=len(v))) for _ in range(2000))
    return medians[49], medians[1949]
def median_with_interval(v):
    lo, hi = median_interval(v)
    return f"{statistics.median(v):.3f} [95 % {lo:.3f}-{hi:.3f}]"
print(f"{name}:")
for label, d in (("fail-safe", fs), ("plan check", pc)):
    rs = list(d.values())
    print(f"  {label:10}: {len(rs)} runs, {sum(r['outcome'] == 'collided' for r in rs)} collided, "
          f"{sum(int(r['fallbacks']) for r in rs) / len(rs):.2f} overrides a run, "
          f"{sum(int(r['best_effort_cycles']) for r in rs)} best-effort cycles, "
          f"worst clearance {min(float(r['min_clearance_m']) for r in rs):+.3f} m")
time, path, by_family = [], [], {}
# By how near the plan check's run came to a cylinder: where it cut into its own margin the
# fail-safe controller, which keeps it, flies the longer way round.
BANDS = ((0.0, 0.05), (0.05, 0.1), (0.1, 0.15), (0.15, 0.2), (0.2, float("inf")))
by_band = {band: ([], []) for band in BANDS}
for k, a in fs.items():
    b = pc.get(k)
    if b is None or not (clear(a) and clear(b)):
        continue
    t = float(a["time_to_goal_s"]) / float(b["time_to_goal_s"])
    p = float(a["path_length_m"]) / float(b["path_length_m"])
    time.append(t)
    path.append(p)
    by_family.setdefault(a["family"], []).append(t)
    clearance = float(b["min_clearance_m"])
    for lo, hi in BANDS:
        if lo <= clearance < hi:
            by_band[(lo, hi)][0].append(t)
            by_band[(lo, hi)][1].append(p)
if not time:
    sys.exit(f"{name}: no run reached the goal clear both ways")
print(f"  both clear: {len(time)}; time ratio median {median_with_interval(time)} "
      f"(p10-p90 {quantile(time, .1):.2f}-{quantile(time, .9):.2f}), path ratio median "
      f"{median_with_interval(path)} (p10-p90 {quantile(path, .1):.2f}-{quantile(path, .9):.2f})")
print("  time ratio by family: " + ", ".join(
    f"{f} {statistics.median(v):.3f}" for f, v in sorted(by_family.items())))
print("  by the plan check's clearance (runs: time / path ratio medians): " + ", ".join(
    f"[{lo:.2f}, {hi:.2f}) m {len(t)}: {statistics.median(t):.3f} / {statistics.median(p):.3f}"
    for (lo, hi), (t, p) in by_band.items() if t))
kept = [(t, p) for (lo, _), (ts, ps) in by_band.items() if lo >= 0.1 for t, p in zip(ts, ps)]
if kept:
    print(f"  where the plan check kept 0.1 m or more: {len(kept)} runs, time ratio median "
          f"{median_with_interval([t for t, _ in kept])}, path {median_with_interval([p for _, p in kept])}")
PY
}
compare "survey (paper-2-delays, 120 runs)" "$WORK/survey-fail-safe" "$WORK/survey-plan-check"
for field in $FIELDS; do
    compare "$field ($RUNS runs)" "$WORK/$field-fail-safe" "$WORK/$field-plan-check"
done
