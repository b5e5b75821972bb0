"""Time of `jthermo demo`'s Bode figure (`plots.plot_bode`) of a 4-zone state-space model: every
channel (4 x 4, 32 log axes) against the channels the demo draws (each heater to its own zone
and heater 1 to zone 2), drawn and written to PNG; the model and spectral estimate computed
once first, so the rows time the drawing (matplotlib) alone:

    python benchmarks/demo_bode.py          # writes benchmarks/results/demo_bode.md
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    from jthermo import demo, plots
    from jthermo.identify.fit import fit
    from jthermo.printer import generate, make_printer
    from jthermo.validate import bode, spectral_estimate

    p = make_printer(4, demo.ID_EFFECTS, seed=0)
    est = generate(p, "prbs", 3600.0, seed=0)
    val = generate(p, "prbs", 1800.0, seed=1)
    model = fit(est, "ss", demo.FAMILY_ORDERS["ss"], seed=0).model
    spec = spectral_estimate(val)
    bode(model, spec[0])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, chans in (("all 16 channels", None),
                             ("demo: 4 own + 1 coupling", [(i, i) for i in range(4)] + [(1, 0)])) * 2:
            t, c = time.perf_counter(), time.process_time()
            plots.plot_bode({"ss": model}, spectral=spec, channels=chans, path=Path(tmp) / "b.png")
            rows.append((label, time.perf_counter() - t, time.process_time() - c))
    load = Path("/proc/loadavg").read_text().split()[0]
    text = "\n".join(["# `jthermo demo`'s Bode figure: drawing time", "",
                      f"`python benchmarks/demo_bode.py`, 1-minute load {load} at the end (2 shared CPUs).", "",
                      "| channels | wall s | CPU s |", "|---|---|---|"]
                     + [f"| {a} | {w:.2f} | {c:.2f} |" for a, w, c in rows]) + "\n"
    out = ROOT / "benchmarks/results/demo_bode.md"
    if "--out" in sys.argv:
        out = Path(sys.argv[sys.argv.index("--out") + 1])
    out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
