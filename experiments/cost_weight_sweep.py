"""Cost-weight sweep: does the effort weight move the tuned controller?

On the Klipper hot-end's design model (fitted to one record, as in `experiments/own_plant.py`),
a `pid_relay` PID at 200 °C is tuned on the own-plant scenarios (`tune.own.OWN_SCENARIOS`:
set-point changes and load) with the plain mean cost (`tune(normalise=False, guard=False)`:
the cost alone decides) for a range of effort weights, all other weights at
`tune.own.OWN_WEIGHTS`, in two ways:

- `normalised`: each weight divided by its term's value for the start (`tune.own.term_scales`,
  `tune.terms.normalised_weights`), the own-plant default;
- `raw`: the weights as given, the cost before this change (effort = mean squared input change
  per sample, ~1e-4 against a tracking term of ~10-100 °C²).

Reported per weight, on held-out scenarios: the tuned gains, the effort term (mean Δu²), the
tracking term (mean e², true temperatures), the overshoot term and the measured-output MSE.

Usage:  python experiments/cost_weight_sweep.py [--steps N] [--rollouts N] [--duration S]
Writes `experiments/results/cost_weight_sweep.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "experiments"))

from own_plant import DEVICES, load

from jthermo.control.design import design
from jthermo.identify import fit
from jthermo.tune import tune
from jthermo.tune.own import OWN_SCENARIOS, OWN_WEIGHTS, term_scales
from jthermo.tune.terms import TERMS, batch_parts, normalised_weights
from jthermo.tune.training import HELD_OUT, make_batches

OUT = ROOT / "experiments" / "results"
EFFORT = (0.01, 0.1, 1.0, 10.0, 100.0)


def monotone(xs, increasing: bool) -> bool:
    d = np.diff(np.asarray(xs, np.float64))
    return bool(np.all(d >= 0) if increasing else np.all(d <= 0))


def sweep(device: str, steps: int, rollouts: int, duration: float, seed: int) -> dict:
    spec = DEVICES[device]
    t0 = time.perf_counter()
    res = fit(load(spec["design"]), spec["family"], spec["orders"])
    model, env = res.model, res.envelope
    r = np.asarray(spec["setpoint"], np.float64)
    kw = {"envelope": env, "setpoint": r}
    start = design("pid_relay", model, setpoint=r)
    scales = term_scales(start, model, rollouts=rollouts, duration=duration, seed=seed, kw=kw)
    held = make_batches([model], OWN_SCENARIOS, rollouts=rollouts, duration=duration,
                        seed=seed + HELD_OUT, scenario_kw=kw)[0]

    def figures(c):
        parts = np.mean(np.asarray(batch_parts(c, held)), axis=0)
        out = {k: float(parts[i]) for i, k in enumerate(TERMS) if k != "uniformity"}
        out["mse"] = float(parts[-1])
        out.update({g: float(np.asarray(getattr(c, g))[0]) for g in ("kp", "ti", "td")})
        return out

    rows = [{"mode": "start", "w_effort": None, **figures(start)}]
    for mode in ("normalised", "raw"):
        for we in EFFORT:
            given = {**OWN_WEIGHTS, "effort": we}
            w = normalised_weights(given, scales) if mode == "normalised" else given
            # weights as arrays: traced, so one compilation serves every weight
            tuned = tune(start, model, kind=OWN_SCENARIOS, rollouts=rollouts, steps=steps,
                         duration=duration, seed=seed, normalise=False, guard=False,
                         weights={k: jnp.asarray(v, jnp.float64) for k, v in w.items()},
                         scenario_kw=kw)
            rows.append({"mode": mode, "w_effort": we, **figures(tuned.controller)})
            print(json.dumps(rows[-1]), flush=True)
    checks = {}
    for mode in ("normalised", "raw"):
        rs = [x for x in rows if x["mode"] == mode]
        eff = [x["effort"] for x in rs]
        checks[mode] = {"effort_falls_monotonically": monotone(eff, False),
                        "kp_falls_monotonically": monotone([x["kp"] for x in rs], False),
                        "td_falls_monotonically": monotone([x["td"] for x in rs], False),
                        "effort_ratio_first_to_last": eff[0] / eff[-1] if eff[-1] > 0 else None}
    return {"device": device, "setpoint": r.tolist(), "ts": float(model.ts),
            "duration": duration, "steps": steps, "rollouts": rollouts, "seed": seed,
            "weights": OWN_WEIGHTS, "term_scales": scales, "rows": rows, "checks": checks,
            "seconds": time.perf_counter() - t0}


def markdown(res: dict, args) -> str:
    lines = ["# Cost-weight sweep: the effort weight moves the tuned PID", "",
             (f"`python experiments/cost_weight_sweep.py --steps {args.steps} --rollouts "
             f"{args.rollouts} --duration {args.duration:g} --seed {args.seed}`."
             f" Device {res['device']} design model (Ts {res['ts']:g} s), `pid_relay` start at "
             f"{res['setpoint']} °C, tuned on {', '.join(OWN_SCENARIOS)} with the plain mean cost"
             f" (no guard), other weights {res['weights']}; figures on held-out scenarios. "
             f"Term scales (the start's values): "
             f"{ {k: float(f'{v:.4g}') for k, v in res['term_scales'].items()} }."), "",
             "| weights | w_effort | kp (1/°C) | ti (s) | td (s) | effort = mean Δu² | tracking (°C²) | overshoot (°C²) | window | mse (°C²) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for x in res["rows"]:
        lines.append(f"| {x['mode']} | {x['w_effort'] if x['w_effort'] is not None else '-'} | "
                     f"{x['kp']:.4g} | {x['ti']:.4g} | {x['td']:.4g} | {x['effort']:.4g} | "
                     f"{x['tracking']:.4g} | {x['overshoot']:.4g} | {x['window']:.4g} | "
                     f"{x['mse']:.4g} |")
    lines += [""]
    for mode, c in res["checks"].items():
        lines.append(f"- {mode}: effort falls monotonically with w_effort: "
                     f"{c['effort_falls_monotonically']}; kp: {c['kp_falls_monotonically']}; "
                     f"td: {c['td_falls_monotonically']}; effort at w=0.01 / at w=100: "
                     f"{c['effort_ratio_first_to_last']:.3g}")
    lines += ["", f"{res['seconds']:.0f} s wall (shared, loaded machine)."]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="hotend", choices=sorted(DEVICES))
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--rollouts", type=int, default=2)
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    res = sweep(args.device, args.steps, args.rollouts, args.duration, args.seed)
    (OUT / "cost_weight_sweep.json").write_text(json.dumps(res, indent=1))
    (OUT / "cost_weight_sweep.md").write_text(markdown(res, args))


if __name__ == "__main__":
    main()
