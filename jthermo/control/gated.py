"""Band-limited use of a controller (the thesis' finding that control is best used close to
the target): active inside a temperature band around the set point, a fixed input outside.

Per zone, with $e = r - y$ and the smooth indicator
$s = \\sigma\\bigl((b - |e|_\\delta)/w\\bigr)$ ($\\sigma$ the logistic function,
$|e|_\\delta = \\sqrt{e^2 + \\delta^2}$, w the transition width):

$$u = s\\, u_{ctrl} + (1 - s)\\, u_{out}(e), \\qquad
  u_{out}(e) = \\sigma(e/w)\\, u_{below} + (1 - \\sigma(e/w))\\, u_{above},$$

so below the band the input is `u_below` (e.g. full power to heat up), above it `u_above`.
Everything is smooth, so the band and the inner gains can be tuned by gradient.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._types import Input, Output, Setpoint
from ..errors import ControlError
from ._base import U_MAX, U_MIN, AbstractController, ControllerState


class Gated(AbstractController):
    """A controller used only inside ±`band` °C of the set point."""

    inner: AbstractController
    band: Float[Array, ""]          # half-width of the active band, °C, tunable
    u_below: Float[Array, " nu"]    # input below the band, power fraction
    u_above: Float[Array, " nu"]    # input above the band, power fraction
    width: float = eqx.field(static=True)   # transition width, °C

    def init(self, y0: Output, r0: Setpoint) -> ControllerState:
        return self.inner.init(y0, r0)

    def step(self, state, y: Output, r: Setpoint) -> tuple[Input, ControllerState]:
        u_c, state = self.inner.step(state, y, r)
        e = r - y
        w = self.width
        s = jax.nn.sigmoid((self.band - jnp.sqrt(e * e + (0.1 * w) ** 2)) / w)
        below = jax.nn.sigmoid(e / w)
        u_out = below * self.u_below + (1.0 - below) * self.u_above
        u = s * u_c + (1.0 - s) * u_out
        return jnp.clip(u, U_MIN, U_MAX), state


def gated(controller: AbstractController, band=3.0, u_outside=None, *, u_below=1.0,
          u_above=0.0, width=None, n=None) -> Gated:
    """Wrap `controller` so that it acts only within ±`band` °C of the set point.

    **Arguments:**
    - `band`: half-width of the active band in °C (positive).
    - `u_outside`: one fixed input outside the band (overrides `u_below`/`u_above`).
    - `u_below`, `u_above`: inputs used below / above the band (defaults: full power, off).
    - `width`: transition width in °C (default band/10).
    - `n`: number of inputs (default: taken from the controller's first array leaf).
    """
    band_f = float(band)
    if not band_f > 0:
        raise ControlError(f"gated: band must be positive, got {band}")
    if u_outside is not None:
        u_below = u_above = u_outside
    if n is None:
        leaves = [x for x in jax.tree_util.tree_leaves(controller) if eqx.is_inexact_array(x)]
        if not leaves or leaves[0].ndim != 1:
            raise ControlError("gated: cannot tell the number of inputs; pass n=")
        n = leaves[0].shape[0]
    width_f = band_f / 10.0 if width is None else float(width)
    if not width_f > 0:
        raise ControlError(f"gated: width must be positive, got {width}")
    dt = jnp.result_type(float)
    return Gated(inner=controller, band=jnp.asarray(band_f, dt),
                 u_below=jnp.broadcast_to(jnp.asarray(u_below, dt), (n,)),
                 u_above=jnp.broadcast_to(jnp.asarray(u_above, dt), (n,)), width=width_f)
