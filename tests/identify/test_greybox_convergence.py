"""The grey-box fit says which zones did not converge and by how much a further
Gauss–Newton step would still lower their cost."""

import numpy as np

from jthermo.identify.greybox import fit_greybox
from jthermo.identify.pem import EXPECTED_IMPROVEMENT_TOL

from .test_greybox_scale import _bed


def test_converged_flag_matches_zone_report():
    data, _, _ = _bed(n=3, T=900, seed=2)
    done = fit_greybox(data)
    assert done.converged and done.extra["zones_not_converged"] == []
    assert len(done.extra["expected_improvement"]) == 3
    assert max(done.extra["expected_improvement"]) < EXPECTED_IMPROVEMENT_TOL
    # two LM steps from the ARX start leave every zone short of its optimum
    short = fit_greybox(data, max_steps=2)
    assert not short.converged
    bad = short.extra["zones_not_converged"]
    assert bad and all(short.extra["expected_improvement"][i] >= EXPECTED_IMPROVEMENT_TOL
                       for i in bad)
    assert short.cost > done.cost
    np.testing.assert_array_less(np.asarray(done.extra["zone_costs"]),
                                 np.asarray(short.extra["zone_costs"]) * (1 + 1e-12))


def _zone_cost(model, data, x0):
    import jax.numpy as jnp

    w = jnp.asarray(data.w) if data.w.shape[1] else None
    sim = np.asarray(model.simulate(jnp.asarray(data.u), w, jnp.asarray(x0)))
    return np.mean((np.asarray(data.y) - sim) ** 2, axis=0)


def test_zero_gain_lies_on_its_bound_and_converges():
    """A heater that does not reach a zone: its least-squares gain is at or below 0, where a
    log-gain used to creep without converging. The fit converges, lists the gain at its bound
    and is a constrained minimum: no small move of any parameter lowers a zone's cost
    (finite differences through the model's own simulation)."""
    import jax.numpy as jnp

    from jthermo.data import from_arrays
    from jthermo.models.greybox import BedModel

    rng = np.random.default_rng(7)
    n, T = 3, 1500
    gain = np.array([[50.0, 8.0, 1e-9], [8.0, 50.0, 8.0], [1e-9, 8.0, 50.0]])
    true = BedModel.from_physical(np.full(n, 1000.0), [5.0, 6.0, 7.0], gain)
    u = np.repeat(rng.integers(0, 2, (T // 20 + 1, n)) * 0.6 + 0.2, 20, axis=0)[:T]
    w = np.full((T, 1), 24.0)
    y = np.asarray(true.simulate(u, w, x0=jnp.full(n, 30.0))) + 0.05 * rng.standard_normal((T, n))
    data = from_arrays(u, y, 1.0, w)
    fit = fit_greybox(data)
    assert fit.converged and fit.extra["zones_not_converged"] == []
    at_zero = fit.extra["gains_at_zero"]
    assert at_zero and all(tuple(p) in {(0, 2), (2, 0)} for p in at_zero)
    assert np.all(np.isfinite(np.asarray(fit.model.log_gain)))
    base = _zone_cost(fit.model, data, fit.x0)
    h = 1e-4
    for field, shape in (("log_loss", (n,)), ("log_gain", (n, n))):
        for idx in np.ndindex(shape):
            for s in (-h, h):
                arr = np.asarray(getattr(fit.model, field)).copy()
                if field == "log_gain" and list(idx) in at_zero:
                    # on the bound: only a gain above it is feasible (log of a positive gain)
                    arr[idx] = np.log(1e-3 * np.exp(np.asarray(fit.model.log_gain)).max())
                else:
                    arr[idx] += s
                moved = BedModel(fit.model.log_capacity, *(
                    (jnp.asarray(arr) if f == field else getattr(fit.model, f))
                    for f in ("log_loss", "log_gain")), surroundings=24.0, ts=1.0)
                cost = _zone_cost(moved, data, fit.x0)
                assert cost[idx[0]] >= base[idx[0]] * (1 - 1e-9), (field, idx, s)
    for i in range(n):
        for s in (-1e-3, 1e-3):
            x0 = np.asarray(fit.x0).copy()
            x0[i] += s
            assert _zone_cost(fit.model, data, x0)[i] >= base[i] * (1 - 1e-12)
