"""Schedule feed-forward: neutral at zero taps, an exact FIR of the announced events, inside the
feedback's anti-windup; the scenarios' event schedule (preview, jitter, wrong map)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.closedloop import PREVIEW_S, event_schedule, make_scenario
from jthermo.control import ScheduleFF, design, mimo_from, with_schedule
from jthermo.errors import ControlError
from jthermo.printer import make_printer

from .loop import bed_plant

N, L = 3, 6


def _run(ctrl, y, r, s):
    def body(c, inp):
        u, c = ctrl.step_schedule(c, *inp)
        return c, u

    _, us = jax.lax.scan(body, ctrl.init(y[0], r[0]), (y, r, s))
    return np.asarray(us)


@pytest.mark.parametrize("family", ["pi_mimo", "lqg"])
def test_schedule_ff_is_an_fir_of_the_events_inside_the_feedback(family):
    plant = bed_plant(N, seed=1)
    fb = design(family, plant)
    rng = np.random.default_rng(0)
    T = 60
    y = jnp.asarray(plant.y0 + 0.2 * rng.standard_normal((T, N)))
    r = jnp.broadcast_to(plant.y0, (T, N))
    s = jnp.asarray((rng.uniform(size=(T, 1 + N)) < 0.2).astype(float))
    zero = with_schedule(fb, taps=L)
    u_fb = _run(zero, y, r, s)
    np.testing.assert_array_equal(u_fb, _run(fb, y, r, jnp.zeros((T, 0))))  # taps 0: neutral
    h_rec, h_las = rng.normal(0, 0.1, (L, N)), rng.normal(0, 0.1, (L, N))
    ff = ScheduleFF(feedback=fb, h_recoat=jnp.asarray(h_rec), h_laser=jnp.asarray(h_las))
    # the expected FIR, by NumPy convolution of each event stream with its taps
    sn = np.asarray(s)
    want = np.zeros((T, N))
    for i in range(N):
        want[:, i] = (np.convolve(sn[:, 0], ff.scale * h_rec[:, i])[:T]
                      + np.convolve(sn[:, 1 + i], ff.scale * h_las[:, i])[:T])
    u = _run(ff, y, r, s)
    # unsaturated and the feedback sees the same y: the difference is the FIR alone (the PI's
    # integrator and the LQG's observer see only the feedback's part of the input)
    assert np.all((u > 0) & (u < 1))
    np.testing.assert_allclose(u - u_fb, want, atol=1e-12)
    assert np.max(np.abs(want[1:])) > 1e-2       # the FIR is not negligible after sample 0


def test_schedule_ff_anti_windup_and_checks():
    plant = bed_plant(N, seed=1)
    fb = mimo_from(design("pi_lambda", plant))
    ff = ScheduleFF(feedback=fb, h_recoat=jnp.full((L, N), 100.0), h_laser=jnp.zeros((L, N)))
    y = jnp.broadcast_to(plant.y0, (20, N))
    s = jnp.zeros((20, 1 + N)).at[2, 0].set(1.0)
    u = _run(ff, y, y, s)
    assert np.all(u[2:2 + L] == 1.0) and np.all(u[2 + L:] == u[0])   # the integrator did not wind up
    with pytest.raises(ControlError, match="schedule row has 2"):
        ff.step_schedule(ff.init(y[0], y[0]), y[0], y[0], jnp.zeros(2))
    with pytest.raises(ControlError, match="MIMOPI or an LQG"):
        ScheduleFF(feedback=design("pi_lambda", plant), h_recoat=jnp.zeros((L, N)),
                   h_laser=jnp.zeros((L, N)))


def test_event_schedule_preview_jitter_and_wrong_map():
    p = make_printer(2, ("recoat_cooling", "laser_exposure"))
    sc = make_scenario("print", p, 300.0, 0)
    P = int(PREVIEW_S)
    ev = np.concatenate([np.asarray(sc.d.recoat)[:, None], np.asarray(sc.d.laser > 0)], axis=1)
    exact = np.asarray(event_schedule(p, sc.d, jax.random.key(1), jitter_s=0.0, wrong_p=0.0))
    np.testing.assert_array_equal(exact[:-P], ev[P:])
    assert np.all(exact[-P:] == 0.0)
    shifts = set()
    for k in range(12):
        s = np.asarray(event_schedule(p, sc.d, jax.random.key(k), wrong_p=0.0))
        shifts.add(int(np.flatnonzero(s[:, 0])[0]) - int(np.flatnonzero(exact[:, 0])[0]))
    assert shifts <= {-2, -1, 0, 1, 2} and len(shifts) > 1
    wrong = np.asarray(event_schedule(p, sc.d, jax.random.key(1), jitter_s=0.0, wrong_p=0.5))
    assert np.any(wrong[:, 1:] != exact[:, 1:]) and np.array_equal(wrong[:, 0], exact[:, 0])
    assert sc.s.shape == (300, 3)


def test_ff_init_cancels_most_of_the_events_open_loop():
    """The model-based start of the taps (`tune.ff_init`): within ±limit, and on the printer's
    own open-loop responses it removes most of a recoat's and an exposure's effect."""
    from jthermo.tune.ff_init import event_responses, init_schedule_ff, shifted_responses
    from jthermo.tune.report import printer_model

    pr = make_printer(2, ["recoat_cooling", "laser_exposure"], seed=0)
    ctrl = init_schedule_ff(design("pi_ff", printer_model(pr), taps=30), pr, limit=0.3)
    h_rec, h_las = (np.asarray(h) for h in ctrl.effective_taps())
    assert np.max(np.abs(h_rec)) <= 0.3 + 1e-12 and np.max(np.abs(h_las)) <= 0.3 + 1e-12
    R = event_responses(pr, 30, preview=round(PREVIEW_S / pr.ts))
    cols = [shifted_responses(R["G"][m], 30) for m in range(2)]
    rec = R["recoat"].reshape(-1) + np.concatenate(cols, axis=1) @ h_rec.T.reshape(-1)
    las = R["laser"][0].reshape(-1) + cols[0] @ h_las[:, 0]
    rms = lambda v: float(np.sqrt(np.mean(v ** 2)))
    assert rms(rec) < 0.5 * rms(R["recoat"])
    assert rms(las) < 0.8 * rms(R["laser"][0])
    with pytest.raises(ControlError):
        init_schedule_ff(design("pi_mimo", printer_model(pr)), pr)


def test_rescaled_mimo_pi_is_the_same_loop():
    """`MIMOPI.rescaled` (what `tune_report` tunes): gains stored in units of their diagonal,
    the same effective gains and the same input, inside a schedule feed-forward too."""
    from jthermo.tune.report import rescaled_start

    plant = bed_plant(N, seed=1)
    c = design("pi_ff", plant, taps=L)
    r = rescaled_start(c)
    fb = r.feedback
    assert fb.kp_scale > 0 and fb.ki_scale > 0
    np.testing.assert_allclose(np.abs(np.diag(np.asarray(fb.kp))).mean(), 1.0, rtol=1e-12)
    for a, b in zip(c.feedback.gains(), fb.gains()):
        np.testing.assert_allclose(a, b, rtol=1e-13)
    y, ref = jnp.asarray(plant.y0) + 0.3, jnp.asarray(plant.y0)
    s = jnp.ones(1 + N)
    u1, _ = c.step_schedule(c.init(y, ref), y, ref, s)
    u2, _ = r.step_schedule(r.init(y, ref), y, ref, s)
    np.testing.assert_allclose(u1, u2, rtol=1e-13)
