import numpy as np
import pytest
from matplotlib.figure import Figure

from jthermo import StateSpace
from jthermo import plots as P
from jthermo import validate as V
from jthermo.data import from_arrays
from jthermo.errors import DataError
from jthermo.inputs import prbs

T = 200


@pytest.fixture(scope="module")
def setup():
    A = np.array([[0.9, 0.05], [0.0, 0.8]])
    B = np.array([[0.1, 0.02], [0.03, 0.2]])
    m = StateSpace(A, B, np.eye(2), ts=1.0, u0=[0.5, 0.5], y0=[20.0, 21.0])
    m2 = StateSpace(A * 0.98, B, np.eye(2), ts=1.0, u0=[0.5, 0.5], y0=[20.0, 21.0])
    u = np.asarray(prbs(0, T, 2))
    y = np.asarray(m.simulate(u)) + 0.02 * np.random.default_rng(0).standard_normal((T, 2))
    return m, m2, from_arrays(u, y)


def _png_ok(fig, path):
    assert isinstance(fig, Figure)
    assert path.exists() and path.stat().st_size > 1000
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in path.parent.iterdir() if p.name.endswith(".tmp")]


def test_identification_plots(setup, tmp_path):
    m, m2, data = setup
    r1, r2 = V.compare(m, data, x0="zero"), V.compare(m2, data, x0="zero")
    fig = P.plot_compare(data, {"true": r1["yhat"], "other": r2["yhat"]},
                         {"true": r1["fit_percent"], "other": r2["fit_percent"]},
                         path=tmp_path / "compare.png")
    _png_ok(fig, tmp_path / "compare.png")
    assert any(f"{r1['fit_percent'][0]:.1f} %" in t.get_text()
               for t in fig.axes[0].get_legend().get_texts())
    res = V.residual_tests(m, data, max_lag=10, x0="zero")
    _png_ok(P.plot_residual_tests(res, path=tmp_path / "resid.png"), tmp_path / "resid.png")
    spec = V.spectral_estimate(data)
    _png_ok(P.plot_bode({"true": m, "other": m2}, spec, path=tmp_path / "bode.png"),
            tmp_path / "bode.png")
    _png_ok(P.plot_step([m, m2], 40, path=tmp_path / "sub" / "step.png"), tmp_path / "sub" / "step.png")
    _png_ok(P.plot_pzmap({"true": m}, path=tmp_path / "pz.png"), tmp_path / "pz.png")


def test_control_and_diagnosis_plots(tmp_path):
    t = np.arange(100.0)
    y = 180 + np.random.default_rng(1).standard_normal((100, 4)) * 0.3
    u = np.clip(0.5 + 0.1 * np.random.default_rng(2).standard_normal((100, 4)), 0, 1)
    _png_ok(P.plot_closed_loop(t, y, u, 180.0, window=1.0, path=tmp_path / "cl.png"), tmp_path / "cl.png")
    P.plot_closed_loop(t, y, u, np.full(100, 180.0))           # a set-point trajectory
    _png_ok(P.plot_tuning_curve(np.exp(-t / 30) + 0.1, path=tmp_path / "tune.png"), tmp_path / "tune.png")
    P.plot_tuning_curve({"a": [3.0, 2.0, 1.0], "b": [3.0, 1.0, -0.5]})
    _png_ok(P.plot_bed_heatmap(np.linspace(175, 185, 6), 2, 3, path=tmp_path / "bed.png"),
            tmp_path / "bed.png")
    P.plot_bed_heatmap(np.arange(5.0), 2, 3)                   # a partly filled grid
    _png_ok(P.plot_residuals(t, y - 180, 0.5 * (y - 180), path=tmp_path / "res.png"), tmp_path / "res.png")


def test_plot_errors():
    with pytest.raises(DataError, match="do not fit"):
        P.plot_bed_heatmap(np.arange(7.0), 2, 3)
    with pytest.raises(DataError, match="lengths differ"):
        P.plot_closed_loop(np.arange(10.0), np.zeros((9, 2)), np.zeros((10, 2)), 0.0)
    with pytest.raises(DataError, match="set point"):
        P.plot_closed_loop(np.arange(10.0), np.zeros((10, 2)), np.zeros((10, 2)), np.zeros(3))
    with pytest.raises(DataError, match="empty"):
        P.plot_tuning_curve([])
    with pytest.raises(DataError, match="shapes differ"):
        P.plot_residuals(np.arange(10.0), np.zeros((10, 2)), np.zeros((10, 1)))


def test_no_pyplot_import():
    import subprocess
    import sys
    code = "import sys, jthermo.plots; print('matplotlib.pyplot' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_closed_loop_draws_each_zones_set_point():
    """Two zones at 55 and 45 °C: two set-point lines at their own levels, not one at 50."""
    t = np.arange(50.0)
    y = np.column_stack([np.full(50, 54.0), np.full(50, 46.0)])
    fig = P.plot_closed_loop(t, y, np.full((50, 2), 0.5), np.array([55.0, 45.0]))
    dashed = [ln for ln in fig.axes[0].get_lines() if ln.get_linestyle() == "--"]
    assert sorted(float(ln.get_ydata()[0]) for ln in dashed) == [45.0, 55.0]
    assert [ln.get_color() for ln in dashed] == [ln.get_color() for ln in fig.axes[0].get_lines()
                                                 if ln.get_linestyle() == "-"]
