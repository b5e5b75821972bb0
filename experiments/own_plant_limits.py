"""How far below the best classical design any controller can get on a real device's
set-point changes, by their size.

Fitted as `experiments/own_plant.py` does (design model from one record, evaluation plant from
another). For set-point changes $\\delta$ (`closedloop.model_scenario` `tracking`: $r \\to r +
\\delta \\to r - \\delta$) from a fraction of the default size (`models.envelope.change_scale`)
up to the earlier 10 % of the recorded range, on the evaluation plant (held-out seed, one
rollout): the MSE of the classical designs from the design model, the full-power floor
(`tune.own.tracking_floor`: every heater at its limit after each change until the new set
point; the plant's lag and power), the recording's measurement-noise variance (in every
measured MSE), and the most any controller within the input limits can be below the best
classical design, $1 - (\\text{floor} + \\sigma^2) / \\text{MSE}_{best}$. Also the minimum of
each fitted model's step response over its first 30 s (negative: an inverse response, which
no heater has; the floor is then not a strict bound).

Usage:  python experiments/own_plant_limits.py [--devices tclab,hotend]
        ->  experiments/results/own_plant_limits.md (and .json)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "experiments"))

from own_plant import DEVICES, OUT, load  # noqa: E402

from jthermo.closedloop import metrics, model_duration, model_scenario, simulate  # noqa: E402
from jthermo.identify import fit  # noqa: E402
from jthermo.models.envelope import check_reachable  # noqa: E402
from jthermo.tune.own import MAX_SATURATED_CHANGES, classical_at, tracking_floor  # noqa: E402
from jthermo.tune.training import HELD_OUT  # noqa: E402

#: change sizes as multiples of the default (`change_scale`) one; "10 %": the earlier size
FACTORS = (0.25, 0.5, 1.0, 2.0)
FAMILIES = ("lqg", "pid_relay", "pi_untuned", "imc", "pi_lambda")


def device(name):
    spec = DEVICES[name]
    fd = fit(load(spec["design"]), spec["family"], spec["orders"])
    fe = fit(load(spec["evaluation"]), spec["family"], spec["orders"])
    env = fd.envelope.check(fd.model)
    r = check_reachable(fd.model, env, spec["setpoint"])
    dur = model_duration(fd.model)
    ctrls = classical_at(fd.model, r, FAMILIES)
    default = np.max(np.asarray(model_scenario("tracking", fe.model, dur, HELD_OUT, envelope=env,
                                               setpoint=r).r), axis=0) - r
    sizes = [(f"{f:g} x default", f * default) for f in FACTORS]
    sizes.append(("10 % of range", 0.1 * np.asarray(env.span)))
    noise = float(np.mean(np.square(env.noise_std)))
    rows = []
    for label, delta in sizes:
        sc = model_scenario("tracking", fe.model, dur, HELD_OUT, envelope=env, setpoint=r,
                            step_c=delta)
        floor = tracking_floor(fe.model, env, r, dur, HELD_OUT, "tracking", step_c=delta)
        mse = {}
        for f, c in ctrls.items():
            m = metrics(simulate(fe.model, c, sc), sc)
            mse[f] = {"mse": m["mse"], "saturated": m["saturated_fraction"]}
        best = min(mse, key=lambda f: mse[f]["mse"])
        calm = [f for f in mse if mse[f]["saturated"] <= MAX_SATURATED_CHANGES]
        best_calm = min(calm, key=lambda f: mse[f]["mse"]) if calm else None
        bound = floor + noise
        rows.append({"size": label, "delta_C": np.round(delta, 4).tolist(), "floor": floor,
                     "bound": bound, "classical": mse, "best": best,
                     "most_below_best_percent": 100.0 * (1.0 - bound / mse[best]["mse"]),
                     "best_not_bang_bang": best_calm,
                     "most_below_best_not_bang_bang_percent": None if best_calm is None else
                     100.0 * (1.0 - bound / mse[best_calm]["mse"])})
    steps = {k: float(np.min(np.asarray(m.step_response(int(round(30.0 / env.ts))))[:, 0, 0]))
             for k, m in (("design", fd.model), ("evaluation", fe.model))}
    return {"device": name, "setpoints": r.tolist(), "duration": dur, "noise_mse": noise,
            "default_change_C": default.tolist(), "rows": rows,
            "step_response_min_30s": steps}


def markdown(results) -> str:
    lines = ["# Own devices: how far below the best classical design any controller can be",
             "", __doc__.split("\n\n")[1].replace("\n", " "), "",
             "`python experiments/own_plant_limits.py` (one rollout, held-out seed "
             f"{HELD_OUT}). MSE in °C² on the evaluation plant; (bang-bang): at an input "
             f"limit more than {100 * MAX_SATURATED_CHANGES:.0f} % of the run.", ""]
    for d in results:
        lines += [f"## {d['device']}", "",
                  f"- set points {np.round(d['setpoints'], 2).tolist()} °C, default change "
                  f"δ = {np.round(d['default_change_C'], 3).tolist()} °C, measurement-noise "
                  f"variance {d['noise_mse']:.4g} °C², runs of {d['duration']:g} s",
                  f"- step response of input 1 on output 1, minimum over the first 30 s: "
                  f"design model {d['step_response_min_30s']['design']:.3g} °C, evaluation "
                  f"model {d['step_response_min_30s']['evaluation']:.3g} °C per unit input", "",
                  "| change | δ (°C) | " + " | ".join(FAMILIES) + " | floor | floor + noise | "
                  "most below best | most below best not bang-bang |",
                  "|---|---|" + "---|" * len(FAMILIES) + "---|---|---|---|"]
        for row in d["rows"]:
            cells = []
            for f in FAMILIES:
                c = row["classical"].get(f)
                cells.append("—" if c is None else f"{c['mse']:.4g}"
                             + (" (bang-bang)" if c["saturated"] > MAX_SATURATED_CHANGES else ""))
            calm = row["most_below_best_not_bang_bang_percent"]
            lines.append(f"| {row['size']} | {row['delta_C']} | " + " | ".join(cells)
                         + f" | {row['floor']:.4g} | {row['bound']:.4g} | "
                         f"{row['most_below_best_percent']:.1f} % ({row['best']}) | "
                         + ("—" if calm is None else
                            f"{calm:.1f} % ({row['best_not_bang_bang']})") + " |")
        lines.append("")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--devices", default="tclab,hotend")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    results = [device(n) for n in args.devices.split(",")]
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "own_plant_limits.json").write_text(json.dumps(results, indent=1, default=float))
    (OUT / "own_plant_limits.md").write_text(markdown(results))
    print(markdown(results))
    print(f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
