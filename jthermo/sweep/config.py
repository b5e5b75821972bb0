"""Sweep configuration: the TOML schema and its checks, the embedded default sweep, and the
list of trials a configuration defines (grid or random draws, each with a stable id)."""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
from pathlib import Path

import numpy as np

from ..errors import ConfigError

KINDS = ("arx", "identify", "tune")

#: `[data]` keys each kind reads: where the data (or the plant) comes from; anything else is a
#: typo and a `ConfigError`. The trial settings of `SETTINGS` may be given here too (the same
#: for every trial, not part of the trial ids).
DATA_KEYS = {
    "arx": ("data", "validation", "zones", "samples", "noise", "data_seed"),
    "identify": ("data", "validation", "zones", "effects", "duration", "data_seed"),
    "tune": ("plant", "model", "validation_plant", "zones", "powder", "plant_seed",
             "classical", "references"),
}
#: trial settings each kind reads from the parameters ([space], [fixed]) or from [data]; the
#: identification kinds also take every order name and every option of `identify.fit`, the
#: tuning kind a cost weight `w_<term>` per term of `closedloop.DEFAULT_WEIGHTS`
SETTINGS = {
    "arx": ("seed", "n_starts", "criterion"),
    "identify": ("family", "seed", "n_starts", "criterion"),
    "tune": ("controller", "rollouts", "steps", "seed", "lr", "duration", "setpoint"),
}
#: the `[data]` keys of a simulated record that a trial may also take as parameters ([space],
#: [fixed]): a sweep over record lengths, zone counts or data seeds. With `data = "file"`
#: they have nothing to act on and are refused.
RECORD_KEYS = {
    "arx": ("zones", "samples", "noise", "data_seed"),
    "identify": ("zones", "duration", "data_seed"),
    "tune": (),
}

DEFAULT_CONFIG = """
# The embedded default: ARX orders on a simulated two-zone bed (each trial a `fit` and a
# `compare`, one compile per order set: 18 trials), then read the best ones.
[sweep]
name = "default"
kind = "arx"
method = "grid"
seed = 0
objective = "mean_fit_percent"
direction = "max"

[data]
zones = 2
samples = 2000
noise = 0.05

[space]
na = [1, 2, 3]
nb = [1, 2, 3]
nk = [1, 2]
"""

_DEFAULTS = {"method": "grid", "samples": 10, "seed": 0, "objective": None, "direction": None}
_OBJECTIVES = {"arx": ("mean_fit_percent", "max"), "identify": ("mean_fit_percent", "max"),
               "tune": ("tuned_cost", "min")}


# ---------------------------------------------------------------- configuration


def parse_config(text: str, source: str = "config") -> dict:
    """Parse and check a sweep configuration (TOML text)."""
    import tomllib

    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML ({exc})") from None
    return check_config(raw, source)


def load_config(path: str | os.PathLike) -> dict:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such file") from None
    except (UnicodeDecodeError, IsADirectoryError):
        raise ConfigError(f"{p}: not a text TOML file") from None
    return parse_config(text, str(p))


def default_config() -> dict:
    """The embedded default sweep (fast ARX order grid on simulated data)."""
    return parse_config(DEFAULT_CONFIG, "default config")


def check_config(raw: dict, source: str = "config") -> dict:
    sweep = raw.get("sweep")
    if not isinstance(sweep, dict):
        raise ConfigError(f"{source}: missing [sweep] table")
    unknown = set(raw) - {"sweep", "data", "space", "fixed"}
    if unknown:
        raise ConfigError(f"{source}: unknown table [{min(unknown)}] (expected sweep, data, space, fixed)")
    cfg = {**_DEFAULTS, **sweep}
    bad = set(cfg) - {"name", "kind", *_DEFAULTS}
    if bad:
        raise ConfigError(f"{source}: unknown key `{min(bad)}` in [sweep]")
    if not isinstance(cfg.get("name"), str) or not cfg["name"] or "/" in cfg["name"]:
        raise ConfigError(f"{source}: [sweep] needs a plain `name`")
    if cfg.get("kind") not in KINDS:
        raise ConfigError(f"{source}: [sweep] kind must be one of {', '.join(KINDS)}, got {cfg.get('kind')!r}")
    if cfg["method"] not in ("grid", "random"):
        raise ConfigError(f"{source}: [sweep] method must be 'grid' or 'random', got {cfg['method']!r}")
    if not isinstance(cfg["samples"], int) or not 1 <= cfg["samples"] <= 100000:
        raise ConfigError(f"{source}: [sweep] samples must be an integer in 1..100000")
    if not isinstance(cfg["seed"], int):
        raise ConfigError(f"{source}: [sweep] seed must be an integer")
    obj, direction = _OBJECTIVES[cfg["kind"]]
    cfg["objective"] = cfg["objective"] or obj
    cfg["direction"] = cfg["direction"] or direction
    if cfg["direction"] not in ("min", "max"):
        raise ConfigError(f"{source}: [sweep] direction must be 'min' or 'max'")
    space = raw.get("space")
    if not isinstance(space, dict) or not space:
        raise ConfigError(f"{source}: missing or empty [space] table")
    for k, v in space.items():
        if isinstance(v, list):
            if not v:
                raise ConfigError(f"{source}: [space] `{k}` is an empty list")
        elif isinstance(v, dict):
            if cfg["method"] != "random":
                raise ConfigError(f"{source}: [space] `{k}` is a range; ranges need method = 'random'")
            if not {"low", "high"} <= set(v) or not all(isinstance(v[b], (int, float)) for b in ("low", "high")) \
                    or not v["low"] <= v["high"]:
                raise ConfigError(f"{source}: [space] `{k}` range needs numbers low <= high")
            if v.get("log") and v["low"] <= 0:
                raise ConfigError(f"{source}: [space] `{k}` log range needs low > 0")
        else:
            raise ConfigError(f"{source}: [space] `{k}` must be a list of values or a range table")
    cfg["data"] = dict(raw.get("data", {}))
    cfg["fixed"] = dict(raw.get("fixed", {}))
    cfg["space"] = space
    _check_names(cfg, source)
    n = count_trials(cfg)
    if n > 100000:
        raise ConfigError(f"{source}: the grid has {n} trials (more than 100000)")
    return cfg


def trial_settings(kind: str) -> frozenset[str]:
    """The names a trial of `kind` reads from its parameters (see `SETTINGS`, `RECORD_KEYS`)."""
    names = set(SETTINGS[kind]) | set(RECORD_KEYS[kind])
    if kind in ("arx", "identify"):
        import inspect

        from ..identify.result import FITTERS, ORDER_NAMES

        names |= {n for orders in ORDER_NAMES.values() for n in orders}
        fitters = [FITTERS["arx"]] if kind == "arx" else FITTERS.values()
        names |= {n for f in fitters for n in inspect.signature(f.options).parameters}
        names -= {"data", "y", "u", "ts", "progress"}
        if kind == "arx":
            names -= {"nc", "nd", "nf", "n"}
    else:
        from ..closedloop import DEFAULT_WEIGHTS

        names |= {f"w_{t}" for t in DEFAULT_WEIGHTS}
    return frozenset(names)


def _check_names(cfg: dict, source: str) -> None:
    """Every [data] key and parameter name is one the kind reads (a typo is an error)."""
    kind = cfg["kind"]
    known = trial_settings(kind)
    for key in cfg["data"]:
        if key not in DATA_KEYS[kind] and key not in known:
            raise ConfigError(f"{source}: unknown key `{key}` in [data] for kind {kind} "
                              f"(known: {', '.join(sorted(DATA_KEYS[kind]))}, or a trial setting)")
    for table in ("fixed", "space"):
        for key in cfg[table]:
            if key not in known:
                raise ConfigError(f"{source}: unknown parameter `{key}` in [{table}] for kind "
                                  f"{kind} (known: {', '.join(sorted(known))})")
            if key in RECORD_KEYS[kind] and "data" in cfg["data"]:
                raise ConfigError(f"{source}: parameter `{key}` in [{table}] describes a "
                                  f"simulated record, but [data] names a data file")


def count_trials(cfg: dict) -> int:
    if cfg["method"] == "random":
        return cfg["samples"]
    return math.prod(len(v) for v in cfg["space"].values())


# ---------------------------------------------------------------- trials


#: bumped when what a trial computes changes within one jthermo version (part of every id)
TRIAL_FORMAT = 2


def trial_salt() -> str:
    """What every trial id is salted with: the jthermo version and `TRIAL_FORMAT`, so a sweep
    resumed after an upgrade reruns its trials instead of reusing stale results."""
    from .. import __version__

    return f"jthermo {__version__} trial {TRIAL_FORMAT}"


def trial_id(params: dict, salt: str | None = None) -> str:
    """A stable id: the first 12 hex digits of the SHA-1 of `salt` (default `trial_salt()`)
    and the sorted JSON parameters."""
    salt = trial_salt() if salt is None else salt
    text = json.dumps({"salt": salt, "params": params}, sort_keys=True)
    return hashlib.sha1(text.encode()).hexdigest()[:12]


def current_rows(rows: list[dict]) -> list[dict]:
    """The result records written under the current `trial_salt` (an older jthermo's are
    stale: their ids are not this version's, and they are never reused or ranked)."""
    salt = trial_salt()
    return [r for r in rows if r.get("salt") == salt]


def trials(cfg: dict) -> list[dict]:
    """The sweep's trials, each `{"id", "params"}`, in a deterministic order."""
    space = cfg["space"]
    names = sorted(space)
    out = []
    if cfg["method"] == "grid":
        for combo in itertools.product(*(space[n] for n in names)):
            params = {**cfg["fixed"], **dict(zip(names, combo))}
            out.append({"id": trial_id(params), "params": params})
    else:
        rng = np.random.default_rng(cfg["seed"])
        seen = set()
        for _ in range(cfg["samples"]):
            params = dict(cfg["fixed"])
            for n in names:
                v = space[n]
                if isinstance(v, list):
                    params[n] = v[int(rng.integers(len(v)))]
                elif isinstance(v["low"], int) and isinstance(v["high"], int) and not v.get("log"):
                    params[n] = int(rng.integers(v["low"], v["high"] + 1))
                elif v.get("log"):
                    params[n] = float(math.exp(rng.uniform(math.log(v["low"]), math.log(v["high"]))))
                else:
                    params[n] = float(rng.uniform(v["low"], v["high"]))
            tid = trial_id(params)
            if tid not in seen:
                seen.add(tid)
                out.append({"id": tid, "params": params})
    return out
