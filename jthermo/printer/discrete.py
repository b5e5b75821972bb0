"""The virtual printer with its sample-time matrices precomputed (`Printer.discretise`): the
exact zero-order-hold step of the linear part, with ETD2RK sub-steps for radiation and the
recoat sweep (see `jthermo.printer`)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .integration import PhiMatrices
from .state import PrinterDisturbance, PrinterState


class DiscretePrinter(eqx.Module):
    """A printer with its sample-time matrices precomputed: same `step`/`output` interface."""

    printer: eqx.Module                  # the `plant.Printer` it was made from
    disc: PhiMatrices
    Bp: Array
    bs: Array
    Bl: Array
    m: int = eqx.field(static=True)
    recoat: bool = eqx.field(static=True, default=True)   # False: no sweep term (see discretise)

    def step(self, x: PrinterState, u, d: PrinterDisturbance | None = None) -> PrinterState:
        pr = self.printer
        if d is None:
            d = pr.default_disturbance()
        u = jnp.asarray(u, self.Bp.dtype)
        if pr.delay:
            u_now = x.buffer[0]
            buffer = jnp.concatenate([x.buffer[1:], u[None]], axis=0)
        else:
            u_now, buffer = u, x.buffer
        p = pr._power(u_now)
        b = self.Bp @ p + self.bs * d.ambient + self.Bl @ d.laser
        since = jnp.where(d.recoat > 0.5, 0.0, x.since)
        E, P1, P2 = self.disc.E, self.disc.P1, self.disc.P2
        if not (pr.has("radiative_loss") or (self.recoat and pr.has("recoat_cooling"))):
            z = E @ x.z + P1 @ b
        else:
            h, n = pr.ts / self.m, pr.zones
            # the nonlinear terms act on the zone rows only and `b` is constant over the
            # sample: P1 b once, then zone columns (a third fewer multiply-adds per sub-step)
            P1b, P1n, P2n = P1 @ b, P1[:, :n], P2[:, :n]

            def sub(z, j):
                t = since + j * h
                f0 = pr._nonlinear(z, t, d.ambient, self.recoat)[:n]
                a = E @ z + P1b + P1n @ f0
                f1 = pr._nonlinear(a, t + h, d.ambient, self.recoat)[:n]
                return a + P2n @ (f1 - f0), None

            z, _ = jax.lax.scan(sub, x.z, jnp.arange(self.m, dtype=x.z.dtype))
        return PrinterState(z=z, buffer=buffer, since=since + pr.ts)

    def output(self, x):
        return self.printer.output(x)

    def temperatures(self, x):
        return self.printer.temperatures(x)
