"""The data layer: every validation error (with its message), re-gridding, pre-processing, I/O."""

from pathlib import Path

import numpy as np
import pytest

from jthermo import data
from jthermo.data import IOData
from jthermo.errors import DataError

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"


def _cols(T=50, ts=1.0, **extra):
    rng = np.random.default_rng(0)
    cols = {"t": ts * np.arange(T), "u_h1": rng.random(T), "y_z1": 20 + rng.random(T)}
    cols.update(extra)
    return cols


def _csv(tmp_path, text, name="d.csv"):
    p = tmp_path / name
    p.write_text(text) if isinstance(text, str) else p.write_bytes(text)
    return p


def _good_text(T=20):
    rows = ["t,u_h1,y_z1,w_amb"] + [f"{k},{0.1 * (k % 3)},{20 + 0.01 * k},{25}" for k in range(T)]
    return "\n".join(rows) + "\n"


# ---------------------------------------------------------------- IOData and from_arrays


def test_iodata_structure_errors():
    u, y, w = np.zeros((20, 1)), np.zeros((20, 1)), np.zeros((20, 0))
    ok = dict(u=u, y=y, w=w, ts=1.0, input_names=("a",), output_names=("b",), signal_names=())
    IOData(**ok)
    with pytest.raises(DataError, match="`u` must be a 2-D"):
        IOData(**{**ok, "u": np.zeros(20)})
    with pytest.raises(DataError, match="unequal lengths u=20, y=19"):
        IOData(**{**ok, "y": np.zeros((19, 1))})
    with pytest.raises(DataError, match="number of names does not match"):
        IOData(**{**ok, "input_names": ("a", "b")})
    with pytest.raises(DataError, match="sample time must be positive"):
        IOData(**{**ok, "ts": 0.0})
    with pytest.raises(DataError, match="sample time must be positive"):
        IOData(**{**ok, "ts": float("nan")})


def test_from_arrays_ok_and_names():
    d = data.from_arrays(np.ones(30) * np.arange(30) % 2, np.arange(30.0), ts=2.0)
    assert d.u.shape == (30, 1) and d.w.shape == (30, 0) and d.ts == 2.0
    assert d.input_names == ("1",) and d.output_names == ("1",)
    np.testing.assert_array_equal(d.t, 2.0 * np.arange(30))
    assert len(d) == 30 and d.n_inputs == 1 and d.n_outputs == 1


def test_from_arrays_errors():
    u, y = np.zeros((20, 2)), np.zeros((20, 2))
    with pytest.raises(DataError, match="`u` is not numeric"):
        data.from_arrays([["a", "b"]] * 20, y)
    with pytest.raises(DataError, match="must be 1-D or 2-D, got 3-D"):
        data.from_arrays(np.zeros((20, 2, 1)), y)
    with pytest.raises(DataError, match="both inputs `u` and outputs `y` are required"):
        data.from_arrays(None, y)
    with pytest.raises(DataError, match="unequal lengths"):
        data.from_arrays(u, np.zeros((19, 2)))
    with pytest.raises(DataError, match="2 columns in `u` but 1 names"):
        data.from_arrays(u, y, input_names=["a"])
    bad = y.copy()
    bad[5, 1] = np.nan
    with pytest.raises(DataError, match="column `y_2` has NaN at row 6"):
        data.from_arrays(u, bad)
    bad[5, 1] = -np.inf
    with pytest.raises(DataError, match="column `y_2` has inf at row 6"):
        data.from_arrays(u, bad)
    bad[5, 1] = 1e12
    with pytest.raises(DataError, match="column `y_2` has an implausible value 1e\\+12 at row 6"):
        data.from_arrays(u, bad)
    with pytest.raises(DataError, match="only 5 samples; at least 10"):
        data.from_arrays(u[:5], y[:5])


# ---------------------------------------------------------------- from_columns


def test_from_columns_errors():
    c = _cols()
    with pytest.raises(DataError, match="missing column `t`"):
        data.from_columns({k: v for k, v in c.items() if k != "t"})
    with pytest.raises(DataError, match="unknown column `temp`"):
        data.from_columns({**c, "temp": c["t"]})
    with pytest.raises(DataError, match=r"no input column \(u_<name>\)"):
        data.from_columns({k: v for k, v in c.items() if k != "u_h1"})
    with pytest.raises(DataError, match=r"no output column \(y_<name>\)"):
        data.from_columns({k: v for k, v in c.items() if k != "y_z1"})
    with pytest.raises(DataError, match="column `w_` has no name after its prefix"):
        data.from_columns({**c, "w_": c["t"]})
    with pytest.raises(DataError, match="column `u_h1` is not numeric"):
        data.from_columns({**c, "u_h1": np.array(["x"] * 50)})
    with pytest.raises(DataError, match="unequal lengths"):
        data.from_columns({**c, "u_h1": c["u_h1"][:-1]})
    with pytest.raises(DataError, match="must be one-dimensional"):
        data.from_columns({**c, "u_h1": c["u_h1"][:, None]})
    with pytest.raises(DataError, match="only 5 samples"):
        data.from_columns({k: v[:5] for k, v in c.items()})
    with pytest.raises(DataError, match="column `t` has NaN at row 3"):
        data.from_columns({**c, "t": np.where(np.arange(50) == 2, np.nan, c["t"])})


def test_time_axis_errors():
    c = _cols()
    t = c["t"].copy()
    t[10] = t[9]
    with pytest.raises(DataError, match="time `t` is duplicated at row 11"):
        data.from_columns({**c, "t": t})
    t = c["t"].copy()
    t[10] = 3.0
    with pytest.raises(DataError, match="time `t` is decreasing at row 11"):
        data.from_columns({**c, "t": t})
    t = c["t"].copy()
    t[20:] += 0.5           # three off-grid steps in a row (1.5, 1.4, 1.3 Ts): an irregular clock
    t[21:] += 0.4
    t[22:] += 0.3
    with pytest.raises(DataError, match="time `t` is not uniform: step 1.5 s at row 21"):
        data.from_columns({**c, "t": t})
    t = c["t"].copy()
    t[10] -= 0.6            # a step under half a sample that no displaced stamp explains
    t[11:] -= 0.6
    with pytest.raises(DataError, match="step 0.4 s at row 11"):
        data.from_columns({**c, "t": t})
    t = c["t"].copy()
    t[20:] += 4.0           # a gap of 5 samples
    with pytest.raises(DataError, match="gap over 3 samples"):
        data.from_columns({**c, "t": t})


def test_epoch_time_stamps_accepted():
    c = _cols()
    d = data.from_columns({**c, "t": 1.7e9 + c["t"]})
    assert d.t0 == 1.7e9 and d.ts == 1.0


def test_regrid_jitter_and_dropped_sample():
    c = _cols(T=60)
    rng = np.random.default_rng(3)
    t = c["t"] + rng.uniform(-0.05, 0.05, 60)
    d = data.from_columns({**c, "t": t})
    assert d.notes and "re-gridded" in d.notes[0] and "dropped" not in d.notes[0]
    np.testing.assert_allclose(np.diff(d.t), d.ts)
    keep = np.ones(60, bool)
    keep[30] = False        # one dropped sample
    d = data.from_columns({k: v[keep] for k, v in c.items()})
    assert "1 dropped sample(s) filled" in d.notes[0] and d.n_samples == 60
    # the filled sample is the linear interpolation of its neighbours
    np.testing.assert_allclose(d.y[30, 0], 0.5 * (c["y_z1"][29] + c["y_z1"][31]))
    np.testing.assert_allclose(d.y[31, 0], c["y_z1"][31])
    d = data.from_columns({k: v for k, v in c.items()}, jitter_tolerance=0.2)
    assert d.notes == ()


# ---------------------------------------------------------------- CSV parsing and files


def test_csv_round_trip(tmp_path):
    p = _csv(tmp_path, _good_text())
    d = data.load(p)
    assert d.input_names == ("h1",) and d.output_names == ("z1",) and d.signal_names == ("amb",)
    data.save_csv(d, tmp_path / "out.csv")
    d2 = data.load(tmp_path / "out.csv")
    np.testing.assert_allclose(d2.y, d.y)
    np.testing.assert_allclose(d2.w, d.w)
    assert d2.ts == d.ts


def test_csv_errors(tmp_path):
    cases = {
        "binary content": b"t,u_a,y_b\n\x00\x01\x02\n",
        "empty file": "",
        "column `u_a` appears twice": "t,u_a,u_a,y_b\n0,1,1,1\n",
        "empty column name": "t,,y_b\n0,1,1\n",
        "header has no `t` column": "time,u_a,y_b\n0,1,1\n",
        "header only, no data rows": "t,u_a,y_b\n",
        "row 3 has 2 fields, the header has 3": "t,u_a,y_b\n0,1,1\n1,1\n",
        "column `y_b` has non-numeric value 'hot' at row 2": "t,u_a,y_b\n0,1,hot\n",
        "column `y_b` has NaN at row 2": "t,u_a,y_b\n0,1,nan\n" + "".join(f"{k},1,1\n" for k in range(1, 12)),
        "column `u_a` has inf at row 3": "t,u_a,y_b\n0,1,1\n1,inf,1\n" + "".join(f"{k},1,1\n" for k in range(2, 12)),
        "unknown column `z`": "t,u_a,y_b,z\n" + "".join(f"{k},1,1,1\n" for k in range(12)),
    }
    for i, (msg, text) in enumerate(cases.items()):
        p = _csv(tmp_path, text, f"c{i}.csv")
        with pytest.raises(DataError, match=msg.replace("(", r"\(")):
            data.load(p)
    with pytest.raises(DataError, match="not a text CSV file \\(binary or non-UTF-8"):
        data.load(_csv(tmp_path, b"t,u_a,y_b\n\xff\xfe\xfa\n", "bin.csv"))
    with pytest.raises(DataError, match="no such file"):
        data.load(tmp_path / "missing.csv")
    with pytest.raises(DataError, match="is a directory"):
        data.load_csv(tmp_path)


def test_dataframe_parquet_npz(tmp_path):
    pd = pytest.importorskip("pandas")
    c = _cols()
    df = pd.DataFrame(c)
    d = data.from_dataframe(df)
    np.testing.assert_array_equal(d.y[:, 0], c["y_z1"])
    with pytest.raises(DataError, match="column `u_h1` is not numeric"):
        data.from_dataframe(df.assign(u_h1=["x"] * 50))
    df.to_parquet(tmp_path / "d.parquet")
    np.testing.assert_array_equal(data.load(tmp_path / "d.parquet").u, d.u)
    with pytest.raises(DataError, match="no such file"):
        data.load(tmp_path / "none.parquet")
    (tmp_path / "bad.parquet").write_bytes(b"garbage")
    with pytest.raises(DataError, match="not a readable Parquet file"):
        data.load(tmp_path / "bad.parquet")
    np.savez(tmp_path / "d.npz", **c)
    np.testing.assert_array_equal(data.load(tmp_path / "d.npz").y, d.y)
    with pytest.raises(DataError, match="no such file"):
        data.load(tmp_path / "none.npz")
    (tmp_path / "bad.npz").write_bytes(b"garbage")
    with pytest.raises(DataError, match="not a readable .npz file"):
        data.load(tmp_path / "bad.npz")
    np.savez(tmp_path / "s.npz", **{**c, "u_h1": np.array(["a"] * 50)})
    with pytest.raises(DataError, match="column `u_h1` is not numeric"):
        data.load(tmp_path / "s.npz")


# ---------------------------------------------------------------- checks and pre-processing


def test_checks():
    d = data.from_columns(_cols())
    data.require_excitation(d)
    with pytest.raises(DataError, match="input `u_h1` is constant \\(0.5\\)"):
        data.require_excitation(d.replace(u=np.full_like(d.u, 0.5)))
    data.require_output_variation(d)
    name = d.output_names[0]
    flat = d.replace(y=np.column_stack([np.full(d.n_samples, 25.0), *np.asarray(d.y)[:, 1:].T]))
    with pytest.raises(DataError, match=f"output `y_{name}` is constant \\(25\\): nothing to identify"):
        data.require_output_variation(flat)
    data.require_samples(d, 10)
    with pytest.raises(DataError, match="50 samples are too few for a ARX with 60 parameters"):
        data.require_samples(d, 60, "ARX")


def test_idle_and_kept_inputs():
    """A logged heater never switched on is idle; keeping the other inputs drops it, and a
    record where a left-out input varies is refused."""
    rng = np.random.default_rng(1)
    d = data.from_columns(_cols(u_h2=np.zeros(50), u_h3=rng.random(50)))
    assert data.idle_inputs(d) == [d.input_names.index("h2")]
    kept = data.keep_inputs(d, ["h3", "h1"])
    assert kept.input_names == ("h3", "h1")
    np.testing.assert_array_equal(kept.u, np.asarray(d.u)[:, [2, 0]])
    with pytest.raises(DataError, match="input `u_h1` varies in this record, but the model has no such input"):
        data.keep_inputs(d, ["h3"], "validation data")
    with pytest.raises(DataError, match="no input `u_h9`"):
        data.keep_inputs(d, ["h9"])


def test_kept_outputs():
    rng = np.random.default_rng(2)
    d = data.from_columns(_cols(y_z2=30 + rng.random(50)))
    one = data.keep_outputs(d, ["y_z2"])
    assert one.output_names == ("z2",) and one.n_outputs == 1
    np.testing.assert_array_equal(one.y[:, 0], np.asarray(d.y)[:, 1])
    with pytest.raises(DataError, match="no output `y_z7` \\(its outputs: y_z1, y_z2\\)"):
        data.keep_outputs(d, ["z7"], "--outputs")
    with pytest.raises(DataError, match="distinct"):
        data.keep_outputs(d, ["z1", "z1"])


def test_preprocessing():
    rng = np.random.default_rng(1)
    T = 400
    k = np.arange(T, dtype=float)
    d = data.from_arrays(rng.random(T), 5 + 0.01 * k + rng.standard_normal(T), ts=1.0)
    c = data.crop(d, 100, 300)
    assert c.n_samples == 200 and c.t0 == 100.0 and "cropped" in c.notes[-1]
    c = data.crop(d, 10.0, 20.0, unit="s")
    assert c.n_samples == 10
    with pytest.raises(DataError, match="only 5 samples left"):
        data.crop(d, 0, 5)
    m = data.detrend(d)
    np.testing.assert_allclose(m.y.mean(0), 0, atol=1e-12)
    lin = data.detrend(d, "linear")
    X = np.column_stack([np.ones(T), k])
    np.testing.assert_allclose(np.linalg.lstsq(X, lin.y, rcond=None)[0], 0, atol=1e-10)
    assert data.detrend(d, inputs=False).u is d.u
    with pytest.raises(DataError, match="kind must be 'mean' or 'linear'"):
        data.detrend(d, "quadratic")
    h = data.highpass(d, 0.01)
    assert abs(h.y.mean()) < 0.2 and "high-pass" in h.notes[-1]
    with pytest.raises(DataError, match=r"cutoff 0.6 Hz must lie in \(0, 0.5\) Hz"):
        data.highpass(d, 0.6)
    with pytest.raises(DataError, match="too few samples for zero-phase filtering"):
        data.highpass(data.crop(d, 0, 10), 0.1, order=4)
    est, val = data.split(d, 0.7)
    assert (est.n_samples, val.n_samples) == (280, 120) and val.t0 == 280.0
    with pytest.raises(DataError, match=r"fraction must lie in \(0, 1\)"):
        data.split(d, 1.0)


def test_atomic_write_text_leaves_no_partial(tmp_path, monkeypatch):
    p = tmp_path / "r.json"
    data.atomic_write_text(p, "old")

    def boom(*a):
        raise KeyboardInterrupt

    monkeypatch.setattr(data.os, "replace", boom)
    with pytest.raises(KeyboardInterrupt):
        data.atomic_write_text(p, "new")
    assert p.read_text() == "old" and len(list(tmp_path.iterdir())) == 1


# ---------------------------------------------------------------- real TCLab recordings


def _real(rel):
    p = REAL / rel / "data.csv"
    if not p.exists():
        pytest.skip(f"real data {rel} absent")
    return p


def test_real_uniform_file_untouched():
    d = data.load(_real("tclab_cace2020/id_2heaters"))
    assert d.notes == () and d.ts == 1.0 and d.n_inputs == 2 and d.n_outputs == 2


def test_real_jitter_regridded():
    p = _real("tclab_apm_mimo_steps")
    d = data.load(p)
    assert "re-gridded onto a uniform Ts" in d.notes[0] and "dropped" not in d.notes[0]
    np.testing.assert_allclose(np.diff(d.t), d.ts, rtol=1e-9)
    assert abs(d.ts - 1.0) < 0.01
    raw = np.genfromtxt(p, delimiter=",", names=True)
    assert abs(d.n_samples - len(raw)) <= 1
    # interpolated values stay within the recorded range
    assert d.y[:, 0].min() >= raw["y_T1"].min() - 1e-9 and d.y[:, 0].max() <= raw["y_T1"].max() + 1e-9


def test_real_dropped_sample_filled():
    d = data.load(_real("tclab_kantor_cbe30338/step_q1_50_b"))
    assert "1 dropped sample(s) filled" in d.notes[0]
    np.testing.assert_allclose(np.diff(d.t), d.ts)


def test_late_sample_regridded():
    """One late sample (the logger's loop overran; the stamps after it follow on from it)."""
    c = _cols(T=60)
    t = c["t"].copy()
    t[20:] += 0.4           # one step of 1.4 Ts, the others on a shifted grid
    d = data.from_columns({**c, "t": t})
    assert "1 late sample(s) of 1.40 Ts" in d.notes[0] and "dropped" not in d.notes[0]
    np.testing.assert_allclose(np.diff(d.t), 1.0)
    # the grid point between the late sample's neighbours is their linear interpolation
    y = c["y_z1"]
    np.testing.assert_allclose(d.y[20, 0], y[19] + (y[20] - y[19]) / 1.4)
    np.testing.assert_allclose(d.y[:20, 0], y[:20])


def test_displaced_stamp_regridded():
    """One stamp written late, the others on the grid: the pair of steps around it sums to 2 Ts."""
    c = _cols(T=60)
    for shift, note in ((0.45, "between steps of 1.45 and 0.55 Ts"),
                        (0.7, "between steps of 1.70 and 0.30 Ts")):
        t = c["t"].copy()
        t[30] += shift
        d = data.from_columns({**c, "t": t})
        assert f"1 displaced stamp(s) {note}" in d.notes[0], d.notes
        assert d.n_samples == 60 and "late" not in d.notes[0]
        # samples on the grid are kept exactly; the displaced one is re-read off the line
        np.testing.assert_allclose(d.y[29, 0], c["y_z1"][29])
        np.testing.assert_allclose(d.y[31, 0], c["y_z1"][31])


def test_irregular_record_refused():
    """Late stamps are repairable only when isolated and few: an irregular clock is refused."""
    c = _cols(T=200)
    rng = np.random.default_rng(0)
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.55, 1.45, 199))])
    with pytest.raises(DataError, match="time `t` is not uniform"):
        data.from_columns({**c, "t": t})
    t = c["t"].copy()
    for k in range(10, 200, 20):    # 10 late samples in 200: more than 2 %
        t[k:] += 0.4
    with pytest.raises(DataError, match="step 1.4 s at row 11"):
        data.from_columns({**c, "t": t})
    t = c["t"].copy()
    t[30] += 0.45
    t[31] += 0.9                # two displaced stamps in a row: not one
    with pytest.raises(DataError, match="time `t` is not uniform"):
        data.from_columns({**c, "t": t})


def test_real_late_samples_regridded():
    d = data.load(_real("tclab_cace2020/mpc_arx_b"))
    assert "4 late sample(s) of 1.27-1.64 Ts" in d.notes[0]
    np.testing.assert_allclose(np.diff(d.t), d.ts, rtol=1e-9)
    assert d.n_samples == 602 and d.signal_names == ("T1_setpoint", "T2_setpoint")
