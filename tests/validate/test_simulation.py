from statistics import NormalDist

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo import AbstractModel, StateSpace
from jthermo import validate as V
from jthermo.data import from_arrays
from jthermo.errors import DataError, ModelError
from jthermo.inputs import prbs

T = 600


def _plant(nw=0):
    A = np.array([[0.9, 0.05], [0.0, 0.8]])
    B = np.array([[0.1, 0.02], [0.03, 0.2]])
    Bw = np.array([[0.05], [0.02]]) if nw else None
    return StateSpace(A, B, np.eye(2), ts=1.0, Bw=Bw, u0=[0.5, 0.5], y0=[20.0, 21.0],
                      w0=[15.0] if nw else None)


@pytest.fixture(scope="module")
def plant_data():
    m = _plant()
    u = prbs(1, T, 2)
    x0 = jnp.array([1.5, -2.0])
    y = np.asarray(m.simulate(u, None, x0))
    return m, np.asarray(u), y, np.asarray(x0)


def test_fit_percent_matches_numpy_definition():
    rng = np.random.default_rng(0)
    y = rng.standard_normal((200, 3)).cumsum(0)
    yhat = y + 0.3 * rng.standard_normal((200, 3))
    # the standard workloads' definition (shared/bench/workloads.py), per output
    num = np.linalg.norm(y - yhat, axis=0)
    den = np.linalg.norm(y - y.mean(axis=0), axis=0)
    want = 100.0 * (1.0 - num / den)
    np.testing.assert_allclose(np.asarray(V.fit_percent(y, yhat)), want, rtol=1e-12)
    np.testing.assert_allclose(float(V.fit_percent(y[:, 0], yhat[:, 0])), want[0], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(jax.jit(V.fit_percent)(y, yhat)), want, rtol=1e-12)
    with pytest.raises(DataError, match="constant"):
        V.fit_percent(np.ones((10, 1)), np.zeros((10, 1)))
    with pytest.raises(DataError, match="shape"):
        V.fit_percent(y, yhat[:, :2])


def test_compare_estimated_x0_gives_100_percent(plant_data):
    m, u, y, x0 = plant_data
    data = from_arrays(u, y)
    r = V.compare(m, data)
    np.testing.assert_allclose(r["fit_percent"], 100.0, atol=1e-6)
    np.testing.assert_allclose(r["x0"], x0, atol=1e-8)
    assert r["mean_fit_percent"] == pytest.approx(100.0, abs=1e-6)
    assert r["yhat"].shape == y.shape and r["k"] is None
    zero = V.compare(m, data, x0="zero")
    assert max(zero["fit_percent"]) < 99.0          # the initial state matters here
    np.testing.assert_allclose(V.compare(m, data, x0=x0)["fit_percent"], 100.0, atol=1e-6)
    pred = V.compare(m, data, k=3)
    np.testing.assert_allclose(pred["fit_percent"], 100.0, atol=1e-6)
    x_short = V.estimate_initial_state(m, data, n=20)
    np.testing.assert_allclose(np.asarray(x_short), x0, atol=1e-8)


def test_compare_uses_measured_signals():
    m = _plant(nw=1)
    u = prbs(2, 300, 2)
    w = 15.0 + np.sin(np.arange(300) / 20.0)[:, None]
    y = m.simulate(u, w)
    extra = np.column_stack([w, np.zeros(300)])          # an extra, unused measured signal
    r = V.compare(m, from_arrays(u, y, w=extra))
    np.testing.assert_allclose(r["fit_percent"], 100.0, atol=1e-6)
    with pytest.raises(DataError, match="measured signal"):
        V.compare(m, from_arrays(u, y))


def test_fit_percent_of_a_flat_output_is_undefined():
    """An output whose variation is rounding error of its level has no fit % (it was a ratio to
    that error: -1e291 % in a diagnosis of a constant record)."""
    y = np.full((50, 1), 25.0) + np.r_[np.zeros(49), 1e-13][:, None]
    from jthermo.validate.simulation import fit_percent_np

    for f in (V.fit_percent, fit_percent_np):
        with pytest.raises(DataError, match="output 0 is constant"):
            f(y, y + 0.1)
    assert float(V.fit_percent(y + np.arange(50)[:, None] * 1e-3, y)[0]) < 100.0


def test_compare_errors(plant_data):
    m, u, y, _ = plant_data
    with pytest.raises(DataError, match="input"):
        V.compare(m, from_arrays(u[:, :1], y))
    with pytest.raises(DataError, match="output"):
        V.compare(m, from_arrays(u, y[:, :1]))
    with pytest.raises(DataError, match="positive integer"):
        V.compare(m, from_arrays(u, y), k=0)
    with pytest.raises(DataError, match="x0 must be"):
        V.compare(m, from_arrays(u, y), x0="guess")
    with pytest.raises(DataError, match="x0 has shape"):
        V.compare(m, from_arrays(u, y), x0=np.zeros(3))
    with pytest.raises(DataError, match="IOData"):
        V.compare(m, (u, y))
    # a model at Ts = 1 s on data at 2 s is another system (it gave exit 0 with fits of 2-7 %)
    with pytest.raises(DataError, match="sample time 2 s is not the model's 1 s"):
        V.compare(m, from_arrays(u, y, ts=2.0))
    with pytest.raises(DataError, match="sample time"):
        V.residual_tests(m, from_arrays(u, y, ts=2.0))
    assert V.compare(m, from_arrays(u, y, ts=1.002))["fit_percent"]   # a logged record's jitter


def test_residual_tests_white_passes_coloured_fails(plant_data):
    m, u, y, _ = plant_data
    rng = np.random.default_rng(3)
    e = 0.05 * rng.standard_normal(y.shape)
    white = V.residual_tests(m, from_arrays(u, y + e), max_lag=20)
    # white residuals: correlations well inside the family bound, Ljung–Box does not reject
    assert white["whiteness_pass"] and white["independence_pass"]
    assert np.abs(white["auto"][1:]).max() < 0.8 * white["bound_auto_family"]
    assert min(white["ljung_box_p"]) > 0.05
    assert white["auto"].shape == (21, 2) and white["cross"].shape == (41, 2, 2)
    np.testing.assert_allclose(white["auto"][0], 1.0)
    # the bound is z_{1-alpha/2} / sqrt(N)
    assert white["bound"] == pytest.approx(NormalDist().inv_cdf(0.995) / np.sqrt(T))
    # AR(1) coloured noise on output 0 (pole 0.8): its correlation at lag 1 is ~0.8 >> bound
    v = np.zeros(T)
    for k in range(1, T):
        v[k] = 0.8 * v[k - 1] + e[k, 0]
    col = V.residual_tests(m, from_arrays(u, y + np.column_stack([v, e[:, 1]])), max_lag=20)
    assert col["auto_pass"] == [False, True]
    assert col["ljung_box_p"][0] < 1e-10
    assert col["auto"][1, 0] > 0.6


def test_residual_tests_detects_input_correlation(plant_data):
    m, u, y, _ = plant_data
    rng = np.random.default_rng(4)
    e = 0.02 * rng.standard_normal(y.shape)
    wrong = StateSpace(m.A, m.B * np.array([[1.0, 1.0], [1.0, 0.5]]), m.C, ts=1.0, u0=m.u0, y0=m.y0)
    r = V.residual_tests(wrong, from_arrays(u, y + e), max_lag=10)
    assert r["cross_pass"][1][1] is False
    assert np.abs(r["cross"][:, 1, 1]).max() > 3 * r["bound_cross_family"]
    # an input held constant through the record has no cross-correlation: not judged, the
    # other input's pairs are (the same figures as with it varying)
    u_still = u.copy()
    u_still[:, 0] = 0.3             # its float std is 6e-17, not 0: constant to rounding
    y_still = np.asarray(wrong.simulate(jnp.asarray(u_still), None, jnp.zeros(2))) + e
    r_still = V.residual_tests(wrong, from_arrays(u_still, y_still), max_lag=10)
    assert r_still["constant_inputs"] == [r_still["input_names"][0]]
    assert [row[0] for row in r_still["cross_pass"]] == [None, None]
    assert [row[0] for row in r_still["n_outside_cross"]] == [None, None]
    assert np.all(np.isnan(r_still["cross"][:, :, 0])) and np.all(np.isfinite(r_still["cross"][:, :, 1]))
    assert r_still["independence_pass"] is (r_still["cross_pass"][0][1] and r_still["cross_pass"][1][1])
    y_none = np.asarray(m.simulate(jnp.full((T, 2), 0.5), None, jnp.array([1.5, -2.0]))) + e
    assert V.residual_tests(m, from_arrays(np.full((T, 2), 0.5), y_none), max_lag=10)["independence_pass"] is None
    with pytest.raises(DataError, match="max_lag"):
        V.residual_tests(m, from_arrays(u, y), max_lag=0)
    with pytest.raises(DataError, match="alpha"):
        V.residual_tests(m, from_arrays(u, y), alpha=1.5)


def test_correlations_match_numpy():
    rng = np.random.default_rng(5)
    e = rng.standard_normal((100, 2))
    u = rng.standard_normal((100, 1))
    auto, cross = V.correlations(jnp.asarray(e), jnp.asarray(u), 5)
    ec, uc = e - e.mean(0), u - u.mean(0)
    for tau in range(-5, 6):
        a = ec[max(tau, 0):100 + min(tau, 0), 0]
        b = uc[max(-tau, 0):100 - max(tau, 0), 0]
        want = (a @ b) / 100 / (ec[:, 0].std() * uc[:, 0].std())
        assert float(cross[tau + 5, 0, 0]) == pytest.approx(want, rel=1e-10)
    want1 = (ec[1:, 1] @ ec[:-1, 1]) / (ec[:, 1] @ ec[:, 1])
    assert float(auto[1, 1]) == pytest.approx(want1, rel=1e-10)


def test_spectral_estimate_agrees_at_low_frequency():
    # SISO g_k = 0.5^(k-1), white binary input (Phi_u = 1), white noise of std sv.
    N, M, sv = 8000, 30, 0.2
    m = StateSpace([[0.5]], [[1.0]], [[1.0]], ts=1.0)
    rng = np.random.default_rng(6)
    u = rng.choice([-1.0, 1.0], size=(N, 1))
    y_clean = np.asarray(m.simulate(u))
    y = y_clean + sv * rng.standard_normal((N, 1))
    omega, G = V.spectral_estimate(from_arrays(u, y), lag_window=M)
    _, G_clean = V.spectral_estimate(from_arrays(u, y_clean), lag_window=M)
    assert G.shape == (128, 1, 1)
    Gt = np.asarray(m.frequency_response(omega))
    low = omega < 0.5
    tau = np.arange(-M, M + 1)
    w = 0.54 + 0.46 * np.cos(np.pi * tau / M)
    # 1) the noise's share of the error: complex, variance sum(w^2)/N * Phi_v/Phi_u (Ljung 1999 §6.4)
    sigma_v = np.sqrt(np.sum(w ** 2) / N * sv ** 2)
    assert np.abs(G - G_clean)[low].max() < 5 * sigma_v
    # 2) noise-free: the lag window's bias sum_k (1 - w_k)|g_k| + truncation, plus the input's
    #    sample-correlation error, std <= sqrt(sum(w^2)/N) * ||g||_2
    g = np.asarray(m.impulse_response(400))[:, 0, 0]
    bias = np.sum((1 - w[M:]) * np.abs(g[:M + 1])) + np.abs(g[M + 1:]).sum()
    sigma_u = np.sqrt(np.sum(w ** 2) / N) * np.linalg.norm(g)
    assert np.abs(G_clean - Gt)[low].max() < bias + 5 * sigma_u
    _, G_hann = V.spectral_estimate(from_arrays(u, y_clean), lag_window=M, window="hann")
    w_hann = 0.5 + 0.5 * np.cos(np.pi * tau / M)
    bias_hann = np.sum((1 - w_hann[M:]) * np.abs(g[:M + 1])) + np.abs(g[M + 1:]).sum()
    assert np.abs(G_hann - Gt)[low].max() < bias_hann + 5 * sigma_u
    b = V.bode(m, omega)
    np.testing.assert_allclose(b["magnitude"], np.abs(Gt))
    np.testing.assert_allclose(b["phase_deg"][0, 0, 0], np.degrees(np.angle(Gt[0, 0, 0])), atol=1e-9)
    with pytest.raises(DataError, match="lag window"):
        V.spectral_estimate(from_arrays(u, y), lag_window=0)
    with pytest.raises(DataError, match="window must be"):
        V.spectral_estimate(from_arrays(u, y), window="boxcar")


def test_rga_closed_form():
    G = np.array([[2.0, 0.5], [0.8, 1.5]])
    lam = 1.0 / (1.0 - G[0, 1] * G[1, 0] / (G[0, 0] * G[1, 1]))
    R = np.asarray(V.rga(G))
    np.testing.assert_allclose(R, [[lam, 1 - lam], [1 - lam, lam]], rtol=1e-12)
    R3 = np.asarray(V.rga(np.random.default_rng(0).standard_normal((3, 3))))
    np.testing.assert_allclose(R3.sum(0), 1.0, rtol=1e-10)
    np.testing.assert_allclose(R3.sum(1), 1.0, rtol=1e-10)
    with pytest.raises(ModelError, match="singular"):
        V.rga([[1.0, 2.0], [2.0, 4.0]])
    with pytest.raises(ModelError, match="square"):
        V.rga(np.ones((2, 3)))
    m = _plant()
    np.testing.assert_allclose(np.asarray(V.steady_state_rga(m)), np.asarray(V.rga(m.dcgain())))


def test_transmission_zeros():
    rng = np.random.default_rng(7)
    A = np.diag([0.9, 0.7, 0.5])
    B = rng.standard_normal((3, 2))
    C = rng.standard_normal((2, 3))
    D = np.array([[1.0, 0.2], [0.1, 0.8]])
    pz = V.poles_zeros(StateSpace(A, B, C, D))
    want = np.sort_complex(np.linalg.eigvals(A - B @ np.linalg.solve(D, C)))  # invertible D
    np.testing.assert_allclose(pz["zeros"], want, atol=1e-9)
    np.testing.assert_allclose(pz["poles"], [0.5, 0.7, 0.9], atol=1e-12)
    # SISO (z - 0.5) / ((z - 0.9)(z - 0.8)) in controllable canonical form: one zero at 0.5
    siso = StateSpace([[1.7, -0.72], [1.0, 0.0]], [[1.0], [0.0]], [[1.0, -0.5]])
    pz = V.poles_zeros(siso)
    np.testing.assert_allclose(pz["zeros"], [0.5], atol=1e-10)
    np.testing.assert_allclose(pz["channel_zeros"][0][0], [0.5], atol=1e-10)
    # non-square: only channel zeros
    pz = V.poles_zeros(StateSpace(A, B[:, :1], C, D[:, :1]))
    assert pz["zeros"] is None and len(pz["channel_zeros"]) == 2


def test_step_info_first_order():
    a, b = 0.9, 0.1
    m = StateSpace([[a]], [[b]], [[1.0]], ts=2.0)
    info = V.step_info(m, 200)
    assert info["gain"][0, 0] == pytest.approx(b / (1 - a))
    # s_k / gain = 1 - a^k: 10 % at k = ln 0.9/ln a, 90 % at ln 0.1/ln a (interpolated)
    rise = 2.0 * (np.log(0.1) - np.log(0.9)) / np.log(a)
    assert info["rise_time"][0, 0] == pytest.approx(rise, abs=2.0 * 0.05)
    settle = 2.0 * np.ceil(np.log(0.02) / np.log(a))
    assert info["settling_time"][0, 0] == pytest.approx(settle, abs=2.0)
    assert info["overshoot_percent"][0, 0] == 0.0 and info["stable"]
    with pytest.raises(DataError, match="n must"):
        V.step_info(m, 1)


def test_information_criteria():
    ic = V.information_criteria(jnp.array([1.0, 0.5]), jnp.array([2, 4]), 100)
    np.testing.assert_allclose(np.asarray(ic["fpe"]), [1.0 * 1.02 / 0.98, 0.5 * 1.04 / 0.96])
    np.testing.assert_allclose(np.asarray(ic["aic"]), [4.0, 100 * np.log(0.5) + 8])
    np.testing.assert_allclose(np.asarray(ic["bic"]), [2 * np.log(100), 100 * np.log(0.5) + 4 * np.log(100)])
    cov = np.diag([0.5, 0.2])
    assert float(V.information_criteria(cov, 3, 50)["aic"]) == pytest.approx(50 * np.log(0.1) + 6)
    with pytest.raises(DataError, match="positive"):
        V.information_criteria(0.0, 2, 100)
    with pytest.raises(DataError, match="parameters"):
        V.information_criteria(1.0, 100, 100)


class _Cubic(AbstractModel):
    """A nonlinear model (cubic output map) for the initial-state fallback."""

    ss: StateSpace

    def to_statespace(self):
        return self.ss

    def simulate(self, u, w=None, x0=None):
        x0 = jnp.zeros(1) if x0 is None else x0

        def body(x, uk):
            return 0.9 * x + 0.1 * (uk[0] - 0.5), x[0] + x[0] ** 3

        return jax.lax.scan(body, x0, jnp.asarray(u))[1][:, None]


def test_estimate_initial_state_nonlinear_is_no_worse_than_steady():
    m = _Cubic(StateSpace([[0.9]], [[0.1]], [[1.0]], u0=[0.5]))
    u = np.asarray(prbs(5, T, 2))[:, :1]
    y = np.asarray(m.simulate(u, None, jnp.array([1.2])))
    data = from_arrays(u, y)
    x_est = V.estimate_initial_state(m, data, n=30)
    x_st = m.initial_state(y[0])
    err = lambda x: float(np.sum((y[:30] - np.asarray(m.simulate(u, None, x))[:30]) ** 2))
    assert err(x_est) <= err(x_st)
    np.testing.assert_allclose(np.asarray(x_est), [1.2], atol=1e-6)   # Gauss-Newton converged


def test_level_offsets_flag_a_shift_that_alone_makes_the_fit_negative():
    """The mean error bounds the fit: fit <= 100 (1 - |m| / std y); an output is flagged where
    that bound is negative and the shift carries at least half the squared error."""
    rng = np.random.default_rng(3)
    y = 50.0 + np.cumsum(rng.standard_normal((800, 3)), axis=0) * 0.2
    noise = 0.1 * rng.standard_normal((800, 3))
    sd = y.std(axis=0)
    shift = np.array([0.0, 0.5, 2.0]) * sd          # none, below std, twice the std
    yhat = y - noise - shift
    out = V.level_offsets(y, yhat, ["a", "b", "c"])
    assert [o["shifted"] for o in out] == [False, False, True]
    assert [o["output"] for o in out] == ["a", "b", "c"]
    np.testing.assert_allclose([o["mean_error"] for o in out], shift + noise.mean(axis=0))
    fits = np.asarray(V.fit_percent(y, yhat))
    bound = 100.0 * (1.0 - np.abs([o["mean_error"] for o in out]) / sd)
    assert np.all(fits <= bound + 1e-9) and fits[2] < 0
    notes = V.level_offset_notes(out)
    assert len(notes) == 1 and "error c +" in notes[0] and "error a" not in notes[0] and " b " not in notes[0]
    assert V.level_offset_notes(V.level_offsets(y, y - noise)) == []
    # a large error that is not a shift (wrong dynamics) is not called one
    wrong = y - 3.0 * sd * np.sin(np.arange(800) / 20.0)[:, None]
    assert not any(o["shifted"] for o in V.level_offsets(y, wrong))
