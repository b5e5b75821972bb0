"""The demo's experiment loop: a tie the records leave open, settled by one designed experiment.

A one-zone virtual printer hides a 3 s heater lag (`CASE`). On its PRBS estimation record and
short validation record a lag and a pure dead time fit about equally well, so the diagnosis
names the lag with the dead time as its rival (a tie, reported as one). `diagnose.diagnose_loop` then designs the
input that separates the two, runs it on the same printer (`printer_runner`, a fresh noise draw)
and diagnoses again with every record pooled. The section reports what each round named; where
the first round leaves no tie, or the experiment leaves it open, it says so: the outcome is
read from the run, never assumed.
"""

from __future__ import annotations

import time

import numpy as np

#: the concealed effect, zones, estimation and validation seconds, PRBS levels and holds (s),
#: white + AR(1) sensor noise (°C), the designed record's seconds and the candidates tried (the
#: rival pair: the demo's blind diagnosis of the whole library is its section 6). The short
#: validation record is what leaves the tie: on it the lag does not beat the dead time at the
#: rivals' level (seed 0: confidence 0.87, the dead time its rival); the designed record, as the
#: next validation record, separates them (confidence 0.998, no rival)
CASE = {"effect": ("heater_lag", {"time_constant_s": 3.0}), "zones": 1, "est_s": 1200, "val_s": 300,
        "levels": (0.35, 0.65), "hold": (40, 120), "noise": 0.1, "design_s": 1200,
        "mechanisms": ("heater_lag", "input_delay")}
#: AR(1) pole of the coloured part of the sensor noise
NOISE_POLE = 0.8


def printer_runner(printer, noise: float, seed: int, u_rest: float):
    """`run(u) -> IOData`: the printer from its steady state at `u_rest` on the inputs `u (T, nu)`,
    its surroundings measured, white plus AR(1) sensor noise of std `noise` each (°C); each call
    draws its own noise (`seed`, then `seed + 1`, ...)."""
    import jax

    from ..data import from_arrays
    from ..printer import disturbances, input_names, simulate_open_loop, steady_state

    calls = [0]

    def run(u):
        u = np.asarray(u, float)
        s = seed + calls[0]
        calls[0] += 1
        d = disturbances(printer, u.shape[0], jax.random.key(s))
        y, _ = simulate_open_loop(printer, u, d, steady_state(printer, u_rest))
        rng = np.random.default_rng(s)
        y = np.asarray(y) + rng.normal(size=np.shape(y)) * noise
        w = rng.normal(size=y.shape) * noise * np.sqrt(1 - NOISE_POLE ** 2)
        c = np.zeros_like(y)
        for k in range(1, len(y)):
            c[k] = NOISE_POLE * c[k - 1] + w[k]
        names = input_names(printer)
        return from_arrays(u, y + c, printer.ts, np.asarray(d.ambient)[:, None], input_names=names,
                           output_names=[f"y_{i + 1}" for i in range(y.shape[1])], signal_names=["ambient"])

    return run


def _round(r: dict) -> dict:
    f = r["findings"][0] if r["findings"] else None
    return {"records": r["records"], "named": None if f is None else f["mechanism"],
            "confidence": None if f is None else f["confidence"], "rivals": [] if f is None else list(f["rivals"]),
            "next": r["next"]["why"]}


def outcome(rounds: list[dict], tie: bool, settled: bool, truth: str) -> str:
    """One sentence on what the loop did, read from its rounds (`_round`): no tie to settle, the
    tie settled (and whether on the concealed effect `truth`), or the tie still open."""
    first, last = rounds[0], rounds[-1]
    if not tie:
        return (f"no tie to settle: the first records already name `{first['named']}` with no rival"
                if first["named"] else "no tie to settle: the first records name nothing")
    if not settled:
        return f"the tie is still open after {len(rounds) - 1} experiment(s): {last['next']}"
    if last["named"] is None:
        return "the experiment left no finding: the tie dissolved into nothing named"
    return (f"one designed experiment settled the tie: `{last['named']}` (confidence {last['confidence']:.3f}), "
            "no rival left" + ("" if last["named"] == truth else f"; but the concealed effect was `{truth}`"))


def settle_tie(seed: int = 0, case: dict = CASE, *, n_steps: int | None = None) -> dict:
    """Run `CASE` through `diagnose_loop` with at most one experiment; the JSON-ready outcome:
    `concealed`, `rounds` (each diagnosis: records pooled, top finding, confidence, rivals, next
    step), `tie` (the first round left one), `settled` (the loop left no finding uncertain),
    `named_truth` (the last round's top finding is the concealed effect), `experiment`
    (the design's figures, or `None`), `outcome` (one sentence), `seconds`."""
    from ..inputs import prbs
    from ..printer import make_printer
    from . import experiment as X
    from .loop import diagnose_loop

    t0 = time.perf_counter()
    name, params = case["effect"]
    p = make_printer(case["zones"], {name: params}, seed=seed)
    u_rest = 0.5 * (case["levels"][0] + case["levels"][1])
    run = printer_runner(p, case["noise"], 10 * seed + 2, u_rest)
    T_est, T_val = (round(case[k] / p.ts) for k in ("est_s", "val_s"))
    hold = tuple(max(1, round(h / p.ts)) for h in case["hold"])
    rec = run(np.asarray(prbs(10 * seed + 1, T_est + T_val, p.n_inputs, levels=case["levels"], hold=hold)))
    est = rec.replace(u=rec.u[:T_est], y=rec.y[:T_est], w=rec.w[:T_est])
    val = rec.replace(u=rec.u[T_est:], y=rec.y[T_est:], w=rec.w[T_est:], t0=float(T_est * p.ts))
    out = diagnose_loop(est, val, run, max_experiments=1, duration=round(case["design_s"] / p.ts),
                        seed=seed, mechanisms=case["mechanisms"],
                        n_steps=X.N_STEPS if n_steps is None else n_steps)
    rounds = [_round(r) for r in out["rounds"]]
    tie = bool(out["rounds"][0]["next"]["experiment_needed"])
    named_truth = rounds[-1]["named"] == name
    exp = out["experiments"][0] if out["experiments"] else None
    return {"concealed": {"mechanism": name, **params}, "zones": case["zones"], "noise_C": case["noise"],
            "rounds": rounds, "tie": tie, "settled": bool(out["settled"]), "named_truth": named_truth,
            "experiment": None if exp is None else {k: exp.get(k) for k in
                                                    ("rivals", "duration_s", "separation_designed",
                                                     "separation_prbs")},
            "outcome": outcome(rounds, tie, bool(out["settled"]), name),
            "seconds": round(time.perf_counter() - t0, 1)}


def report_section(rep, S: dict | None) -> None:
    """The demo report's section on the loop (nothing when the stage did not run)."""
    if not S:
        return
    c = S["concealed"]
    rep.heading("7. A tie and the experiment that separates it")
    rep.para(f"A {S['zones']}-zone printer hides `{c['mechanism']}` ("
             + ", ".join(f"{k} = {v}" for k, v in c.items() if k != "mechanism")
             + f"), sensor noise {S['noise_C']} °C. Each diagnosis pools every record so far; the designed "
             "record is the next validation record (`diagnose_loop`, at most one experiment).")
    rep.table([{"round": i + 1, "estimation records": r["records"], "top finding": r["named"] or "—",
                "confidence": r["confidence"], "rivals": ", ".join(r["rivals"]) or "—", "next step": r["next"]}
               for i, r in enumerate(S["rounds"])])
    e = S.get("experiment")
    if e:
        rep.para(f"Designed record: {e['duration_s']:.0f} s separating {', '.join(e['rivals'])}; separation "
                 f"{e['separation_designed']:.3g} against {e['separation_prbs']:.3g} for a PRBS of the same "
                 "length and limits.")
    rep.para(f"Outcome: **{S['outcome']}** ({S['seconds']:.0f} s).")


__all__ = ["CASE", "outcome", "printer_runner", "report_section", "settle_tie"]
