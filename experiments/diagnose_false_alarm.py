"""False-alarm rate and power of `jthermo diagnose` on a study plant outside the library's forms.

The decision rule (`jthermo.diagnose.decide`: whitened likelihood ratio on estimation, one-sided
Diebold–Mariano on validation, Bonferroni over the candidates) states a family-wise false-alarm
rate of `ALPHA` = 1 % per record. This script measures it and the power per mechanism.

The study plant is written here, not taken from `jthermo.printer`, so that its physics is not the
candidate library's functional forms. Zone temperatures $T_i$ (°C), surroundings $T_\\infty$:

$$\\dot T_i = a_i (T_\\infty - T_i) + \\sum_j B_{ij}\\, q_j - c\\,\\Delta_i |\\Delta_i|^{1/3}
   + g (W_i - T_i), \\qquad \\Delta_i = T_i - T_\\infty$$

- **null**: every extra term off: a linear first-order zone with every heater reaching it and
  constant surroundings, i.e. exactly the baseline model class (nothing missing); $N$ = 1-6,
  random time constants, gains, cross-gains, input levels and hold times, white + AR(1) noise.
- **convection h(T)** (natural convection, $h \\propto \\Delta^{1/3}$; nearest candidate
  `radiative_loss`): size = the extra loss at the mean temperature rise as a share of the linear loss.
- **fractional delay** (heater power $q_j(t) = u_j(t - d)$, $d$ a multiple of Ts/4; candidate
  `input_delay`): size = $d$ in s.
- **two-body sensor** (the sensor is a second body, $\\dot s_i = (T_i - s_i)/\\tau_s$, $y = s$;
  the vocabulary has no sensor lag, so the nearest name is `heater_lag`): size = $\\tau_s$ in s.
- **slow wall body** ($\\dot W_i = g_w (T_i - W_i) - l_w (W_i - T_\\infty)$ with a time constant of
  about the record length; candidate `heat_accumulation`): size = $g / a_i$, the wall's share.

Simulated with Euler sub-steps of Ts/8 (Ts = 1 s), inputs held over each sample. Nothing here sets
a threshold: `decide.ALPHA` is fixed in the library.

    .venv/bin/python experiments/diagnose_false_alarm.py [--nulls 40] [--per-size 2] [--est 1200] [--val 600]

Writes `experiments/results/diagnose_false_alarm.{md,json,png}` (the JSON after every record).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np
from scipy.stats import beta

from jthermo.data import atomic_write_text, from_arrays, split
from jthermo.diagnose import diagnose, to_json
from jthermo.diagnose.decide import ALPHA
from jthermo.inputs import prbs

ROOT = Path(__file__).resolve().parents[1]
SUB = 8                   # Euler sub-steps per sample
#: study effect -> (the candidate name counted as correct, effect sizes)
EFFECTS = {
    "convection_hT": ("radiative_loss", (0.05, 0.15, 0.3)),
    "fractional_delay": ("input_delay", (0.75, 1.5, 3.25)),
    "two_body_sensor": ("heater_lag", (2.0, 5.0, 10.0)),
    "slow_wall": ("heat_accumulation", (0.1, 0.25, 0.5)),
}


def draw_plant(rng, zones):
    """Random linear part: rates a (1/s), gains B (°C/s per unit input), surroundings (°C)."""
    a = 1.0 / rng.uniform(150.0, 600.0, zones)
    rise = rng.uniform(60.0, 150.0, zones)                 # °C at full power, own heater
    B = np.diag(rise * a)
    cross = rng.uniform(0.0, 0.3, (zones, zones)) * (1 - np.eye(zones))
    B = B + cross * (rise * a)[:, None]
    return a, B, float(rng.uniform(18.0, 30.0))


def simulate(u, ts, a, B, t_inf, effect=None, size=0.0, x_rise=None):
    """Output `(T, n)` of the study plant for inputs `u (T, nu)` held over each sample."""
    T, n = u.shape[0], a.size
    dt = ts / SUB
    delay = round(size / dt) if effect == "fractional_delay" else 0
    uf = np.repeat(u, SUB, axis=0)
    uf = np.concatenate([np.repeat(uf[:1], delay, axis=0), uf])[:T * SUB]
    rise0 = np.linalg.solve(np.diag(a), B @ u.mean(axis=0))       # linear steady rise
    c = 0.0
    if effect == "convection_hT":                                  # extra loss = size * linear at rise0
        c = size * a * rise0 / np.abs(rise0) ** (4.0 / 3.0)
    g = size * a if effect == "slow_wall" else np.zeros(n)
    gw, lw = 1.0 / (0.5 * T * ts), 0.5 / (T * ts)                   # wall: time constant ~ record
    x = t_inf + (rise0 if x_rise is None else x_rise)
    wall = t_inf + rise0 * gw / (gw + lw)
    s = x.copy()
    y = np.empty((T, n))
    for k in range(T * SUB):
        d = x - t_inf
        dx = a * (t_inf - x) + B @ uf[k] - c * d * np.abs(d) ** (1.0 / 3.0) + g * (wall - x)
        wall = wall + dt * (gw * (x - wall) - lw * (wall - t_inf))
        if effect == "two_body_sensor":
            s = s + dt * (x - s) / size
        x = x + dt * dx
        if k % SUB == SUB - 1:
            y[k // SUB] = s if effect == "two_body_sensor" else x
    return y


def make_record(case_seed, zones, effect, size, n_est, n_val):
    rng = np.random.default_rng(np.random.SeedSequence([case_seed, 1414]))
    a, B, t_inf = draw_plant(rng, zones)
    T = n_est + n_val
    lo = float(rng.uniform(0.1, 0.5))
    hi = float(min(1.0, lo + rng.uniform(0.25, 0.5)))
    hold = (int(rng.integers(2, 6)), int(rng.integers(10, 40)))
    u = np.asarray(prbs(int(rng.integers(0, 2**31)), T, zones, levels=(lo, hi), hold=hold), float)
    # settle the slow parts on the mean input first, so the record starts near its operating point
    y = simulate(u, 1.0, a, B, t_inf, effect, size)
    noise = float(rng.uniform(0.02, 0.12))
    pole = float(rng.uniform(0.0, 0.9))
    w = rng.normal(size=y.shape) * noise * np.sqrt(1 - pole ** 2)
    col = np.zeros_like(y)
    for k in range(1, T):
        col[k] = pole * col[k - 1] + w[k]
    y = y + rng.normal(size=y.shape) * noise * 0.5 + col
    amb = np.full((T, 1), t_inf)
    data = from_arrays(u, y, 1.0, amb, signal_names=["ambient"])
    est, val = split(data, n_est / T)
    return est, val, {"noise_C": noise, "ar_pole": pole, "levels": [lo, hi], "hold": list(hold)}


def specs(n_nulls, per_size):
    """(case id, zones, effect, size) of every record; zones drawn from the case's own seed."""
    out = []
    for i in range(n_nulls):
        out.append((i, int(np.random.default_rng([i, 7]).integers(1, 7)), None, 0.0))
    j = 10_000
    for eff, (_, sizes) in EFFECTS.items():
        for s in sizes:
            for _ in range(per_size):
                out.append((j, int(np.random.default_rng([j, 7]).integers(1, 4)), eff, s))
                j += 1
    return out


def clopper_pearson(k, n, level=0.95):
    """Two-sided exact binomial interval of a rate k/n."""
    lo = 0.0 if k == 0 else float(beta.ppf((1 - level) / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - (1 - level) / 2, k + 1, n - k))
    return lo, hi


def summarise(rows):
    nulls = [r for r in rows if r["effect"] is None]
    fa = sum(r["alarm"] for r in nulls)
    power = {}
    for eff, (name, sizes) in EFFECTS.items():
        for s in sizes:
            rs = [r for r in rows if r["effect"] == eff and r["size"] == s]
            if rs:
                power.setdefault(eff, []).append({
                    "size": s, "records": len(rs), "detected": sum(r["alarm"] for r in rs),
                    "top1": sum(r["top"] == name for r in rs)})
    return {"nulls": len(nulls), "false_alarms": fa,
            "false_alarm_ci95": clopper_pearson(fa, len(nulls)) if nulls else None,
            "stated_alpha": ALPHA, "power": power}


def write(rows, meta, out):
    summ = summarise(rows)
    atomic_write_text(out / "diagnose_false_alarm.json",
                      json.dumps({"meta": meta, "summary": summ, "records": rows}, indent=1, default=float))
    lines = ["# Diagnosis: false-alarm rate and power", "",
             "Made by `experiments/diagnose_false_alarm.py` " + meta["args"] + ". Study plant written in the",
             "script (not the library's forms): h(T) convection, fractional delays, a two-body sensor, a",
             "slow wall body. Nulls: linear zones of the baseline class, N = 1-6, white + AR(1) noise.",
             f"Records: {meta['est_s']} s estimation + {meta['val_s']} s validation, Ts = 1 s.", ""]
    if summ["nulls"]:
        lo, hi = summ["false_alarm_ci95"]
        lines += [f"- **False-alarm rate**: {summ['false_alarms']}/{summ['nulls']} null records "
                  f"= {100 * summ['false_alarms'] / summ['nulls']:.1f} % (95 % Clopper-Pearson "
                  f"{100 * lo:.1f}-{100 * hi:.1f} %), stated {100 * ALPHA:.0f} % family-wise.", ""]
    lines += ["| study effect | counted as | size | records | detected (any finding) | top-1 correct |",
              "|---|---|---|---|---|---|"]
    for eff, ps in summ["power"].items():
        for p in ps:
            lines.append(f"| {eff} | {EFFECTS[eff][0]} | {p['size']:g} | {p['records']} | "
                         f"{p['detected']} | {p['top1']} |")
    lines += ["", "| record | effect | size | N | noise °C | AR pole | named | rivals | baseline fit % | "
              "augmented fit % | s |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['effect'] or 'null'} | {r['size']:g} | {r['zones']} | "
                     f"{r['noise_C']:.3f} | {r['ar_pole']:.2f} | {', '.join(r['named']) or '-'} | "
                     f"{', '.join(r['rivals']) or '-'} | {r['baseline_fit']:.2f} | {r['augmented_fit']:.2f} | "
                     f"{r['seconds']:.0f} |")
    lines += ["", f"Wall time {meta['wall_s']:.0f} s on a shared 2-core machine, load average "
              f"{meta['load']} (1/5/15 min) at the end: timings are inflated by other jobs.", ""]
    atomic_write_text(out / "diagnose_false_alarm.md", "\n".join(lines) + "\n")
    return summ


def plot(summ, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(EFFECTS), figsize=(3.2 * len(EFFECTS), 3.0), squeeze=False)
    for ax, (eff, (name, _)) in zip(axes[0], EFFECTS.items()):
        ps = summ["power"].get(eff, [])
        if ps:
            s = [p["size"] for p in ps]
            ax.plot(s, [p["detected"] / p["records"] for p in ps], "o-", label="detected")
            ax.plot(s, [p["top1"] / p["records"] for p in ps], "s--", label=f"top-1 = {name}")
        if summ["nulls"]:
            ax.axhline(summ["false_alarms"] / summ["nulls"], color="k", lw=0.8, ls=":",
                       label="null false-alarm rate")
        ax.set_ylim(-0.05, 1.05)
        ax.set_title(eff, fontsize=9)
        ax.set_xlabel("effect size")
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel("share of records")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--nulls", type=int, default=40)
    ap.add_argument("--per-size", type=int, default=2)
    ap.add_argument("--est", type=int, default=1200, help="estimation samples (s)")
    ap.add_argument("--val", type=int, default=600, help="validation samples (s)")
    ap.add_argument("--n-iter", type=int, default=None, help="diagnose's LM iterations (default: its own)")
    ap.add_argument("--out", default="experiments/results")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"args": " ".join(f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items()
                             if k != "out" and v is not None),
            "est_s": args.est, "val_s": args.val}
    kw = {} if args.n_iter is None else {"n_iter": args.n_iter}
    rows = []
    t0 = time.perf_counter()
    for case, zones, eff, size in specs(args.nulls, args.per_size):
        est, val, info = make_record(case, zones, eff, size, args.est, args.val)
        t1 = time.perf_counter()
        res = to_json(diagnose(est, val, **kw))
        named = [f["mechanism"] for f in res["findings"]]
        rows.append({"case": case, "effect": eff, "size": size, "zones": zones, **info,
                     "named": named, "top": named[0] if named else None, "alarm": bool(named),
                     "rivals": res["findings"][0]["rivals"] if named else [],
                     "baseline_fit": res["baseline"]["mean_fit_percent"],
                     "augmented_fit": res["augmented"]["mean_fit_percent"],
                     "seconds": time.perf_counter() - t1})
        print(f"{case} {eff} {size} N{zones}: {named or '-'} ({rows[-1]['seconds']:.0f} s)", flush=True)
        meta.update(wall_s=time.perf_counter() - t0, load=" ".join(f"{v:.2f}" for v in os.getloadavg()))
        summ = write(rows, meta, out)
    plot(summ, out / "diagnose_false_alarm.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
