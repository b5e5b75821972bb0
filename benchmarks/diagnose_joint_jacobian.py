"""The joint fit's Jacobian: `recurrence.radiative`'s tangent rule against JAX's own derivative.

Diagnoses the latency record of `benchmarks/diagnose_profile.py` (one hour, 4 zones) up to its
first joint fit (`joint.fit_joint`), keeps that call's inputs and stops. Then times, warm (after
one compiling call), the forward-mode Jacobian the Levenberg–Marquardt iteration forms
(`jax.linearize` of the coupled residual, one tangent per free-parameter slot, vmapped over the
call's models), with the coupled simulation's recurrence differentiated three ways:

- `rule`: `recurrence.radiative` (the tangents obey one linear recurrence, inputs of all steps
  computed outside the loop);
- `plain`: the same scan body differentiated by JAX (the code before 71aa95f);
- `rule, dense hold`: the rule, with the zero-order hold as before (`common.zoh_dense`: the dense
  $2m \\times 2m$ exponential, instead of `mechanisms.zoh_blocks`'s $m \\times m$ blocks).

CPU s = user + system of the process (load-robust); wall s and the 1-minute load beside.

    python benchmarks/diagnose_joint_jacobian.py

Writes `benchmarks/results/diagnose_joint_jacobian.md`.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import cpu_seconds, zoh_dense  # noqa: E402

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
RECORD = ["--experiment", "prbs", "--zones", "4", "--effects",
          "lateral_conduction,radiative_loss,heater_lag"]
REPS = 5


class _Captured(Exception):
    pass



def _plain(E, P, a, r, F, sig, s0):
    """The recurrence's scan as `mechanisms.simulate_full` wrote it before `recurrence`."""
    import jax
    import jax.numpy as jnp

    n = a.shape[0]

    def body(s, inp):
        fk, s4 = inp
        q = a * s[:n] - r * ((s[:n] + 273.15) ** 4 - s4)
        return jnp.sum(E * s[None, :], axis=1) + jnp.sum(P * q[None, :], axis=1) + fk, s[:n]

    return jax.lax.scan(body, s0, (F, sig))[1]


def _capture(est, val):
    import jthermo.diagnose.joint as J
    import jthermo.diagnose.select as S
    from jthermo.data import load

    box = {}

    def grab(*a, **k):
        box["args"] = a
        raise _Captured

    J.fit_joint = grab
    try:
        S.diagnose(load(est), load(val))
    except _Captured:
        pass
    return box["args"]


def main() -> None:
    import jax

    from jthermo import runtime

    runtime.enable_cache()
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    import jthermo.diagnose.mechanisms as M
    from jthermo.diagnose.recurrence import radiative

    with tempfile.TemporaryDirectory(prefix="jthermo-jac-") as d:
        tmp = Path(d)
        for name, dur, seed in (("est.csv", "3600", "1"), ("val.csv", "1800", "2")):
            subprocess.run([sys.executable, "-m", "jthermo.cli", "generate", *RECORD, "--duration", dur,
                            "--seed", seed, "--out", str(tmp / name), "--quiet"], check=True)
        Theta0, on, rec0, mask, y, weight, fper, fsh, lay, n_iter, n_active = _capture(tmp / "est.csv",
                                                                                       tmp / "val.csv")
    from jax._src import compilation_cache

    # the Jacobians compile here: JAX decides once per process whether it reads the cache
    compilation_cache.reset_cache()
    jax.config.update("jax_enable_compilation_cache", False)
    Mo, n, P = Theta0.shape
    V = jnp.concatenate([Theta0.reshape(Mo, -1), rec0], axis=1)
    tang = jnp.eye(V.shape[1])[:n_active]

    def jac(v, o, fp):
        def res(x):
            Th, r = x[:n * P].reshape(n, P), x[n * P:]
            return (weight[:, None] * (y - M.simulate_full(Th, o, {**fsh, **fp}, lay, r))).reshape(-1)

        _, f = jax.linearize(res, v)
        return jax.vmap(f, out_axes=1)(tang)

    rows, Js = [], {}
    zoh = M.zoh_blocks
    for name, fn, hold in (("rule", radiative, zoh), ("plain", _plain, zoh),
                           ("rule, dense hold", radiative, zoh_dense)):
        M.radiative, M.zoh_blocks = fn, hold
        J = jax.jit(jax.vmap(jac))
        c0 = cpu_seconds()
        comp = J.lower(V, on, fper).compile()
        c_comp = cpu_seconds() - c0
        Js[name] = np.asarray(comp(V, on, fper))
        t = []
        for _ in range(REPS):
            w0, c0, ld = time.perf_counter(), cpu_seconds(), os.getloadavg()[0]
            jax.block_until_ready(comp(V, on, fper))
            t.append((time.perf_counter() - w0, cpu_seconds() - c0, ld))
        rows.append((name, c_comp, min(c for _, c, _ in t), min(w for w, _, _ in t), t[0][2]))
    M.radiative, M.zoh_blocks = radiative, zoh
    rel = lambda J: float(np.abs(Js["rule"] - J).max() / np.abs(J).max())
    lines = ["# The joint fit's Jacobian: tangent rule against JAX's derivative of the scan", "",
             f"`python benchmarks/diagnose_joint_jacobian.py`: the latency record's first joint fit "
             f"({Mo} models, {n} zones, T = {y.shape[0]}, {n_active} tangents each), one Jacobian of the "
             f"coupled residual (as one Levenberg–Marquardt iteration forms it): its compile (no cache), then "
             f"its run, best of {REPS}. "
             "CPU s = user + system (load-robust).", "",
             "| recurrence derivative | compile CPU s | run CPU s | run wall s | load |", "|---|---|---|---|---|"]
    lines += [f"| {nm} | {cc:.2f} | {c:.3f} | {w:.3f} | {ld:.1f} |" for nm, cc, c, w, ld in rows]
    lines += ["", "Largest difference of the `rule` Jacobian from the others, relative to their largest entry: "
              f"`plain` {rel(Js['plain']):.1e}, `rule, dense hold` {rel(Js['rule, dense hold']):.1e}.", ""]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "diagnose_joint_jacobian.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
