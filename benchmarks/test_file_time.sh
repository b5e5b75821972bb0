#!/usr/bin/env bash
# CPU and wall time of one or more test files run alone (no xdist), cold (an empty compilation
# cache of its own) then warm (the same cache again), with each test's cost (test_cost.py).
#   bash benchmarks/test_file_time.sh OUTDIR LABEL tests/a.py [tests/b.py ...]
# Appends one line per run to OUTDIR/times.txt: label, commit, run, wall, user, sys, load before/after.
set -u
out=$(realpath -m "$1"); label=$2; shift 2
mkdir -p "$out"
cache=$(mktemp -d /tmp/jthermo-file-cache.XXXX)
for run in cold warm; do
  la0=$(cut -d' ' -f1-3 /proc/loadavg)
  cost="$out/cost_${label}_$run.jsonl"; rm -f "$cost"
  /usr/bin/time -f "wall %e user %U sys %S" -o "$out/time.tmp" env JTHERMO_CACHE_DIR=$cache \
    JTHERMO_TEST_COST="$cost" PYTHONPATH=benchmarks .venv/bin/python -m pytest "$@" \
    -p no:cacheprovider -p test_cost --durations=15 > "$out/pytest_${label}_$run.log" 2>&1
  echo "$label $(git rev-parse --short HEAD) $run $(cat "$out/time.tmp") load $la0 / $(cut -d' ' -f1-3 /proc/loadavg) | $(grep -E "passed|failed|error" "$out/pytest_${label}_$run.log" | tail -1)" >> "$out/times.txt"
  tail -1 "$out/times.txt"
done
rm -rf "$cache" "$out/time.tmp"
