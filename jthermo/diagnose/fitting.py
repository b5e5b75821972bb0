"""The diagnosis fits: mechanism-library models of every zone and record, one problem after another.

`jthermo.identify.pem.minimize` compiles one solve per model structure; diagnosis fits eight
structures (and combinations) for every zone at once. Here a structure is a 0/1 mask over one
flat parameter vector plus the mechanism switches, so all candidates and zones share one
compiled solve of the masked Levenberg–Marquardt `jthermo.identify.lm.masked_lm`. The cost is
the simulation error (output error).

The problems of one call run one after another (`jax.lax.map`), not in lockstep (`jax.vmap`),
so that each does only its own work: it forms its Jacobian (nearly all of an iteration's time)
only where its parameters moved (a rejected step reuses it), stops once its cost fell by less
than `RTOL` of itself over `identify.lm.STALL` iterations, and a joint model that repeats an
earlier one (the callers pad to fixed slot counts, one compiled shape) is copied, not refitted.
Under `vmap` every problem would run the whole `n_iter` Jacobians; one after another gives the
same finding, with costs equal to the vmapped fixed-iteration solve's to about `RTOL` (measured
by `python benchmarks/diagnose_profile.py`).

The Jacobian is formed in forward mode: a joint fit has m = T·N residuals (14,400 on a 4-zone,
T = 3600 record) against at most 68 free parameters, so reverse mode would need one pass per
residual against one tangent per parameter. Every call of a stage has one static width (its
widest problem's free-parameter count) rather than each call its own: each distinct width is
one more compiled program, whose compile costs more than the narrower Jacobian saves cold
(measured by `python benchmarks/diagnose_zone_width.py`).

The iteration caps (`select.N_ITER`, `JOINT_ITER`) and `RTOL` are set by the answers, not the
time: fewer iterations or a looser `RTOL` stop the fits of many heater gains and of slow bodies
on their plateaus and move a candidate's estimation statistic (m log of its sum of squares) by
thousands (measured by `python benchmarks/diagnose_zone_convergence.py`).

A fourth damping trial with geodesic acceleration (`masked_lm(..., geodesic=True)`, `GEODESIC`)
follows the curved valleys (log gains and rates) that the plain steps crawl along, in fewer
iterations and to no higher cost; it stays off because it flips a drift named with a
stored-heat body as its rival to `heat_accumulation` on a development-set record
(`python experiments/diagnose_heldout_same.py`). Nielsen's gain-ratio damping, five trials
instead of three, a step scaled instead of clipped, acceleration on all three trials and an
extrapolated step were measured and rejected (some final costs above the plain solver's, or no
less work).

The traced programs are kept in the cache directory (`stored.exported_call`): a later process
neither traces them nor lowers them again (the same programs, the same executables). The
validation stage's program is not compiled in a thread while the candidates are fitted: the
thread's compile takes the core the fits use, so the candidates' stage grows by as much as the
validation stage saves.

A call's problems are spread over threads (`_run_spread`, `n_threads`), one problem per
compiled call (`CALL_SIZE`), each thread taking the next problem when its last one is done: one
after another in one call (`lax.map`) they left the second core mostly idle. Each problem's fit
is the same computation as in one call, bit for bit. One problem per call rather than one call
per thread, because the problems' iteration counts differ (up to `select.N_ITER`): a thread
that is done takes the next problem, and a call's shape no longer depends on the number of
problems (fewer programs to compile). The joint fits' damped systems are factored one matrix at
a time in `masked_lm` (`identify/lm.py`): a batched LU is dealt by jaxlib to XLA's CPU pool and
waited for on a pool thread, and two such waits fill a two-thread pool, a deadlock.

The coupled programs (`fit_joint`, hence `fit_records`), `sim_zones` and, one problem after
another, the per-zone fits (`fit_zones`) are compiled with `runtime.quick_compile()` options
(XLA's older CPU fusion emitters): they compile in less time and run in the same time, with the
same fits.
"""

from __future__ import annotations

import functools
import os
import threading
from concurrent.futures import ThreadPoolExecutor

import jax
import jax.numpy as jnp
import numpy as np

from ..identify.lm import masked_lm
from ..runtime import quick_compile
from ..stored import exported_call, exported_compile
from .pool import simulate_full, simulate_zone

#: every fit stops once its cost fell by less than this share of itself over the last
#: `identify.lm.STALL` iterations (at most `n_iter`); such a fit has converged to about this
#: share of its cost (see the module docstring)
RTOL = 1e-10
#: a zone fit whose $m \log V$ fell by more than this over its last `FALL_WINDOW` iterations
#: has not converged at its cap (`still_falling`): the diagnosis continues it
FALL_LR = 1.0
FALL_WINDOW = 20

#: the per-zone fits' fourth damping trial with geodesic acceleration (`masked_lm(...,
#: geodesic=...)`); off until the checks in the module docstring are done (kept off on a case
#: of development set 16)
GEODESIC = False


@functools.cache
def _compiled(fn, static: tuple, quick: bool = True):
    """`fn` jitted with `static` argument names, with `runtime.quick_compile()` options if
    `quick` (once per process: the options are probed on first use, not at import)."""
    return jax.jit(fn, static_argnames=static, compiler_options=quick_compile() if quick else None)


def run_problems(fn, static: tuple, *args):
    """`fn(*args)` compiled with `runtime.quick_compile()` options (`static` its static argument
    names), through `stored.exported_call`: a process after the first loads the traced program
    from the cache directory instead of tracing it (the same program, the same executable)."""
    return exported_call(fn, args, _compiled(fn, static), compiler_options=quick_compile())


#: most threads a fitting call's problems are spread over (measured on two cores only)
MAX_THREADS = 2
#: problems per compiled call when spread over threads (None: one call per thread)
CALL_SIZE = 1


def n_threads() -> int:
    """How many threads `_run_spread` spreads a call's problems over: the cores this process
    may use, at most `MAX_THREADS`; one where the caller is not the main thread (a diagnosis
    run beside other work, as `jthermo demo` runs it, leaves them the other core). The
    environment variable `JTHERMO_FIT_THREADS` overrides (a positive integer; 1: one call)."""
    env = os.environ.get("JTHERMO_FIT_THREADS", "").strip()
    if env.isdigit():                   # anything else: the default
        return max(1, int(env))
    if threading.current_thread() is not threading.main_thread():
        return 1
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:              # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_THREADS))


def call_rows(budget: np.ndarray, n_calls: int) -> list[np.ndarray]:
    """Rows of a batch for `n_calls` calls of equal size $\\lceil B/n \\rceil$: the problems with
    iterations to do (`budget > 0`) dealt in turn, then those without, then padding (`-1`)."""
    budget = np.asarray(budget)
    order = np.concatenate([np.flatnonzero(budget > 0), np.flatnonzero(budget <= 0)])
    size = -(-order.size // n_calls)
    order = np.concatenate([order, np.full(size * n_calls - order.size, -1)])
    return [order[i::n_calls] for i in range(n_calls)]


def _run_spread(fn, static: tuple, args: tuple, batched: tuple):
    """`run_problems(fn, static, *args)` with the problems spread over `n_threads()` threads, `CALL_SIZE`
    problems per call (one compiled program of that shape, compiled before the threads start),
    each thread taking the next call when its last one is done: `fn` fits its problems one
    after another (`lax.map`), which left the second core idle. `batched`: positions of the
    arguments with a leading problem axis (pytrees); the last argument is each problem's
    iterations. Padding rows repeat a call's first row with no iterations and are dropped.
    Each problem's fit is the same computation as in one call, bit for bit."""
    budget = np.asarray(args[-1])
    k = min(n_threads(), budget.size)
    if k <= 1:
        return run_problems(fn, static, *args[:-1], jnp.asarray(budget, jnp.int32))
    host = {i: jax.tree_util.tree_map(np.asarray, args[i]) for i in batched}
    n_calls = k if CALL_SIZE is None else -(-budget.size // CALL_SIZE)
    calls = []
    for rows in call_rows(budget, n_calls):
        pad = rows < 0
        take = np.where(pad, rows[0], rows)
        a = list(args[:-1])
        for i in batched:
            a[i] = jax.tree_util.tree_map(lambda x: x[take], host[i])
        calls.append((rows, (*a, np.where(pad, 0, budget[take]).astype(np.int32))))
    run = lambda c: jax.block_until_ready(run_problems(fn, static, *c[1]))     # noqa: E731
    # compiled once, before the threads (without the cache: by the first call, here)
    first = [] if exported_compile(fn, calls[0][1], quick_compile()) else [run(calls[0])]
    pool = ThreadPoolExecutor(k)
    try:
        outs = first + list(pool.map(run, calls[len(first):]))
    finally:                            # an error: the calls not started are dropped
        pool.shutdown(wait=True, cancel_futures=True)
    where = np.concatenate([rows for rows, _ in calls])
    keep = where >= 0
    inverse = np.empty(budget.size, int)
    inverse[where[keep]] = np.flatnonzero(keep)
    join = lambda *xs: np.concatenate([np.asarray(x) for x in xs])[inverse]      # noqa: E731
    return jax.tree_util.tree_map(join, *outs)


def _zone_residual(theta, on, z, lay):
    return z["y"] - simulate_zone(theta, on, z, lay)


def _fit_zones(theta0, mask, on, per, shared, lay, n_iter, n_active, budget):
    def one(a):
        t, m, o, p, b = a
        z = {**shared, **p}
        return masked_lm(lambda th: _zone_residual(th, o, z, lay), t, m, n_iter, n_active, rtol=RTOL,
                         budget=b, geodesic=GEODESIC)

    return jax.lax.map(one, (theta0, mask, on, per, budget))


def fit_zones(theta0, mask, on, per, shared, lay, n_iter, n_active=None, budget=None):
    """Fit B independent zone problems: `theta0, mask (B, P)`, `on (B, 8)`, `per` a dict of
    per-problem arrays (leading B axis: y, ynb, events, delay), `shared` a dict common to all;
    `n_active` (static) at least the largest number of free parameters of one problem; `budget`
    `(B,)` each problem's iterations, at most `n_iter` (default `n_iter` each; 0 returns the
    start: one compiled program for any budget). Returns (θ `(B, P)`, cost `(B,)`, the cost after
    each iteration `(B, n_iter)`)."""
    budget = np.full(theta0.shape[0], n_iter) if budget is None else np.asarray(budget)
    return _run_spread(_fit_zones, ("lay", "n_iter", "n_active"),
                       (theta0, mask, on, per, shared, lay, n_iter, n_active, budget), (0, 1, 2, 3))


def still_falling(hist, m: int) -> np.ndarray:
    """Which fits, cost histories `hist (B, n_iter)` of `m` residuals each, were still falling
    at their iteration cap: $m \\log(V_{k-W} / V_k) >$ `FALL_LR` over the last `FALL_WINDOW`
    iterations, the units of the diagnosis's likelihood ratios (a fit that stopped on `RTOL`
    repeats its final cost: 0)."""
    h = np.asarray(hist, float)
    w = min(FALL_WINDOW, h.shape[1] - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        fall = m * np.log(h[:, -1 - w] / h[:, -1])
    return np.isfinite(fall) & (fall > FALL_LR)


def _sim_zones(theta, on, per, shared, lay):
    return jax.vmap(lambda t, o, p: simulate_zone(t, o, {**shared, **p}, lay))(theta, on, per)


def sim_zones(theta, on, per, shared, lay):
    """Per-zone (series-parallel) simulations of B problems, `(B, T)`."""
    return run_problems(_sim_zones, ("lay",), theta, on, per, shared, lay)


def _fit_coupled(Theta, on, rec0, mask, budget, y, weight, fp, f_shared, lay, n_iter, n_active):
    """Masked LM on one coupled model's vector $[\\mathrm{vec}\\,\\Theta;\\ r]$ (zone parameters,
    record parameters): residual $w_k (y_k - \\hat y_k(\\Theta, r))$, $w$ the per-sample weight;
    `budget` iterations (a traced integer, at most `n_iter`)."""
    f = {**f_shared, **fp}
    nP = Theta.size
    split = lambda v: (v[:nP].reshape(Theta.shape), v[nP:])

    def res(v):
        Th, r = split(v)
        return (weight[:, None] * (y - simulate_full(Th, on, f, lay, r))).reshape(-1)

    v, c, _ = masked_lm(res, jnp.concatenate([Theta.reshape(-1), rec0]), mask, n_iter, n_active,
                        rtol=RTOL, budget=budget)
    Th, r = split(v)
    return Th, r, simulate_full(Th, on, f, lay, r), c


def _fit_joint(Theta0, on, rec0, mask, y, weight, f_per, f_shared, lay, n_iter, n_active=None,
               budget=None):
    """`fit_joint`'s compiled program: the models one after another (`lax.map`), each with its
    own `budget[j]` iterations."""
    M = Theta0.shape[0]
    budget = jnp.full(M, n_iter, jnp.int32) if budget is None else budget
    return jax.lax.map(lambda a: _fit_coupled(*a[:5], y, weight, a[5], f_shared, lay, n_iter, n_active),
                       (Theta0, on, rec0, mask, budget, f_per))


def first_copies(*trees) -> np.ndarray:
    """For each j of the first axis shared by every array in `trees`, the first index whose
    entries equal j's in every array (j itself where none before it does): `(M,)`. Traced
    arrays cannot be compared: then `arange(M)`."""
    leaves = jax.tree_util.tree_leaves(trees)
    M = leaves[0].shape[0]
    if any(isinstance(x, jax.core.Tracer) for x in leaves):
        return np.arange(M)
    arrs = [np.asarray(x) for x in leaves]
    first: dict = {}
    return np.array([first.setdefault(b"".join(np.ascontiguousarray(a[j]).tobytes() for a in arrs), j)
                     for j in range(M)])


def fit_joint(Theta0, on, rec0, mask, y, weight, f_per, f_shared, lay, n_iter, n_active=None):
    """Fit M coupled models jointly over all zones by simulation error (output error): the zones'
    parameters `Theta0 (M, n, P)` and the record parameters `rec0 (M, R)` (initial states, drift,
    surroundings level offset; see `simulate_full`), `mask (M, n P + R)` 1 where free, `on (M, 8)`,
    `y (T, n)`, `weight (T,)` per-sample weights (0 for padding), `f_per` per-model entries of the
    simulation's dict. Returns
    (Θ (M, n, P), rec (M, R), yhat (M, T, n), cost (M,)).

    The models are fitted one after another (`lax.map`, not `vmap`), so that each forms its
    Jacobian only where its parameters moved (`masked_lm(..., budget=...)`: a rejected step
    reuses it) and a model that repeats an earlier one (padding to a fixed number of slots)
    is not fitted again but copied: the same iterates as the vmapped fixed-iteration solve."""
    src = first_copies(Theta0, on, rec0, mask, f_per)
    budget = np.where(src == np.arange(src.size), n_iter, 0).astype(np.int32)
    out = _run_spread(_fit_joint, ("lay", "n_iter", "n_active"),
                      (Theta0, on, rec0, mask, y, weight, f_per, f_shared, lay, n_iter, n_active, budget),
                      (0, 1, 2, 3, 6))
    return jax.tree_util.tree_map(lambda x: x[src], out)     # copies take their first's fit


def fit_records(Theta, on, rec0, mask, y, f_per, f_shared, lay, n_iter):
    """Estimate each model's record parameters (initial states, drift) on a record by masked LM
    on the coupled simulation, then simulate it: `Theta (M, n, P)`, `on (M, 8)`,
    `rec0, mask (M, R)`; returns (rec, yhat (M, T, n), cost (M,))."""
    full = jnp.concatenate([jnp.zeros((Theta.shape[0], Theta[0].size), mask.dtype), mask], axis=1)
    _, r, yh, c = fit_joint(Theta, on, rec0, full, y, jnp.ones(y.shape[0], y.dtype), f_per, f_shared,
                            lay, n_iter, rec0.shape[1])
    return r, yh, c


__all__ = ["FALL_LR", "FALL_WINDOW", "fit_joint", "fit_records", "fit_zones", "sim_zones", "still_falling"]
