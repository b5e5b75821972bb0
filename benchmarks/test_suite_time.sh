#!/usr/bin/env bash
# Wall and CPU time of `make test`'s command (pytest -n 2 --dist loadfile -m "not slow") with a
# compilation cache of its own: empty at the start (cold, as on a machine that never ran the
# tests), then the same command again on the cache it filled (warm); the load average before and
# after each, and a per-test timeline (benchmarks/test_timeline.py: JAX's program making too)
# summed by file.
#   bash benchmarks/test_suite_time.sh [cold|warm|both]
#   bash benchmarks/test_suite_time.sh report LOGS [cold|warm|both]   # the report again from LOGS
# Run from the repository root, the venv built (make .venv/.installed). Writes
# benchmarks/results/test_suite_time.md (a headline table, the times and the per-file tables);
# the logs stay in a temporary folder, printed at the end.
set -u
report=benchmarks/results/test_suite_time.md
if [ "${1:-}" = report ]; then
  out=$2; mode=${3:-both}
else
  mode=${1:-both}
  out=$(mktemp -d /tmp/jthermo-test-suite-time.XXXX)
fi
runs=$([ "$mode" = both ] && echo "cold warm" || echo "$mode")
if [ "${1:-}" != report ]; then
  cache=$(mktemp -d /tmp/jthermo-tests-cache.XXXX)
  for run in $runs; do
    rm -f "$out/timeline_$run.jsonl"
    la0=$(cut -d' ' -f1-3 /proc/loadavg)
    s=$(date +%s.%N)
    { time JTHERMO_CACHE_DIR=$cache JTHERMO_TIMELINE="$out/timeline_$run.jsonl" PYTHONPATH=benchmarks${PYTHONPATH:+:$PYTHONPATH} \
        .venv/bin/python -m pytest -n 2 --dist loadfile -m "not slow" -p no:cacheprovider \
        -p test_timeline --durations=40 > "$out/pytest_$run.log" 2>&1 ; } 2> "$out/time_$run.txt"
    e=$(date +%s.%N)
    echo "$run $(git rev-parse --short HEAD) wall $(echo "$e - $s" | bc) load_before $la0 load_after $(cut -d' ' -f1-3 /proc/loadavg) $(tr '\n' ' ' < "$out/time_$run.txt") | $(tail -1 "$out/pytest_$run.log")" >> "$out/times.txt"
  done
  rm -rf "$cache"
fi
summary=benchmarks/test_timeline_summary.py
{
  echo '# `make test` wall and CPU time, cold and warm'
  echo
  echo "\`bash benchmarks/test_suite_time.sh $mode\`: make test's command on a compilation cache of its own (cold: empty). Seconds of the xdist workers; \"programs made\" are JAX's backend compiles, a read from the persistent cache included; \"the rest\" is running the tests (Python, XLA, their subprocesses)."
  echo
  .venv/bin/python $summary --headline $(for run in $runs; do echo "$run=$out/timeline_$run.jsonl"; done)
  echo
  echo "One line per run (wall s, load before and after, time, pytest's summary):"
  echo
  sed 's/^/    /' "$out/times.txt"
  for run in $runs; do echo; echo "## $run: seconds per test file"; echo; .venv/bin/python $summary "$out/timeline_$run.jsonl"; done
} > "$report"
echo "logs: $out; report: $report"
