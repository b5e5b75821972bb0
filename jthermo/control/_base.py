"""The interface every controller shares.

Controllers are pure: they hand their state back to the caller and never keep it on `self`,
so a closed loop is one `lax.scan` and a batch of loops one `vmap`. Tunable gains are array
leaves (`eqx.is_inexact_array`), so `jax.grad` reaches them.
"""

from __future__ import annotations

import abc
from typing import Any

import equinox as eqx

from .._types import Input, Output, Setpoint

ControllerState = Any   # a pytree with fixed shapes and dtypes (a scan carry)

U_MIN, U_MAX = 0.0, 1.0   # actuator limits, power fraction


class AbstractController(eqx.Module):
    """A discrete-time controller with sample time `ts` (s).

    `step` returns the *requested* input; the loop saturates it to [`U_MIN`, `U_MAX`] = [0, 1].
    Controllers with anti-windup saturate internally as well, so that their state knows about
    the limit.
    """

    def __repr__(self) -> str:
        """The controller with its gains' values (not only their shapes)."""
        return eqx.tree_pformat(self, short_arrays=False)

    @abc.abstractmethod
    def init(self, y0: Output, r0: Setpoint) -> ControllerState:
        """Controller state before the first sample, given the first measurement and set point."""

    @abc.abstractmethod
    def step(self, state: ControllerState, y: Output, r: Setpoint) -> tuple[Input, ControllerState]:
        """One sample: measurement `y` (°C), set point `r` (°C) -> input `u` (power fraction)."""

    def step_schedule(self, state: ControllerState, y: Output, r: Setpoint,
                      schedule) -> tuple[Input, ControllerState]:
        """One sample given the build job's event schedule as well (`closedloop.Scenario.s`
        row k: `[recoat, exposure of zone 1..N]`, announced ahead; None when the scenario
        carries none). Controllers without feed-forward from the schedule ignore it."""
        return self.step(state, y, r)
