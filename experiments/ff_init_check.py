"""How much of each announced event's open-loop effect the model-based start of the schedule
feed-forward (`jthermo.tune.ff_init.init_schedule_ff`) cancels on the realistic 4-zone printer
(PA12, plant seed 0, default taps and preview): rms and peak of the output deviation over the
fit horizon without and with the feed-forward, for a recoat and for one exposed sample per zone.

    .venv/bin/python experiments/ff_init_check.py [--taps 40]

Writes experiments/results/ff_init_check.json (default taps) or ff_init_check_taps<L>.json.
"""

import argparse
import json
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

from jthermo.closedloop import PREVIEW_S, REALISTIC_EFFECTS
from jthermo.control import design
from jthermo.printer import make_printer
from jthermo.tune import ff_init
from jthermo.tune.report import printer_model

HERE = Path(__file__).resolve().parent


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--taps", type=int, default=None)
    args = ap.parse_args(argv)
    pr = make_printer(4, REALISTIC_EFFECTS, powder="PA12", seed=0)
    ctrl = design("pi_ff", printer_model(pr), **({} if args.taps is None else {"taps": args.taps}))
    L, P = ctrl.taps, round(PREVIEW_S / pr.ts)
    R = ff_init.event_responses(pr, L, preview=P)
    h_rec, h_las = (np.asarray(h) for h in ff_init.init_schedule_ff(ctrl, pr).effective_taps())
    cols = [ff_init.shifted_responses(R["G"][m], L) for m in range(pr.n_inputs)]
    rms = lambda v: float(np.sqrt(np.mean(np.square(v))))
    rec = R["recoat"].reshape(-1) + np.concatenate(cols, axis=1) @ h_rec.T.reshape(-1)
    out = {"taps": L, "preview": P, "horizon": int(R["G"].shape[1]),
           "recoat": {"rms_without": rms(R["recoat"]), "rms_with": rms(rec),
                      "peak_without": float(np.max(np.abs(R["recoat"]))),
                      "peak_with": float(np.max(np.abs(rec)))},
           "laser": []}
    for i in range(pr.zones):
        las = R["laser"][i].reshape(-1) + cols[i] @ h_las[:, i]
        out["laser"].append({"zone": i, "rms_without": rms(R["laser"][i]), "rms_with": rms(las)})
    out["max_abs_tap"] = float(max(np.max(np.abs(h_rec)), np.max(np.abs(h_las))))
    path = HERE / "results" / ("ff_init_check.json" if args.taps is None
                                else f"ff_init_check_taps{args.taps}.json")
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
