"""Per-zone fits over two XLA CPU devices (`--xla_force_host_platform_device_count=2`, set
before JAX starts): the diagnosis's first `fitting.fit_zones` call on the latency benchmark's kind
of record (N = 4) is captured, then run as one jitted `_fit_zones` and as a `jax.shard_map` of it
over the two devices (problems dealt alternately), each twice (first call compiles), printing
wall s and the sum of the costs (the same in both). No persistent cache (`JTHERMO_NO_CACHE=1`).
A probe for issue 13, 2026-11-28 (printed, no results file): whole 12.26 / 11.84 s, sharded
7.79 / 7.47 s, the same costs, no hang in two runs; the joint fits' counterpart
(`diagnose_shard_joint.py`) hung.

    JTHERMO_NO_CACHE=1 python benchmarks/diagnose_shard_zones.py
"""
import os, sys, time, subprocess, tempfile, faulthandler
os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=" + os.environ.get("NDEV", "2")
faulthandler.dump_traceback_later(300, exit=True)
from pathlib import Path
import numpy as np
import jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
from jax.sharding import PartitionSpec as Ps
from jthermo.cli.common import load_data
from jthermo.diagnose import select as S, fitting as F
print(jax.devices())
got = []
orig = S.fit_zones
def spy(*a):
    got.append(a)
    return orig(*a)
S.fit_zones = spy
with tempfile.TemporaryDirectory() as tmp:
    d = Path(tmp)
    for name, dur, seed in (("est.csv", "3600", "1"), ("val.csv", "1800", "2")):
        subprocess.run([sys.executable, "-m", "jthermo.cli", "generate", "--zones", "4", "--effects",
                        "lateral_conduction,radiative_loss,heater_lag", "--duration", dur, "--seed", seed,
                        "--out", str(d / name), "--quiet"], check=True)
    est, val = load_data(str(d / "est.csv"), "e"), load_data(str(d / "val.csv"), "v")
    S.diagnose(est, val)
theta0, mask, on, per, shared, lay, n_iter, n_active = got[0][:8]
B = theta0.shape[0]
budget = jnp.full(B, n_iter, jnp.int32)
order = np.concatenate([np.arange(0, B, 2), np.arange(1, B, 2)])
take = lambda x: jnp.asarray(np.asarray(x)[order])
args = (take(theta0), take(mask), take(on), {k: take(v) for k, v in per.items()}, budget)
whole = jax.jit(lambda th, m, o, p, b: F._fit_zones(th, m, o, p, shared, lay, n_iter, n_active, b))
mesh = jax.make_mesh((2,), ("p",))
sharded = jax.jit(jax.shard_map(lambda th, m, o, p, b: F._fit_zones(th, m, o, p, shared, lay, n_iter, n_active, b),
                                mesh=mesh, in_specs=Ps("p"), out_specs=Ps("p"), check_vma=False))
from jax.sharding import NamedSharding
sh_args = jax.tree_util.tree_map(lambda x: jax.device_put(x, NamedSharding(mesh, Ps("p"))), args)
plan = (("whole", whole), ("sharded", sharded), ("whole", whole), ("sharded", sharded)) if len(jax.devices()) > 1 else (("whole", whole),) * 2
for name, f in plan:
    a = sh_args if name == "sharded" else args
    t = time.perf_counter(); out = jax.block_until_ready(f(*a)); t1 = time.perf_counter() - t
    t = time.perf_counter(); out = jax.block_until_ready(f(*a)); t2 = time.perf_counter() - t
    print(name, "first %.2f again %.2f" % (t1, t2), float(np.asarray(out[1]).sum()), flush=True)
