"""Accuracy and coverage of the fitted families on data from a known model of each family.

For ARX, ARMAX, OE, BJ and SS a true model of that family is built on the W1 plant (N = 4
zones: diagonal poles a_i in [0.92, 0.96], grid-coupled gains B), data are simulated from rest
(T samples for estimation, T for validation, separate seeds; the noise is coloured where the
family models it), the family is fitted with its true orders, and we report

- the validation simulation fit % of the fitted model next to the true model's (both simulated
  from rest, x = 0 at u = 0, as the data start), and
- the coverage (of the unconstrained estimator, `physics="none"`: the true models are generic
  linear systems, their parameters those of the family's own structure): the fraction of the true parameters inside the reported ±3σ intervals
  (`FitResult.std`; for polynomial families in the layout of `Polynomial.flat_coefficients`,
  for SS the packed `[A, B, K]` in the basis C = I).

Usage:
    python experiments/identification_coverage.py [--seeds 10] [--T 6000]
        [--families arx armax oe bj ss] [--out experiments/results/identification_coverage.md]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from identification import w1_prbs  # noqa: E402  (the W1 input of the benchmark)

from jthermo.data import atomic_write_text, from_arrays  # noqa: E402
from jthermo.identify.fit import fit  # noqa: E402
from jthermo.models import StateSpace  # noqa: E402
from jthermo.models.polynomial import ARMAX, ARX, OE, BoxJenkins  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
N = 4
FAMILIES = ("arx", "armax", "oe", "bj", "ss")
#: the ss data come from an innovations model and the study checks the covariance of its
#: prediction-error (maximum-likelihood) estimate: prediction focus (the default is simulation)
FIT_OPTIONS = {"ss": {"focus": "prediction"}}
ORDERS = {"arx": (1, 1, 1), "armax": (1, 1, 1, 1), "oe": (1, 1, 1), "bj": (1, 1, 1, 1, 1),
          "ss": (N,)}


def w1_plant(n: int = N) -> tuple[np.ndarray, np.ndarray]:
    """Poles `a (n,)` and gains `B (n, n)` of the W1 plant (seed 0): see ../shared/bench."""
    rng = np.random.default_rng(np.random.SeedSequence([0, n, 0]))
    a = rng.uniform(0.92, 0.96, n)
    b = rng.uniform(0.15, 0.25, n)
    rows = max(1, int(np.floor(np.sqrt(n))))
    cols = int(np.ceil(n / rows))
    P = np.stack([np.arange(n) // cols, np.arange(n) % cols], 1).astype(float)
    d2 = ((P[:, None] - P[None]) ** 2).sum(-1)
    return a, b[:, None] * np.exp(-d2 / 0.8)


def true_model(family: str):
    """The true model of `family` on the W1 plant, at rest at u0 = 0, y0 = 0."""
    a, B = w1_plant()
    b = B[:, :, None]                                         # (ny, nu, 1), delay 1
    c = np.array([0.5, 0.3, 0.6, 0.4])[:, None]
    if family == "arx":
        return ARX(-a[:, None], b, nk=1), 0.03
    if family == "armax":
        return ARMAX(-a[:, None], b, c, nk=1), 0.03
    f = np.repeat(-a[:, None, None], N, axis=1)               # F_ij = A_i
    if family == "oe":
        return OE(b, f, nk=1), 0.1
    if family == "bj":
        d = np.full((N, 1), -0.7)                             # W1's AR(1) measurement noise
        return BoxJenkins(b, 0.5 * c, d, f, nk=1), 0.07
    if family == "ss":
        A = np.diag(a) + 0.01 * (np.ones((N, N)) - np.eye(N))    # weak thermal coupling
        K = np.diag([0.5, 0.6, 0.4, 0.55])
        return StateSpace(A, B, np.eye(N), np.zeros((N, N)), K), 0.05
    raise ValueError(family)


def simulate(model, u: np.ndarray, e: np.ndarray | None = None) -> np.ndarray:
    """Innovations-form simulation from rest (x = 0, u0 = 0): y = y0 + C x + D u + e."""
    ss = model if isinstance(model, StateSpace) else model.to_statespace()
    A, Bm, C, D, K = (np.asarray(m) for m in (ss.A, ss.B, ss.C, ss.D, ss.K))
    u0, y0 = np.asarray(ss.u0), np.asarray(ss.y0)
    try:   # at rest at u = 0 (the data's start): x0 solves x = A x + B (0 - u0)
        x = np.linalg.solve(np.eye(A.shape[0]) - A, Bm @ (0.0 - u0))
    except np.linalg.LinAlgError:
        x = np.zeros(A.shape[0])
    e = np.zeros((u.shape[0], C.shape[0])) if e is None else e
    du = u - u0
    Bu = du @ Bm.T + e @ K.T
    y = np.empty((u.shape[0], C.shape[0]))
    for k in range(u.shape[0]):
        y[k] = C @ x
        x = A @ x + Bu[k]
    return y + y0 + du @ D.T + e


def dataset(family: str, T: int, seed: int, split: int):
    model, sigma = true_model(family)
    rng = np.random.default_rng(np.random.SeedSequence([seed, split, 7]))
    u = w1_prbs(T, N, rng)
    e = sigma * rng.standard_normal((T, N))
    return u, simulate(model, u, e)


def fit_percent(y, yhat) -> float:
    num = np.linalg.norm(y - yhat, axis=0)
    den = np.linalg.norm(y - y.mean(axis=0), axis=0)
    return float(np.mean(100.0 * (1.0 - num / den)))


def true_parameters(family: str, res) -> np.ndarray:
    """True values in the layout of `res.std`."""
    model, _ = true_model(family)
    if family == "ss":
        A, B, K = (np.asarray(m) for m in (model.A, model.B, model.K))
        return np.concatenate([A.ravel(), B.ravel(), K.ravel()])
    return np.asarray(model.flat_coefficients())


def estimated_parameters(family: str, res) -> tuple[np.ndarray, np.ndarray]:
    if family == "ss":
        m = res.extra["parametrised"]
        nA, nB, nK = m.A.size, m.B.size, m.K.size
        if not m.fixed_c or not np.allclose(np.asarray(m.C), np.eye(N)):
            raise RuntimeError("SS coverage needs the basis C = I")
        est = np.concatenate([np.asarray(m.A).ravel(), np.asarray(m.B).ravel(),
                              np.asarray(m.K).ravel()])
        std = np.asarray(res.std)[:nA + nB + nK]
        return est, std
    return np.asarray(res.model.flat_coefficients()), np.asarray(res.std)


def run(families, seeds, T, n_starts, out_json=None):
    rows = []
    for fam in families:
        model, _ = true_model(fam)
        for s in range(seeds):
            u, y = dataset(fam, T, s, 1)
            uv, yv = dataset(fam, T, s, 2)
            data = from_arrays(u, y)
            t0 = time.perf_counter()
            kw = dict(FIT_OPTIONS.get(fam, {}), **({} if n_starts is None else {"n_starts": n_starts}))
            res = fit(data, fam, ORDERS[fam], physics="none", **kw)   # the unconstrained estimator
            sec = time.perf_counter() - t0
            f_hat = fit_percent(yv, simulate(res.model, uv))
            f_true = fit_percent(yv, simulate(model, uv))
            est, std = estimated_parameters(fam, res)
            tru = true_parameters(fam, res)
            inside = np.abs(est - tru) <= 3 * std
            z = (est - tru) / np.where(std > 0, std, np.nan)
            row = {"family": fam, "seed": s, "fit": f_hat, "fit_true": f_true,
                   "gap": f_true - f_hat, "inside": int(inside.sum()), "n": int(inside.size),
                   "max_abs_z": float(np.nanmax(np.abs(z))), "seconds": sec,
                   "offset": str(res.extra.get("offset", res.extra.get("operating_point", ""))),
                   "converged": bool(res.converged)}
            rows.append(row)
            print(json.dumps(row), flush=True)
            if out_json:
                atomic_write_text(out_json, json.dumps(rows, indent=1))
    return rows


def summary(rows) -> str:
    lines = ["| family | seeds | fit % (mean) | true fit % (mean) | worst gap (points) | "
             "coverage ±3σ | worst |z| | s/fit (mean) |", "|---|---|---|---|---|---|---|---|"]
    for fam in FAMILIES:
        r = [x for x in rows if x["family"] == fam]
        if not r:
            continue
        cov = sum(x["inside"] for x in r) / sum(x["n"] for x in r)
        lines.append(f"| {fam.upper()} | {len(r)} | {np.mean([x['fit'] for x in r]):.2f} | "
                     f"{np.mean([x['fit_true'] for x in r]):.2f} | "
                     f"{max(x['gap'] for x in r):.2f} | {100 * cov:.1f} % "
                     f"({sum(x['inside'] for x in r)}/{sum(x['n'] for x in r)}) | "
                     f"{max(x['max_abs_z'] for x in r):.1f} | "
                     f"{np.mean([x['seconds'] for x in r]):.1f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--T", type=int, default=6000)
    ap.add_argument("--families", nargs="+", default=list(FAMILIES), choices=FAMILIES)
    ap.add_argument("--n-starts", type=int, default=None, help="default: fit()'s default")
    ap.add_argument("--out", type=Path, default=ROOT / "experiments" / "results" /
                    "identification_coverage.md")
    args = ap.parse_args(argv)
    rows = run(args.families, args.seeds, args.T, args.n_starts,
               out_json=args.out.with_suffix(".json"))
    load = os.getloadavg()
    text = ("# Accuracy and ±3σ coverage on data from known models (N = 4)\n\n"
            f"T = {args.T} estimation + {args.T} validation samples per seed; true orders; "
            "fit % = validation simulation fit from rest (mean over outputs); gap = true model's "
            "fit − fitted model's fit (positive = fitted is worse).\n\n"
            f"Command: `python experiments/identification_coverage.py "
            f"{' '.join(argv if argv is not None else sys.argv[1:])}`; load average at the end "
            f"{load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} on {os.cpu_count()} cores.\n\n"
            + summary(rows))
    atomic_write_text(args.out, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
