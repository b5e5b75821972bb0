"""Export to / import from python-control and scipy.signal: round trips and frequency responses."""

import numpy as np
import pytest
from scipy import signal

from jthermo import interop
from jthermo.errors import ConfigError, ModelError
from jthermo.models import StateSpace

control = pytest.importorskip("control")


def _model(nw=0):
    rng = np.random.default_rng(0)
    A = np.diag([0.95, 0.8, 0.5]) + 0.02 * rng.normal(size=(3, 3))
    return StateSpace(A, rng.normal(size=(3, 2)), rng.normal(size=(2, 3)), D=0.1 * rng.normal(size=(2, 2)),
                      ts=2.0, Bw=rng.normal(size=(3, nw)) if nw else None,
                      y0=[20.0, 21.0], u0=[0.1, 0.2], w0=[25.0] * nw if nw else None)


OMEGA = np.logspace(-3, np.log10(np.pi / 2.0), 25)   # up to Nyquist for ts = 2 s


def test_to_control_frequency_response():
    m = _model()
    sys = interop.to_control(m)
    assert sys.dt == 2.0 and sys.ninputs == 2 and sys.noutputs == 2
    G = np.asarray(m.frequency_response(OMEGA))                   # (nf, ny, nu)
    resp = sys.frequency_response(OMEGA)
    Gc = np.moveaxis(resp.magnitude * np.exp(1j * resp.phase), -1, 0)
    np.testing.assert_allclose(Gc, G, rtol=1e-10, atol=1e-12)


def test_to_control_simulation_matches():
    m = _model()
    u = np.random.default_rng(1).random((30, 2))
    y = np.asarray(m.simulate(u))
    # python-control works with (n, T): transpose, and deviations from the operating point
    resp = control.forced_response(interop.to_control(m), T=np.arange(30) * 2.0, U=(u - np.asarray(m.u0)).T)
    np.testing.assert_allclose(resp.outputs.T + np.asarray(m.y0), y, rtol=1e-10, atol=1e-10)


def test_measured_signals_become_inputs():
    m = _model(nw=1)
    sys = interop.to_control(m)
    assert sys.ninputs == 3 and sys.input_labels == ["u1", "u2", "w1"]
    assert interop.to_control(m, include_signals=False).ninputs == 2


def test_transfer_function_matches():
    m = _model()
    tf = interop.to_transfer_function(m)
    assert isinstance(tf, control.TransferFunction) and tf.dt == 2.0
    z = np.exp(1j * OMEGA[5] * 2.0)
    np.testing.assert_allclose(tf(z), np.asarray(m.frequency_response(OMEGA[5:6]))[0], rtol=1e-8)


def test_dlti_round_trip_and_dlsim():
    m = _model()
    d = interop.to_dlti(m)
    assert d.dt == 2.0
    u = np.random.default_rng(2).random((40, 2))
    _, y, _ = signal.dlsim(d, u - np.asarray(m.u0))
    np.testing.assert_allclose(y + np.asarray(m.y0), np.asarray(m.simulate(u)), rtol=1e-10, atol=1e-10)
    back = interop.from_dlti(d)
    np.testing.assert_allclose(np.asarray(back.frequency_response(OMEGA)),
                               np.asarray(m.frequency_response(OMEGA)), rtol=1e-10, atol=1e-12)
    assert back.ts == 2.0


def test_control_round_trip():
    m = _model()
    back = interop.from_control(interop.to_control(m))
    for name in "ABCD":
        np.testing.assert_array_equal(np.asarray(getattr(back, name)), np.asarray(getattr(m, name)))


def test_from_siso_transfer_functions():
    tf = control.tf([0.5], [1.0, -0.9], dt=1.0)
    ss = interop.from_control(tf)
    np.testing.assert_allclose(np.asarray(ss.dcgain()), [[5.0]], rtol=1e-12)
    d = signal.dlti([0.5], [1.0, -0.9], dt=1.0)
    np.testing.assert_allclose(np.asarray(interop.from_dlti(d).dcgain()), [[5.0]], rtol=1e-12)


def test_static_gain_import():
    ss = interop.from_control(control.ss([], [], [], [[2.0]], dt=1.0))
    np.testing.assert_allclose(np.asarray(ss.dcgain()), [[2.0]])


def test_import_errors():
    with pytest.raises(ConfigError, match="continuous-time"):
        interop.from_control(control.tf([1.0], [1.0, 1.0]))
    with pytest.raises(ConfigError, match="unspecified-sample-time"):
        interop.from_dlti(signal.dlti([1.0], [1.0, 0.5], dt=True))
    with pytest.raises(ConfigError, match="expected a scipy.signal.dlti"):
        interop.from_dlti(signal.lti([1.0], [1.0, 1.0]))
    with pytest.raises(ConfigError, match="expected a control.StateSpace"):
        interop.from_control("not a system")
    with pytest.raises(ConfigError, match="expected a scipy.signal.dlti"):
        interop.from_dlti(control.tf([1.0], [1.0, 0.5], dt=1.0))
    with pytest.raises(ModelError, match="NaN or inf"):
        interop.from_dlti(signal.dlti([[np.nan]], [[1.0]], [[1.0]], [[0.0]], dt=1.0))
    with pytest.raises(ModelError, match="expected a jthermo model"):
        interop.to_control("nope")
