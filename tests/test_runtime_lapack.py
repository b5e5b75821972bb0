"""`runtime.one_matrix_at_a_time`: every LAPACK call with batch dimensions is lowered to a loop
over single matrices on the CPU (no kernel of jaxlib's deals chunks to XLA's pool and waits
for them), with the same values and derivatives, and two threads' programs of batched solves
then finish together (they hung before, every time: both pool threads in `ParallelBatchMap`)."""

from __future__ import annotations

import os
import re
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo import runtime
from jthermo.cli.watchdog import Stalled, run_watched

#: the two-thread child's watchdog: seconds without CPU work (every thread asleep) before it
#: is killed; it needs a few CPU seconds, or hangs for good (2.5 CPU s, then asleep)
IDLE_S = 30

CHILD = r"""
import os, sys, threading
os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:2])   # a two-thread XLA pool
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
from jthermo import runtime
runtime.one_matrix_at_a_time()
rng = np.random.default_rng(0)
As = [jnp.asarray(rng.normal(size=(9, 33, 33)) + 8 * np.eye(33)) for _ in range(4)]
b = jnp.ones((9, 33))
solve = jax.vmap(jnp.linalg.solve)
progs = [jax.jit(lambda As, b: [solve(A, b) for A in As]),
         jax.jit(lambda As, b: [solve(A.mT, b) for A in As])]
for p in progs:
    jax.block_until_ready(p(As, b))
out = {}
def work(k):
    for i in range(20):
        out[k] = [np.asarray(o) for o in progs[k](As, b + i)]
ts = [threading.Thread(target=work, args=(k,)) for k in range(2)]
[t.start() for t in ts]; [t.join() for t in ts]
ref = [np.linalg.solve(np.asarray(A), np.asarray(b + 19)[..., None])[..., 0] for A in As]
err = max(float(np.max(np.abs(o - r))) for o, r in zip(out[0], ref))
print("finished", err)
"""


@pytest.fixture(scope="module", autouse=True)
def rule():
    assert runtime.one_matrix_at_a_time()
    assert runtime.one_matrix_at_a_time()      # idempotent


def _lapack_operands(fn, *args) -> list[tuple[str, str]]:
    """`(kernel, first operand type)` of every LAPACK custom call in `fn`'s lowered program."""
    text = jax.jit(fn).lower(*args).as_text()
    return re.findall(r"custom_call @(lapack_\w+)\(.*?\)[^\n]*?: \((tensor<[^>,]*>)", text)


def _rank(tensor: str) -> int:
    return tensor.count("x")


@pytest.mark.parametrize("zones", [1, 16])
def test_batched_factorisations_lower_to_single_matrices_with_the_same_values(zones):
    n = 2 * zones + 1                     # the printer's state size at `zones`
    rng = np.random.default_rng(zones)
    A = rng.normal(size=(3, 2, n, n)) + 2 * n * np.eye(n)
    S = A @ np.swapaxes(A, -1, -2)
    b = rng.normal(size=(3, 2, n))

    def many(A, S, b):
        solve = jax.vmap(jax.vmap(jnp.linalg.solve))
        return {"solve": solve(A, b), "inv": jnp.linalg.inv(A),
                "chol": jnp.linalg.cholesky(S), "eigh": jnp.linalg.eigvalsh(S),
                "svd": jnp.linalg.svd(A, compute_uv=False), "r": jnp.linalg.qr(A)[1],
                "eig": jnp.sort_complex(jnp.linalg.eigvals(A)), "det": jnp.linalg.det(A)}

    calls = _lapack_operands(many, A, S, b)
    kernels = {k for k, _ in calls}
    assert {"lapack_dgetrf_ffi", "lapack_dpotrf_ffi", "lapack_dsyevd_ffi", "lapack_dgesdd_ffi",
            "lapack_dgeqrf_ffi", "lapack_dgeev_ffi"} <= kernels, kernels
    assert all(_rank(t) == 2 for _, t in calls), calls        # one matrix per kernel call
    got = jax.device_get(jax.jit(many)(A, S, b))
    # independently, one matrix at a time in NumPy
    want = {"solve": np.linalg.solve(A, b[..., None])[..., 0], "inv": np.linalg.inv(A),
            "chol": np.linalg.cholesky(S), "eigh": np.linalg.eigvalsh(S),
            "svd": np.linalg.svd(A, compute_uv=False), "r": np.linalg.qr(A)[1],
            "eig": np.sort_complex(np.linalg.eigvals(A)), "det": np.linalg.det(A)}
    for k, v in want.items():
        np.testing.assert_allclose(got[k], v, rtol=1e-9, atol=1e-9 * np.max(np.abs(v)), err_msg=k)


@pytest.mark.parametrize("zones", [1, 16])
def test_gradient_through_a_batched_solve_matches_its_closed_form(zones):
    """$f = \\sum_k \\|A_k^{-1} b_k\\|^2$: $\\partial f / \\partial A_k = -2 A_k^{-T} x_k x_k^T$."""
    n = 2 * zones + 1
    rng = np.random.default_rng(7 + zones)
    A = rng.normal(size=(9, n, n)) + 2 * n * np.eye(n)
    b = rng.normal(size=(9, n))
    f = lambda A: jnp.sum(jax.vmap(jnp.linalg.solve)(A, b) ** 2)   # noqa: E731
    calls = _lapack_operands(jax.grad(f), A)
    assert calls and all(_rank(t) == 2 for _, t in calls), calls
    x = np.linalg.solve(A, b[..., None])
    want = -2.0 * np.linalg.solve(np.swapaxes(A, -1, -2), x) @ np.swapaxes(x, -1, -2)
    np.testing.assert_allclose(jax.grad(f)(A), want, rtol=1e-8, atol=1e-12)


def test_an_unbatched_call_keeps_its_kernel_and_a_batched_one_becomes_a_loop():
    A, b = np.eye(5) * 3.0, np.ones(5)
    one = jax.jit(jnp.linalg.solve).lower(A, b).as_text()
    many = jax.jit(jax.vmap(jnp.linalg.solve)).lower(np.stack([A] * 4), np.stack([b] * 4)).as_text()
    assert "lapack_dgetrf_ffi" in one and "lapack_dgetrf_ffi" in many
    # the batched solve's factorisation and triangular solves sit in loops of their own (the
    # pivots' permutation is a loop in both)
    assert many.count("stablehlo.while") > one.count("stablehlo.while")
    np.testing.assert_allclose(jnp.linalg.solve(A, b), b / 3.0)


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinities here")
def test_two_threads_of_batched_solves_finish():
    """Two programs, each with four independent batched solves (9 x 33 x 33: above jaxlib's
    2e5-flop chunking threshold), run from two threads on a two-thread pool: without the rule
    this child hangs with every thread asleep; `run_watched` kills it then."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    try:
        r = run_watched([sys.executable, "-c", CHILD], IDLE_S, env=env)
    except Stalled as exc:
        pytest.fail(f"two threads of batched solves: {exc}")
    assert r.returncode == 0, r.stderr[-2000:]
    line = r.stdout.strip().splitlines()[-1]
    assert line.startswith("finished")
    assert float(line.split()[1]) < 1e-9
