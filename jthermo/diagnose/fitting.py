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
Under `vmap` every problem ran the whole `n_iter` Jacobians. On the latency record's diagnosis
this took the warm run from 37.0 to 24.2 CPU s (candidates 7.08 -> 2.85, validation 2.97 ->
1.86, joint combination 25.48 -> 18.22) and the cold one from 58.4 to 42.4, with the same
finding and fit to 1e-7 points (`python benchmarks/diagnose_profile.py --tag _s26_before` /
`_s26_after`, load 6-9); costs equal the vmapped fixed-iteration solve's to about `RTOL`
(`benchmarks/diagnose_latency_s26.py`).

Where the time goes now (the latency record, 4 zones, T = 3600; `python
benchmarks/diagnose_anatomy.py --tag _s31`, `benchmarks/results/diagnose_anatomy_s31.md`): the
40 per-zone problems stop after 4 to 60 iterations (those that reach `N_ITER` = 60 are still
falling); the forward-selection rounds fit 7 and 6 distinct joint models (m = 14,400 residuals,
37 to 57 free parameters under a static `n_active` of 68), 4 iterations for the refitted smaller
model, 9 to 25 (mostly the cap, `JOINT_ITER` = 25) for the additions, at 70 to 85 ms an iteration
(one residual, a simulation, under the CPU clock's 10 ms; the rest is the forward-mode Jacobian:
reverse mode would need one pass per residual, 14,400 against 68
tangents). Cut to the call's own largest free-parameter count, the joint calls run 8.49 -> 7.29
and 9.77 -> 7.70 CPU s, but each distinct width is one more compiled program (16 CPU s each at
load 7); XLA's default options instead of `quick_compile()`: per-zone fits 6.46 -> 4.91 CPU s,
the joint ones no faster, costs equal to 8e-11 but parameters up to 0.13 relative apart (`python
benchmarks/diagnose_fit_variants.py --tag _s31`). Neither is adopted.

At `select.N_ITER` = 200 the candidates' fits are a large part of a warm diagnosis (24.8 of 59.5
CPU s at `_s33_iter200`; 18.5 of 42.6, beside the joint stage's 19.8, since the candidates start
with live heater gains, `mechanisms.live_gains`: `benchmarks/results/diagnose_profile_s34.md`),
and fewer iterations would change the answers (`python
benchmarks/diagnose_zone_convergence.py --record latency | heldout:12:08 | heldout:12:04 |
heldout:12:13 --tag _h34`): on the latency record 8 of 48 problems reach the cap (stored-heat
bodies, within 9e-6 of their cost at 300 iterations), but on development set 12's lamp case (N = 5) 38 of
65 do, several still 17 to 42 times their final cost at 100; `RTOL` 1e-7 instead of 1e-10
(27 % fewer iterations on the latency record) stops those on plateaus and moves a candidate's
estimation statistic (m log of its sum of squares) by up to 8460 there, by 151 on the slow-body
case 13 already at 1e-8; a cap of 100 by up to 7880 (lamp) and 136-156 (cases 04, 13); no
extra body starts by 3450 (lamp) and 122 (case 04).

A fourth damping trial with geodesic acceleration (`masked_lm(..., geodesic=True)`, `GEODESIC`)
follows the curved valleys (log gains and rates) that the plain steps crawl along. Replayed on
the diagnosis's own per-zone problems with the same stop (`python benchmarks/lm_variants.py`,
`benchmarks/results/lm_variants_h35_try2/3/4.md`, load 5-8): the latency record 2952 -> 2303
iterations (replay CPU 16.0 -> 16.0 s), development set 12's lamp case 10316 -> 4466 (20.4 -> 7.7 s), development set 14's
case 00 (N = 7) 15034 -> 9924 (22.5 -> 14.0 s); no problem's final cost above the plain solver's
by more than 1e-9 of itself (0 of 204), many lower (to -81 %: plateaus the plain solver stopped
on). Development set 14's cases 00-02 name the same (`experiments/results/diagnose_heldout_same_fresh14_mz9_vs_
h35geo_set14_f0.md`), but case 00's reported `ambient_variation` estimation statistic moved 9.6 ->
-80.0 although its per-zone costs only fell (not explained yet), and the real recordings and a
same-window CPU A/B were not run: not switched on. Nielsen's gain-ratio damping (2 of 48 latency
problems up to 8e-3 above), five trials instead of three (5 above, to 2e-6), a step scaled instead
of clipped (more iterations, 2 above to 3e-7), acceleration on all three trials (14:00: 2 above,
to 0.13) and an extrapolated step (fewer iterations, no less CPU) were measured and rejected.
Rechecked on 2026-11-28 (`GEODESIC = True` in a copy of the tree, `PYTHONPATH=TREE`): 14:00's
shift came from the common surroundings drift's unfinished fit, which now continues
(`joint.common_drift_fit`, `CONTINUE_ROUNDS`): 10.27 with and without. Real recordings 10/10
identical (`diagnose_heldout_same_diagnose_real_s36_vs_diagnose_real_s37geo.md`), set 20's nulls
10/10 quiet (`..._s36drift_nulls20_vs_s37geo_nulls20.md`), the latency record the same findings and
fit at warm 32.4-32.5 -> 29.2-30.6 CPU s, its per-zone fits 14.3-14.8 -> 11.8-12.2
(`benchmarks/results/diagnose_warm_cpu_s37geo.md`, interleaved, load 1.4-4.1); but development set
16's case 05 (a drift named at 0.275 with the body its rival) flipped to `heat_accumulation`
(`diagnose_heldout_hard_s37geo_set16_partial.log`), so it stays off.

Narrower Jacobians were measured and not adopted. A candidate call's Jacobian is formed over
its widest problem, the surroundings drift's (19 free parameters, width 20 on the latency
record), while the others free 7 to 10; fitting the drift's problems in a call of their own
(the rest at width 12) took the latency record's candidate call, warm, 19.5 -> 14.2 CPU s with
costs equal to 5e-11 (`python benchmarks/diagnose_zone_width.py --tag _h34`, load 3) and the
whole diagnosis warm 37.5 -> 34.2 CPU s, but the second program's compile (4.4 -> 8.7 s) ate
the gain cold (60.1 -> 60.0 CPU s; `benchmarks/diagnose_profile.py --tag _h34_width` against
`_h34_main`, load 3.5). From the shell no difference showed above the noise on the latency
record (`python benchmarks/diagnose_latency_ab.py --tag _h34` / `_h34b`, 4 interleaved rounds,
load 2.4-4.0: cold 61.3 s wall both, warm 36.6 vs 35.3 s), and a first call on a one-zone
record was slower: 24.1 / 25.8 -> 28.8 / 28.1 s wall cold, 10.7 / 11.2 -> 10.5 s warm
(`benchmarks/results/diagnose_split_n1_s34.md`, load 3.0-3.4). Same answers either way
(`experiments/diagnose_heldout_same.py`, `diagnose_heldout_same_*h34speed*.md`).

The traced programs are kept in the cache directory (`stored.exported_call`): a later process
neither traces them nor lowers them again (the same programs, the same executables). Compiling
the validation stage's program (its shapes are known before any candidate is fitted) in a
thread while the candidates are fitted was measured and not adopted (a715d4f, reverted): the
validation stage fell from 5.6-7.3 to 0.5-0.8 s wall on a first call, but the candidates'
stage grew by as much (the thread's compile takes the core their fits use), the same report;
three interleaved cold pairs, load 1.3-1.7: 41.1 / 46.6 / 49.4 s without, 44.3 / 53.0 / 36.4 s
with (`benchmarks/results/diagnose_profile_s38_{base,prep}{1,2,3}.md`).

A call's problems are spread over threads (`_run_spread`, `n_threads`), one problem per
compiled call (`CALL_SIZE`), each thread taking the next problem when its last one is done: one
after another in one call (`lax.map`) they left the second core mostly idle. Each problem's fit
is the same computation as in one call, bit for bit (held-out set 24 rerun: every name, rival,
LR and fit equal, `experiments/results/diagnose_heldout_same_fresh24_mz9_vs_s42shares_set24.md`).
The split hung in sessions 27 and 41 (`benchmarks/results/diagnose_threads_deadlock.md`): the
joint fits' damped systems (68 free parameters) were factored by a batched LU that jaxlib deals
to XLA's CPU pool and waits for on a pool thread, and two such waits filled a two-thread pool;
`masked_lm` now factors one matrix at a time (`identify/lm.py`), and the split joint fits run
(`python benchmarks/diagnose_shard_devices.py --fits joint --tag _s42_lmap`, two XLA devices:
5.8 -> 4.3 s). The latency record's diagnosis from the shell, interleaved with the code before
(`python benchmarks/diagnose_latency_ab.py --a TREE --tag _s42`, load 0.8-1.6): cold 44.8 / 45.2
-> 36.8 / 31.8 s, warm 33.6 / 30.4 -> 24.4 / 20.1 s. One problem per call rather than one call
per thread, because the problems' iteration counts differ (up to `select.N_ITER`): a thread
that is done takes the next problem, and a call's shape no longer depends on the number of
problems (fewer programs to compile); not measured against one call per thread from the shell.

The coupled programs (`fit_joint`, hence `fit_records`) and `sim_zones` are compiled with
`runtime.quick_compile()` options (XLA's older CPU fusion emitters): on the latency record's
diagnosis they compile in 8.48 instead of 11.57 (first joint fit), 8.12 instead of 9.58
(validation) and 0.89 instead of 1.69 CPU s, run in the same time and give the same fits to
5e-13 (`python benchmarks/diagnose_compile_options.py`, load 6-8, measured on the vmapped
solve). The per-zone fits (`fit_zones`) kept XLA's default options under `vmap` (the older
emitters compiled in 5.88 instead of 7.36 CPU s but ran in 6.65 instead of 5.53); one problem
after another the quick options cost less to compile than they may cost to run, so they take
them too: the latency record's candidates fit, first call (compile + run) 6.98 -> 5.09 CPU s,
warm 1.79 -> 2.02 CPU s (`benchmarks/results/diagnose_latency_s26.md` as of 03e0778 and now, load 1.3-3.0; costs
equal to 7e-11).
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


def _run(fn, static: tuple, *args):
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
    """`_run(fn, static, *args)` with the problems spread over `n_threads()` threads, `CALL_SIZE`
    problems per call (one compiled program of that shape, compiled before the threads start),
    each thread taking the next call when its last one is done: `fn` fits its problems one
    after another (`lax.map`), which left the second core idle. `batched`: positions of the
    arguments with a leading problem axis (pytrees); the last argument is each problem's
    iterations. Padding rows repeat a call's first row with no iterations and are dropped.
    Each problem's fit is the same computation as in one call, bit for bit."""
    budget = np.asarray(args[-1])
    k = min(n_threads(), budget.size)
    if k <= 1:
        return _run(fn, static, *args[:-1], jnp.asarray(budget, jnp.int32))
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
    run = lambda c: jax.block_until_ready(_run(fn, static, *c[1]))     # noqa: E731
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
    return _run(_sim_zones, ("lay",), theta, on, per, shared, lay)


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


def _first_copies(*trees) -> np.ndarray:
    """For each j of the leading axis shared by every array in `trees`, the first index whose
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
    src = _first_copies(Theta0, on, rec0, mask, f_per)
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
