"""Evaluation of tuned controllers on held-out seeds, the printer's design model
(`printer_model`) and `tune_report`, the one-call tune-and-compare of a controller family."""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..closedloop import (
    REALISTIC_EFFECTS,
    compiled_make_scenario,
    cost,
    make_scenario,
    metric_arrays,
    rollouts,
    unlabelled,
)
from ..control._base import AbstractController
from ..control.design import design
from ..control.margins import peak_sensitivity
from ..control.mimo_pi import MIMOPI
from ..control.schedule_ff import ScheduleFF
from ..errors import ControlError
from ..models._base import AbstractModel, StateSpace
from ..printer import Printer, PrinterState, make_printer
from ..progress import stage
from ..runtime import one_matrix_at_a_time, one_shot, simulate_compile
from .ff_init import init_schedule_ff, tuned_fields
from .terms import batch_terms, group_batch
from .training import (
    DURATION,
    HELD_OUT,
    SCENARIOS,
    VALIDATION,
    as_kinds,
    best_reference_terms,
    loop_ms,
    make_batches,
    plant_ensemble,
    tune,
)


def _evaluate_fn(plant, controller, scenarios, weights):
    """Cost and test figures (means over rollouts) of one batch of scenarios: one program."""
    traj = rollouts(plant, controller, scenarios)
    return cost(traj, scenarios, weights), {k: jnp.mean(v) for k, v in metric_arrays(traj, scenarios).items()}


@functools.cache
def quick_evaluate():
    """`_evaluate_fn` compiled with `runtime.simulate_compile()` options, and the scenario
    builder `closedloop.compiled_make_scenario()` (a printer's scenarios as one program with
    `runtime.one_shot()` options; a fitted model's eager): compiled once per controller structure
    and scenario kind and run once, they cut the cold CPU time of `jthermo demo`'s held-out
    scenarios of the classical designs, with the same figures."""
    return (eqx.filter_jit(_evaluate_fn, compiler_options=simulate_compile()),
            compiled_make_scenario())


def evaluate(controller: AbstractController, plant, kind=SCENARIOS, seeds=(HELD_OUT,), *,
             rollouts: int = 8, duration: float = DURATION, weights=None,
             scenario_kw=None) -> dict:
    """Held-out evaluation: per scenario, the mean cost and metrics over `rollouts`
    realisations for each seed in `seeds` (use seeds never used in tuning); `scenario_kw`
    goes to `make_scenario` (a fitted model's `envelope`, `setpoint`).

    **Returns:** `{"cost": mean over scenarios, "scenarios": {kind: {"cost", "mse", ...}}}`.
    """
    run, scenario = quick_evaluate()
    out = {}
    for k in as_kinds(kind):
        costs, mets = [], []
        for s in seeds:
            sc = scenario(k, plant, duration, jax.random.key(int(s)),
                          n_rollouts=int(rollouts), **dict(scenario_kw or {}))
            # the kind is a label no rollout or score reads: one program for every kind
            J, m = jax.device_get(run(unlabelled(plant), controller, unlabelled(sc), weights))
            costs.append(float(J))
            mets.append(m)
        m = {name: float(np.mean([d[name] for d in mets])) for name in mets[0]}
        out[k] = {"cost": float(np.mean(costs)), **m}
    return {"cost": float(np.mean([v["cost"] for v in out.values()])), "scenarios": out}


def printer_model(printer):
    """The printer linearised at the window centre as a `StateSpace` (the grey-box model with
    the printer's known parameters): Jacobians of its one-sample map (`Printer.discretise`)
    at the steady state with no recoat or laser, outputs the bed sensors, operating point the
    steady input and the window-centre readings. Input delay is left out (a design model)."""
    if printer.has_areas:
        raise ControlError("printer_model: printers with areas 1–3 are not supported here")
    Ad, Bd, u0, y0 = _design_point(printer)
    C = jnp.eye(Ad.shape[0], dtype=Ad.dtype)[:printer.n_outputs]
    return StateSpace(Ad, Bd, C, ts=printer.ts, u0=u0, y0=y0)


@eqx.filter_jit
def _design_point(printer):
    """`(A, B, u0, y0)`: the Jacobians of the one-sample map in the state and the input at the
    steady state, the steady input and the readings there, as one compiled program (eager, it
    compiled about a hundred small ones: `benchmarks/tuning_profile.py`, phase design model)."""
    x0 = printer.initial_state()
    u0 = printer.steady_input()
    disc = printer.discretise()
    d = printer.default_disturbance()

    def f(z, u):
        buf = jnp.broadcast_to(u, x0.buffer.shape)        # the delay line holds u: no delay
        return disc.step(PrinterState(z=z, buffer=buf, since=x0.since), u, d).z

    return jax.jacfwd(f, 0)(x0.z, u0), jax.jacfwd(f, 1)(x0.z, u0), u0, printer.output(x0)


@functools.cache
def _one_shot_printer_model():
    return eqx.filter_jit(printer_model, compiler_options=one_shot())


def _printer_model(printer):
    """`printer_model` as one compiled program (eager, its conversions compiled a dozen small
    ones), compiled with `runtime.one_shot()` options (-O0: it runs once)."""
    return _one_shot_printer_model()(printer)


def _plant_from(plant, *, zones: int, powder: str, plant_seed: int):
    if isinstance(plant, str):
        if plant != "printer":
            raise ControlError(f"tune: unknown plant {plant!r} (use 'printer' or pass a plant)")
        return make_printer(zones, REALISTIC_EFFECTS, powder=powder, seed=plant_seed)
    if isinstance(plant, (Printer, AbstractModel)):
        return plant
    raise ControlError(f"tune: unsupported plant {type(plant).__name__}")


def rescaled_start(ctrl):
    """A MIMO PI (alone or inside a schedule feed-forward) with its gain matrices stored in
    units of their diagonal (`MIMOPI.rescaled`): the same loop, but an optimiser step no longer
    moves an off-diagonal entry (0 at the start, outside log space) by an absolute 0.05, which
    against integral gains per sample far below that destabilised the loop in one step (on the
    4-zone printer, the first Adam step)."""
    if isinstance(ctrl, MIMOPI):
        return ctrl.rescaled()
    if isinstance(ctrl, ScheduleFF) and isinstance(ctrl.feedback, MIMOPI):
        return eqx.tree_at(lambda c: c.feedback, ctrl, ctrl.feedback.rescaled())
    return ctrl


#: the classical designs `best_classical` is taken over (from the same design model)
CLASSICAL = ("pi_untuned", "pi_lambda", "pi_decoupled", "feedforward", "imc", "lqg",
             "pid_relay")


def classical_designs(model, families: Sequence[str] = CLASSICAL) -> dict:
    """`{family: controller}` of the classical designs on `model`; a design rule that does not
    apply to the model (a `ControlError`, e.g. IMC on non-minimum-phase zeros) is left out."""
    out = {}
    for f in families:
        try:
            out[f] = design(f, model)
        except ControlError:
            continue
    return out


def _same_controller(a, b) -> bool:
    """Same type, structure and leaf values (compared in NumPy: no compile)."""
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    return ta == tb and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))


def held_out_study(plants: dict, seeds, *, rollouts: int, duration: float,
                   chunk: int | None = None) -> tuple[list, list]:
    """`(items, batches)` of `held_out_terms`: the items `(label, kind, seed)` for every plant of
    `plants`, scenario and seed, and their grouped scenarios in batches of `chunk` items (all:
    None), the last one filled up by repeating its items; built once, simulated for any number
    of controllers (`held_out_terms(..., study=...)`)."""
    items = [(lab, k, s) for lab in plants for k in SCENARIOS for s in seeds]
    study = [(plants[lab], k, make_scenario(k, plants[lab], duration, jax.random.key(int(s)),
                                            n_rollouts=int(rollouts), shared=True))
             for lab, k, s in items]
    n = len(study) if not chunk else int(chunk)
    parts = [study[i:i + n] for i in range(0, len(study), n)]
    return items, [group_batch(p + [p[j % len(p)] for j in range(n - len(p))]) for p in parts]


def held_out_terms(ctrls: dict, plants: dict, seeds, *, rollouts: int, duration: float,
                   weights=None, chunk: int | None = None, study=None) -> dict:
    """Mean cost and measured MSE of each controller of `ctrls` (`{name: controller}`) on each
    plant of `plants` (`{label: plant}`) in the three scenarios, over `rollouts` realisations
    per seed of `seeds`, on the lean path (`batch_terms`: cost and mse accumulated in the scan,
    equal to `evaluate`'s `closedloop.cost` and `metrics` mse at weights without overshoot).
    Every plant, scenario and seed is one batch, simulated in one compiled program per
    controller structure; each distinct controller is simulated once (equal leaves, e.g. the
    start design and the same classical design made again, count as one). `chunk`: simulate
    the items in batches of this many (the last one filled up by repeating its items), so
    that a program compiled for a training batch of that many items (`tune`) serves here too.
    Every controller's simulations are dispatched before any is read, so that compiling the
    next structure overlaps running the previous one. `study`: `held_out_study`'s `(items,
    batches)` for these plants, seeds, rollouts, duration and chunk, made once for many calls.

    **Returns:** `{name: {label: {"cost": mean over scenarios, "scenarios": {kind: {"cost",
    "mse"}}}}}`.
    """
    items, batches = study if study is not None else held_out_study(
        plants, seeds, rollouts=rollouts, duration=duration, chunk=chunk)
    reps: list = []

    def distinct(c):
        r = next((r for r in reps if r is c or _same_controller(r, c)), None)
        if r is None:
            reps.append(c)
        return c if r is None else r

    which = {name: distinct(c) for name, c in ctrls.items()}
    done: dict[int, dict] = {}
    pending = [[batch_terms(c, b, weights) for b in batches] for c in reps]
    for c, outs in zip(reps, pending):
        v = np.concatenate([np.asarray(o) for o in outs])[:len(items)]
        per = {lab: {k: {q: float(np.mean([v[i, j] for i, (l2, k2, _) in enumerate(items)
                                            if l2 == lab and k2 == k]))
                         for j, q in enumerate(("cost", "mse"))} for k in SCENARIOS}
               for lab in plants}
        done[id(c)] = {lab: {"cost": float(np.mean([d["cost"] for d in sc.values()])),
                             "scenarios": sc} for lab, sc in per.items()}
    return {name: done[id(c)] for name, c in which.items()}


def _staged(name: str, fn: Callable) -> Callable:
    """`fn` run inside `progress.stage(name)` (for the second thread: the watchdog names it)."""
    def run(*args, **kwargs):
        with stage(name):
            return fn(*args, **kwargs)
    return run


def _training_sets(plants, rollouts: int, duration: float, seed: int):
    """`(batches, validation)` as `tune` draws them for `plants` in the three scenarios: the
    training batch from `seed`, the guard's from `seed + VALIDATION` with the same rollouts
    and length."""
    train = make_batches(plants, SCENARIOS, rollouts=rollouts, duration=duration, seed=seed)
    sc = train[0][0][2]
    B, T = sc.r.shape[:2]
    val = make_batches(plants, SCENARIOS, rollouts=int(B), duration=float(T * sc.ts),
                       seed=int(seed) + VALIDATION)[0]
    return train, val


def _fixed_held_out(model, start, lam_pi, refs, plants: dict, seeds, kw: dict):
    """`(classical, study, terms)` for `tune_report`: the classical designs on `model`
    (`classical_designs`, with `lam_pi` as pi_lambda), the held-out study (`held_out_study`)
    and `held_out_terms` of the start, the lambda PI and every classical design on it,
    structures other than those of the start and `refs` simulated first (the tuning compiles
    those itself meanwhile: not both threads at once)."""
    classical = {**classical_designs(model), "pi_lambda": lam_pi}
    ctrls = {"start": start, "lambda_pi": lam_pi, **classical}
    tuning = [jax.tree_util.tree_structure(c) for c in (start, *refs)]
    ctrls = dict(sorted(ctrls.items(),
                        key=lambda kv: jax.tree_util.tree_structure(kv[1]) in tuning))
    study = held_out_study(plants, seeds, rollouts=kw["rollouts"], duration=kw["duration"],
                           chunk=kw["chunk"])
    return classical, study, held_out_terms(ctrls, plants, seeds, study=study, **kw)


def _held_out_comparison(res: dict, label: str, classical: Sequence[str] = ()) -> dict:
    """From `held_out_terms` results `res` (with `start`, `tuned`, `lambda_pi` and the
    `classical` design names), on plant `label`: the mean costs, `improvement_percent` =
    100·(1 − tuned/lambda_pi), the best classical design and
    `improvement_vs_best_classical_percent` = 100·(1 − tuned/best classical), per-scenario
    MSE/cost."""
    r = {name: v[label] for name, v in res.items()}
    suffix = {"start": "before", "tuned": "after", "lambda_pi": "lambda_pi"}
    scen = {k: {f"{q}_{suffix[name]}": r[name]["scenarios"][k][q]
                for q in ("mse", "cost") for name in suffix} for k in SCENARIOS}
    tuned, lam_c = r["tuned"]["cost"], r["lambda_pi"]["cost"]
    out = {"start_cost": r["start"]["cost"], "tuned_cost": tuned, "lambda_pi_cost": lam_c,
           "improvement_percent": 100.0 * (1.0 - tuned / lam_c), "scenarios": scen}
    costs = {f: r[f]["cost"] for f in classical}
    finite = {f: v for f, v in costs.items() if np.isfinite(v)}
    if finite:
        best = min(finite, key=finite.get)
        out.update(best_classical=best, best_classical_cost=finite[best],
                   improvement_vs_best_classical_percent=100.0 * (1.0 - tuned / finite[best]),
                   classical_costs=costs)
    return out


def _gain_plants(plant, gain_change: float) -> dict:
    """`{label: plant}` with every heater gain of the `Printer` scaled by 1 ± `gain_change`."""
    return {f"gain_{label}_{round(100 * gain_change)}_cost":
            eqx.tree_at(lambda q: q.gain, plant, plant.gain * (1.0 + sign * gain_change))
            for sign, label in ((1.0, "plus"), (-1.0, "minus"))}


def robustness(ctrls: dict, plant, model, seeds, *, rollouts: int, duration: float,
               weights=None, gain_change: float = 0.2, terms: dict | None = None) -> dict:
    """The loops of `ctrls` (`{name: controller}`) judged beyond their tuning: peak sensitivity
    $M_s$ on the linear `model` (`control.margins.peak_sensitivity`; None for a controller
    with no linear feedback form) and, for a `Printer`, the held-out cost with every heater gain
    scaled by 1 ± `gain_change`. `terms`: `held_out_terms` results that already hold the
    gain-changed plants (`_gain_plants` labels), else they are simulated here."""
    out: dict = {"ms": {}, "stable": {}}
    for name, c in ctrls.items():
        try:
            m = peak_sensitivity(model, c)
        except ControlError:
            m = {"ms": None, "stable": None}
        out["ms"][name], out["stable"][name] = m["ms"], m["stable"]
    if isinstance(plant, Printer):
        gp = _gain_plants(plant, gain_change)
        if terms is None or any(lab not in terms[n] for n in ctrls for lab in gp):
            terms = held_out_terms(ctrls, gp, seeds, rollouts=rollouts, duration=duration,
                                   weights=weights)
        for lab in gp:
            out[lab] = {name: terms[name][lab]["cost"] for name in ctrls}
    return out


def tune_report(controller_family: str, *, plant="printer", model=None, rollouts: int = 8,
                steps: int = 200, seed: int = 0, lr: float = 0.05, zones: int = 4,
                powder: str = "PA12", duration: float = DURATION, plant_seed: int = 0,
                eval_rollouts: int | None = None, weights=None, ensemble: int = 2,
                references: Sequence[str] = ("pi_lambda",), changed_powder: str | None = "auto",
                check_robustness: bool = True, ff_init: bool = True,
                ms_max: float | None = 2.0, optimiser: str = "adam", ms_weight: float = 0.0,
                params: Sequence[str] | str | None = "auto", train_dtype: str | None = None,
                progress: Callable[[int, float], None] | None = None) -> dict:
    """Tune one controller family against the virtual printer and report on held-out seeds.

    Starts from the classical design of `controller_family` (see `control.design`) on `model`
    (default: the printer linearised at the window centre, `printer_model`), tunes it on
    disturbance seeds drawn from `seed` on the printer and, for a `Printer`, `ensemble`
    perturbed copies of it (`plant_ensemble`), guarded on validation seeds against the start
    and the designs named in `references` (families designed on the same model), and evaluates
    start, tuned and the lambda-tuned diagonal PI on the held-out seed `seed + HELD_OUT` in
    the three scenarios, with every classical design of `CLASSICAL` on the same model and seeds
    (the best of them: `best_classical`); for the built-in printer also on the printer with
    `changed_powder` (`"auto"`: PA11 when tuned on PA12, else PA12; None: skip), which tuning
    never saw; with `check_robustness`, the peak sensitivity of the tuned, start and best
    classical loops on `model` and their cost at ±20 % heater gain (`robustness`). With
    `ff_init`, a schedule feed-forward family on a `Printer` starts with its taps at the
    least-squares inverse of each event's effect (`ff_init.init_schedule_ff`), not at zero.
    With `ms_max` (None: off), the guard returns only an iterate whose peak sensitivity on
    `model` is at most `ms_max` (else the start design), for the families `peak_sensitivity`
    covers; others are tuned unconstrained and reported with `computable: False`.
    `optimiser`: `"adam"` or `"lbfgs"` (`minimise`; `steps` is then the most iterations).
    `ms_weight` > 0 also penalises the soft peak sensitivity above `ms_max` inside the tuning
    objective (`tune`, `sensitivity.ms_penalty`). `params`: the fields tuned (`tune`; None:
    every array leaf; `"auto"`: `ff_init.tuned_fields`, the taps alone for `pi_ff`, `lqg_ff`).
    `train_dtype`: `"float32"` for the training rollouts only (`tune`); the guard and every
    held-out figure stay in the plant's precision.

    Two threads: while this one linearises the printer, designs and tunes, a second one draws
    the training and validation scenarios, simulates the start and the references on the
    training set (while this one compiles the training step), then designs the classical
    controllers and simulates every controller tuning does not change on the held-out seeds,
    so that on two cores their compiles and runs overlap the tuning loop; the results are
    those of one thread. Both threads' programs factor batches of matrices (at 16 zones the
    plants' steady states, 9 x 33 x 33), which jaxlib's batched LAPACK kernels deal to XLA's
    CPU pool and wait for: two at once deadlocked a two-core machine (every thread asleep),
    so they are lowered one matrix at a time first (`runtime.one_matrix_at_a_time`, the same
    figures bit for bit). Against no second thread (its work in turn on this one, with the
    batched kernels) this measured faster on `lqg` at 16 zones cold and about equal warm, with
    the same report (`python experiments/printer_scale.py --zones '' --ab`).
    The main thread names its stages for the watchdog (`progress.stage`), the second one
    each task it runs.

    **Returns:** a JSON-ready dict with `controller`, `start_cost`, `tuned_cost`,
    `lambda_pi_cost`, `improvement_percent` (100·(1 − tuned/lambda_pi)), `best_classical`,
    `best_classical_cost`, `improvement_vs_best_classical_percent`, `classical_costs`,
    `robustness` (`{"ms", "stable", "gain_plus_20_cost", "gain_minus_20_cost"}`), `scenarios`
    (per-scenario MSE and cost before/after, and of the lambda PI), `changed_powder` (the same
    figures on the other powder, or None), `ms_constraint` (`{"ms_max", "chosen_ms",
    "satisfied", "computable", "rejected_for_ms"}`, None when `ms_max` is None), `history`,
    `seconds`, and
    the tuned controller under the key `"tuned"` (not JSON: pop it before writing).
    """
    t0 = time.perf_counter()
    one_matrix_at_a_time()   # two threads' programs: no LAPACK kernel may wait on XLA's pool
    pl = _plant_from(plant, zones=zones, powder=powder, plant_seed=plant_seed)
    if changed_powder == "auto":
        changed_powder = "PA11" if powder != "PA11" else "PA12"
    ens = plant_ensemble(pl, ensemble, seed=plant_seed) if isinstance(pl, Printer) and \
        ensemble else [pl]
    # a second thread draws the training and validation scenarios while this one linearises
    # the printer and designs, then simulates the designs that tuning does not change on the
    # held-out seeds while the tuning loop runs: their compiles and runs overlap this thread's
    with ThreadPoolExecutor(max_workers=1) as pool, stage("tune: designing"):
        drawn = pool.submit(_staged("tune: drawing scenarios", _training_sets), ens, rollouts,
                            duration, seed)
        if model is None:
            model = pl if isinstance(pl, AbstractModel) else _printer_model(pl)
        start = design(controller_family, model)
        if ff_init and isinstance(start, ScheduleFF) and isinstance(pl, Printer):
            # schedule feed-forward taps from the printer's response to each event (`ff_init`)
            start = init_schedule_ff(start, pl)
        start = rescaled_start(start)
        lam_pi = design("pi_lambda", model)
        refs = [design(f, model) for f in references if f != controller_family]
        seeds = (int(seed) + HELD_OUT,)
        er = eval_rollouts or rollouts
        plants = {"plant": pl}
        if isinstance(plant, str) and changed_powder:
            # the same controllers on the printer with the other powder, never seen in tuning
            plants["changed"] = _plant_from("printer", zones=zones, powder=changed_powder,
                                            plant_seed=plant_seed)
        if check_robustness and isinstance(pl, Printer):
            plants.update(_gain_plants(pl, 0.2))
        # every controller on every plant, scenario and seed: one program per controller
        # structure in batches of the training's item count: the tuned structure's (and the
        # references') compiled simulation serves again (same plants structure, rollouts and
        # duration)
        chunk = len(ens) * len(as_kinds(SCENARIOS)) if er == rollouts else None
        kw = {"rollouts": er, "duration": duration, "weights": weights, "chunk": chunk}
        # the references on the training set, while this thread compiles the training step
        best = pool.submit(_staged("tune: references on the training set",
                                   lambda: best_reference_terms([start, *refs],
                                                                drawn.result()[0], weights,
                                                                with_first=True)))
        fixed = pool.submit(_staged("tune: classical designs on held-out seeds", _fixed_held_out),
                            model, start, lam_pi, refs, plants, seeds, kw)
        train, val = drawn.result()
        with stage("tune: training"):
            res = tune(start, pl, plants=ens, scenarios=train, validation=val, lr=lr, steps=steps,
                       weights=weights, references=refs, progress=progress,
                       reference_terms=best.result,
                       ms_max=ms_max, ms_model=model, optimiser=optimiser, ms_weight=ms_weight,
                       params=tuned_fields(start) if params == "auto" else params,
                       train_dtype=train_dtype)
        with stage("tune: waiting for the classical designs' held-out evaluation"):
            classical, study, terms = fixed.result()
    ms_c = (res.guard or {}).get("ms_constraint")
    if ms_c is None and ms_max is not None:     # no guard record: judge the returned loop
        ms = loop_ms(model, res.controller)
        ms_c = {"ms_max": float(ms_max), "chosen_ms": ms, "computable": ms is not None,
                "satisfied": None if ms is None else bool(ms <= ms_max), "rejected_for_ms": []}
    ctrls = {"start": start, "tuned": res.controller, "lambda_pi": lam_pi, **classical}
    with stage("tune: held-out evaluation"):
        terms["tuned"] = terms["start"] if _same_controller(res.controller, start) else \
            held_out_terms({"tuned": res.controller}, plants, seeds, study=study, **kw)["tuned"]
    held = _held_out_comparison(terms, "plant", classical)
    changed = None if "changed" not in plants else {
        "powder": changed_powder, **_held_out_comparison(terms, "changed", classical)}
    robust = None
    if check_robustness:
        best = held.get("best_classical")
        names = ["tuned", "start"] + ([] if best is None else [best])
        with stage("tune: robustness"):
            robust = robustness({("best_classical" if n == best else n): ctrls[n]
                                 for n in names}, pl, model, seeds, rollouts=er,
                                duration=duration, weights=weights,
                                terms={("best_classical" if n == best else n): terms[n]
                                       for n in names})
    return {"controller": controller_family, **held,
            "changed_powder": changed, "robustness": robust, "ms_constraint": ms_c,
            "train_start_cost": res.start_cost, "train_tuned_cost": res.tuned_cost,
            "guard": {k: v for k, v in (res.guard or {}).items() if k != "candidates"},
            "ensemble": len(plants),
            "history": [float(h) for h in res.history], "rollouts": int(rollouts),
            "optimiser": res.method, "evaluations": res.evaluations,
            "ms_weight": float(ms_weight), "train_dtype": train_dtype,
            "steps": int(steps), "seed": int(seed), "held_out_seeds": list(seeds),
            "duration": float(duration), "zones": int(getattr(pl, "zones", 0) or 0),
            "powder": powder, "ff_init": bool(ff_init and isinstance(start, ScheduleFF)),
            "seconds": time.perf_counter() - t0, "tuned": res.controller}
