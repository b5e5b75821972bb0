"""Which diagnoses could the finite χ² evidence tail (`decide.chi2_log_tail`) change? (issue 14)

Before it, `decide.prefer_evidence` and `joint.forward_select` ranked candidates by
`scipy.stats.chi2.logsf`, which is $-\\infty$ above a likelihood ratio of about 1400: ties then
kept the validation order. This wrapper runs another experiment script unchanged (its arguments
after `--`) with two spies installed:

- every `prefer_evidence` call also computes the old ranking (SciPy's `logsf`); a call whose first
  row differs is a **changed** top;
- every `chi2_log_tail` call from the joint forward selection whose SciPy value underflows is
  counted; a diagnosis with at most one such call per run cannot have had two underflowing passing
  additions in a round, so its additions are as before (more: **possibly changed**, compare).

After each diagnosis one line `SCREEN {...}` is printed (and appended to `--log`). A diagnosis
with neither is identical to the one before the change (the procedure is deterministic).

    .venv/bin/python experiments/diagnose_evidence_screen.py --log /tmp/screen.jsonl -- \\
        experiments/diagnose_heldout_hard.py --seed-set 20 --only lamp_saturation --cases 95 --tag x
"""

from __future__ import annotations

import argparse
import json
import runpy
import sys
import traceback

import numpy as np
from scipy.stats import chi2

import jthermo.diagnose as JD
from jthermo.diagnose import decide as D
from jthermo.diagnose import select as S

STATE = {"top_changed": [], "joint_underflow": 0}


def old_prefer_evidence(rows, tied, dof):
    """`prefer_evidence` as it was: evidence by SciPy's `chi2.logsf` (underflowing)."""
    saved = D.chi2_log_tail
    D.chi2_log_tail = lambda x, k: float(chi2.logsf(x, max(int(k), 1)))
    try:
        return ORIG_PREFER(rows, tied, dof)
    finally:
        D.chi2_log_tail = saved


ORIG_PREFER = D.prefer_evidence
ORIG_TAIL = D.chi2_log_tail


def spy_prefer(rows, tied, dof):
    new = ORIG_PREFER(rows, tied, dof)
    old = old_prefer_evidence(rows, tied, dof)
    if new and old and new[0]["mechanism"] != old[0]["mechanism"]:
        STATE["top_changed"].append({"old": old[0]["mechanism"], "new": new[0]["mechanism"],
                                     "lr": {r["mechanism"]: round(float(r["estimation_lr"]), 1) for r in rows}})
    return new


def spy_tail(x, k):
    caller = sys._getframe(1).f_code.co_name
    if caller == "forward_select" and not np.isfinite(chi2.logsf(x, max(int(k), 1))):
        STATE["joint_underflow"] += 1
    return ORIG_TAIL(x, k)


def main():
    argv = sys.argv[1:]
    if "--" not in argv:
        raise SystemExit("usage: diagnose_evidence_screen.py --log FILE -- SCRIPT ARGS...")
    k = argv.index("--")
    ap = argparse.ArgumentParser()
    ap.add_argument("--log", required=True)
    a = ap.parse_args(argv[:k])
    script, rest = argv[k + 1], argv[k + 2:]
    D.prefer_evidence = spy_prefer
    D.chi2_log_tail = spy_tail
    orig_diag = S.diagnose

    def diag(*args, **kw):
        STATE["top_changed"], STATE["joint_underflow"] = [], 0
        res = orig_diag(*args, **kw)
        line = {"script": script, "args": rest, "named": [f["mechanism"] for f in res["findings"]],
                "top_changed": STATE["top_changed"], "joint_underflow_calls": STATE["joint_underflow"],
                "verdict": ("changed" if STATE["top_changed"] else
                            "possibly changed" if STATE["joint_underflow"] > 1 else "unchanged")}
        print("SCREEN " + json.dumps(line), flush=True)
        with open(a.log, "a") as f:
            f.write(json.dumps(line) + "\n")
        return res

    JD.diagnose = diag
    S.diagnose = diag
    sys.argv = [script] + rest
    try:
        runpy.run_path(script, run_name="__main__")
    except SystemExit as e:
        return e.code or 0
    except Exception:
        traceback.print_exc()
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
