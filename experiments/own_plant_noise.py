"""Issue 18: which measurement noise the own-device scenarios should carry.

Fitted as `experiments/own_plant.py` does. Per output of the design record: the recording's
white-noise estimate the scenarios use (`models.Envelope.noise_std`: robust std of the second
differences / sqrt(6)), against the std (and robust std) of the fit's residuals on its own
estimation record, one-step-ahead (`validate.compare(k=1)`) and simulated (`k=None`; the
same here: these simulation-focus state-space fits have no noise model, K = 0). The residuals
carry the model's error as well as the sensor's noise (on the hot-end, the inverse step
response the fit has), so they are a ceiling on the sensor noise, not an estimate of it: the
scenarios keep the envelope's.

Usage:  python experiments/own_plant_noise.py  ->  experiments/results/own_plant_noise.md
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "experiments"))

from own_plant import DEVICES, OUT, load  # noqa: E402

from jthermo.identify import fit  # noqa: E402
from jthermo.validate import compare  # noqa: E402


def robust_std(x):
    return 1.4826 * np.median(np.abs(x - np.median(x, axis=0)), axis=0)


def main():
    lines = ["# Own devices: measurement noise of the scenarios against the fit's residuals", "",
             __doc__.split("\n\n")[1].replace("\n", " "), "",
             "`python experiments/own_plant_noise.py`; °C per output.", "",
             "| device | envelope noise_std | one-step residual std (robust) | "
             "simulation residual std (robust) |", "|---|---|---|---|"]
    for name, spec in DEVICES.items():
        data = load(spec["design"])
        res = fit(data, spec["family"], spec["orders"])
        cells = []
        for k in (1, None):
            e = np.asarray(data.y) - np.asarray(compare(res.model, data, k=k)["yhat"])
            cells.append(f"{np.round(e.std(axis=0), 4).tolist()} "
                         f"({np.round(robust_std(e), 4).tolist()})")
        lines.append(f"| {name} | {np.round(res.envelope.noise_std, 4).tolist()} | "
                     + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    (OUT / "own_plant_noise.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
