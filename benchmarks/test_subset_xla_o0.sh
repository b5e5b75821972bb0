#!/bin/bash
# Cold-cache CPU seconds of a test subset (the closed-loop and printer tests) with XLA's
# default backend optimisation and with --xla_backend_optimization_level=0 (issue 13 item 3:
# the suite is compile-bound on a cold cache). Each run gets a fresh JTHERMO_CACHE_DIR.
#     bash benchmarks/test_subset_xla_o0.sh > benchmarks/results/test_subset_xla_o0.md
set -u
cd "$(dirname "$0")/.."
TESTS="tests/closedloop tests/printer/test_plant.py"
echo "# Test subset, cold compilation cache: XLA default vs --xla_backend_optimization_level=0"
echo
echo "\`bash benchmarks/test_subset_xla_o0.sh\`: \`pytest -m 'not slow' $TESTS\`, one process, each run"
echo "with an empty cache directory; 2 shared cores (wall follows the load, CPU s much less)."
echo
echo "| XLA_FLAGS | result | wall s | CPU s (user+sys) | load before | load after |"
echo "|---|---|---|---|---|---|"
for flags in "" "--xla_backend_optimization_level=0"; do
    dir=$(mktemp -d)
    l0=$(cut -d' ' -f1 /proc/loadavg)
    out=$(JTHERMO_CACHE_DIR=$dir XLA_FLAGS="$flags" /usr/bin/time -f "TIME %e %U %S" \
          .venv/bin/pytest -q -p no:cacheprovider -m "not slow" $TESTS 2>&1)
    t=$(echo "$out" | grep "^TIME" | tail -1)
    res=$(echo "$out" | grep -Eo "[0-9]+ (passed|failed)[^=]*" | tail -1)
    echo "| ${flags:-(default)} | ${res:-see log} | $(echo $t | awk '{print $2}') | $(echo $t | awk '{printf "%.1f", $3+$4}') | $l0 | $(cut -d' ' -f1 /proc/loadavg) |"
    rm -rf "$dir"
done
