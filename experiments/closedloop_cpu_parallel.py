"""Can a CPU reach the W2 goal (20x the NumPy batch loop at N = 16, B = 256)? Hand-written
JAX scans of W2 (no jthermo code): batched carry with a matmul, the matmul written as a fused
broadcast-sum ("ew"), scan unroll 1 and 4, and, when the process sees several host devices,
the batch split over them with `shard_map` (one scan per core, no per-step thread sync).

    python experiments/closedloop_cpu_parallel.py
    XLA_FLAGS=--xla_force_host_platform_device_count=2 python experiments/closedloop_cpu_parallel.py

Prints cold and median warm seconds and the median ratio to NumPy of interleaved repeats.
"""
import sys
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp, numpy as np
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[2] / "shared" / "bench"))
import workloads as wl
from _timing import compare_interleaved
N, B, T = 16, 256, 3600
su = wl.closed_loop_setup(N, T, B, 0)
p = su["plant"]
a = jnp.asarray(p["a"]); BT = jnp.asarray(p["B"].T); kp = jnp.asarray(su["kp"]); ki = jnp.asarray(su["ki"])
dd = jnp.asarray(su["d"])
def body(c, dk):
    x, s, J = c
    e = 4.0 - x; st = s + e; v = 0.5 + kp * e + ki * st; u = jnp.clip(v, 0, 1)
    wind = ((v > 1) & (e > 0)) | ((v < 0) & (e < 0))
    return (a * x + u @ BT + dk, jnp.where(wind, s, st), J + jnp.sum(e * e, -1)), None
def body_ew(c, dk):
    x, s, J = c
    e = 4.0 - x; st = s + e; v = 0.5 + kp * e + ki * st; u = jnp.clip(v, 0, 1)
    wind = ((v > 1) & (e > 0)) | ((v < 0) & (e < 0))
    return (a * x + jnp.sum(u[..., :, None] * BT, -2) + dk, jnp.where(wind, s, st), J + jnp.sum(e * e, -1)), None
def make(bd, unroll=1):
    @jax.jit
    def f(dd):
        z = jnp.zeros((dd.shape[0], N))
        (_, _, J), _ = jax.lax.scan(bd, (z, z, jnp.zeros(dd.shape[0])), jnp.swapaxes(dd, 0, 1), unroll=unroll)
        return J / (T * N)
    return f
cands = {"numpy": lambda: wl.rollout_numpy(su)}
for nm, bd in (("batched", body), ("ew", body_ew)):
    for u in (1, 4):
        f = make(bd, u); cands[f"{nm}_u{u}"] = (lambda f=f: f(dd))
if len(jax.devices()) > 1:
    from jax.sharding import Mesh, PartitionSpec as P, NamedSharding
    mesh = Mesh(np.array(jax.devices()), ("b",))
    from jax import shard_map
    f1 = make(body, 1)
    fs = jax.jit(shard_map(lambda d: f1(d), mesh=mesh, in_specs=P("b"), out_specs=P("b"), check_vma=False))
    dds = jax.device_put(dd, NamedSharding(mesh, P("b")))
    cands["sharded"] = lambda: fs(dds)
Jn = wl.rollout_numpy(su)
compare_interleaved(cands, Jn)
