"""The diagnosis as an experiment loop: diagnose, and where a finding is uncertain, design the
record that separates it from its rivals, run it, diagnose again with every record pooled.

A finding is settled when the records name it with confidence and no rival is left within the
tests' resolution (`next_step`); a tie the records cannot separate stays a tie (the finding's
`rivals`), and the experiment that separates it (`experiment.design_experiment`) is what the
loop asks for next.

The designed record is the next validation record, and the one it replaces joins the pooled
estimation records (`select.diagnose` with a list): nothing a record showed is thrown away, and
the new record is used where its design puts its power. The design maximises the rivals'
prediction gap on a record the diagnosis *validates* on, after the nuisances re-estimated there
(`experiment.nuisance_jacobians`), and a tie is decided on the validation record (its
Diebold–Mariano comparison, `decide.is_rival`): pooled into the estimation records only, the
designed record adds to the likelihood ratios but leaves the validation comparison that made
the tie as it was (on the one-zone lamp case of `tests/diagnose/test_loop.py`, two designed
records pooled that way left the lag tied with the dead time at confidence 0.65 and 0.76).

A diagnosis that names nothing is settled only when nothing is left open: a candidate that one
of the two tests finds significant at the family-wise level while the other does not confirm
it (`unconfirmed`: the estimation likelihood ratio far above its critical value with the
validation z just under it, or a large validation gain with a likelihood ratio the estimation
record's excitation leaves small) is evidence the records cannot settle, and an experiment is
asked for. Under the null each test alone passes at most at the family-wise rate (1 %), so
by the union bound an experiment is asked for on at most 2 % of the records of a plant with
nothing missing (a bound from the tests' levels, not a measured rate),
and the pooled diagnosis after it keeps both tests; a candidate that changes the validation
error by less than `experiment.OPEN_REDUCTION` (a z on a loss differential that is all round-off) opens
nothing.
"""

from __future__ import annotations

import numpy as np

from ..data import IOData
from ..errors import ConfigError
from . import experiment as X
from .checks import as_records
from .experiment import OPEN_REDUCTION, unconfirmed
from .select import diagnose


def _one_test(c: dict) -> str:
    z = f"validation z {c['validation_z']:.2f} (critical {c['validation_z_critical']:.2f})"
    lr = f"estimation LR {c['estimation_lr']:.1f} (critical {c['estimation_lr_critical']:.1f})"
    return (f"`{c['mechanism']}` passes {z}, not {lr}" if c["validation_z"] >= c["validation_z_critical"]
            else f"`{c['mechanism']}` passes {lr}, not {z}")


def open_ties(result: dict) -> list[dict]:
    """The findings the records leave unsettled: uncertain, or tied with rivals."""
    return [f for f in result.get("findings") or [] if f.get("uncertain") or f.get("rivals")]


def _confidence(f: dict) -> str:
    c = f.get("confidence")
    return "" if c is None else f" (confidence {c:.2f})"


def next_step(result: dict) -> dict:
    """What to do after a diagnosis: `experiment_needed` (bool), `why` (one sentence), `rivals`
    (the explanations an experiment must separate, the unsettled finding first). An experiment
    is needed for an uncertain or tied finding (`open_ties`) and, when nothing is named, for a
    candidate only one test passes (`unconfirmed`; its rivals are the design's,
    `experiment.rival_set`: that candidate, the best other one, the baseline)."""
    fs = result.get("findings") or []
    ties = open_ties(result)
    if ties:
        f = ties[0]
        rivals = [f["mechanism"], *f.get("rivals", [])]
        tie = (f" tied with {', '.join(f'`{m}`' for m in f['rivals'])}" if f.get("rivals") else "")
        return {"experiment_needed": True, "rivals": rivals,
                "why": f"`{f['mechanism']}` is uncertain{_confidence(f)}{tie}"}
    if fs:
        return {"experiment_needed": False, "rivals": [],
                "why": "no experiment needed: " + ", ".join(f"`{f['mechanism']}`{_confidence(f)}" for f in fs)
                       + " named with no rival"}
    open_ = unconfirmed(result)
    if open_:
        return {"experiment_needed": True, "rivals": list(X.rival_set(result)[0]),
                "why": "nothing confirmed by both tests: " + _one_test(open_[0])}
    return {"experiment_needed": False, "rivals": [],
            "why": "no experiment needed: no candidate improves on the baseline significantly"}


def diagnose_loop(records, val: IOData, run, max_experiments: int = 2, *, duration: int | None = None,
                  hold: int = X.HOLD, y_max=None, seed: int = 0, n_steps: int = X.N_STEPS,
                  **diagnose_kw) -> dict:
    """Diagnose, then design → run → pooled diagnosis until no finding is uncertain, at most
    `max_experiments` times.

    **Arguments:**
    - `records`: the estimation record(s) (`IOData` or a list); `val` the validation record.
    - `run(u) -> IOData`: runs the inputs `u (T, nu)` (every input, as the records name them)
      on the plant and returns the measured record (a lab script, the virtual printer).
    - `duration`, `hold`, `y_max`, `seed`, `n_steps`: the designs' (`experiment.design_experiment`).
    - the rest: `select.diagnose`'s keywords.

    **Returns:** `result` (the last diagnosis), `records` (the estimation records pooled in
    it: the given ones, then each earlier validation record), `validation` (the record it
    validated on: the last designed one, or `val`), `experiments` (each design's JSON
    summary), `rounds` (each diagnosis's findings and `next_step`), `settled` (no finding left
    uncertain)."""
    if not (isinstance(max_experiments, (int, np.integer)) and max_experiments >= 0):
        raise ConfigError(f"diagnose_loop: max_experiments must be a non-negative integer, got {max_experiments!r}")
    if not callable(run):
        raise ConfigError("diagnose_loop: `run` must be a function run(u) -> IOData")
    records = as_records(records)
    rounds, designs = [], []
    while True:
        result = diagnose(records, val, seed=seed, **diagnose_kw)
        step = next_step(result)
        rounds.append({"records": len(records), "next": step,
                       "runner": (result.get("localisation") or {}).get("runner"),
                       "findings": [{k: f[k] for k in ("mechanism", "confidence", "rivals", "uncertain")}
                                    for f in result["findings"]]})
        if not step["experiment_needed"] or len(designs) >= max_experiments:
            break
        d = X.design_experiment(result, records, val, duration=duration, hold=hold, seed=seed + len(designs),
                                n_steps=n_steps, y_max=y_max)
        new = run(np.asarray(d["u"], float))
        if not isinstance(new, IOData):
            raise ConfigError(f"diagnose_loop: run(u) must return IOData, got {type(new).__name__}")
        designs.append(X.to_json(d))
        records, val = records + [val], new
    return {"result": result, "records": records, "validation": val, "experiments": designs,
            "rounds": rounds, "settled": not step["experiment_needed"]}


__all__ = ["OPEN_REDUCTION", "diagnose_loop", "next_step", "open_ties", "unconfirmed"]
