"""`experiments/diagnose_study.py` with the compilation cache on, as the `jthermo` command runs.

The study itself does not enable jthermo's cache directory, so the programs that a process
keeps there (`stored.exported_call`: the diagnosis's fits since session 27) would not be
exercised by it. This wrapper enables the cache (`runtime.enable_cache()`: `JTHERMO_CACHE_DIR`
or the per-user default) and the Threefry setting of the command, then runs the study with the
given arguments:

    JTHERMO_CACHE_DIR=/tmp/c python benchmarks/diagnose_study_cached.py --no-real \\
        --only ambient,radiation,delay_3s,lag_10s --out benchmarks/results --tag _s27_after
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

STUDY = Path(__file__).resolve().parent.parent / "experiments" / "diagnose_study.py"

if __name__ == "__main__":
    from jthermo import runtime

    runtime.enable_cache()
    runtime.unroll_threefry()
    sys.argv = [str(STUDY), *sys.argv[1:]]
    sys.path.insert(0, str(STUDY.parent))
    runpy.run_path(str(STUDY), run_name="__main__")
