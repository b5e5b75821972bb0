"""The diagnosis's fits over two XLA CPU devices instead of one: with
`--xla_force_host_platform_device_count=2` (set here before JAX starts) a captured fitting call
on the latency record (`diagnose_profile.write_record`, N = 4) runs as one jitted program and as
a `jax.shard_map` of it over the two devices (problems dealt alternately), each twice (the first
call compiles; no persistent cache), comparing wall s and the sum of the fitted costs.

- `--fits zones`: the first per-zone call (`fitting._fit_zones`, the candidates);
- `--fits joint`: the second joint call (`fitting._fit_joint`: the top mechanism refitted and
  six additions, padded to 8 slots; a padding copy is refitted, the same answer).

A probe: the per-zone fits split with the same costs and no hang; the
joint fits' sharded call never returned (the watchdog's stacks after 400 s), as the threaded
splits did (`diagnose_zone_threads.py`, `results/diagnose_threads_deadlock.md`), until
`masked_lm` factored one matrix at a time (the cause, in that record; `--tag _s42_lmap`). A
watchdog (`--watchdog` s) prints the stacks and exits with status 1.

    python benchmarks/diagnose_shard_devices.py --fits zones [--watchdog 400]

Writes `benchmarks/results/diagnose_shard_devices_{fits}.md` (not after a hang).
"""

from __future__ import annotations

import os

os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
os.environ["JTHERMO_NO_CACHE"] = "1"
os.environ["JTHERMO_FIT_THREADS"] = "1"      # the captured calls whole; the split is the devices'

import argparse
import faulthandler
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np
from diagnose_profile import write_record
from jax.sharding import NamedSharding
from jax.sharding import PartitionSpec as Ps

from jthermo import data
from jthermo.diagnose import fitting as F
from jthermo.diagnose import joint as J
from jthermo.diagnose import select as S

HERE = Path(__file__).resolve().parent


def captured_call(fits: str) -> tuple:
    """(program of the batched arguments, batched arguments `(B, ...)`) of the diagnosis's first
    per-zone call or second joint call on the latency record."""
    mod, name = (S, "fit_zones") if fits == "zones" else (J, "fit_joint")
    got, real = [], getattr(mod, name)

    def spy(*a):
        got.append(a)
        return real(*a)

    setattr(mod, name, spy)
    try:
        e, v = write_record(Path(tempfile.mkdtemp()))
        S.diagnose(data.load(e), data.load(v))
    finally:
        setattr(mod, name, real)
    if fits == "zones":
        theta0, mask, on, per, shared, lay, n_iter, n_active = got[0][:8]
        batched = (theta0, mask, on, per)
        program = lambda th, m, o, p, b: F._fit_zones(th, m, o, p, shared, lay, n_iter, n_active, b)
    else:
        Theta0, on, rec0, mask, y, weight, f_per, f_shared, lay, n_iter, n_active = got[1][:11]
        batched = (Theta0, on, rec0, mask, f_per)
        program = lambda th, o, r, m, fp, b: F._fit_joint(th, o, r, m, y, weight, fp, f_shared, lay, n_iter,
                                                          n_active, b)
    B = batched[0].shape[0]
    rows = np.arange(B + B % 2) % B                    # an even count: two equal shares
    order = np.concatenate([rows[0::2], rows[1::2]])   # dealt alternately
    args = jax.tree_util.tree_map(lambda x: jnp.asarray(np.asarray(x)[order]), batched)
    return program, (*args, jnp.full(order.size, n_iter, jnp.int32))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--fits", choices=("zones", "joint"), default="zones")
    ap.add_argument("--watchdog", type=float, default=400.0)
    args = ap.parse_args(argv)
    faulthandler.dump_traceback_later(args.watchdog, exit=True)
    program, call_args = captured_call(args.fits)
    mesh = jax.make_mesh((2,), ("p",))
    runs = {"one device": (jax.jit(program), call_args),
            "two devices": (jax.jit(jax.shard_map(program, mesh=mesh, in_specs=Ps("p"), out_specs=Ps("p"),
                                                  check_vma=False)),
                            jax.tree_util.tree_map(lambda x: jax.device_put(x, NamedSharding(mesh, Ps("p"))),
                                                   call_args))}
    rows = []
    for label in ("one device", "two devices") * 2:
        f, a = runs[label]
        times = []
        for _ in range(2):
            t = time.perf_counter()
            out = jax.block_until_ready(f(*a))
            times.append(time.perf_counter() - t)
        cost = float(np.asarray(out[1] if args.fits == "zones" else out[3]).sum())
        rows.append((label, *times, cost))
        print(rows[-1], flush=True)
    lines = [f"# The diagnosis's {args.fits} fits over two XLA CPU devices", "",
             (f"Made by `python benchmarks/diagnose_shard_devices.py --fits {args.fits}"
              f"`; {os.cpu_count()} CPUs, 1-minute load "
              f"{os.getloadavg()[0]:.2f} at the end; no persistent cache."), "",
             "| run | first call s | second call s | sum of the costs |", "|---|---|---|---|"]
    lines += [f"| {label} | {a:.2f} | {b:.2f} | {c:.12g} |" for label, a, b, c in rows]
    out = HERE / "results" / "diagnose_shard_devices.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
