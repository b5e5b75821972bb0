"""What one sweep trial does, per kind: a fast NumPy ARX order fit (`arx`), a model fit and
validation (`identify`) or a controller tuning report (`tune`); `run_trial` records the
outcome (failures included) as a JSON-ready dict."""

from __future__ import annotations

import math
import time
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np

from ..errors import ConfigError, JThermoError


def _simulated_arx_data(settings: dict):
    """A small, deterministic multi-zone data set: a 2nd-order coupled bed with noise."""
    zones = int(settings.get("zones", 2))
    T = int(settings.get("samples", 2000))
    noise = float(settings.get("noise", 0.05))
    seed = int(settings.get("data_seed", 0))
    rng = np.random.default_rng(seed)
    # input: random binary levels held for 5..30 samples per channel
    u = np.empty((T, zones))
    for j in range(zones):
        k = 0
        while k < T:
            h = int(rng.integers(5, 31))
            u[k:k + h, j] = rng.choice([0.2, 0.6])
            k += h
    A1 = 1.6 * np.eye(zones)
    A2 = -0.64 * np.eye(zones) + 0.01 * (np.ones((zones, zones)) - np.eye(zones))
    B = 0.5 * np.eye(zones) + 0.1 * (np.ones((zones, zones)) - np.eye(zones))
    y = np.zeros((T, zones))
    for k in range(2, T):
        y[k] = A1 @ y[k - 1] + A2 @ y[k - 2] + B @ u[k - 2]
    y = y + 20.0 + noise * rng.standard_normal((T, zones))
    return u, y


def _arx_trial(params: dict, settings: dict) -> dict:
    """Diagonal MISO ARX by least squares (numpy only: fast, no compile), simulation fit on the
    second half of the data."""
    na, nb, nk = int(params.get("na", 2)), int(params.get("nb", 2)), int(params.get("nk", 1))
    if na < 0 or nb < 1 or nk < 0:
        raise ConfigError(f"arx trial: invalid orders na={na}, nb={nb}, nk={nk}")
    if "data" in settings:
        from ..data import load

        d = load(settings["data"])
        u, y = d.u, d.y
    else:
        u, y = _simulated_arx_data(settings)
    T, ny = y.shape
    nu = u.shape[1]
    half = T // 2
    u_mean, y_mean = u[:half].mean(0), y[:half].mean(0)
    du, dy = u - u_mean, y - y_mean
    lag = max(na, nb + nk - 1, 1)
    fits = []
    n_params = na + nb * nu
    for i in range(ny):
        rows = range(lag, half)
        X = np.array([[-dy[k - j, i] for j in range(1, na + 1)]
                      + [du[k - nk - j, m] for m in range(nu) for j in range(nb)] for k in rows])
        theta, *_ = np.linalg.lstsq(X, dy[lag:half, i], rcond=None)
        a, b = theta[:na], theta[na:].reshape(nu, nb)
        # simulate on the validation half from the measured initial lags
        ysim = dy[:, i].copy()
        for k in range(half, T):
            ysim[k] = -sum(a[j - 1] * ysim[k - j] for j in range(1, na + 1)) + sum(
                b[m, j] * du[k - nk - j, m] for m in range(nu) for j in range(nb))
        yv, ys = dy[half:, i], ysim[half:]
        fits.append(float(100.0 * (1.0 - np.linalg.norm(yv - ys) / np.linalg.norm(yv - yv.mean()))))
    fits = [f if math.isfinite(f) else -1e9 for f in fits]
    return {"fit_percent": fits, "mean_fit_percent": float(np.mean(fits)), "n_params": n_params}


def _identify_trial(params: dict, settings: dict) -> dict:
    from .. import data as data_mod
    from ..identify.fit import fit
    from ..validate import compare

    family = params.get("family", settings.get("family", "arx"))
    from ..identify.fit import ORDER_NAMES

    names = ORDER_NAMES.get(family, ())
    given = [n for n in names if n in params]
    if given and len(given) != len(names):
        raise ConfigError(f"identify trial: {family} needs all of the orders {', '.join(names)}")
    orders = tuple(int(params[n]) for n in names) if given else None
    if "data" in settings:
        est = data_mod.load(settings["data"])
        val = data_mod.load(settings["validation"]) if "validation" in settings else None
    else:
        from ..printer import generate, make_printer

        p = make_printer(int(settings.get("zones", 2)), tuple(settings.get("effects", ())),
                         seed=int(settings.get("data_seed", 0)))
        est = generate(p, "prbs", float(settings.get("duration", 1200)), seed=int(settings.get("data_seed", 0)))
        val = None
    if val is None:
        est, val = data_mod.split(est, 0.5)
    res = fit(est, family, orders, seed=int(params.get("seed", 0)))
    cmp = compare(res.model, val)
    return {"family": family, "orders": dict(res.orders or {}),
            "fit_percent": cmp["fit_percent"], "mean_fit_percent": cmp["mean_fit_percent"],
            "converged": bool(getattr(res, "converged", True))}


def _tune_trial(params: dict, settings: dict) -> dict:
    from ..tune import tune_report

    family = params.get("controller", settings.get("controller", "pi_lambda"))
    kwargs = {k: v for k, v in params.items() if k not in ("controller",)}
    weights = {k[len("w_"):]: float(v) for k, v in kwargs.items() if k.startswith("w_")}
    extra: dict[str, Any] = {}
    if weights:
        extra["weights"] = weights
    rep = tune_report(family, plant=settings.get("plant", "printer"), model=None,
                      rollouts=int(params.get("rollouts", settings.get("rollouts", 8))),
                      steps=int(params.get("steps", settings.get("steps", 20))),
                      seed=int(params.get("seed", settings.get("seed", 0))), progress=None, **extra)
    return {k: v for k, v in rep.items() if isinstance(v, (int, float, str, bool, list, dict, type(None)))}


_TRIAL_FUNCS: dict[str, Callable[[dict, dict], dict]] = {
    "arx": _arx_trial, "identify": _identify_trial, "tune": _tune_trial}


def run_trial(kind: str, trial: dict, settings: dict) -> dict:
    """Run one trial; never raises: failures are recorded with their one-line reason."""
    t0 = time.perf_counter()
    record: dict[str, Any] = {"id": trial["id"], "params": trial["params"], "kind": kind}
    try:
        if kind != "arx":
            import jax

            jax.config.update("jax_enable_x64", True)  # a worker process: identification needs float64
        metrics = _TRIAL_FUNCS[kind](trial["params"], settings)
        record.update(status="ok", metrics=clean_json(metrics))
    except JThermoError as exc:
        record.update(status="error", error=" ".join(str(exc).split()))
    except Exception as exc:  # noqa: BLE001 - one failing trial must not stop a sweep
        record.update(status="error", error=f"{type(exc).__name__}: {' '.join(str(exc).split())}",
                      where=traceback.format_exc(limit=2).splitlines()[-1][:200])
    record["seconds"] = time.perf_counter() - t0
    record["finished_at"] = time.time()
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
