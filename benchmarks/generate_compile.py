"""Compile options of the virtual printer's open-loop experiment (`printer.generate`): XLA's
default options against `runtime.one_shot()` (-O0, older fusion emitters), each in a fresh
process with an empty compilation cache, modes interleaved. Two workloads: `jthermo demo`'s
two 4-zone PRBS records (3600 s and 1800 s, two programs), and a 10-hour 9-zone record
generated twice (first call = compile + run, second = run alone). The outputs of both modes
are compared.

    python benchmarks/generate_compile.py      # writes benchmarks/results/generate_compile.md
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def child(mode: str) -> dict:
    import equinox as eqx
    import jax
    import numpy as np

    jax.config.update("jax_enable_x64", True)
    from jthermo import demo, runtime
    from jthermo.printer import generate, make_printer, runs

    runtime.enable_cache()
    runtime.unroll_threefry()
    if mode == "default options":   # as before: the program jitted with XLA's defaults
        plain = eqx.filter_jit(runs._generate_fn)
        runs._generate_core = lambda: plain
    rows, ys = [], []

    def timed(label, printer, duration, seed):
        t, c = time.perf_counter(), time.process_time()
        d = generate(printer, "prbs", duration, seed=seed)
        rows.append([label, time.perf_counter() - t, time.process_time() - c])
        ys.append(np.asarray(d.y).ravel())

    p4 = make_printer(4, demo.ID_EFFECTS, seed=0)
    timed("demo estimation record (4 zones, 3600 s)", p4, 3600.0, 0)
    timed("demo validation record (4 zones, 1800 s)", p4, 1800.0, 1)
    p9 = make_printer(9, demo.ID_EFFECTS, seed=0)
    timed("9 zones, 36000 s, first call", p9, 36000.0, 0)
    timed("9 zones, 36000 s, second call", p9, 36000.0, 1)
    np.save(os.environ["OUT_NPY"], np.concatenate(ys))
    return {"rows": rows}


def main() -> None:
    if len(sys.argv) > 2 and sys.argv[1] == "--child":
        print(json.dumps(child(sys.argv[2])))
        return
    import numpy as np

    runs, outs = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(2):
            for mode in ("default options", "one_shot"):
                with tempfile.TemporaryDirectory() as cache:
                    npy = str(Path(tmp) / f"{rep}_{mode.replace(' ', '_')}.npy")
                    env = {**os.environ, "JTHERMO_CACHE_DIR": cache, "OUT_NPY": npy}
                    load = Path("/proc/loadavg").read_text().split()[0]
                    p = subprocess.run([sys.executable, __file__, "--child", mode], env=env,
                                       capture_output=True, text=True, check=True)
                    runs.append((mode, load, json.loads(p.stdout.strip().splitlines()[-1])["rows"]))
                    outs[mode] = np.load(npy)
        diff = float(np.max(np.abs(outs["default options"] - outs["one_shot"])))
    lines = ["# `printer.generate`: compile options", "",
             "`python benchmarks/generate_compile.py`: each mode in a fresh process with an empty "
             "compilation cache, modes interleaved; 2 shared CPUs, 1-minute load before each process.", "",
             "| mode | record | wall s | CPU s | load |", "|---|---|---|---|---|"]
    for mode, load, rows in runs:
        lines += [f"| {mode} | {a} | {w:.2f} | {c:.2f} | {load} |" for a, w, c in rows]
    lines += ["", f"Largest difference of an output between the modes: {diff:.2e} °C."]
    text = "\n".join(lines) + "\n"
    (ROOT / "benchmarks/results/generate_compile.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
