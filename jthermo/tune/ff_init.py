"""A model-based start for the schedule feed-forward (`control.schedule_ff.ScheduleFF`): the
taps that best cancel, on the printer's own response, the effect of an announced event.

The feed-forward is linear in its taps, so the open-loop output it produces is a sum of
shifted heater impulse responses. For one recoat announced at sample 0 (it lands `preview`
samples later) and for one exposed sample of zone i, the printer is run open loop from its
steady state with that event alone; the taps are the regularised least-squares solution of

$$\\min_h \\sum_k \\lVert \\Delta y^{event}_k + \\sum_{j<L} G_{k-j}\\, h_j \\rVert^2
+ \\mu \\lVert h \\rVert^2$$

with $G$ the heaters' impulse responses (through the input delay): an inverse of the event's
effect over the window, the best the FIR can do with no feedback. Recoat taps use every heater,
laser taps of zone i heater i only (the structure of `ScheduleFF`). Feedback then only sees
what the FIR cannot cancel, and tuning starts from there instead of from zero taps. On a real
printer the same responses come from an identified model with the recoat flag and exposure as
measured inputs; here they come from the virtual printer (as `printer_model` does for the
feedback design).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..closedloop.scenarios import PREVIEW_S
from ..control.schedule_ff import ScheduleFF
from ..errors import ControlError
from ..printer import Printer, PrinterDisturbance


def _open_loop(printer: Printer, u, recoat, laser):
    """Outputs (T, ny) of the printer from its steady state under inputs u (T, nu) and events."""
    disc = printer.discretise()
    x0 = printer.initial_state()
    amb = jnp.full(recoat.shape, printer.surroundings, recoat.dtype)

    def body(x, inp):
        uk, rk, lk, ak = inp
        x1 = disc.step(x, uk, PrinterDisturbance(recoat=rk, laser=lk, ambient=ak))
        return x1, printer.output(x1)

    return jax.lax.scan(body, x0, (u, recoat, laser, amb))[1]


def event_responses(printer: Printer, taps: int, *, preview: int, horizon: int | None = None,
                    du: float = 0.01) -> dict:
    """Open-loop responses over `horizon` samples (default `taps` + 3·`preview` + 60):
    `"G"` (nu, H, ny) per unit heater impulse at sample 0, `"recoat"` (H, ny) to a recoat at
    sample `preview`, `"laser"` (nz, H, ny) to one sample of zone i's nominal laser power at
    sample `preview`; each minus the run with no event."""
    H = int(horizon or taps + 3 * preview + 60)
    dt = printer.capacity.dtype
    u0 = jnp.asarray(printer.steady_input(), dt)
    nu, nz = u0.shape[0], printer.zones
    U = jnp.broadcast_to(u0, (H, nu))
    zr, zl = jnp.zeros((H,), dt), jnp.zeros((H, nz), dt)
    base = _open_loop(printer, U, zr, zl)
    G = jnp.stack([(_open_loop(printer, U.at[0, m].add(du), zr, zl) - base) / du
                   for m in range(nu)])
    out = {"G": np.asarray(G), "recoat": None, "laser": None}
    if printer.has("recoat_cooling"):
        out["recoat"] = np.asarray(_open_loop(printer, U, zr.at[preview].set(1.0), zl) - base)
    if printer.has("laser_exposure"):
        q = float(printer.param("laser_exposure", "power_W"))
        out["laser"] = np.stack([np.asarray(_open_loop(printer, U, zr,
                                                       zl.at[preview, i].set(q)) - base)
                                 for i in range(nz)])
    return out


def shifted_responses(G_m: np.ndarray, taps: int) -> np.ndarray:
    """Columns: heater m's impulse response (H, ny) delayed by j = 0..taps-1, flattened."""
    H, ny = G_m.shape
    cols = np.zeros((H, ny, taps))
    for j in range(taps):
        cols[j:, :, j] = G_m[:H - j]
    return cols.reshape(H * ny, taps)


def init_schedule_ff(ctrl: ScheduleFF, printer: Printer, *, preview_s: float = PREVIEW_S,
                     ridge: float = 1e-3, limit: float = 0.3) -> ScheduleFF:
    """`ctrl` with its feed-forward taps set to the least-squares inverse of the printer's
    response to each announced event (module docstring); the penalty $\\mu$ (on the taps
    and their first differences, relative to the mean squared heater response) starts at
    `ridge` and grows ×4 until every effective tap lies within ±`limit` power fraction (the
    FIR must stay inside the heaters' range around the operating input)."""
    if not isinstance(ctrl, ScheduleFF):
        raise ControlError("init_schedule_ff: needs a ScheduleFF controller")
    if not isinstance(printer, Printer) or printer.has_areas:
        raise ControlError("init_schedule_ff: needs a virtual printer without areas")
    L, nu = ctrl.h_recoat.shape
    if nu != printer.n_inputs or nu != printer.zones:
        raise ControlError(f"init_schedule_ff: {nu} heaters in the controller, printer has "
                           f"{printer.n_inputs} inputs and {printer.zones} zones")
    P = round(preview_s / printer.ts)
    R = event_responses(printer, L, preview=P)
    cols = [shifted_responses(R["G"][m], L) for m in range(nu)]
    g2 = float(np.mean(np.sum(R["G"] ** 2, axis=(1, 2))))
    D = np.eye(L) - np.eye(L, k=-1)                  # first differences of the taps
    reg1 = np.eye(L) + D.T @ D

    def solve(A, b, mu):
        n = A.shape[1] // L
        return np.linalg.solve(A.T @ A + mu * g2 * np.kron(np.eye(n), reg1), -A.T @ b)

    def fit(A, b):
        # the least regularisation (from `ridge` up, ×4) whose taps stay within ±limit
        mu = ridge
        for _ in range(20):
            h = solve(A, b, mu)
            if np.max(np.abs(h)) <= limit:
                break
            mu *= 4.0
        return np.clip(h, -limit, limit)

    h_rec = np.zeros((L, nu))
    h_las = np.zeros((L, nu))
    if R["recoat"] is not None:
        h_rec = fit(np.concatenate(cols, axis=1), R["recoat"].reshape(-1)).reshape(nu, L).T
    if R["laser"] is not None:
        for i in range(nu):
            h_las[:, i] = fit(cols[i], R["laser"][i].reshape(-1))
    dt = ctrl.h_recoat.dtype
    to = lambda h: jnp.asarray(h / ctrl.scale, dt)
    return eqx.tree_at(lambda c: (c.h_recoat, c.h_laser), ctrl, (to(h_rec), to(h_las)))


#: the fields of a `ScheduleFF` that tuning moves by default: the taps only
FF_FIELDS = ("h_recoat", "h_laser")


def tuned_fields(ctrl) -> tuple[str, ...] | None:
    """The fields `tune` moves by default for `ctrl` (`params`; None: every array leaf).

    A schedule feed-forward tunes its taps with the feedback (MIMO PI or LQG) frozen at its
    design: the feed-forward does not enter the sensitivity $S = (I - G K)^{-1}$, so the loop
    keeps the design's $M_s$ (on the printer within the limit 2:
    experiments/results/schedule_ff_study.md) by construction, and the set-point tracking of
    the design (no events there); the feed-forward does the disturbance work. Tuned jointly,
    the PI gains left $M_s \\le 2$ within a few iterates."""
    if isinstance(ctrl, ScheduleFF):
        return FF_FIELDS
    return None
