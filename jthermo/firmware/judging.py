"""The judgement of `calibrate`'s controllers on the cross-record plant, and whether the tuned
PID is a tuning to use.

- `ultimate`: the relay test (`PID_CALIBRATE`) on a model, its $K_u$ and $T_u$ per heater.
- `judge`: every controller's figures (`tuning.evaluate`) on the judging plant, the Klipper
  PIDs as the tuning's compiled batch, each other structure compiled for one run.
- `agreement`: the design and judging models must agree on the relay test's $K_u$ and $T_u$
  (`KU_AGREEMENT`, `TU_AGREEMENT`): a loop tuned on one is otherwise a guess on the other.
- `why_not`: the reasons the tuned PID is not a tuning to use (that disagreement, a start-up
  overshoot above `ACCEPT_OVERSHOOT_C`, an input limit more than `ACCEPT_SATURATED` of the time).
- `oracle`: the same PID search run on the judging plant itself, the reachable part of the
  floor + noise (a measurement of the data, not a tuning to use).
"""

from __future__ import annotations

import math
import time

import jax
import numpy as np

from ..control.design import design, design_point
from ..errors import ControlError
from ..models.envelope import equilibrium_input
from . import tuning
from .pid import KlipperPID, pid_calibrate

#: the design and the judging models must agree on the relay test's ultimate gain and period
#: within these factors: a loop tuned on one is otherwise a guess on the other (the records
#: do not pin the dynamics near the crossover, e.g. a short closed-loop heat-up)
KU_AGREEMENT, TU_AGREEMENT = 2.0, 1.5
#: the start-up overshoot (°C) and the share of the time at an input limit that a tuned loop
#: may show on the judging plant to be reported as a tuning to use
ACCEPT_OVERSHOOT_C, ACCEPT_SATURATED = 1.0, 0.25


def ultimate(dp, model, r, n, max_power, say):
    """PID_CALIBRATE on the model per heater -> (autotunes or None, K_u, T_u); the model's
    relay design's when the relay test does not oscillate on the model."""
    try:
        cal = [pid_calibrate(dp, float(np.asarray(r)[i]), i, max_power=max_power)
               for i in range(n)]
        return (cal, *tuning.ultimate(cal))
    except ControlError as exc:
        say(f"PID_CALIBRATE on the model: {exc}")
    c = design("pid_relay", model, setpoint=r)
    return None, np.asarray(c.kp, np.float64) / 0.6, 2.0 * np.asarray(c.ti, np.float64)


def judge(ctrls: dict, plant, scs: dict) -> tuple[dict, dict]:
    """Every controller's `tuning.evaluate` figures on `plant`, controllers of one structure
    (the Klipper PIDs) simulated as one batch; and `{name: {kind: (y, u, r)}}` of the first
    rollout, for the figures."""
    groups: dict = {}
    for n, c in ctrls.items():
        groups.setdefault(jax.tree_util.tree_structure(c), []).append(n)
    table, first = {}, {}
    for names in groups.values():
        pid = isinstance(ctrls[names[0]], KlipperPID)     # the tuning's compiled batch
        trajs = tuning.runs([ctrls[n] for n in names], plant, scs,
                            tuning.BATCH if pid else len(names), once=not pid)
        for i, (n, row) in enumerate(zip(names, tuning.rows(trajs, scs, len(names)))):
            table[n] = row
            first[n] = {k: tuple(np.asarray(a[i, 0]) for a in (t.y, t.u, t.r))
                        for k, t in trajs.items()}
    return table, first


def oracle(val_model, env, r, kw, *, duration, seed, rollouts, steps, load, scs, bound,
            max_power, say) -> dict:
    """The same search (`tuning.tune_firmware_pid`) run on the judging plant itself and judged
    there on the judgement's held-out rollouts `scs`: the best a firmware PID does where the
    plant is known, the reachable part of the floor + noise. It measures the data, not a
    tuning to use (it has seen the validation record)."""
    say("oracle: the firmware PID tuned on the judging plant itself")
    t0 = time.thread_time()
    _, ku, tu = ultimate(design_point(val_model, setpoint=r), val_model, r,
                          int(val_model.n_outputs), max_power, lambda s: None)
    kw = {**kw, "u_hold": equilibrium_input(val_model, r, env.signals(val_model))}
    t = tuning.tune_firmware_pid(val_model, env, r, ku, tu, duration=duration, seed=seed,
                                 rollouts=rollouts, steps=steps, kw=kw, load=load)
    row = tuning.evaluate(t["controller"], val_model, scs)
    pct = None if not bound else 100.0 * (row["mse"] / bound - 1.0)
    say(f"oracle: set-point MSE {row['mse']:.3g} °C²"
        + ("" if pct is None else f", {pct:+.1f} % against the floor + noise"))
    return {**row, "vs_bound_percent": pct, "factors": t["factors"],
            "gains": t["controller"].gains(), "cpu_s": time.thread_time() - t0}


def agreement(ku, tu, val_model, model, r, max_power) -> str | None:
    """None when the judging model's relay test (`PID_CALIBRATE` on it) gives $K_u$ and $T_u$
    within `KU_AGREEMENT`, `TU_AGREEMENT` of the design model's, per heater; else the sentence
    saying how far apart they are."""
    if val_model is model:
        return None
    _, ku_v, tu_v = ultimate(design_point(val_model, setpoint=r), val_model, r,
                              len(np.atleast_1d(ku)), max_power, lambda s: None)
    rk = np.maximum(ku / ku_v, ku_v / ku)
    rt = np.maximum(tu / tu_v, tu_v / tu)
    if np.all(rk <= KU_AGREEMENT) and np.all(rt <= TU_AGREEMENT):
        return None
    i = int(np.argmax(np.maximum(rk / KU_AGREEMENT, rt / TU_AGREEMENT)))
    return (f"the estimation and validation records disagree on the loop's dynamics: the relay "
            f"test on their models gives K_u {ku[i]:.3g} and {ku_v[i]:.3g} duty/°C, T_u "
            f"{tu[i]:.3g} and {tu_v[i]:.3g} s (heater {i}; at most a factor "
            f"{KU_AGREEMENT:g} and {TU_AGREEMENT:g} apart for a tuning the data support)")


def why_not(agree: str | None, fw: dict) -> str | None:
    """Why the tuned PID is not a tuning to use (None when it is): the records disagree
    (`_agreement`), or on the judging plant it overshoots its start-up by more than
    `ACCEPT_OVERSHOOT_C` or sits at an input limit more than `ACCEPT_SATURATED` of the
    set-point changes or the load step."""
    parts = [agree] if agree else []
    if not all(math.isfinite(fw[k]) for k in ("mse", "overshoot_C", "saturated_fraction")):
        parts.append("the tuned loop gives non-finite figures on the judging plant")
    else:
        if fw["overshoot_C"] > ACCEPT_OVERSHOOT_C:
            parts.append(f"on the judging plant the tuned loop overshoots its start-up by "
                         f"{fw['overshoot_C']:.2f} °C (at most {ACCEPT_OVERSHOOT_C:g})")
        sat = max(fw["saturated_fraction"], fw.get("load_saturated_fraction", 0.0))
        if sat > ACCEPT_SATURATED:
            parts.append(f"on the judging plant the tuned loop sits at an input limit "
                         f"{100 * sat:.0f} % of the time (at most {100 * ACCEPT_SATURATED:.0f} %)")
    return "; ".join(parts) or None


__all__ = ["ACCEPT_OVERSHOOT_C", "ACCEPT_SATURATED", "KU_AGREEMENT", "TU_AGREEMENT", "agreement",
           "judge", "oracle", "ultimate", "why_not"]
