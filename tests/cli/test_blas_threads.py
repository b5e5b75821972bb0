"""The `jthermo` command runs with one BLAS thread unless the user set a thread variable
(`jthermo.cli.one_blas_thread`; measured in benchmarks/results/identification_blas.md)."""

import os
import subprocess
import sys

import pytest

from jthermo.cli import BLAS_THREAD_VARS

PROBE = ("import os, sys, jthermo.cli as c; set_ = c.one_blas_thread(); "
         "print(set_, 'numpy' in sys.modules, *[os.environ.get(v) for v in c.BLAS_THREAD_VARS])")


def _probe(**env_vars):
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARS}
    env.update(env_vars)
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True,
                         check=True)
    return out.stdout.split()


def test_sets_one_thread_before_numpy_loads():
    assert _probe() == ["True", "False", "1", "1", "1"]


@pytest.mark.parametrize("var", BLAS_THREAD_VARS)
def test_a_user_setting_is_left_alone(var):
    got = _probe(**{var: "3"})
    assert got[0] == "False"
    assert got[2:] == ["3" if v == var else "None" for v in BLAS_THREAD_VARS]
