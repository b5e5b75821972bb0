"""Rejected attempt: keep `jthermo simulate`'s compiled run program as a serialized executable
(`jax.experimental.serialize_executable`) so that a warm process skips the lowering of
`jit(Exported.call)` and the persistent-cache lookup. Three child processes: `save` compiles
the run program (as `stored.exported_call` would) and writes the pickled executable; `old`
runs the command's warm path (export read, lower, executable from JAX's cache, execute);
`new` initialises LAPACK (scipy), loads the pickled executable and executes it. Each prints
its stamps (wall / CPU s since the child's first line) and the mse, or the error.

    python benchmarks/simulate_serialized_executable.py   # -> results/simulate_serialized_executable.md
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent

CHILD = r'''
import sys, time, pickle
T0 = time.perf_counter(); C0 = time.process_time()
def stamp(msg): print(f"| {msg} | {time.perf_counter()-T0:.3f} | {time.process_time()-C0:.3f} |", flush=True)
from jthermo import runtime
runtime.enable_cache(); runtime.unroll_threefry()
import jax; jax.config.update("jax_enable_x64", True)
import numpy as np
from jthermo.closedloop import engine as E
from jthermo.printer import make_printer
from jthermo.cli.control import stored_printer_model
from jthermo import stored
design = sys.modules["jthermo.control.design"].design
stamp("imports")
plant = make_printer(16, E.REALISTIC_EFFECTS, powder="PA12", seed=0)
ctrl = design("pi_lambda", stored_printer_model(plant))
args = ("tracking", plant, ctrl, 3600.0, np.asarray(0, np.int64), 256)
exp, arrays = stored._exported_program(E._seeded_metrics_fn, args)
stamp("set-up, export read")
mode, path = sys.argv[1], sys.argv[2]
from jax.experimental import serialize_executable as se
if mode == "old":
    out = stored._caller(exp, runtime.simulate_compile())(*arrays)
    stamp("lower jit(Exported.call), executable from JAX's cache, dispatch")
elif mode == "save":
    comp = jax.jit(exp.call, compiler_options=runtime.simulate_compile()).lower(*arrays).compile()
    blob = pickle.dumps(se.serialize(comp))
    open(path, "wb").write(blob)
    stamp(f"compiled, serialized ({len(blob)} bytes)")
    out = comp(*arrays)
else:
    from jax._src.lax.linalg import initialize_lapack
    initialize_lapack(); stamp("LAPACK initialisation (imports scipy)")
    s, it, ot = pickle.loads(open(path, "rb").read())
    comp = se.deserialize_and_load(s, it, ot); stamp("executable deserialized and loaded")
    out = comp(*arrays)
try:
    vals = jax.device_get(out)[0]
    stamp(f"executed: mse {float(vals['mse'])!r}")
except Exception as exc:
    stamp(f"execution failed: {type(exc).__name__}: {str(exc).splitlines()[0]}")
'''


def main() -> None:
    load = Path("/proc/loadavg").read_text().split()[0]
    lines = ["# Rejected: the run program as a serialized executable", "",
             f"`python benchmarks/simulate_serialized_executable.py` (1-minute load {load}): "
             "stamps of each child, wall / CPU s since its first line.", ""]
    with tempfile.TemporaryDirectory() as cache:
        path = str(Path(cache) / "exec.pkl")
        env = {**os.environ, "JTHERMO_CACHE_DIR": cache}
        for mode in ("save", "old", "new", "old", "new"):
            r = subprocess.run([sys.executable, "-c", CHILD, mode, path], env=env,
                               capture_output=True, text=True)
            lines += [f"## {mode}", "", "| stamp | wall s | CPU s |", "|---|---|---|",
                      *[ln for ln in r.stdout.splitlines() if ln.startswith("|")], ""]
            if r.returncode:
                lines += [f"exit status {r.returncode}: `{(r.stderr.strip().splitlines() or ['?'])[-1]}`", ""]
    text = "\n".join(lines)
    (HERE / "results" / "simulate_serialized_executable.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
