#!/usr/bin/env bash
# Before/after of test files in one window: for each round, the files as at commit BEFORE (the
# library and test files FILES checked out from it into the work tree, restored after) then as
# at HEAD, each cold and warm (benchmarks/test_file_time.sh).
#   bash benchmarks/test_file_ab.sh OUTDIR BEFORE "jthermo/x.py tests/y.py" tests/y.py [...]
set -u
out=$1; before=$2; files=$3; shift 3
for round in 1; do
  git checkout "$before" -- $files
  bash benchmarks/test_file_time.sh "$out" before "$@"
  git checkout HEAD -- $files
  bash benchmarks/test_file_time.sh "$out" after "$@"
done
