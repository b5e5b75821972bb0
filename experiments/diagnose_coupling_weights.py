"""Which couplings a pruned joint model keeps (`joint.kept_couplings`) on the README tour's kind
of record at N zones, against the printer's truth, for several shares.

Each N: the records of `diagnose_zone_scaling.py` (`jthermo generate --zones N --effects
lateral_conduction,radiative_loss,heater_lag`, one hour `--seed 1`, 30 min `--seed 2`), then
`diagnose` up to its joint stage (the per-zone fits), where the inputs of `pruned_start` are
taken: the grid's heater gains and the per-zone `lateral_conduction` fits' exchanges. Truth: the
printer's exchanges are between zones that share a grid side (`printer.geometry.grid_edges`),
its heater gains a Gaussian footprint (own heater 1, side neighbours 0.36, diagonal 0.13).

    .venv/bin/python experiments/diagnose_coupling_weights.py --zones 6,9,16

Writes `experiments/results/diagnose_coupling_weights.md`.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from jthermo.cli.common import load_data
from jthermo.diagnose import joint as J
from jthermo.diagnose import select as S
from jthermo.printer.geometry import grid_edges

HERE = Path(__file__).resolve().parent
EFFECTS = "lateral_conduction,radiative_loss,heater_lag"
RULES = ((0.05, None), (0.1, None), (0.2, None), (0.3, None), (0.1, 3), (0.1, 4), (0.1, 5), (0.2, 4))


class _Stop(Exception):
    pass


def inputs(n: int, tmp: Path, cache: Path | None) -> dict:
    if cache is not None and (cache / f"n{n}.npz").exists():
        return dict(np.load(cache / f"n{n}.npz"))
    for name, dur, seed in (("est.csv", "3600", "1"), ("val.csv", "1800", "2")):
        subprocess.run([sys.executable, "-m", "jthermo.cli", "generate", "--zones", str(n), "--effects", EFFECTS,
                        "--duration", dur, "--seed", seed, "--out", str(tmp / name), "--quiet"], check=True)
    got = {}

    def spy(neutral, lay, u, y, theta_k):
        got.update(gain=np.exp(neutral[:, lay.sl("log_b")]), u=u, y=y,
                   exch=np.exp(theta_k[:, lay.sl("log_k")][:, :n - 1]))
        raise _Stop

    S.pruned_start = spy
    try:
        S.diagnose(load_data(str(tmp / "est.csv"), "e"), load_data(str(tmp / "val.csv"), "v"))
    except _Stop:
        pass
    if cache is not None:
        np.savez(cache / f"n{n}.npz", **got)
    return got


def rows(n: int, got: dict) -> list[str]:
    edges = {frozenset(e) for e in grid_edges(n)}
    others = [[j for j in range(n) if j != i] for i in range(n)]
    is_edge = np.array([[frozenset((i, j)) in edges for j in others[i]] for i in range(n)])
    rms = lambda v: np.sqrt(np.mean(np.square(v), axis=0))
    wb = got["gain"] * rms(got["u"])[None, :]
    out = []
    for share, most in RULES:
        kb, kk = J.kept_couplings(got["gain"], got["u"], got["exch"], got["y"], share, most)
        own = int(np.sum(np.diag(kb)))
        held_b = float(np.sum(wb * ~kb) / np.sum(wb))
        out.append(f"| {n} | {share:g} | {most or '-'} | {int(kb.sum())} / {n * n} | {own}/{n} | {held_b:.3f} | "
                   f"{int(kk.sum())} / {n * (n - 1)} | {int((kk & is_edge).sum())}/{int(is_edge.sum())} | "
                   f"{int((kk & ~is_edge).sum())} |")
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--zones", default="6,9,16")
    ap.add_argument("--cache", default=None, help="folder to keep / reuse each N's inputs in (.npz)")
    args = ap.parse_args(argv)
    lines = ["# Couplings a pruned joint model keeps", "",
             (f"Made by `python experiments/diagnose_coupling_weights.py --zones {args.zones}"
             f"` (see its docstring). Gains weigh "
             "grid gain × rms(input), exchanges per-zone fitted rate × rms(temperature difference); "
             "each zone keeps those of at least `share` of its largest, at most its `at most` strongest. "
             "Held gain weight: the share of all gains' weight that the held (not fitted) gains carry."), "",
             ("| N | share | at most | gains kept | own heater kept | held gain weight | exchanges kept (directed) | "
             "grid-side exchanges kept | other exchanges kept |"),
             "|---|---|---|---|---|---|---|---|---|"]
    out = HERE / "results" / "diagnose_coupling_weights.md"
    for n in sorted(int(z) for z in args.zones.split(",")):
        with tempfile.TemporaryDirectory() as tmp:
            lines += rows(n, inputs(n, Path(tmp), None if args.cache is None else Path(args.cache)))
        out.write_text("\n".join(lines) + "\n")
        print("\n".join(lines[-len(RULES):]), flush=True)


if __name__ == "__main__":
    main()
