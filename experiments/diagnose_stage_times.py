"""Where a diagnosis's time goes, stage by stage, on the README tour's kind of record at N zones
(the records of `diagnose_zone_scaling.py`), in one process with the command's compilation
cache (`runtime.enable_cache`, `JTHERMO_CACHE_DIR`; run it twice for a warm second process):
wall and CPU seconds from the start to each progress tick (`diagnose(progress=...)`)
and the joint stage's fits (`joint.JointFits.fit`: calls, models, restricted or not, Jacobian width).

    .venv/bin/python experiments/diagnose_stage_times.py --zones 16

Writes `experiments/results/diagnose_stage_times.md`.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from jthermo import runtime
from jthermo.cli.common import load_data
from jthermo.diagnose import joint as J
from jthermo.diagnose import select as S

HERE = Path(__file__).resolve().parent
EFFECTS = "lateral_conduction,radiative_loss,heater_lag"


def cpu() -> float:
    t = time.process_time()
    return t


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--zones", type=int, default=16)
    args = ap.parse_args(argv)
    n = args.zones
    cache = runtime.enable_cache()
    warm = cache is not None and any(Path(cache).glob("*-cache"))
    rows, fits = [], []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for name, dur, seed in (("est.csv", "3600", "1"), ("val.csv", "1800", "2")):
            subprocess.run([sys.executable, "-m", "jthermo.cli", "generate", "--zones", str(n), "--effects",
                            EFFECTS, "--duration", dur, "--seed", seed, "--out", str(d / name), "--quiet"],
                           check=True)
        est, val = load_data(str(d / "est.csv"), "e"), load_data(str(d / "val.csv"), "v")
        t0, c0 = time.perf_counter(), cpu()
        last = [t0, c0]

        def tick(step, total, info):
            t, c = time.perf_counter(), cpu()
            rows.append((info.get("stage", "?"), t - last[0], c - last[1]))
            last[:] = [t, c]

        fit = J.JointFits.fit

        def spy(self, models, validate, restricted=False):
            t, c = time.perf_counter(), cpu()
            out = fit(self, models, validate, restricted)
            fits.append((len(models), restricted, self.n_active_add if restricted else self.n_active,
                         time.perf_counter() - t, cpu() - c))
            return out

        J.JointFits.fit = spy
        res = S.diagnose(est, val, progress=tick)
        J.JointFits.fit = fit
    lines = [f"# Diagnosis stage times, N = {n}", "",
             f"Made by `python experiments/diagnose_stage_times.py --zones {n}"
             f"`; one process, compilation cache "
             + ("warm (filled by an earlier process)" if warm else "cold (empty or off)")
             + "; CPU: the process's (all threads). Named: "
             + ", ".join(f["mechanism"] for f in res["findings"])
             + f"; augmented fit {res['augmented']['mean_fit_percent']:.2f} %.", "",
             "| stage (ends) | wall s | CPU s |", "|---|---|---|"]
    lines += [f"| {s} | {w:.1f} | {c:.1f} |" for s, w, c in rows]
    lines += ["", "Joint fits (`JointFits.fit` calls, in order):", "",
              "| models | restricted | Jacobian width | wall s | CPU s |", "|---|---|---|---|---|"]
    lines += [f"| {m} | {r} | {w} | {t:.1f} | {c:.1f} |" for m, r, w, t, c in fits]
    out = HERE / "results" / "diagnose_stage_times.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
