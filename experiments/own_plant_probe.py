"""Issue 18 probe: how far a hand-moved Ziegler–Nichols PID (kp, ti, td scaled) gets on the
hot-end's set-point changes (`closedloop.model_scenario` `tracking`: ±10 % of the recorded
range around 200 °C) and on its start-up step (`preheat`, heaters off to 200 °C), against LQG
and the full-power floors (`tune.own.tracking_floor`), on the evaluation plant (the model
fitted to the other record), one held-out seed. Shows what the tuner could reach in principle
and whether any PID of the grid holds the start-up overshoot to 2 °C.

Usage:  python experiments/own_plant_probe.py  ->  experiments/results/own_plant_probe.md
"""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)


ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "experiments"))

from own_plant import OUT  # noqa: E402
from own_plant_overshoot import setup  # noqa: E402

from jthermo.closedloop import metrics, simulate  # noqa: E402
from jthermo.control.design import design  # noqa: E402
from jthermo.control.relay import DiagonalPID  # noqa: E402
from jthermo.tune.own import STARTUP, tracking_floor  # noqa: E402
from jthermo.tune.training import HELD_OUT  # noqa: E402


def main():
    fd, fe, env, r, dur, scs = setup()      # hot-end fits, held-out scenarios
    kinds = ("tracking", STARTUP)
    zn = design("pid_relay", fd.model, setpoint=r)

    def run(c):
        out = []
        for k in kinds:
            m = metrics(simulate(fe.model, c, scs[k]), scs[k])
            out += [m["mse"], m["overshoot_C"]]
        return out

    lqg = run(design("lqg", fd.model, setpoint=r))
    floors = [tracking_floor(fe.model, env, r, dur, HELD_OUT, k) for k in kinds]
    lines = ["# Hot-end: hand-moved Ziegler–Nichols PID against LQG and the full-power floors",
             "", ("`python experiments/own_plant_probe.py`: set-point changes (±10 % of the "
                  f"range around {r.tolist()} °C) and start-up on the evaluation plant (seed "
                  f"{HELD_OUT}, one rollout). Floors (full power after each change, from steady "
                  f"state): changes {floors[0]:.4g} °C², start-up {floors[1]:.4g} °C². LQG: "
                  f"changes MSE {lqg[0]:.4g} °C², overshoot {lqg[1]:.3g} °C; start-up MSE "
                  f"{lqg[2]:.4g} °C², overshoot {lqg[3]:.3g} °C."), "",
             "| kp × | ti × | td × | changes MSE (°C²) | vs LQG (%) | overshoot (°C) | "
             "start-up MSE (°C²) | start-up overshoot (°C) |",
             "|---|---|---|---|---|---|---|---|"]
    for kf, tif, tdf in itertools.product((0.5, 1.0, 2.0, 4.0), (1.0, 3.0), (0.5, 1.0, 2.0)):
        c = DiagonalPID(zn.kp * kf, zn.ti * tif, zn.td * tdf, zn.u0, ts=zn.ts)
        v = run(c)
        lines.append(f"| {kf:g} | {tif:g} | {tdf:g} | {v[0]:.4g} | "
                     f"{100 * (1 - v[0] / lqg[0]):.1f} | {v[1]:.3g} | {v[2]:.4g} | {v[3]:.3g} |")
    (OUT / "own_plant_probe.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
