#!/usr/bin/env bash
# Wall time of a few test files without the compilation cache, with an empty one (cold) and
# with the cache the cold run filled (warm), one after the other; the load average next to each.
#   bash benchmarks/test_cache.sh [OUTDIR] [TEST FILES...]
# (issue 13; the run quoted in the README wrote benchmarks/results/test_cache/).
out=${1:-benchmarks/results/test_cache}; shift || true
files=${*:-tests/closedloop/test_engine.py tests/tune/test_optimiser.py}
mkdir -p "$out"; cache=$(mktemp -d)
for run in nocache cold warm; do
  if [ $run = nocache ]; then E="JTHERMO_NO_CACHE=1"; else E="JTHERMO_CACHE_DIR=$cache"; fi
  s=$(date +%s.%N)
  env $E .venv/bin/python -m pytest -q -p no:cacheprovider -m "not slow" $files --durations=8 > "$out/tests_$run.log" 2>&1
  e=$(date +%s.%N)
  echo "$run $(echo "$e - $s" | bc) load $(cut -d' ' -f1-3 /proc/loadavg)" >> "$out/times.txt"
done
rm -rf "$cache"
