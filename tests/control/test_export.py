"""Exported controllers: the C compiles with `-Wall -Werror` and matches the JAX controller over
a closed-loop run (saturation, anti-windup and schedule feed-forward exercised) to 1e-12."""

import ctypes
import json
import shutil
import subprocess

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.control import DiagonalPI, design, mimo_from, with_schedule
from jthermo.control.relay import DiagonalPID
from jthermo.control.export import tables, to_c, to_json
from jthermo.errors import ControlError
from tests.control.loop import bed_plant

CC = shutil.which("cc") or shutil.which("gcc")
N, T = 3, 240


def _schedule(seed=0):
    """Event rows [recoat, exposure 1..N]: a recoat every 60 s, a random exposure map per layer."""
    rng = np.random.default_rng(seed)
    s = np.zeros((T, 1 + N))
    for k0 in range(7, T, 60):
        s[k0, 0] = 1.0
        s[k0 + 10:k0 + 25, 1:] = rng.integers(0, 2, N)
    return jnp.asarray(s)


def _closed_loop(ctrl, plant, sched):
    """JAX closed loop on the linear bed; a big set-point step drives the heaters to their
    limits, recoats cool every zone. Returns the controller's inputs (y, r, s) and its u."""
    r = jnp.broadcast_to(plant.y0 + jnp.where(jnp.arange(T)[:, None] < 80, 25.0, 0.0), (T, N))
    cool = 2.0 * sched[:, :1] * jnp.ones((1, N))

    def body(carry, inp):
        x, c = carry
        rk, sk, dk = inp
        y = plant.output(x)
        u, c = ctrl.step_schedule(c, y, rk, sk)
        u = jnp.clip(u, 0.0, 1.0)
        return (plant.step(x, u) - dk, c), (y, u)

    x0 = plant.initial_state(plant.y0)
    c0 = ctrl.init(plant.output(x0), r[0])
    _, (ys, us) = jax.lax.scan(body, (x0, c0), (r, sched, cool))
    return np.asarray(ys), np.asarray(r), np.asarray(sched), np.asarray(us)


def _controllers():
    plant = bed_plant(N, seed=1)
    rng = np.random.default_rng(3)
    lam = design("pi_lambda", plant)
    mimo = mimo_from(design("pi_decoupled", plant))
    mimo = mimo.__class__(kp=mimo.kp + 0.01 * rng.standard_normal((N, N)),
                          ki=mimo.ki + 0.001 * rng.standard_normal((N, N)), u0=mimo.u0,
                          mask=None, ts=mimo.ts)
    ff = with_schedule(mimo, taps=12)
    ff = ff.__class__(feedback=mimo, h_recoat=jnp.asarray(0.05 * rng.standard_normal((12, N))),
                      h_laser=jnp.asarray(0.05 * rng.standard_normal((12, N))))
    lqg_ff = with_schedule(design("lqg", plant), taps=8)
    lqg_ff = lqg_ff.__class__(feedback=lqg_ff.feedback,
                              h_recoat=jnp.asarray(0.05 * rng.standard_normal((8, N))),
                              h_laser=jnp.full((8, N), -0.02))
    tustin = DiagonalPI(lam.kp, lam.ti, lam.u0, antiwindup="backcalc", method="tustin")
    weighted = DiagonalPI(lam.kp, lam.ti, lam.u0, b=0.4)    # set-point weight b < 1
    pid = design("pid_relay", plant)
    pid_b = DiagonalPID(pid.kp, pid.ti, pid.td, pid.u0, ts=pid.ts, b=0.4)
    return plant, {"lambda_pi": lam, "tustin_backcalc": tustin, "pi_b04": weighted,
                   "pid_relay": pid, "pid_b04": pid_b,
                   "decoupled": design(
        "pi_decoupled", plant), "mimo_pi": mimo, "pi_ff": ff, "lqg": design("lqg", plant),
        "lqg_ff": lqg_ff}


@pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
def test_exported_c_matches_jax(tmp_path):
    plant, ctrls = _controllers()
    sched = _schedule()
    for name, ctrl in ctrls.items():
        ys, rs, ss, us = _closed_loop(ctrl, plant, sched)
        assert us.min() == 0.0 or us.max() == 1.0, f"{name}: the run never saturates"
        h, c = to_c(ctrl, tmp_path / name, name=f"ctl_{name}")
        subprocess.run([CC, "-std=c99", "-c", "-Wall", "-Wextra", "-Werror", "-pedantic",
                        str(c), "-o", str(tmp_path / f"{name}.o")], check=True)
        so = tmp_path / f"{name}.so"
        subprocess.run([CC, "-std=c99", "-shared", "-fPIC", "-O2", "-ffp-contract=off", str(c),
                        "-o", str(so)], check=True)
        lib = ctypes.CDLL(str(so))
        getattr(lib, f"ctl_{name}_state_size").restype = ctypes.c_size_t
        state = ctypes.create_string_buffer(getattr(lib, f"ctl_{name}_state_size")())
        dp = ctypes.POINTER(ctypes.c_double)

        def ptr(a):
            return np.ascontiguousarray(a, np.float64).ctypes.data_as(dp)

        ys_c, rs_c, ss_c = (np.ascontiguousarray(a, np.float64) for a in (ys, rs, ss))
        getattr(lib, f"ctl_{name}_init")(state, ptr(ys_c[0]), ptr(rs_c[0]))
        u_c = np.zeros((T, N))
        out = np.zeros(N)
        step = getattr(lib, f"ctl_{name}_step")
        for k in range(T):
            step(state, ptr(ys_c[k]), ptr(rs_c[k]), ptr(ss_c[k]), out.ctypes.data_as(dp))
            u_c[k] = out
        np.testing.assert_allclose(u_c, us, rtol=0, atol=1e-12, err_msg=name)


def test_json_tables_round_trip(tmp_path):
    _, ctrls = _controllers()
    path = to_json(ctrls["pi_ff"], tmp_path / "pi_ff.json")
    t = json.loads(path.read_text())
    assert t["kind"] == "mimo_pi" and t["feedforward"]["taps"] == 12
    np.testing.assert_array_equal(np.asarray(t["tables"]["Kp"]), np.asarray(ctrls["pi_ff"].feedback.kp))
    np.testing.assert_array_equal(np.asarray(t["feedforward"]["h_laser"]),
                                  np.asarray(ctrls["pi_ff"].effective_taps()[1]))
    assert tables(ctrls["lqg"])["kind"] == "lqg"


def test_export_refuses_what_it_cannot_write(tmp_path):
    plant, ctrls = _controllers()
    with pytest.raises(ControlError, match="no code export for IMC"):
        tables(design("imc", plant))
    with pytest.raises(Exception, match="C identifier"):
        to_c(ctrls["mimo_pi"], tmp_path, name="1bad-name")


@pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
def test_cli_export(tmp_path, capsys):
    from jthermo import io
    from jthermo.cli import main

    plant, ctrls = _controllers()
    io.save(ctrls["pi_ff"], tmp_path / "c.jtm")
    assert main(["export", str(tmp_path / "c.jtm"), "--to", "c", "--out", str(tmp_path / "c"),
                 "--json", str(tmp_path / "r.json"), "--quiet"]) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["kind"] == "mimo_pi" and rep["schedule_feedforward"] and len(rep["files"]) == 2
    subprocess.run([CC, "-c", "-Wall", "-Werror", str(tmp_path / "c" / "jthermo_ctrl.c"), "-o",
                    str(tmp_path / "c.o")], check=True)
    assert main(["export", str(tmp_path / "c.jtm"), "--to", "json", "--out",
                 str(tmp_path / "j"), "--quiet"]) == 0
    assert json.loads((tmp_path / "j" / "jthermo_ctrl.json").read_text())["feedforward"]["taps"] == 12
    io.save(design("imc", plant), tmp_path / "imc.jtm")
    capsys.readouterr()
    assert main(["export", str(tmp_path / "imc.jtm"), "--to", "c", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "no code export for IMC" in err and "Traceback" not in err and len(err.splitlines()) == 1
