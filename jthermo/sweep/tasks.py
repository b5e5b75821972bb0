"""What one sweep trial does, per kind: fit a model with `identify.fit` and score it with
`validate.compare` on validation data (`arx`: ARX orders, by default on a simulated coupled
bed; `identify`: any family, by default on the virtual printer's data; both on a data file
with `data = "file.csv"`), or tune a controller (`tune`: on the virtual printer, or on a
user's fitted model with `model = "file.jtm"` / `plant = "file.jtm"`, `tune.tune_own_plant`).

`run_trial` records the outcome (failures included) as a JSON-ready dict. Every trial runs in
float64 inside a scoped `jax.enable_x64` context, as the `jthermo` command does; JAX's global
configuration is left as it was (an in-process sweep changes nothing for its caller)."""

from __future__ import annotations

import math
import os
import time
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np

from .. import runtime
from ..errors import ConfigError, JThermoError
from .config import RECORD_KEYS, trial_salt, trial_settings

#: trial settings that `fit` takes as named arguments (the rest are family options)
_FIT_ARGS = ("seed", "n_starts", "criterion")


def setting(name: str, params: dict, settings: dict, default=None):
    """A trial setting: the trial's parameter, else the sweep's `[data]` value, else `default`."""
    return params.get(name, settings.get(name, default))


def float64():
    """A context in which JAX computes in float64, restoring the caller's setting on exit
    (`jax.enable_x64`, `jax.experimental.enable_x64` on older JAX)."""
    import jax

    scoped = getattr(jax, "enable_x64", None)
    if scoped is None:  # JAX before the context manager moved to the top level
        from jax.experimental import enable_x64 as scoped
    return scoped(True)


def simulated_bed(settings: dict):
    """A small, deterministic multi-zone record (`IOData`, Ts = 1 s): a 2nd-order coupled bed
    $y_k = 1.6 y_{k-1} - (0.64 I - 0.01 (J - I)) y_{k-2} + (0.5 I + 0.1 (J - I)) u_{k-2}$ (J: all
    ones) around 20 °C, random binary heater levels held 5..30 samples, white sensor noise."""
    from ..data import from_arrays

    zones = int(settings.get("zones", 2))
    T = int(settings.get("samples", 2000))
    noise = float(settings.get("noise", 0.05))
    rng = np.random.default_rng(int(settings.get("data_seed", 0)))
    u = np.empty((T, zones))
    for j in range(zones):
        k = 0
        while k < T:
            h = int(rng.integers(5, 31))
            u[k:k + h, j] = rng.choice([0.2, 0.6])
            k += h
    off = np.ones((zones, zones)) - np.eye(zones)
    A1, A2 = 1.6 * np.eye(zones), -0.64 * np.eye(zones) + 0.01 * off
    B = 0.5 * np.eye(zones) + 0.1 * off
    y = np.zeros((T, zones))
    for k in range(2, T):
        y[k] = A1 @ y[k - 1] + A2 @ y[k - 2] + B @ u[k - 2]
    y = y + 20.0 + noise * rng.standard_normal((T, zones))
    return from_arrays(u, y, ts=1.0)


def _records(kind: str, settings: dict):
    """(estimation, validation) records: the data file(s) of `[data]`, else simulated; with no
    validation record, the first and second halves of the estimation one."""
    from .. import data as data_mod

    if "data" in settings:
        est = data_mod.load(settings["data"])
        val = data_mod.load(settings["validation"]) if "validation" in settings else None
    elif kind == "arx":
        est, val = simulated_bed(settings), None
    else:
        from ..printer import generate, make_printer

        seed = int(settings.get("data_seed", 0))
        p = make_printer(int(settings.get("zones", 2)), tuple(settings.get("effects", ())), seed=seed)
        est, val = generate(p, "prbs", float(settings.get("duration", 1200)), seed=seed), None
    return data_mod.split(est, 0.5) if val is None else (est, val)


def _fit_trial(kind: str, params: dict, settings: dict) -> dict:
    """`fit(est, family, orders, **options)` then `compare(model, val)` (simulation fit %)."""
    from ..identify import fit
    from ..identify.result import ORDER_NAMES
    from ..validate import compare

    family = "arx" if kind == "arx" else setting("family", params, settings, "arx")
    if family not in ORDER_NAMES:
        raise ConfigError(f"{kind} trial: unknown family {family!r} "
                          f"(expected one of {', '.join(ORDER_NAMES)})")
    names = ORDER_NAMES[family]
    given = [n for n in names if setting(n, params, settings) is not None]
    if given and len(given) != len(names):
        raise ConfigError(f"{kind} trial: {family} needs all of the orders {', '.join(names)}")
    orders = tuple(setting(n, params, settings) for n in names) if given else None
    skip = {"family", *names, *(n for o in ORDER_NAMES.values() for n in o), *RECORD_KEYS[kind]}
    options = {k: setting(k, params, settings) for k in trial_settings(kind) - skip
               if setting(k, params, settings) is not None}
    est, val = _records(kind, {**settings, **{k: params[k] for k in RECORD_KEYS[kind] if k in params}})
    res = fit(est, family, orders, **options)
    cmp = compare(res.model, val)
    return {"family": family, "orders": dict(res.orders or {}), "options": options,
            "fit_percent": cmp["fit_percent"], "mean_fit_percent": cmp["mean_fit_percent"],
            "converged": bool(getattr(res, "converged", True))}


def _own_plant(settings: dict):
    """(design model, plant, validation plant, envelope) of a tune sweep on fitted models:
    `model` designs (default: the plant), `plant` is tuned on (default: the model)."""
    from .. import io

    files = {k: settings[k] for k in ("model", "plant", "validation_plant")
             if k in settings and settings[k] != "printer"}
    loaded = {k: io.load_model(v) for k, v in files.items()}
    model = loaded.get("model", loaded.get("plant"))
    env = io.load_envelope(files.get("model", files.get("plant")))
    return model, loaded.get("plant", model), loaded.get("validation_plant"), env


def _tune_trial(params: dict, settings: dict) -> dict:
    from ..closedloop import DEFAULT_WEIGHTS
    from ..tune import tune_own_plant, tune_report

    family = setting("controller", params, settings, "pi_lambda")
    weights = {t: float(setting(f"w_{t}", params, settings)) for t in DEFAULT_WEIGHTS
               if setting(f"w_{t}", params, settings) is not None}
    common = {"rollouts": int(setting("rollouts", params, settings, 8)),
              "steps": int(setting("steps", params, settings, 20)),
              "seed": int(setting("seed", params, settings, 0)),
              "lr": float(setting("lr", params, settings, 0.05)),
              "weights": weights or None, "progress": None}
    if "duration" in params or "duration" in settings:
        common["duration"] = float(setting("duration", params, settings))
    if "references" in settings:
        common["references"] = tuple(settings["references"])
    if settings.get("plant", "printer") != "printer" or "plant" not in settings and "model" in settings:
        model, plant, validation, env = _own_plant(settings)
        extra = {"classical": tuple(settings["classical"])} if "classical" in settings else {}
        rep = tune_own_plant(family, model, plant=plant, envelope=env,
                             setpoint=setting("setpoint", params, settings),
                             validation_plant=validation, **common, **extra)
    else:   # the virtual printer, designed from its linearisation or from `model`
        for k in ("setpoint", "validation_plant", "classical"):
            if setting(k, params, settings) is not None:
                raise ConfigError(f"tune trial: `{k}` is for a fitted plant (plant = \"file.jtm\")")
        from .. import io

        model = io.load_model(settings["model"]) if "model" in settings else None
        rep = tune_report(family, plant="printer", model=model,
                          zones=int(settings.get("zones", 4)),
                          powder=str(settings.get("powder", "PA12")),
                          plant_seed=int(settings.get("plant_seed", 0)), **common)
    return {k: v for k, v in rep.items() if isinstance(v, (int, float, str, bool, list, dict, type(None)))}


_TRIAL_FUNCS: dict[str, Callable[[dict, dict], dict]] = {
    "arx": lambda params, settings: _fit_trial("arx", params, settings),
    "identify": lambda params, settings: _fit_trial("identify", params, settings),
    "tune": _tune_trial}


def run_trial(kind: str, trial: dict, settings: dict) -> dict:
    """Run one trial in float64 (scoped); never raises: failures are recorded with their
    one-line reason. The process's compiled programs are kept below the memory-map bound
    first (`runtime.guard`): a worker runs trials of many shapes."""
    runtime.one_matrix_at_a_time()   # a worker process: LAPACK one matrix at a time, as the CLI
    runtime.guard()
    t0 = time.perf_counter()
    record: dict[str, Any] = {"id": trial["id"], "params": trial["params"], "kind": kind,
                              "salt": trial_salt()}
    try:
        with float64():
            metrics = _TRIAL_FUNCS[kind](trial["params"], settings)
        record.update(status="ok", metrics=clean_json(metrics))
    except JThermoError as exc:
        record.update(status="error", error=" ".join(str(exc).split()))
    except Exception as exc:  # noqa: BLE001 - one failing trial must not stop a sweep
        record.update(status="error", error=f"{type(exc).__name__}: {' '.join(str(exc).split())}",
                      where=traceback.format_exc(limit=2).splitlines()[-1][:200])
    record["seconds"] = time.perf_counter() - t0
    record["finished_at"] = time.time()
    # the process that ran it and its memory maps at the end (a worker's health over a sweep)
    record["worker"] = {"pid": os.getpid(), "maps": runtime.memory_maps()}
    return record


def clean_json(x):
    """A JSON-ready copy: NumPy values become numbers and lists, NaN and inf None."""
    if isinstance(x, dict):
        return {str(k): clean_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [clean_json(v) for v in x]
    if isinstance(x, (np.generic, np.ndarray)):
        return clean_json(np.asarray(x).tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x
