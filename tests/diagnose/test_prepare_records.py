"""The validation stage's fit program is compiled in a thread while the candidates are fitted
(`fitting.prepare_records`): the validation call then lowers nothing."""

import collections

import pytest
from jax import monitoring

from jthermo import stored
from jthermo.diagnose import diagnose
from jthermo.diagnose import select as S
from tests.diagnose.records import record

LOWERING = "/jax/core/compile/jaxpr_to_mlir_module_duration"
MECHS = ("heater_lag", "input_delay")


def _lowerings_in_validation(n_val: int) -> tuple[int, dict]:
    """Programs JAX lowered between the candidates' and the validation stage's ticks of a
    diagnosis whose validation record has `n_val` samples (a length no other test uses)."""
    est, val = record("input_delay", 3, n_est=600, n_val=n_val)
    events, stage = collections.Counter(), {"now": None}

    def count(name, _secs, **_):
        events[(stage["now"], name)] += 1

    def tick(_i, _total, info):
        stage["now"] = info["stage"]

    monitoring.register_event_duration_secs_listener(count)
    try:
        res = diagnose(est, val, mechanisms=MECHS, progress=tick)
    finally:
        monitoring.unregister_event_duration_listener(count)
    return events[("candidates", LOWERING)], res


def test_validation_program_is_prepared_during_the_candidates(monkeypatch):
    if stored.cache_dir() is None:
        pytest.skip("no compilation cache: nothing is prepared")
    n, res = _lowerings_in_validation(431)
    assert n == 0
    # the count can fail: without the preparation the validation call lowers its program
    monkeypatch.setattr(S, "prepare_records", lambda *a, **k: False)
    n_plain, _ = _lowerings_in_validation(433)
    assert n_plain > 0
    assert res["findings"] and res["findings"][0]["mechanism"] == "input_delay"
