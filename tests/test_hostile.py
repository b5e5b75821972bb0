"""Hostile input: malformed, truncated or garbage files at `fit`, `diagnose` and `simulate`.

The contract (DESIGN.md): one line on stderr, exit status 2, no traceback, no output file.
Each bad file is a valid record (`GOOD_ROWS` rows) with one defect, passed beside a valid one:
the one error line must name the bad file and its defect, so a rejection for another reason
(the good file, a too-short record, a crash turned into an error) fails the test.
"""

import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jthermo import cli

pytestmark = pytest.mark.filterwarnings("ignore")

HEADER = ["t", "u_1", "u_2", "y_1", "y_2"]
#: rows of the valid records: `diagnose` needs 10 * (3 + inputs) = 50 samples, `fit` 10
GOOD_ROWS = 80

#: defect -> what the one error line must say about it
DEFECT_MESSAGE = {
    "wrong_header": r"header has no `t` column",
    "unknown_column": r"unknown column `(temp|power|z_1|U_1)`",
    "missing_prefix": r"column `[uy]_` has no name after its prefix",
    "text_in_number": r"has non-numeric value",
    "nan": r"has NaN at row",
    "inf": r"has inf at row",
    "duplicate_time": r"time `t` is duplicated",
    "decreasing_time": r"time `t` is decreasing",
    "big_gap": r"time `t` is not uniform",
    "huge": r"has an implausible value",
    "empty": r"empty file",
    "header_only": r"header only, no data rows",
    "binary": r"not a text CSV file \(binary",
    "non_utf8": r"not a text CSV file \(binary or non-UTF-8",
    "ragged": r"row \d+ has [1-4] fields, the header has 5",
    "too_short": r"only [1-9] samples; at least 10 are needed",
    "missing": r"no such file",
}


def _rows(T, rng):
    return [[float(k), *np.round(rng.random(2), 3), *np.round(20 + rng.random(2), 3)] for k in range(T)]


def _is_number(text):
    try:
        float(text)
    except ValueError:
        return False
    return True


def _text(header, rows):
    return "\n".join([",".join(header)] + [",".join(str(v) for v in r) for r in rows]) + "\n"


@st.composite
def malformed(draw):
    """(name of the defect, file bytes or None for a missing path)."""
    kind = draw(st.sampled_from(sorted(DEFECT_MESSAGE)))
    seed = draw(st.integers(0, 2**16))
    rng = np.random.default_rng(seed)
    T = draw(st.integers(GOOD_ROWS - 20, GOOD_ROWS))  # long enough: the defect is the only fault
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
        rows[r][c] = draw(st.text(st.characters(whitelist_categories=("L",)), min_size=1,
                                  max_size=6).filter(lambda v: not _is_number(v)))  # not "nan", "inf"
    elif kind == "nan":
        rows[r][c] = draw(st.sampled_from(["nan", "NaN", "-nan"]))
    elif kind == "inf":
        rows[r][c] = draw(st.sampled_from(["inf", "-inf", "Infinity", "1e999"]))
    elif kind == "duplicate_time":
        rows[r][0] = rows[r - 1][0]
    elif kind == "decreasing_time":
        rows[r][0] = rows[r - 1][0] - draw(st.floats(0.5, 100))
    elif kind == "big_gap":  # one gap of more than MAX_GAP_SAMPLES = 3 sample times
        gap = draw(st.integers(5, 1000))
        for row in rows[r:]:
            row[0] += gap
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
    path.write_text(_text(HEADER, _rows(GOOD_ROWS, rng)))
    return path


def _write(tmp, content, name):
    p = tmp / name
    if content is not None:
        p.write_bytes(content)
    elif p.exists():
        p.unlink()
    return p


def _assert_contract(argv, capsys, outputs, says=None):
    """Exit 2 with one error line (matching the regex `says` when given), no traceback, no
    file in `outputs`."""
    rc = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert rc == 2, (argv, err)
    assert len(lines) == 1 and lines[0].startswith("jthermo: error:"), err
    assert "Traceback" not in err + out
    if says is not None:
        assert re.search(says, lines[0]), (says, lines[0])
    for p in outputs:
        assert not p.exists(), p


def _names_defect(kind, path):
    """The error line names the bad file, then says what is wrong with it."""
    return re.escape(str(path)) + r"\b.*" + DEFECT_MESSAGE[kind]


def test_the_good_file_is_accepted(tmp_path, capsys, monkeypatch):
    """The valid partner of every bad file passes `fit`, and `diagnose`'s data checks and its
    baseline fit (stopped there: the full diagnosis is tests/diagnose' business), so the
    rejections above come from the bad file alone."""
    import jthermo.diagnose as diag

    good = _good_csv(tmp_path / "good.csv")
    js = tmp_path / "r.json"
    rc = cli.main([str(a) for a in ["fit", good, "--model", "arx", "--orders", "1,1,1",
                                     "--validation", good, "--json", js, "--quiet"]])
    assert rc == 0, capsys.readouterr().err
    assert js.stat().st_size > 0

    class Reached(Exception):
        pass

    real, stages = diag.diagnose, []

    def first_stage(est, val, **kw):
        def stop(i, total, info):
            stages.append(info["stage"])
            raise Reached
        try:
            real(est, val, **{**kw, "progress": stop})
        except Reached:
            pass
        return {"verdict": "stopped", "findings": []}

    monkeypatch.setattr(diag, "diagnose", first_stage)
    rc = cli.main([str(a) for a in ["diagnose", good, "--validation", good,
                                     "--json", tmp_path / "d.json", "--quiet"]])
    assert rc == 0, capsys.readouterr().err
    assert stages == ["baseline"]


_SETTINGS = settings(max_examples=30, deadline=None, derandomize=True,
                     suppress_health_check=[HealthCheck.function_scoped_fixture])


@_SETTINGS
@given(bad=malformed(), as_validation=st.booleans())
def test_fit_rejects_malformed(bad, as_validation, tmp_path, capsys):
    kind, content = bad
    f = _write(tmp_path, content, "bad.csv")
    good = _good_csv(tmp_path / "good.csv")
    js, out = tmp_path / "r.json", tmp_path / "m.jtm"
    est, val = (good, f) if as_validation else (f, good)
    _assert_contract(["fit", est, "--model", "arx", "--orders", "1,1,1", "--validation", val,
                      "--json", js, "--out", out, "--quiet"], capsys, [js, out],
                     _names_defect(kind, f))


@_SETTINGS
@given(bad=malformed(), as_validation=st.booleans())
def test_diagnose_rejects_malformed(bad, as_validation, tmp_path, capsys):
    kind, content = bad
    f = _write(tmp_path, content, "bad.csv")
    good = _good_csv(tmp_path / "good.csv")
    js, rep = tmp_path / "d.json", tmp_path / "report"
    est, val = (good, f) if as_validation else (f, good)
    _assert_contract(["diagnose", est, "--validation", val, "--json", js, "--report", rep, "--quiet"],
                     capsys, [js, rep], _names_defect(kind, f))


@_SETTINGS
@given(bad=malformed(), which=st.sampled_from(["--controller-file", "--plant"]))
def test_simulate_rejects_malformed_files(bad, which, tmp_path, capsys):
    kind, content = bad
    f = _write(tmp_path, content, "bad.jtm")
    js = tmp_path / "s.json"
    argv = ["simulate", "--scenario", "tracking", "--rollouts", "2", "--duration", "60", "--json", js, "--quiet"]
    argv += [which, f] if which == "--controller-file" else ["--controller", "pi_lambda", "--plant", f]
    says = "no such file" if kind == "missing" else "not a jthermo save file"
    _assert_contract(argv, capsys, [js], re.escape(str(f)) + r"\b.*" + says)


def test_truncated_model_file(tmp_path, capsys):
    from jthermo import io
    from jthermo.models import StateSpace

    m = io.save(StateSpace(0.5 * np.eye(2), np.eye(2), np.eye(2)), tmp_path / "m.jtm")
    raw = m.read_bytes()
    for n in (0, 10, len(raw) // 2, len(raw) - 5):
        m.write_bytes(raw[:n])
        _assert_contract(["validate", m, _good_csv(tmp_path / "g.csv"), "--json", tmp_path / "v.json"],
                         capsys, [tmp_path / "v.json"])
        _assert_contract(["simulate", "--scenario", "tracking", "--controller", "pi_lambda", "--plant", m],
                         capsys, [])
