"""Sweep results and tuning histories as pandas DataFrames, for the scripts and notebooks that
read them: one row per trial (its parameters, status and metrics as columns), one row per
tuning iteration. pandas is imported only when a frame is asked for."""

from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError
from .config import current_rows


def _pandas():
    try:
        import pandas
    except ImportError:
        raise ConfigError("DataFrames need pandas: pip install 'pandas>=2.0'") from None
    return pandas


def _scalar(v) -> bool:
    return v is None or isinstance(v, (bool, int, float, str, np.generic))


def _flat(metrics: dict) -> dict:
    """Scalar metrics as they are, a list of scalars (one per output) as `name_1 .. name_n`;
    nested tables (per-scenario reports) are left out."""
    out = {}
    for k, v in metrics.items():
        if _scalar(v):
            out[k] = v
        elif isinstance(v, (list, tuple)) and all(_scalar(x) for x in v):
            out.update({f"{k}_{i}": x for i, x in enumerate(v, 1)})
    return out


def results_frame(rows: list[dict], cfg: dict | None = None, *, stale: bool = False):
    """A DataFrame of a sweep's trials: one row per trial id (its latest record), columns `id`,
    `status`, the parameters, `seconds`, `error` and the flattened metrics (a metric named
    like a parameter is left out: the column holds what was asked for).

    **Arguments:**
    - `rows`: the records of a results file (`read_results(path)`).
    - `cfg`: the sweep's configuration; with it the rows are sorted best first by its
      objective, and failed trials come last.
    - `stale`: keep the records of another jthermo version too (default: `current_rows`).
    """
    pd = _pandas()
    latest = {r["id"]: r for r in (rows if stale else current_rows(rows))}
    table = []
    for r in latest.values():
        params = dict(r.get("params", {}))
        metrics = {k: v for k, v in _flat(r.get("metrics") or {}).items() if k not in params}
        table.append({"id": r["id"], "status": r.get("status"), **params,
                      "seconds": r.get("seconds"), "error": r.get("error"), **metrics})
    df = pd.DataFrame(table)
    if cfg is not None and not df.empty and cfg["objective"] in df:
        score = pd.to_numeric(df[cfg["objective"]], errors="coerce")
        df = df.assign(_key=score).sort_values("_key", ascending=cfg["direction"] == "min",
                                               na_position="last", kind="stable")
        df = df.drop(columns="_key").reset_index(drop=True)
    return df


def history_frame(result):
    """A DataFrame of a tuning run's training cost per iteration (columns `iteration`, `cost`).

    `result`: a `tune.TuneResult`, or a report dict with a `"history"` list (`tune_report`,
    `tune_own_plant`, a sweep's tune trial metrics)."""
    from ..tune import TuneResult

    pd = _pandas()
    history = result.get("history") if isinstance(result, dict) else \
        result.history if isinstance(result, TuneResult) else None
    if history is None:
        raise ConfigError(f"history_frame: {type(result).__name__} carries no tuning history")
    cost = [math.nan if v is None else float(v) for v in np.ravel(np.asarray(history, dtype=object))]
    return pd.DataFrame({"iteration": np.arange(len(cost)), "cost": np.asarray(cost, float)})
