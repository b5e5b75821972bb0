"""Fit ARX/ARMAX/OE/BJ to the reference workload: python experiments/polynomial_workload.py N T n_starts [families]."""
import sys, time
from pathlib import Path; sys.path.insert(0, str(Path(__file__).resolve().parents[1].parent / "shared" / "bench"))
import jax, numpy as np
jax.config.update("jax_enable_x64", True)
import workloads as wl
from jthermo.data import from_arrays
from jthermo.identify.fit import fit
N=int(sys.argv[1]); T=int(sys.argv[2]); ns=int(sys.argv[3])
est,val=wl.estimation_validation(N,T,0)
d=from_arrays(est["u"],est["y"])
print("oracle", wl.fit_percent(val["y"], val["y_clean"]))
cases=[("arx",(1,1,1)),("arx",(2,2,1)),("armax",(1,1,1,1)),("armax",(2,2,2,1)),("oe",(1,1,1)),("oe",(2,2,1)),("bj",(1,1,1,1,1)),("bj",(2,2,2,2,1))]
if len(sys.argv)>4: cases=[c for c in cases if c[0] in sys.argv[4].split(",")]
for fam,o in cases:
  for rep in range(2):
    t=time.time(); r=fit(d,fam,o, n_starts=ns); dt=time.time()-t
    ys=np.asarray(r.model.simulate(val["u"]))
    print(fam,o, r.extra["offset"], "fit %.2f"%wl.fit_percent(val["y"],ys), "cost %.4g"%r.cost, r.converged, "%.1fs"%dt, np.asarray(r.extra["n_steps"]).ravel()[:4], flush=True)
