"""Seconds of `tune.printer_model` (the printer's design model, used by `jthermo simulate` and
`jthermo tune`): the Jacobians eagerly (the former code) against one compiled program
(`_linearise`), each in a fresh process, cold (empty compilation cache) then warm; checks
that both give the same matrices. Writes `benchmarks/results/printer_model_speed.md`.

    python benchmarks/printer_model_speed.py
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = r"""
import sys, time, jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
from jthermo import runtime; runtime.enable_cache(sys.argv[2])
from jthermo.printer import make_printer, PrinterState
from jthermo import closedloop as cl
from jthermo.tune import printer_model
plant = make_printer(16, cl.REALISTIC_EFFECTS, powder="PA12", seed=0)
t = time.perf_counter()
if sys.argv[1] == "eager":
    x0, u0 = plant.initial_state(), plant.steady_input()
    disc, d = plant.discretise(), plant.default_disturbance()
    def f(z, u):
        buf = jnp.broadcast_to(u, x0.buffer.shape)
        return disc.step(PrinterState(z=z, buffer=buf, since=x0.since), u, d).z
    A, B = jax.jacfwd(f, 0)(x0.z, u0), jax.jacfwd(f, 1)(x0.z, u0)
else:
    m = printer_model(plant); A, B = m.A, m.B
jax.block_until_ready(B)
print(time.perf_counter() - t)
np.save(sys.argv[3], np.concatenate([np.asarray(A), np.asarray(B)], axis=1))
"""


def main() -> None:
    import numpy as np

    rows = []
    with tempfile.TemporaryDirectory() as d:
        for way in ("eager", "jit"):
            cache = Path(d) / f"cache-{way}"
            for phase in ("cold", "warm"):
                load = Path("/proc/loadavg").read_text().split()[0]
                out = subprocess.run([sys.executable, "-c", CHILD, way, str(cache),
                                      str(Path(d) / f"{way}.npy")], check=True,
                                     capture_output=True, text=True).stdout
                rows.append((way, phase, float(out.split()[-1]), load))
                print(rows[-1], flush=True)
        same = np.array_equal(np.load(Path(d) / "eager.npy"), np.load(Path(d) / "jit.npy"))
    lines = ["# printer_model: eager Jacobians vs one compiled program (N = 16)", "",
             (f"`python benchmarks/printer_model_speed.py`, {time.strftime('%Y-%m-%d %H:%M')}; "
             f"same matrices: {same}. Seconds of the call in a fresh process (compilation "
             "included; cold = empty cache), 2 shared cores."), "",
             "| way | phase | s | load |", "|---|---|---|---|"]
    lines += [f"| {w} | {p} | {s:.2f} | {ld} |" for w, p, s, ld in rows]
    res = Path(__file__).resolve().parent / "results" / "printer_model_speed.md"
    res.write_text("\n".join(lines) + "\n")
    print(res.read_text())


if __name__ == "__main__":
    main()
