"""Where the joint fits' time goes, and how far their Levenberg–Marquardt iterations are needed.

The latency record's first joint fit (`joint.JointFits.fit`'s first call: the top mechanism
alone and with each addition, vmapped; `benchmarks/diagnose_compile_options.py` captures its
arguments) is taken apart, warm (compiled first, then run, best of 2), CPU s = user + system:
- one evaluation of the coupled residual of every model (the primal simulation), three of them
  (the damping trials of one iteration), and one Jacobian (`jax.linearize`, then the forward-mode
  tangents under `jax.vmap`, as `identify.lm.masked_lm` forms it);
- the cost after each of `--iters` iterations, per model, relative to its final cost: which
  models have converged (to 1e-10) after how many of the default `select.JOINT_ITER`.

    python benchmarks/diagnose_joint_convergence.py [--iters 40]

Writes `benchmarks/results/diagnose_joint_convergence.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from diagnose_compile_options import capture_latency_record

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"


def _cpu() -> float:
    t = os.times()
    return t.user + t.system


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iters", type=int, default=40)
    args = ap.parse_args(argv)
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    from jthermo.diagnose import mechanisms as M
    from jthermo.diagnose import select
    from jthermo.identify.lm import masked_lm

    got = capture_latency_record()
    Theta0, on, rec0, mask, y, weight, f_per, f_sh, lay, _, n_active = got["fit_joint"]

    def residual_of(Theta, o, f_p):
        f = {**f_sh, **f_p}
        nP = Theta.size
        return lambda v: (weight[:, None] * (y - M.simulate_full(v[:nP].reshape(Theta.shape), o, f, lay,
                                                                 v[nP:]))).reshape(-1)

    def tangents(th, m):
        idx = jnp.nonzero(m > 0, size=n_active, fill_value=0)[0]
        valid = (jnp.arange(n_active) < jnp.sum(m > 0)).astype(th.dtype)
        return jax.nn.one_hot(idx, th.shape[0], dtype=th.dtype) * valid[:, None]

    def primal(Theta, o, r0, m, f_p):
        return residual_of(Theta, o, f_p)(jnp.concatenate([Theta.reshape(-1), r0]))

    def trials(Theta, o, r0, m, f_p):
        res, th = residual_of(Theta, o, f_p), jnp.concatenate([Theta.reshape(-1), r0])
        return jax.vmap(lambda s: jnp.mean(res(th + s * 1e-3 * m) ** 2))(jnp.arange(3.0))

    def jacobian(Theta, o, r0, m, f_p):
        res, th = residual_of(Theta, o, f_p), jnp.concatenate([Theta.reshape(-1), r0])
        _, jvp = jax.linearize(res, th)
        return jax.vmap(jvp, out_axes=1)(tangents(th, m))

    def history(Theta, o, r0, m, f_p):
        res = residual_of(Theta, o, f_p)
        return masked_lm(res, jnp.concatenate([Theta.reshape(-1), r0]), m, args.iters, n_active)[2]

    inputs = (Theta0, on, rec0, mask, f_per)
    parts = []
    for label, fn in (("residual of every model (primal simulation)", primal),
                      ("three damping trials' costs", trials),
                      (f"Jacobian ({n_active} tangents per model)", jacobian)):
        f = jax.jit(jax.vmap(fn))
        jax.block_until_ready(f(*inputs))
        best = np.inf
        for _ in range(2):
            c0 = _cpu()
            jax.block_until_ready(f(*inputs))
            best = min(best, _cpu() - c0)
        parts.append({"part": label, "run_cpu_s": best, "load": os.getloadavg()[0]})
        print(parts[-1], flush=True)
    hist = np.asarray(jax.jit(jax.vmap(history))(*inputs))
    rel = (hist - hist[:, -1:]) / hist[:, -1:]
    n_free = np.asarray(mask).sum(axis=1).astype(int).tolist()
    sets = []
    for j in range(hist.shape[0]):
        o = np.asarray(on[j])
        sets.append(" + ".join(m for k, m in enumerate(M.MECHANISMS) if o[k] > 0))
    # the first iteration within 1e-10 of the final cost (None: only the last one, still falling)
    conv = [int(np.argmax(r <= 1e-10)) + 1 if np.any(r[:-1] <= 1e-10) else None for r in rel]
    at_default = rel[:, select.JOINT_ITER - 1].tolist()
    out = {"parts": parts, "models": sets, "free_parameters": n_free, "n_active": int(n_active),
           "iterations": args.iters, "relative_excess": rel.tolist(), "converged_at": conv,
           "excess_at_joint_iter": at_default}
    lines = ["# The first joint fit of the latency record: its parts and its convergence", "",
             ("`python benchmarks/diagnose_joint_convergence.py`: the latency record's first joint fit "
             f"({hist.shape[0]} models, 4 zones, T = {y.shape[0]}), warm, best of 2, CPU s = user + system."), "",
             "| part (all models at once) | run CPU s | load |", "|---|---|---|"]
    lines += [f"| {p['part']} | {p['run_cpu_s']:.3f} | {p['load']:.1f} |" for p in parts]
    lines += ["", (f"Cost after each iteration relative to the cost after {args.iters}: the first iteration at "
              f"which it is within 1e-10, and the excess left after the default {select.JOINT_ITER}."), "",
              ("| model | free parameters | within 1e-10 at iteration | excess after "
              f"{select.JOINT_ITER} |"), "|---|---|---|---|"]
    lines += [f"| {s} | {nf} | {c if c is not None else f'> {args.iters}'} | {e:.1e} |"
              for s, nf, c, e in zip(sets, n_free, conv, at_default)]
    lines.append("")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "diagnose_joint_convergence.md").write_text("\n".join(lines))
    (RESULTS / "diagnose_joint_convergence.json").write_text(json.dumps(out, indent=1))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
