"""Joint fits over two XLA CPU devices: as `diagnose_shard_zones.py`, for the diagnosis's second
`fitting.fit_joint` call (cur and six additions, padded to 8 slots). A probe for issue 13,
2026-11-28: the jitted whole call ran (10.75 s first, 5.10 again); the sharded one never
returned (the watchdog's stacks after 400 s, both devices' executions waiting), as the threaded
splits did (`diagnose_zone_threads.py`, `results/diagnose_threads_deadlock.md`).

    JTHERMO_NO_CACHE=1 python benchmarks/diagnose_shard_joint.py
"""
import os, sys, time, subprocess, tempfile, faulthandler
os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
faulthandler.dump_traceback_later(float(os.environ.get("DUMP", "400")), exit=True)
from pathlib import Path
import numpy as np
import jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
from jax.sharding import PartitionSpec as Ps, NamedSharding
from jthermo.cli.common import load_data
from jthermo.diagnose import select as S, fitting as F, joint as J
got = []
orig = J.fit_joint
def spy(*a):
    got.append(a)
    return orig(*a)
J.fit_joint = spy
with tempfile.TemporaryDirectory() as tmp:
    d = Path(tmp)
    for name, dur, seed in (("est.csv", "3600", "1"), ("val.csv", "1800", "2")):
        subprocess.run([sys.executable, "-m", "jthermo.cli", "generate", "--zones", "4", "--effects",
                        "lateral_conduction,radiative_loss,heater_lag", "--duration", dur, "--seed", seed,
                        "--out", str(d / name), "--quiet"], check=True)
    est, val = load_data(str(d / "est.csv"), "e"), load_data(str(d / "val.csv"), "v")
    S.diagnose(est, val)
Theta0, on, rec0, mask, y, weight, f_per, f_shared, lay, n_iter, n_active = got[1][:11]
M = Theta0.shape[0]
idx = np.arange(8) % M          # 8 slots, the last copy refitted (same answer)
order = np.concatenate([idx[0::2], idx[1::2]])
take = lambda x: jnp.asarray(np.asarray(x)[order])
budget = jnp.full(8, n_iter, jnp.int32)
args = (take(Theta0), take(on), take(rec0), take(mask), jax.tree_util.tree_map(take, f_per), budget)
body = lambda th, o, r, m, fp, b: F._fit_joint(th, o, r, m, y, weight, fp, f_shared, lay, n_iter, n_active, b)
whole = jax.jit(body)
mesh = jax.make_mesh((2,), ("p",))
sharded = jax.jit(jax.shard_map(body, mesh=mesh, in_specs=Ps("p"), out_specs=Ps("p"), check_vma=False))
sh_args = jax.tree_util.tree_map(lambda x: jax.device_put(x, NamedSharding(mesh, Ps("p"))), args)
for name, f in (("whole", whole), ("sharded", sharded), ("whole", whole), ("sharded", sharded)):
    a = sh_args if name == "sharded" else args
    t = time.perf_counter(); out = jax.block_until_ready(f(*a)); t1 = time.perf_counter() - t
    t = time.perf_counter(); out = jax.block_until_ready(f(*a)); t2 = time.perf_counter() - t
    print(name, "first %.2f again %.2f" % (t1, t2), float(np.asarray(out[3]).sum()), flush=True)
