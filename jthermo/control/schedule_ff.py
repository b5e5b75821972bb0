"""Feed-forward from the build job's event schedule, added to a feedback controller.

A printer knows when it recoats and which zones the laser exposes, layer by layer. The
closed loop hands the controller that schedule, announced `preview` samples ahead
(`closedloop.Scenario.s`: row k is $s_k = [\\rho_{k+P}, \\lambda_{k+P,1..N}]$, the recoat flag
and the per-zone exposure indicator). The feed-forward is a short learned impulse response
(FIR, length L) per event type and zone,

$$u^{ff}_{k,i} = \\sum_{j<L} h^{rec}_{j,i}\\, s_{k-j,0} + h^{las}_{j,i}\\, s_{k-j,1+i},$$

so heater i can start $P$ samples before a recoat lands and keep going for $L - P$ after it.
It enters the feedback controller inside its saturation (`step_offset` of `MIMOPI`, whose
back-calculation sees the feedback's own request, and of `LQG`), and is tuned by gradient with
the feedback gains (all taps start at 0: the wrapped controller unchanged). The feed-forward
is built to cancel its event at the sensors, so an LQG's observer is given the feedback's part
of the applied input only, $\\hat x_{k+1} = A \\hat x_{k|k} + B (u_k - u^{ff}_k - u_{op})$: the
plant sees $u$ and the event, whose effects cancel where the feed-forward is right, and the
observer a plant with neither. Fed the whole of $u$, the observer predicts the heating of a
pulse that the event absorbs, and the state feedback $-L_x \\hat x$ takes the pulse back
(held-out cost of the `lqg_ff` start on the printer, reduced run: 0.955 with the whole input,
0.886 with the feedback's part; `experiments/results/lqg_ff_observer.md`).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._types import Input, Output, Setpoint
from ..errors import ControlError
from ._base import AbstractController
from .lqg import LQG
from .mimo_pi import MIMOPI

#: default FIR length, samples
TAPS = 40


class ScheduleFFState(eqx.Module):
    feedback: Any                          # the feedback controller's state
    events: Float[Array, "L ns"]           # the last L schedule rows, newest first


class ScheduleFF(AbstractController):
    """`feedback` (a `MIMOPI` or an `LQG`) plus the schedule FIR feed-forward (taps tunable)."""

    feedback: MIMOPI | LQG
    h_recoat: Float[Array, "L nu"]         # power fraction per recoat event, per tap and heater
    h_laser: Float[Array, "L nu"]          # power fraction per exposed sample, zone i -> heater i
    # taps are stored in units of `scale` (power fraction): an optimiser step of order 1e-2 on
    # a stored tap moves the heater by `scale` × that, the size of the step the feedback takes
    scale: float = eqx.field(static=True, default=0.05)

    def __check_init__(self):
        if not isinstance(self.feedback, (MIMOPI, LQG)):
            raise ControlError(f"ScheduleFF: the feedback must be a MIMOPI or an LQG, got "
                               f"{type(self.feedback).__name__}")
        if self.h_recoat.ndim != 2 or self.h_laser.shape != self.h_recoat.shape:
            raise ControlError(f"ScheduleFF: h_recoat {self.h_recoat.shape} and h_laser "
                               f"{self.h_laser.shape} must be equal (taps, heaters) shapes")

    @property
    def ts(self) -> float:
        return self.feedback.ts

    @property
    def taps(self) -> int:
        return int(self.h_recoat.shape[0])

    @property
    def n_schedule(self) -> int:
        """Width of a schedule row: the recoat flag and one exposure indicator per heater."""
        return 1 + int(self.h_recoat.shape[1])

    def init(self, y0: Output, r0: Setpoint) -> ScheduleFFState:
        ev = jnp.zeros((self.taps, self.n_schedule), self.h_recoat.dtype)
        return ScheduleFFState(self.feedback.init(y0, r0), ev)

    def feedforward(self, events: Float[Array, "L ns"]) -> Input:
        """$u^{ff}$ from the schedule history (newest row first); the effective taps are
        `scale` × the stored ones (`effective_taps`)."""
        h_rec, h_las = self.effective_taps()
        return events[:, 0] @ h_rec + jnp.sum(h_las * events[:, 1:], axis=0)

    def effective_taps(self) -> tuple[Array, Array]:
        """`(h_recoat, h_laser)` in power fraction per event sample."""
        return self.scale * self.h_recoat, self.scale * self.h_laser

    def step_schedule(self, state: ScheduleFFState, y: Output, r: Setpoint,
                      schedule) -> tuple[Input, ScheduleFFState]:
        row = jnp.zeros((self.n_schedule,), self.h_recoat.dtype) if schedule is None \
            else jnp.asarray(schedule, self.h_recoat.dtype)
        if row.shape != (self.n_schedule,):
            raise ControlError(f"ScheduleFF: a schedule row has {row.shape[0]} entries, "
                               f"expected {self.n_schedule} (recoat + one per heater)")
        events = jnp.concatenate([row[None], state.events[:-1]], axis=0)
        u_ff = self.feedforward(events)
        u, fb = self.feedback.step_offset(state.feedback, y, r, u_ff)
        if isinstance(self.feedback, LQG):
            # the observer predicts with the feedback's part of u (module docstring)
            fb = eqx.tree_at(lambda s: s.x, fb,
                             fb.x - jax.lax.stop_gradient(self.feedback.B) @ u_ff)
        return u, ScheduleFFState(fb, events)

    def step(self, state: ScheduleFFState, y: Output, r: Setpoint) -> tuple[Input, ScheduleFFState]:
        return self.step_schedule(state, y, r, None)


def with_schedule(feedback: MIMOPI | LQG, taps: int = TAPS) -> ScheduleFF:
    """`feedback` with a schedule feed-forward of `taps` samples, all taps 0 (neutral)."""
    if not (isinstance(taps, int) and taps >= 1):
        raise ControlError(f"with_schedule: taps must be a positive integer, got {taps!r}")
    n = int(feedback.u_op.shape[0]) if isinstance(feedback, LQG) else feedback.zones
    dt = feedback.u_op.dtype if isinstance(feedback, LQG) else feedback.u0.dtype
    z = jnp.zeros((taps, n), dt)
    return ScheduleFF(feedback=feedback, h_recoat=z, h_laser=z)
