"""Issue 18 probe: how far a hand-moved Ziegler–Nichols PID (kp, ti, td scaled) gets on the
hot-end's tracking step, against LQG and the full-power floor (`tune.own.tracking_floor`), on
the evaluation plant (the model fitted to the other record), one held-out seed. Shows what the
tuner could reach in principle and the overshoot/MSE trade-off near the floor.

Usage:  python experiments/own_plant_probe.py  ->  experiments/results/own_plant_probe.md
"""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "experiments"))

from own_plant import DEVICES, OUT, load  # noqa: E402

from jthermo.closedloop import model_duration, model_scenario, simulate  # noqa: E402
from jthermo.control.design import design  # noqa: E402
from jthermo.control.relay import DiagonalPID  # noqa: E402
from jthermo.identify import fit  # noqa: E402
from jthermo.models.envelope import check_reachable  # noqa: E402
from jthermo.tune.own import tracking_floor  # noqa: E402
from jthermo.tune.training import HELD_OUT  # noqa: E402


def main():
    spec = DEVICES["hotend"]
    fd = fit(load(spec["design"]), spec["family"], spec["orders"])
    fe = fit(load(spec["evaluation"]), spec["family"], spec["orders"])
    env = fd.envelope.check(fd.model)
    r = check_reachable(fd.model, env, spec["setpoint"])
    dur = model_duration(fd.model)
    sc = model_scenario("tracking", fe.model, dur, HELD_OUT, envelope=env, setpoint=r)
    zn = design("pid_relay", fd.model, setpoint=r)

    def run(c):
        tr = simulate(fe.model, c, sc)
        e = np.asarray(tr.y)[:, 0] - np.asarray(tr.r)[:, 0]
        return float(np.mean(e ** 2)), float(max(e.max(), 0.0))

    lqg = run(design("lqg", fd.model, setpoint=r))
    floor = tracking_floor(fe.model, env, r, dur, HELD_OUT)
    lines = ["# Hot-end: hand-moved Ziegler–Nichols PID near the full-power floor", "",
             ("`python experiments/own_plant_probe.py`: tracking step on the evaluation plant "
              f"(seed {HELD_OUT}, one rollout). Floor {floor:.4g} °C²; LQG MSE {lqg[0]:.4g} °C², "
              f"overshoot {lqg[1]:.3g} °C."), "",
             "| kp × | ti × | td × | tracking MSE (°C²) | vs LQG (%) | overshoot (°C) |",
             "|---|---|---|---|---|---|"]
    for kf, tif, tdf in itertools.product((1.0, 2.0, 4.0), (1.0, 3.0), (1.0, 2.0, 4.0)):
        c = DiagonalPID(zn.kp * kf, zn.ti * tif, zn.td * tdf, zn.u0, ts=zn.ts)
        mse, os_ = run(c)
        lines.append(f"| {kf:g} | {tif:g} | {tdf:g} | {mse:.4g} | "
                     f"{100 * (1 - mse / lqg[0]):.1f} | {os_:.3g} |")
    (OUT / "own_plant_probe.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
