import equinox as eqx
import numpy as np
import pytest

from jthermo.control import (
    FAMILIES,
    IMC,
    LQG,
    DecoupledPI,
    DiagonalPI,
    FeedForward,
    Gated,
    decoupling_matrix,
    design,
    fit_step_model,
    lambda_gains,
    needs_decoupling,
    rga,
    step_models,
)
from jthermo.control.design import StepModel, zeros_stable
from jthermo.control.pi import UNTUNED_KP, UNTUNED_TI
from jthermo.errors import ControlError
from jthermo.models import StateSpace

from .loop import bed_plant


def test_step_model_exact_for_first_order():
    T, K, L = 12.0, 3.0, 0.0
    t = np.arange(400.0)
    s = K * (1 - np.exp(-t / T))
    k, lag, tc = fit_step_model(s, 1.0)
    assert k == pytest.approx(K, rel=1e-6)
    assert tc == pytest.approx(T, rel=0.02)
    assert lag == pytest.approx(L, abs=0.3)


def test_step_model_with_delay():
    t = np.arange(600.0)
    s = 2.0 * (1 - np.exp(-np.clip(t - 5.0, 0, None) / 20.0))
    _, lag, tc = fit_step_model(s, 1.0)
    assert tc == pytest.approx(20.0, rel=0.03) and lag == pytest.approx(5.0, abs=0.5)


def test_lambda_rule():
    kp, ti = lambda_gains(StepModel(np.array([2.0]), np.array([1.0]), np.array([10.0])), lam=4.0)
    assert kp[0] == pytest.approx(10.0 / (2.0 * 5.0)) and ti[0] == 10.0


def test_step_models_of_discrete_first_order():
    a = 0.9
    ss = StateSpace(np.array([[a]]), np.array([[1 - a]]), np.eye(1))
    sm = step_models(ss)
    assert sm.K[0] == pytest.approx(1.0, rel=1e-6)
    # ZOH first order: T = -Ts/ln(a) up to the half-sample lag of sampling
    assert sm.T[0] + sm.L[0] == pytest.approx(-1 / np.log(a), rel=0.1)


def _step_models_full_horizon(ss, transform=None):
    """`step_models` as computed before the early stop: every sample of the horizon."""
    from jthermo.control import rules

    A, B, C, D = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C, ss.D))
    if transform is not None:
        B, D = B @ transform, D @ transform
    S = rules.step_responses(A, B, C, D, rules.step_horizon(ss))
    G0 = C @ np.linalg.solve(np.eye(A.shape[0]) - A, B) + D
    return [np.array(v) for v in zip(*(fit_step_model(S[:, i, i], ss.ts, G0[i, i])
                                       for i in range(S.shape[1])))]


@pytest.mark.parametrize("n, seed, coupled", [(1, 0, False), (3, 0, True), (5, 2, False),
                                              (5, 2, True)])
def test_step_models_early_stop_is_exact(n, seed, coupled):
    """`step_models` stops the step responses once every diagonal one crossed 63.2 % of its
    gain: K, L, T equal, bit for bit, to those from the whole horizon."""
    ss = bed_plant(n, seed)
    W = (np.eye(n) + 0.1 * np.random.default_rng(seed).standard_normal((n, n))
         if coupled else None)
    got = step_models(ss, transform=W)
    for a, b in zip((got.K, got.L, got.T), _step_models_full_horizon(ss, W)):
        np.testing.assert_array_equal(a, b)


def test_rga_and_decision():
    assert np.allclose(rga(np.eye(3)), np.eye(3))
    G = np.array([[1.0, 0.9], [0.9, 1.0]])
    lam = rga(G)
    assert np.allclose(lam.sum(0), 1) and np.allclose(lam.sum(1), 1)
    assert lam[0, 0] == pytest.approx(1 / (1 - 0.81))
    weak = StateSpace(0.9 * np.eye(2), 0.1 * np.eye(2) + 0.001, np.eye(2))
    strong = StateSpace(0.9 * np.eye(2), 0.1 * G, np.eye(2))
    assert not needs_decoupling(weak) and needs_decoupling(strong)
    with pytest.raises(ControlError, match="singular"):
        rga(np.ones((2, 2)))


@pytest.mark.parametrize("kind", ["CB", "G0"])
def test_decoupling_diagonalises(kind):
    plant = bed_plant(3)
    W1 = decoupling_matrix(plant, kind)
    M = np.asarray(plant.C @ plant.B) if kind == "CB" else np.asarray(plant.dcgain())
    assert np.allclose(M @ W1, np.eye(3), atol=1e-10)
    # the loop gain G(0) W1 Fdiag(0) at steady state is diagonal for G0 decoupling
    if kind == "G0":
        L = np.asarray(plant.dcgain()) @ W1 @ np.diag([2.0, 3.0, 4.0])
        assert np.allclose(L - np.diag(np.diag(L)), 0, atol=1e-10)
    with pytest.raises(ControlError, match="kind must be"):
        decoupling_matrix(plant, "bad")


def test_design_errors():
    plant = bed_plant(2)
    with pytest.raises(ControlError, match="unknown controller family"):
        design("nope", plant)
    with pytest.raises(ControlError, match="unstable"):
        design("pi_lambda", StateSpace(1.01 * np.eye(2), np.eye(2), np.eye(2)))
    with pytest.raises(ControlError, match="positive gain"):
        design("pi_lambda", StateSpace(0.9 * np.eye(1), -np.eye(1), np.eye(1)))
    with pytest.raises(ControlError, match="lambda must be positive"):
        design("pi_lambda", plant, lam=-1.0)
    with pytest.raises(ControlError, match="kind must be"):
        design("feedforward", plant, kind="nope")
    with pytest.raises(ControlError, match="design: expected a jthermo model"):
        design("imc", np.eye(2))


def test_zeros_check():
    assert zeros_stable(bed_plant(3))
    # y = C x with a non-minimum-phase zero: two first-order paths of opposite sign
    A = np.diag([0.5, 0.95])
    B = np.array([[1.0], [0.2]])
    C = np.array([[1.0, -1.0]])   # zero at z = ... outside the unit circle
    ss = StateSpace(A, B, C)
    num_zero = (A[0, 0] * B[1, 0] * C[0, 1] + A[1, 1] * B[0, 0] * C[0, 0]) / (B[0, 0] + B[1, 0] * C[0, 1])
    assert zeros_stable(ss) == (abs(num_zero) < 0.98)


def test_every_family_follows_its_design_rule():
    """Each family's controller has its structure, and the gains its rule gives on the model."""
    plant = bed_plant(3)
    u0, y0 = np.asarray(plant.u0), np.asarray(plant.y0)
    W1 = decoupling_matrix(plant, "CB")
    sm = step_models(plant)
    lam_pi = lambda_gains(sm)
    lam_dec = lambda_gains(step_models(plant, transform=W1))
    G0 = np.asarray(plant.dcgain())
    c = {fam: design(fam, plant) for fam in FAMILIES}

    def close(x, want):
        np.testing.assert_allclose(np.asarray(x), want, rtol=1e-9, atol=1e-12)

    assert type(c["pi_untuned"]) is DiagonalPI
    close(c["pi_untuned"].kp, np.full(3, UNTUNED_KP))
    close(c["pi_untuned"].ti, np.full(3, UNTUNED_TI))
    assert type(c["pi_lambda"]) is DiagonalPI
    close(c["pi_lambda"].kp, lam_pi[0])
    close(c["pi_lambda"].ti, lam_pi[1])
    for fam in ("pi_untuned", "pi_lambda"):
        close(c[fam].u0, u0)
    dec = c["pi_decoupled"]
    assert type(dec) is DecoupledPI
    close(dec.W1, W1)
    close(dec.kp, lam_dec[0])
    close(dec.ti, lam_dec[1])
    close(dec.u_bias, u0)
    ff = c["feedforward"]
    assert type(ff) is FeedForward and ff.kind == "neutral"
    close(np.asarray(ff.G0inv) @ G0, np.eye(3))
    close(ff.kp, lam_pi[0])
    close(ff.T, 0.5 * sm.T)
    imc = c["imc"]
    assert type(imc) is IMC and imc.inverse == zeros_stable(plant)
    close(imc.lam, sm.T / 3.0)
    close(np.asarray(imc.CBinv) @ np.asarray(plant.C @ plant.B), np.eye(3))
    lqg = c["lqg"]
    assert type(lqg) is LQG
    close(lqg.q1, np.ones(3))
    close(lqg.qi, np.full(3, 0.01))
    close(lqg.b0, np.zeros(3))
    for ctrl in (ff, imc, lqg):
        close(ctrl.u_op, u0)
        close(ctrl.y_op, y0)
    gp = c["gated_pi"]
    assert type(gp) is Gated and float(gp.band) == 3.0
    assert eqx.tree_equal(gp.inner, c["pi_lambda"])


def test_design_point_moves_along_equilibria():
    """Setpoint and measured-signal moves keep the model: the new point is an equilibrium of
    the original model (closed form), and the controllers are biased there."""
    import jax.numpy as jnp

    from jthermo.control.design import design_point
    from jthermo.models import BedModel

    bed = BedModel.from_physical([1000.0, 1200.0], [2.0, 2.5], [[150.0, 30.0], [20.0, 140.0]],
                                 surroundings=145.0)                 # measured surroundings
    ss = bed.to_statespace()
    A, B, Bw, C = (np.asarray(m) for m in (ss.A, ss.B, ss.Bw, ss.C))
    inv = np.linalg.inv(np.eye(2) - A)
    # nominal point: rest (u = 0) at the nominal surroundings, i.e. y* = 145 °C, not 0 °C
    at = design_point(bed)
    np.testing.assert_allclose(np.asarray(at.y0), [145.0, 145.0], atol=1e-9)
    np.testing.assert_allclose(np.asarray(at.w0), [145.0])
    # at a set point: the input that holds the model there, checked in closed form
    at = design_point(bed, setpoint=174.0)
    u1 = np.asarray(at.u0)
    np.testing.assert_allclose(C @ inv @ (B @ u1 + Bw[:, 0] * 145.0), [174.0, 174.0], atol=1e-9)
    np.testing.assert_allclose(np.asarray(at.y0), 174.0)
    pi = design("pi", bed, setpoint=174.0)                           # alias of pi_lambda
    np.testing.assert_allclose(np.asarray(pi.u0), u1, atol=1e-12)
    # a fitted bed is designed at its data's mean input and surroundings
    fitted = eqx.tree_at(lambda m: m.u_nominal, bed, jnp.asarray([0.4, 0.6]))
    lqg = design("lqg", fitted)
    np.testing.assert_allclose(np.asarray(lqg.u_op), [0.4, 0.6])
    np.testing.assert_allclose(np.asarray(lqg.y_op),
                               C @ inv @ (B @ [0.4, 0.6] + Bw[:, 0] * 145.0), atol=1e-9)


def test_family_aliases():
    from jthermo.control.design import ALIASES, canonical_family

    assert canonical_family("PI") == "pi_lambda" and canonical_family("lqg") == "lqg"
    assert canonical_family("PID") == "pid_relay"
    assert all(v in FAMILIES for v in ALIASES.values())
    with pytest.raises(ControlError, match="unknown controller family"):
        design("pid_autotune", bed_plant())
