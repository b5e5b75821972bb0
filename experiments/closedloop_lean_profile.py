"""Profile of the W2 cost paths (N=16, B=256): NumPy, a hand-written JAX scan, dense Scenario,
CompactScenario at several scan unrolls. `python experiments/closedloop_lean_profile.py [f64|f32] [T]`."""
import sys
import jax
jax.config.update("jax_enable_x64", len(sys.argv) < 2 or sys.argv[1] != "f32")
import jax.numpy as jnp, numpy as np, equinox as eqx
from pathlib import Path; _ROOT = Path(__file__).resolve().parents[1]; sys.path.insert(0, str(_ROOT / "benchmarks")); sys.path.insert(0, str(_ROOT.parent / "shared" / "bench"))
import workloads as wl
from common import compare_interleaved
from jthermo.closedloop import rollout_costs, CompactScenario, Events, Scenario, ModelDisturbance
from jthermo.control.pi import DiagonalPI
from jthermo.models import StateSpace
N, B, T = 16, 256, int(sys.argv[2]) if len(sys.argv) > 2 else 1800
su = wl.closed_loop_setup(N, T, B, 0)
p = su["plant"]
model = StateSpace(p["A"], p["B"], np.eye(N), Bw=np.eye(N), u0=np.zeros(N), w0=np.zeros(N), y0=np.zeros(N))
pi = DiagonalPI(su["kp"], su["kp"] / su["ki"], su["u_ff"], antiwindup="clamp")
TR = {"tracking": 1.0, "uniformity": 0.0, "effort": 0.0, "window": 0.0}
d = su["d"]
E = N
tt = np.full((B, E), -1); zz = np.zeros((B, E), int); ss = np.zeros((B, E))
for b in range(B):
    t_, z_ = np.nonzero(d[b]); tt[b, :len(t_)] = t_; zz[b, :len(t_)] = z_; ss[b, :len(t_)] = d[b, t_, z_]
cs = CompactScenario(r0=jnp.full((B, N), 4.0), r1=jnp.full((B, N), 4.0), t_step=jnp.zeros(B, int),
                     w=jnp.zeros((B, N)), events=Events(jnp.asarray(tt), jnp.asarray(zz), jnp.asarray(ss)),
                     y0=jnp.zeros((B, N)), n_samples=T)
dd = jnp.asarray(d)
cs0 = eqx.tree_at(lambda c: c.events, cs, Events(jnp.zeros((B, 0), int), jnp.zeros((B, 0), int), jnp.zeros((B, 0))))
sc = Scenario(r=jnp.broadcast_to(jnp.full(N, 4.0), (B, T, N)), d=ModelDisturbance(w=dd, dy=jnp.zeros_like(dd)),
              v=jnp.zeros_like(dd), y0=jnp.zeros((B, N)))
x0s = jnp.zeros((B, N))
f_dense = eqx.filter_jit(lambda m, c, s, x: rollout_costs(m, c, s, TR, x))
f_comp = {u: eqx.filter_jit(lambda m, c, s, x, u=u: rollout_costs(m, c, s, TR, x, unroll=u)) for u in (1, 2, 4, 8, 16)}
a = jnp.asarray(p["a"]); BT = jnp.asarray(p["B"].T); kp = jnp.asarray(su["kp"]); ki = jnp.asarray(su["ki"])
@jax.jit
def plain(dd):
    def one(db):
        def body(c, dk):
            x, s, J = c
            e = 4.0 - x; st = s + e; v = 0.5 + kp * e + ki * st; u = jnp.clip(v, 0, 1)
            wind = ((v > 1) & (e > 0)) | ((v < 0) & (e < 0))
            return (a * x + u @ BT + dk, jnp.where(wind, s, st), J + e @ e), None
        (_, _, J), _ = jax.lax.scan(body, (jnp.zeros(N), jnp.zeros(N), 0.0), db)
        return J / (T * N)
    return jax.vmap(one)(dd)
Jn = wl.rollout_numpy(su)
cands = {"numpy": lambda: wl.rollout_numpy(su), "plain": lambda: plain(dd),
         "dense": lambda: f_dense(model, pi, sc, x0s), "compact_u1": lambda: f_comp[1](model, pi, cs, x0s),
         "compact_u4": lambda: f_comp[4](model, pi, cs, x0s), "compact_u2": lambda: f_comp[2](model, pi, cs, x0s), "compact_u8": lambda: f_comp[8](model, pi, cs, x0s), "compact_u16": lambda: f_comp[16](model, pi, cs, x0s), "noev_u8": lambda: f_comp[8](model, pi, cs0, x0s)}
compare_interleaved(cands, Jn)
