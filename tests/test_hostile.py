"""Hostile input: malformed, truncated or garbage files at `fit`, `diagnose` and `simulate`.

The contract (DESIGN.md): one line on stderr, exit status 2, no traceback, no output file.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jthermo import cli

pytestmark = pytest.mark.filterwarnings("ignore")

HEADER = ["t", "u_1", "u_2", "y_1", "y_2"]


def _rows(T, rng):
    return [[float(k), *np.round(rng.random(2), 3), *np.round(20 + rng.random(2), 3)] for k in range(T)]


def _text(header, rows):
    return "\n".join([",".join(header)] + [",".join(str(v) for v in r) for r in rows]) + "\n"


@st.composite
def malformed(draw):
    """(name of the defect, file bytes or None for a missing path)."""
    kind = draw(st.sampled_from([
        "wrong_header", "unknown_column", "text_in_number", "nan", "inf", "duplicate_time",
        "decreasing_time", "huge", "empty", "header_only", "binary", "non_utf8", "ragged",
        "too_short", "missing", "missing_prefix", "big_gap"]))
    seed = draw(st.integers(0, 2**16))
    rng = np.random.default_rng(seed)
    T = draw(st.integers(20, 60))
    rows = _rows(T, rng)
    r = draw(st.integers(1, T - 2))
    c = draw(st.integers(1, 4))
    header = list(HEADER)
    if kind == "wrong_header":
        header[0] = draw(st.sampled_from(["time", "T", "tt", "x"]))
    elif kind == "unknown_column":
        header[c] = draw(st.sampled_from(["temp", "power", "z_1", "U_1"]))
    elif kind == "missing_prefix":
        header[c] = draw(st.sampled_from(["u_", "y_"]))
    elif kind == "text_in_number":
        rows[r][c] = draw(st.text(st.characters(whitelist_categories=("L",)), min_size=1, max_size=6))
    elif kind == "nan":
        rows[r][c] = draw(st.sampled_from(["nan", "NaN", "-nan"]))
    elif kind == "inf":
        rows[r][c] = draw(st.sampled_from(["inf", "-inf", "Infinity", "1e999"]))
    elif kind == "duplicate_time":
        rows[r][0] = rows[r - 1][0]
    elif kind == "decreasing_time":
        rows[r][0] = rows[r - 1][0] - draw(st.floats(0.5, 100))
    elif kind == "big_gap":
        for row in rows[r:]:
            row[0] += draw(st.integers(5, 1000))
    elif kind == "huge":
        rows[r][c] = draw(st.sampled_from(["1e300", "-5e12", "3e10"]))
    elif kind == "ragged":
        rows[r] = rows[r][: draw(st.integers(1, 4))]
    elif kind == "too_short":
        rows = rows[: draw(st.integers(1, 9))]
    if kind == "missing":
        return kind, None
    if kind == "empty":
        return kind, draw(st.sampled_from([b"", b"\n\n", b" \n"]))
    if kind == "header_only":
        return kind, (",".join(header) + "\n").encode()
    if kind == "binary":
        return kind, b"\x00" + draw(st.binary(min_size=1, max_size=200))
    if kind == "non_utf8":
        return kind, b"t,u_1,y_1\n0,\xff\xfe,1\n"
    return kind, _text(header, rows).encode()


def _good_csv(path):
    rng = np.random.default_rng(0)
    path.write_text(_text(HEADER, _rows(40, rng)))
    return path


def _write(tmp, content, name):
    p = tmp / name
    if content is not None:
        p.write_bytes(content)
    elif p.exists():
        p.unlink()
    return p


def _assert_contract(argv, capsys, outputs):
    rc = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert rc == 2, (argv, err)
    assert len(lines) == 1 and lines[0].startswith("jthermo: error:"), err
    assert "Traceback" not in err + out
    for p in outputs:
        assert not p.exists(), p


_SETTINGS = settings(max_examples=30, deadline=None, derandomize=True,
                     suppress_health_check=[HealthCheck.function_scoped_fixture])


@_SETTINGS
@given(bad=malformed(), as_validation=st.booleans())
def test_fit_rejects_malformed(bad, as_validation, tmp_path, capsys):
    _, content = bad
    f = _write(tmp_path, content, "bad.csv")
    good = _good_csv(tmp_path / "good.csv")
    js, out = tmp_path / "r.json", tmp_path / "m.jtm"
    est, val = (good, f) if as_validation else (f, good)
    _assert_contract(["fit", est, "--model", "arx", "--orders", "1,1,1", "--validation", val,
                      "--json", js, "--out", out, "--quiet"], capsys, [js, out])


@_SETTINGS
@given(bad=malformed(), as_validation=st.booleans())
def test_diagnose_rejects_malformed(bad, as_validation, tmp_path, capsys):
    _, content = bad
    f = _write(tmp_path, content, "bad.csv")
    good = _good_csv(tmp_path / "good.csv")
    js, rep = tmp_path / "d.json", tmp_path / "report"
    est, val = (good, f) if as_validation else (f, good)
    _assert_contract(["diagnose", est, "--validation", val, "--json", js, "--report", rep, "--quiet"],
                     capsys, [js, rep])


@_SETTINGS
@given(bad=malformed(), which=st.sampled_from(["--controller-file", "--plant"]))
def test_simulate_rejects_malformed_files(bad, which, tmp_path, capsys):
    _, content = bad
    f = _write(tmp_path, content, "bad.jtm")
    js = tmp_path / "s.json"
    argv = ["simulate", "--scenario", "tracking", "--rollouts", "2", "--duration", "60", "--json", js, "--quiet"]
    argv += [which, f] if which == "--controller-file" else ["--controller", "pi_lambda", "--plant", f]
    _assert_contract(argv, capsys, [js])


def test_truncated_model_file(tmp_path, capsys):
    from jthermo import io
    from jthermo.models._base import StateSpace

    m = io.save(StateSpace(0.5 * np.eye(2), np.eye(2), np.eye(2)), tmp_path / "m.jtm")
    raw = m.read_bytes()
    for n in (0, 10, len(raw) // 2, len(raw) - 5):
        m.write_bytes(raw[:n])
        _assert_contract(["validate", m, _good_csv(tmp_path / "g.csv"), "--json", tmp_path / "v.json"],
                         capsys, [tmp_path / "v.json"])
        _assert_contract(["simulate", "--scenario", "tracking", "--controller", "pi_lambda", "--plant", m],
                         capsys, [])
