"""The hot-end's 200 °C start-up overshoot with a set-point-weighted (2-DOF) PID.

Fitted as `experiments/own_plant.py` does (design model from `heattest_200`, evaluation plant
from `sample_trace`, `ss` order 2, 200 °C). `DiagonalPID`'s proportional part acts on
$e - (1 - b)(r - y_0)$ (set-point weight $b$, integral on $e$, derivative on the measurement):
for the start-up (heaters off to the set point) the input is cut $\\approx (1 - b)(r - y_0)$
before the set point and the integral brings the rest. On the evaluation plant (held-out seed,
one rollout) for the Ziegler–Nichols PID of the relay test (`pid_relay`) and hand-moved gains
(kp, ti, td scaled as in `own_plant_probe.py`), over a grid of b: set-point changes and load
MSE, overshoots, start-up MSE, overshoot and settling time, and whether `tune.own.judge` passes
the loop (settles, not saturated). `--tune` also runs `tune_own_plant` from `pid_relay` with
each b of `--b0` at the start (tracking + load [+ start-up with `--startup`], `--steps`, `--rollouts`).

Usage:  python experiments/own_plant_overshoot.py [--tune --b0 1 0.95 --steps 60 --rollouts 4]
        ->  experiments/results/own_plant_overshoot.md (and .json; with --tune also the tuned table)
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)


ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "experiments"))

from own_plant import DEVICES, OUT, load  # noqa: E402

from jthermo.closedloop import metrics, model_duration, model_scenario, simulate  # noqa: E402
from jthermo.control.design import design  # noqa: E402
from jthermo.control.relay import DiagonalPID  # noqa: E402
from jthermo.identify import fit  # noqa: E402
from jthermo.models.envelope import check_reachable  # noqa: E402
from jthermo.tune.own import OWN_SCENARIOS, STARTUP, judge  # noqa: E402
from jthermo.tune.training import HELD_OUT  # noqa: E402

KINDS = ("tracking", "load", STARTUP)
#: (kp, ti, td) factors on the Ziegler–Nichols gains; (2, 3, 1): the probe's best start-up
GAINS = ((1.0, 1.0, 1.0), (1.0, 3.0, 1.0), (2.0, 3.0, 1.0))
WEIGHTS = (1.0, 0.98, 0.95, 0.9, 0.85, 0.8, 0.7, 0.6)
#: the chosen 2-DOF PID (gain factors, b) and how many held-out seeds it is checked on
CHOSEN, SEEDS = ((2.0, 3.0, 1.0), 0.95), 5


def scenarios(fe, env, r, dur, seed):
    return {k: model_scenario(k, fe.model, dur, seed, envelope=env, setpoint=r) for k in KINDS}


def setup():
    spec = DEVICES["hotend"]
    fd = fit(load(spec["design"]), spec["family"], spec["orders"])
    fe = fit(load(spec["evaluation"]), spec["family"], spec["orders"])
    env = fd.envelope.check(fd.model)
    r = check_reachable(fd.model, env, spec["setpoint"])
    dur = model_duration(fd.model)
    return fd, fe, env, r, dur, scenarios(fe, env, r, dur, HELD_OUT)


def evaluate(c, plant, scs, dur) -> dict:
    """Per scenario: MSE, overshoot, settling; `judge`: None or why the loop is refused."""
    out = {k: {m: float(v) for m, v in metrics(simulate(plant, c, sc), sc).items()
               if m in ("mse", "overshoot_C", "settling_time_s", "saturated_fraction")}
           for k, sc in scs.items()}
    out["judge"] = judge({k: out[k] for k in KINDS}, dur, who="2-DOF PID")
    return out


def row(label, v) -> str:
    t, ld, s = v["tracking"], v["load"], v[STARTUP]
    return (f"| {label} | {t['mse']:.4g} | {t['overshoot_C']:.3g} | {ld['mse']:.4g} | "
            f"{s['mse']:.5g} | {s['overshoot_C']:.3g} | {s['settling_time_s']:.4g} | "
            f"{'ok' if v['judge'] is None else v['judge']} |")


def command_tail(args) -> str:
    """The options a `--tune` run was given, as typed."""
    if not args.tune:
        return ""
    b0 = " ".join(f"{b:g}" for b in args.b0)
    return (f" --tune --b0 {b0} --steps {args.steps} --rollouts {args.rollouts}"
            + (" --startup" if args.startup else ""))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tune", action="store_true")
    ap.add_argument("--b0", type=float, nargs="+", default=[1.0, 0.95])
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--rollouts", type=int, default=4)
    ap.add_argument("--startup", action="store_true", help="tune on the start-up step as well")
    args = ap.parse_args()
    t0 = time.perf_counter()
    fd, fe, env, r, dur, scs = setup()
    zn = design("pid_relay", fd.model, setpoint=r)
    lqg = evaluate(design("lqg", fd.model, setpoint=r), fe.model, scs, dur)
    res = {"lqg": lqg, "grid": []}
    for (kf, tif, tdf), b in itertools.product(GAINS, WEIGHTS):
        c = DiagonalPID(zn.kp * kf, zn.ti * tif, zn.td * tdf, zn.u0, ts=zn.ts, b=b)
        res["grid"].append({"kp_x": kf, "ti_x": tif, "td_x": tdf, "b": b,
                            **evaluate(c, fe.model, scs, dur)})
        print(row(f"{kf:g} | {tif:g} | {tdf:g} | {b:g}", res["grid"][-1]), flush=True)
    lines = ["# Hot-end start-up overshoot with a set-point-weighted (2-DOF) PID", "",
             f"`python experiments/own_plant_overshoot.py{command_tail(args)}`:"
             f" evaluation plant, seed {HELD_OUT}, one rollout per scenario ({dur:.1f} s), set "
             f"point {r.tolist()} °C. LQG: changes MSE {lqg['tracking']['mse']:.4g} °C², "
             f"load MSE {lqg['load']['mse']:.4g} °C², start-up MSE {lqg[STARTUP]['mse']:.5g} °C², "
             f"start-up overshoot {lqg[STARTUP]['overshoot_C']:.3g} °C.", "",
             "| kp × | ti × | td × | b | changes MSE (°C²) | changes overshoot (°C) | load MSE (°C²) "
             "| start-up MSE (°C²) | start-up overshoot (°C) | start-up settling (s) | judge |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    lines += [row(f"{g['kp_x']:g} | {g['ti_x']:g} | {g['td_x']:g} | {g['b']:g}", g)
              for g in res["grid"]]
    (kf, tif, tdf), b_c = CHOSEN
    lines += ["", f"Seeds {HELD_OUT}..{HELD_OUT + SEEDS - 1} (one rollout each), gains × "
              f"({kf:g}, {tif:g}, {tdf:g}):", "",
              "| b | seed | changes MSE (°C²) | changes overshoot (°C) | load MSE (°C²) "
              "| start-up MSE (°C²) | start-up overshoot (°C) | start-up settling (s) | judge |",
              "|---|---|---|---|---|---|---|---|---|"]
    res["seeds"] = []
    for b, seed in itertools.product((1.0, b_c), range(HELD_OUT, HELD_OUT + SEEDS)):
        c = DiagonalPID(zn.kp * kf, zn.ti * tif, zn.td * tdf, zn.u0, ts=zn.ts, b=b)
        v = evaluate(c, fe.model, scenarios(fe, env, r, dur, seed), dur)
        res["seeds"].append({"b": b, "seed": seed, **v})
        lines.append(row(f"{b:g} | {seed}", v))
    if args.tune:
        from jthermo.tune import tune_own_plant
        kinds = OWN_SCENARIOS + ((STARTUP,) if args.startup else ())
        lines += ["", f"Tuned from `pid_relay` with its set-point weight b at the start as "
                  f"given, on {list(kinds)} (`tune_own_plant`, {args.steps} steps, "
                  f"{args.rollouts} rollouts), evaluated as above:", "",
                  "| b at the start | b | kp (1/°C) | ti (s) | td (s) | changes MSE (°C²) | "
                  "changes overshoot (°C) | load MSE (°C²) | start-up MSE (°C²) | "
                  "start-up overshoot (°C) | start-up settling (s) | judge |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        res["tuned"] = []
        for b0 in args.b0:
            start = DiagonalPID(zn.kp, zn.ti, zn.td, zn.u0, ts=zn.ts, b=b0)
            c = tune_own_plant("pid_relay", fd.model, envelope=fd.envelope, setpoint=r,
                               validation_plant=fe.model, steps=args.steps,
                               rollouts=args.rollouts, kinds=kinds, start=start)["tuned"]
            gains = {k: float(getattr(c, k)[0]) for k in ("b", "kp", "ti", "td")}
            res["tuned"].append({"b0": b0, **gains, **evaluate(c, fe.model, scs, dur)})
            lines.append(row(f"{b0:g} | {gains['b']:.3f} | {gains['kp']:.4g} | "
                             f"{gains['ti']:.4g} | {gains['td']:.4g}", res["tuned"][-1]))
    res["seconds"] = time.perf_counter() - t0
    res["load_average"] = os.getloadavg()
    lines += ["", f"{res['seconds']:.0f} s wall on a shared machine (1/5/15-min load average "
              f"at the end {', '.join(f'{x:.1f}' for x in res['load_average'])})."]
    name = "own_plant_overshoot"
    (OUT / f"{name}.md").write_text("\n".join(lines) + "\n")
    (OUT / f"{name}.json").write_text(json.dumps(res, indent=1, default=str))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
