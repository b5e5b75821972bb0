"""Parts of one joint-fit Jacobian, timed alone on random inputs of the latency record's sizes.

The first joint fit of `benchmarks/diagnose_profile.py`'s record vmaps 7 models (4 zones, m = 12
states, T = 3600 samples) and 68 tangents (`benchmarks/diagnose_joint_jacobian.py` times the whole
Jacobian, 0.81 CPU s). Here, each compiled and run alone (best of 5, CPU s = user + system):

- the zero-order hold's tangents (`mechanisms.zoh_blocks` on m × m blocks, and the dense 2m × 2m
  exponential it replaced);
- `recurrence.radiative`'s tangent loop $\\dot S_{k+1} = A_k \\dot S_k + G_k$;
- one of its input terms, $S \\dot E^T$ for every tangent: as `jax.vmap` over the tangents forms
  it, and as one matrix product with the tangents folded into the columns (same numbers).

    python benchmarks/diagnose_jacobian_parts.py

Writes `benchmarks/results/diagnose_jacobian_parts.md`.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
MO, T, M, N, K = 7, 3600, 12, 4, 68
REPS = 5


def _cpu() -> float:
    t = os.times()
    return t.user + t.system


def _time(fn, *args):
    import jax

    c = jax.jit(jax.vmap(fn)).lower(*args).compile()
    ref = jax.block_until_ready(c(*args))
    t = []
    for _ in range(REPS):
        w0, c0 = time.perf_counter(), _cpu()
        jax.block_until_ready(c(*args))
        t.append((_cpu() - c0, time.perf_counter() - w0))
    return min(c for c, _ in t), min(w for _, w in t), ref


def main() -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    import jthermo.diagnose.mechanisms as M_
    from diagnose_joint_jacobian import _zoh_dense

    rng = np.random.default_rng(0)
    A = jnp.asarray(-0.05 * np.eye(M) + 0.01 * rng.standard_normal((MO, M, M)))
    Bc = jnp.asarray(rng.standard_normal((MO, M, 2 * N)))
    dA = jnp.asarray(rng.standard_normal((MO, K, M, M)))
    Ak = jnp.asarray(0.1 * rng.standard_normal((MO, T, M, M)))
    G = jnp.asarray(rng.standard_normal((MO, T, M, K)))
    S = jnp.asarray(rng.standard_normal((MO, T, M)))

    def hold(z):
        return lambda A, Bc, dA: jax.vmap(lambda d: jax.jvp(lambda A: z(A, Bc, 1.0), (A,), (d,))[1])(dA)

    def loop(A, G):
        def body(ds, inp):
            return inp[0] @ ds + inp[1], ds[:N]
        return jax.lax.scan(body, jnp.zeros((M, K)), (A, G), unroll=4)[1]

    def g_vmap(S, dE):
        return jax.vmap(lambda d: S @ d.T, out_axes=2)(dE)

    def g_flat(S, dE):
        return (S @ jnp.transpose(dE, (2, 1, 0)).reshape(M, M * K)).reshape(T, M, K)

    rows = []
    for name, fn, args in (("hold tangents, m x m blocks (`zoh_blocks`)", hold(M_.zoh_blocks), (A, Bc, dA)),
                           ("hold tangents, dense 2m x 2m (before)", hold(_zoh_dense), (A, Bc, dA)),
                           ("tangent loop", loop, (Ak, G)),
                           ("S dE^T, vmap over tangents", g_vmap, (S, dA)),
                           ("S dE^T, one product", g_flat, (S, dA))):
        c, w, ref = _time(fn, *args)
        rows.append((name, c, w, os.getloadavg()[0], ref))
    same = float(jnp.abs(rows[3][4] - rows[4][4]).max() / jnp.abs(rows[3][4]).max())
    lines = ["# Parts of one joint-fit Jacobian, timed alone", "",
             f"`python benchmarks/diagnose_jacobian_parts.py`: random inputs, {MO} models (vmapped), "
             f"T = {T}, m = {M} states, {K} tangents; best of {REPS}. CPU s = user + system "
             "(the process clock counts in steps of 0.01 s).", "",
             "| part | run CPU s | run wall s | load |", "|---|---|---|---|"]
    lines += [f"| {nm} | {c:.3f} | {w:.3f} | {ld:.1f} |" for nm, c, w, ld, _ in rows]
    lines += ["", f"The two forms of S dE^T differ by {same:.1e} of the largest entry.", ""]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "diagnose_jacobian_parts.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
