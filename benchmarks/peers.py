"""jax-sysid, configured and run the same way by every benchmark that compares with it
(`identification.py`'s peer rows, `peers_fair.py`'s configurations): a fit and a simulation from
rest. Imports nothing from the other scripts."""

from __future__ import annotations

import numpy as np

#: jax-sysid configurations: (scaled, rho_th, lbfgs_epochs, seeds)
SYSID_CONFIGS = {
    "doc": (True, 1e-2, 1000, (0,)),
    "unscaled": (False, 1e-2, 1000, (0,)),
    "doc_rho1e-4": (True, 1e-4, 1000, (0,)),
    "doc_3000": (True, 1e-2, 3000, (0,)),
    "doc_rho1e-4_3000": (True, 1e-4, 3000, (0,)),
    "doc_seeds3": (True, 1e-2, 1000, (0, 1, 2)),
}


def sysid_fit(est: dict, N: int, config: str) -> tuple:
    """One jax-sysid fit (every seed of `config`, the best estimation MSE kept): returns
    (model, scaling); `identification.timed` or `child` time it."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from jax_sysid.models import LinearModel
    from jax_sysid.utils import standard_scale

    scaled, rho_th, epochs, seeds = SYSID_CONFIGS[config]
    Y, U = est["y"], est["u"]
    if scaled:
        Y, ymean, ygain = standard_scale(Y)
        U, umean, ugain = standard_scale(U)
    else:
        ymean, ygain, umean, ugain = np.zeros(N), np.ones(N), np.zeros(N), np.ones(N)
    best = None
    for seed in seeds:
        m = LinearModel(N, N, N, feedthrough=False, seed=seed)
        m.loss(rho_x0=1e-3, rho_th=rho_th)
        m.optimization(adam_epochs=0, lbfgs_epochs=epochs, iprint=-1)
        m.fit(Y, U)
        yhat, _ = m.predict(m.x0, U)
        mse = float(np.mean((np.asarray(yhat) - Y) ** 2))
        if best is None or mse < best[0]:
            best = (mse, m)
    return best[1], (ymean, ygain, umean, ugain)


def sysid_sim_from_rest(model, scaling, u: np.ndarray) -> np.ndarray:
    """Simulate the (scaled) jax-sysid model from rest at u = 0, unscaled output."""
    ymean, ygain, umean, ugain = scaling
    A, B, C, _ = (np.asarray(m) for m in model.ssdata())
    us = (u - umean) * ugain
    x = np.linalg.solve(np.eye(A.shape[0]) - A, B @ ((0.0 - umean) * ugain))
    ys = np.empty((u.shape[0], C.shape[0]))
    for k in range(u.shape[0]):
        ys[k] = C @ x
        x = A @ x + B @ us[k]
    return ys / ygain + ymean
