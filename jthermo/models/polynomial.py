"""The general polynomial family $A y = \\frac{B}{F} u(t-n_k) + \\frac{C}{D} e$: ARX, ARMAX, OE, BJ.

MIMO structure, one MISO row per output $i$ (Ljung 1999, §4.2):

$$A_i(q)\\,y(t) = \\sum_j \\frac{B_{ij}(q)}{F_{ij}(q)} u_j(t) + \\frac{C_i(q)}{D_i(q)} e_i(t)$$

with $A_i(q) y = y_i(t) + \\sum_{k=1}^{n_a} \\sum_l a_{i,l,k}\\, y_l(t-k)$ (a diagonal A uses only
$l = i$; a full matrix polynomial A is allowed when $n_d = n_f = 0$), $B_{ij}(q) =
\\sum_{k=0}^{n_b-1} b_{ijk} q^{-(n_{k,ij}+k)}$ (MATLAB's meaning: $n_b$ coefficients after a delay
of $n_k$ samples), and monic $C_i$, $D_i$, $F_{ij}$. Signals are deviations from the operating
point `(u0, y0)` and zero before $t = 0$; `simulate(u)` returns absolute outputs.

Stability: the fitting code (`jthermo.identify.polynomial`) parametrises every monic C, D and F
polynomial by reflection coefficients $\\kappa = \\tanh\\rho$ (Schur–Cohn step-up recursion,
`poly_from_reflection`), so returned C, D and F are stable by construction; A (ARX, ARMAX) is
free and its stability is not enforced.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import ModelError
from ._base import AbstractModel, StateSpace
from .filters import (
    ar_filter as ar_filter,
    companion_free_response as companion_free_response,
    ar_matrix_filter as ar_matrix_filter,
    as_nk as as_nk,
    delay_onehot as delay_onehot,
    fir_monic as fir_monic,
    lagged as lagged,
    poly_from_reflection as poly_from_reflection,
    polymul as polymul,
    rational_sum as rational_sum,
    reflection_from_poly as reflection_from_poly,
    stabilize as stabilize,
)



def placed(x, dtype=None) -> Array:
    """`jnp.asarray(x, dtype)` by a transfer from NumPy: with JAX 0.10 `jnp.asarray` of a host
    array compiles a small XLA program per shape and dtype, `jax.device_put` compiles nothing."""
    return jax.device_put(np.asarray(x, dtype))


def _zeros(shape, dtype) -> Array:
    return placed(np.zeros(shape, dtype))


class Polynomial(AbstractModel):
    """MIMO polynomial model $A y = \\frac{B}{F} u(t-n_k) + \\frac{C}{D} e$ (ARX, ARMAX, OE, BJ).

    **Fields** (coefficients exclude the first coefficient, 1, of monic polynomials):
    - `a`: `(ny, m, na)` with m = ny for a full A, m = 1 for a diagonal A (own output only).
    - `b`: `(ny, nu, nb)`; `c`: `(ny, nc)`; `d`: `(ny, nd)`; `f`: `(ny, nu, nf)`.
    - `u0`, `y0`: the operating point (power fraction, °C); `nk` `(ny, nu)` delays in samples.
    """

    a: Float[Array, "ny m na"]
    b: Float[Array, "ny nu nb"]
    c: Float[Array, "ny nc"]
    d: Float[Array, "ny nd"]
    f: Float[Array, "ny nu nf"]
    u0: Float[Array, " nu"]
    y0: Float[Array, " ny"]
    nk: tuple[tuple[int, ...], ...] = eqx.field(static=True)
    ts_: float = eqx.field(static=True)

    def __init__(self, a=None, b=None, c=None, d=None, f=None, *, nk=1, ts: float = 1.0,
                 u0=None, y0=None, ny: int | None = None, nu: int | None = None):
        if b is None:
            if ny is None or nu is None:
                raise ModelError("Polynomial: give `b` (ny, nu, nb) or both `ny` and `nu`")
            b = _zeros((ny, nu, 0), float)
        b = jnp.asarray(b)
        if b.ndim != 3:
            raise ModelError(f"Polynomial: `b` must be (ny, nu, nb), got shape {b.shape}")
        ny, nu = b.shape[0], b.shape[1]
        dt = b.dtype if jnp.issubdtype(b.dtype, jnp.floating) else jnp.result_type(float)
        b = b.astype(dt)
        self.b = b
        self.a = _zeros((ny, 1, 0), dt) if a is None else jnp.asarray(a, dt)
        if self.a.ndim == 2:          # (ny, na): diagonal A
            self.a = self.a[:, None, :]
        self.c = _zeros((ny, 0), dt) if c is None else jnp.asarray(c, dt)
        self.d = _zeros((ny, 0), dt) if d is None else jnp.asarray(d, dt)
        self.f = _zeros((ny, nu, 0), dt) if f is None else jnp.asarray(f, dt)
        self.u0 = _zeros(nu, dt) if u0 is None else jnp.asarray(u0, dt)
        self.y0 = _zeros(ny, dt) if y0 is None else jnp.asarray(y0, dt)
        self.nk = as_nk(nk, ny, nu)
        self.ts_ = float(ts)

    def __check_init__(self):
        ny, nu = self.b.shape[0], self.b.shape[1]
        want = {"a": (self.a.shape[:2], [(ny, 1), (ny, ny)]), "c": (self.c.shape[:1], [(ny,)]),
                "d": (self.d.shape[:1], [(ny,)]), "f": (self.f.shape[:2], [(ny, nu)]),
                "u0": (self.u0.shape, [(nu,)]), "y0": (self.y0.shape, [(ny,)])}
        for name, (got, ok) in want.items():
            if tuple(got) not in ok:
                raise ModelError(f"Polynomial: `{name}` has shape {getattr(self, name).shape}, "
                                 f"which does not match b {self.b.shape}")
        if self.full_a and ny > 1 and (self.nd or self.nf):
            raise ModelError("Polynomial: a full A matrix polynomial needs nd = nf = 0")
        if self.nb == 0 and nu > 0 and self.na == 0 and self.nc == 0 and self.nd == 0:
            raise ModelError("Polynomial: the model has no parameters (all orders zero)")

    # -- orders ------------------------------------------------------------------------
    @property
    def na(self) -> int:
        return self.a.shape[2]

    @property
    def nb(self) -> int:
        return self.b.shape[2]

    @property
    def nc(self) -> int:
        return self.c.shape[1]

    @property
    def nd(self) -> int:
        return self.d.shape[1]

    @property
    def nf(self) -> int:
        return self.f.shape[2]

    @property
    def full_a(self) -> bool:
        return self.a.shape[1] > 1 or self.b.shape[0] == 1

    @property
    def orders(self) -> dict[str, int]:
        nk = np.asarray(self.nk)
        return {"na": self.na, "nb": self.nb, "nc": self.nc, "nd": self.nd, "nf": self.nf,
                "nk": int(nk.min()) if nk.size else 0}

    @property
    def ts(self) -> float:
        return self.ts_

    @property
    def n_inputs(self) -> int:
        return self.b.shape[1]

    @property
    def n_outputs(self) -> int:
        return self.b.shape[0]

    @property
    def n_signals(self) -> int:
        return 0

    def a_matrices(self) -> Float[Array, "na ny ny"]:
        """The A polynomial as matrices: $A(q) = I + \\sum_k A_k q^{-k}$, `(na, ny, ny)`."""
        ny = self.n_outputs
        if self.a.shape[1] == ny:
            return jnp.moveaxis(self.a, 2, 0)
        return jnp.einsum("ik,ij->kij", self.a[:, 0, :], jnp.eye(ny, dtype=self.a.dtype))

    def flat_coefficients(self) -> Float[Array, "ny p"]:
        """Per-output coefficient vector `[a (m·na), b (nu·nb), c, d, f (nu·nf)]`; the layout of
        `FitResult.std`."""
        ny = self.n_outputs
        return jnp.concatenate([self.a.reshape(ny, -1), self.b.reshape(ny, -1), self.c, self.d,
                                self.f.reshape(ny, -1)], axis=1)

    # -- filters ------------------------------------------------------------------------
    def _max_lag(self) -> int:
        return max(max(row) for row in self.nk) + max(self.nb, 1) - 1

    def _b_lags(self) -> Float[Array, "ny nu L1"]:
        L = self._max_lag()
        sel = delay_onehot(self.nk, self.nb, L)
        return jnp.einsum("ijk,ijkl->ijl", self.b, jnp.asarray(sel, self.b.dtype))

    def _input_part(self, du: Float[Array, "T nu"]) -> Float[Array, "T ny"]:
        """$\\sum_j B_{ij}/F_{ij}\\, \\tilde u_j$ per output."""
        Ul = lagged(du, self._max_lag())                           # (T, nu, L+1)
        return jax.vmap(rational_sum, in_axes=(None, 0, 0), out_axes=1)(Ul, self._b_lags(), self.f)

    def _as2d(self, x, n, what):
        x = jnp.asarray(x)
        if x.ndim == 1:
            x = x[:, None]
        if x.ndim != 2 or x.shape[1] != n:
            raise ModelError(f"Polynomial: `{what}` must be (T, {n}), got shape {x.shape}")
        return x

    def simulate(self, u, w=None, x0=None):
        """Noise-free simulated outputs (°C) from inputs `u (T, nu)`, at rest at the operating
        point before t = 0, or from the state `x0` of `to_statespace()`. With input
        denominators (the parallel realisation) that is the response from rest plus each
        block's free response (`companion_free_response`): O(nx) per sample instead of the
        dense realisation's O(nx^2), what the least-squares initial state of `compare`
        differentiates nx times."""
        if x0 is None:
            du = self._as2d(u, self.n_inputs, "u") - self.u0
            return self.y0 + ar_matrix_filter(self._input_part(du), self.a_matrices())
        if not self._parallel():
            return self.to_statespace().simulate(u, w, x0)
        T = self._as2d(u, self.n_inputs, "u").shape[0]
        ny, nu = self.n_outputs, self.n_inputs
        den, de = self._parallel_denominators()
        n, m = den.shape[-1] - 1, de.shape[-1] - 1
        x0 = jnp.asarray(x0, self.b.dtype)
        if x0.shape != (ny * nu * n + ny * m,):
            raise ModelError(f"Polynomial.simulate: x0 must have shape ({ny * nu * n + ny * m},), "
                             f"got {x0.shape}")
        # one block row per output: its nu pair blocks, then its noise block, zero-padded to a
        # common size (a padded state starts at 0 and stays 0), so one scan serves them all
        k = max(n, m)
        pad = lambda a: jnp.pad(a, ((0, 0), (0, 0), (0, k - a.shape[-1])))  # noqa: E731
        xb = jnp.concatenate([pad(x0[:ny * nu * n].reshape(ny, nu, n)),
                              pad(x0[ny * nu * n:].reshape(ny, 1, m))], axis=1)
        db = jnp.concatenate([pad(den[:, :, 1:]), pad(de[:, None, 1:])], axis=1)
        free = companion_free_response(xb.reshape(ny * (nu + 1), k), db.reshape(ny * (nu + 1), k),
                                       T, ny)
        return self.simulate(u) + free

    def residuals(self, y, u, w=None, x0=None):
        """One-step prediction errors $\\varepsilon_i = \\frac{D_i}{C_i}\\big((A y)_i - \\sum_j
        \\frac{B_{ij}}{F_{ij}} u_j\\big)$ (eq. 2.3 of the thesis), zero initial conditions."""
        if x0 is not None:
            return super().residuals(y, u, w, x0)
        dy = self._as2d(y, self.n_outputs, "y") - self.y0
        du = self._as2d(u, self.n_inputs, "u") - self.u0
        Am = self.a_matrices()
        Ay = dy
        if self.na:
            Yl = lagged(dy, self.na)[:, :, 1:]                    # (T, ny, na): lags 1..na
            Ay = dy + jnp.einsum("kij,tjk->ti", Am, Yl)
        v = Ay - self._input_part(du)
        return ar_filter(fir_monic(v, self.d), self.c)

    def predict(self, y, u, w=None, k: int = 1, x0=None):
        if k == 1 and x0 is None:
            return jnp.asarray(y) - self.residuals(y, u)
        return self.to_statespace().predict(y, u, w, k, x0)

    # -- exact state-space realisation -----------------------------------------------------
    def to_statespace(self) -> StateSpace:
        """Exact innovations realisation: with input denominators F (OE, BJ) one small block
        per input-output pair and one noise block per output (`_parallel_statespace`);
        otherwise observer canonical form per output for a diagonal A, and input/noise block
        plus output-shift states for a full A."""
        ny, nu = self.n_outputs, self.n_inputs
        dt = self.b.dtype
        L = self._max_lag()
        bl = self._b_lags()                                               # (ny, nu, L+1)
        one = jnp.ones((ny, 1), dt)
        if self._parallel():
            return self._parallel_statespace()
        if not self.full_a or ny == 1:
            # per output: den = A_i D_i prod_j F_ij ; num_j = B_ij D_i prod_{l!=j} F_il ;
            # num_e = C_i prod_j F_ij
            Ai = jnp.concatenate([one, self.a[:, 0, :]], axis=1)
            Di = jnp.concatenate([one, self.d], axis=1)
            Ci = jnp.concatenate([one, self.c], axis=1)
            Fij = jnp.concatenate([jnp.ones((ny, nu, 1), dt), self.f], axis=2)
            Fall = jnp.ones((ny, 1), dt)
            for j in range(nu):
                Fall = polymul(Fall, Fij[:, j])
            den = polymul(polymul(Ai, Di), Fall)
            nums = []
            for j in range(nu):
                pj = polymul(bl[:, j], Di)
                for l in range(nu):
                    if l != j:
                        pj = polymul(pj, Fij[:, l])
                nums.append(pj)
            ne = polymul(Ci, Fall)
            n = max(den.shape[1], ne.shape[1], *(p.shape[1] for p in nums)) - 1
            pad = lambda p: jnp.pad(p, ((0, 0), (0, n + 1 - p.shape[1])))  # noqa: E731
            den, ne = pad(den), pad(ne)
            num = jnp.stack([pad(p) for p in nums], axis=1)                 # (ny, nu, n+1)
            if n == 0:
                A = jnp.zeros((0, 0), dt)
                return StateSpace(A, jnp.zeros((0, nu), dt), jnp.zeros((ny, 0), dt),
                                  num[:, :, 0], jnp.zeros((0, ny), dt), ts=self.ts_,
                                  u0=self.u0, y0=self.y0)
            # observer canonical form of each MISO row
            shift = jnp.eye(n, k=1, dtype=dt)
            Ablk = shift[None] - den[:, 1:, None] * jnp.eye(n, dtype=dt)[0][None, None, :]
            Bblk = num[:, :, 1:] - den[:, None, 1:] * num[:, :, :1]          # (ny, nu, n)
            Kblk = ne[:, 1:] - den[:, 1:]                                     # (ny, n)
            eye = jnp.eye(ny, dtype=dt)
            A = jnp.einsum("ij,ikl->ikjl", eye, Ablk).reshape(ny * n, ny * n)
            B = jnp.swapaxes(Bblk, 1, 2).reshape(ny * n, nu)
            K = jnp.einsum("ij,ik->ikj", eye, Kblk).reshape(ny * n, ny)
            C = jnp.einsum("ij,k->ijk", eye, jnp.eye(n, dtype=dt)[0]).reshape(ny, ny * n)
            D = num[:, :, 0]
            return StateSpace(A, B, C, D, K, ts=self.ts_, u0=self.u0, y0=self.y0)
        # full A (nd = nf = 0): z = B u + C e realised per output with den = 1, then
        # y(t) = z(t) - sum_k A_k y(t-k) with states s = [y(t-1); ...; y(t-na)]
        m = max(L, self.nc)
        na = self.na
        if m > 0:
            num = jnp.pad(bl, ((0, 0), (0, 0), (0, m - L)))                  # (ny, nu, m+1)
            ce = jnp.pad(self.c, ((0, 0), (0, m - self.nc)))                 # (ny, m)
            shift = jnp.eye(m, k=1, dtype=dt)
            eye = jnp.eye(ny, dtype=dt)
            Aw = jnp.kron(eye, shift)
            Bwu = jnp.swapaxes(num[:, :, 1:], 1, 2).reshape(ny * m, nu)
            Kw = jnp.einsum("ij,ik->ikj", eye, ce).reshape(ny * m, ny)
            Cw = jnp.einsum("ij,k->ijk", eye, jnp.eye(m, dtype=dt)[0]).reshape(ny, ny * m)
        else:
            Aw = jnp.zeros((0, 0), dt)
            Bwu = jnp.zeros((0, nu), dt)
            Kw = jnp.zeros((0, ny), dt)
            Cw = jnp.zeros((ny, 0), dt)
        Dwu = bl[:, :, 0]
        nw = Aw.shape[0]
        ns = ny * na
        Abar = jnp.moveaxis(self.a_matrices(), 0, 1).reshape(ny, ns)        # [A_1 ... A_na]
        E = jnp.zeros((ns, ny), dt).at[:ny].set(jnp.eye(ny, dtype=dt))
        S = jnp.eye(ns, k=-ny, dtype=dt)
        A = jnp.block([[Aw, jnp.zeros((nw, ns), dt)], [E @ Cw, S - E @ Abar]])
        B = jnp.concatenate([Bwu, E @ Dwu], axis=0)
        K = jnp.concatenate([Kw, E], axis=0)
        C = jnp.concatenate([Cw, -Abar], axis=1)
        return StateSpace(A, B, C, Dwu, K, ts=self.ts_, u0=self.u0, y0=self.y0)

    def _parallel(self) -> bool:
        """Realised in parallel blocks (`_parallel_statespace`): input denominators, diagonal A."""
        return bool(self.nf) and (not self.full_a or self.n_outputs == 1)

    def _parallel_denominators(self):
        """Block denominators of `_parallel_statespace`: pairs $A_i F_{ij}$ `(ny, nu, n+1)`
        (padded to the largest input lag) and noise $A_i D_i$ `(ny, m+1)` (padded to $C_i$)."""
        ny, nu = self.n_outputs, self.n_inputs
        dt = self.b.dtype
        one = jnp.ones((ny, 1), dt)
        Ai = jnp.concatenate([one, self.a[:, 0, :]], axis=1)                  # (ny, na+1)
        Fij = jnp.concatenate([jnp.ones((ny, nu, 1), dt), self.f], axis=2)
        den = polymul(Ai[:, None, :], Fij)                                   # (ny, nu, na+nf+1)
        n = max(self._max_lag(), den.shape[2] - 1)
        den = jnp.pad(den, ((0, 0), (0, 0), (0, n + 1 - den.shape[2])))
        de = polymul(Ai, jnp.concatenate([one, self.d], axis=1))             # (ny, na+nd+1)
        m = max(de.shape[1], self.nc + 1) - 1
        return den, jnp.pad(de, ((0, 0), (0, m + 1 - de.shape[1])))

    def _parallel_statespace(self) -> StateSpace:
        """Parallel realisation of a diagonal-A row with input denominators: pair (i, j) is an
        observer canonical block of $B_{ij}/(A_i F_{ij})$, output i's noise block realises
        $C_i/(A_i D_i)$ (innovations gain). A common denominator $A_i D_i \\prod_j F_{ij}$ would
        multiply up to `nu` nearly equal poles (every heater of a zone sees the zone's time
        constant), whose companion matrix has eigenvalues that rounding moves by
        $\\epsilon^{1/nu}$: outside the unit circle at 16 inputs."""
        ny, nu = self.n_outputs, self.n_inputs
        dt = self.b.dtype
        L = self._max_lag()
        one = jnp.ones((ny, 1), dt)
        den, de = self._parallel_denominators()
        n = den.shape[2] - 1
        num = jnp.pad(self._b_lags(), ((0, 0), (0, 0), (0, n - L)))          # (ny, nu, n+1)
        P = ny * nu
        e0 = jnp.eye(n, dtype=dt)[0]
        Ablk = jnp.eye(n, k=1, dtype=dt)[None] - den.reshape(P, n + 1)[:, 1:, None] * e0[None, None, :]
        Ap = jnp.einsum("pq,pkl->pkql", jnp.eye(P, dtype=dt), Ablk).reshape(P * n, P * n)
        Bblk = num[:, :, 1:] - den[:, :, 1:] * num[:, :, :1]                  # (ny, nu, n)
        Bp = jnp.einsum("ijk,jl->ijkl", Bblk, jnp.eye(nu, dtype=dt)).reshape(P * n, nu)
        Cp = jnp.einsum("iq,jk->iqjk", jnp.eye(ny, dtype=dt),
                        jnp.broadcast_to(e0, (nu, n))).reshape(ny, P * n)
        # noise block of each output: C_i / (A_i D_i), observer canonical with gain K
        m = de.shape[1] - 1
        ce = jnp.pad(jnp.concatenate([one, self.c], axis=1), ((0, 0), (0, m - self.nc)))
        eye = jnp.eye(ny, dtype=dt)
        if m:
            em = jnp.eye(m, dtype=dt)[0]
            Aeb = jnp.eye(m, k=1, dtype=dt)[None] - de[:, 1:, None] * em[None, None, :]
            Ae = jnp.einsum("ij,ikl->ikjl", eye, Aeb).reshape(ny * m, ny * m)
            Ke = jnp.einsum("ij,ik->ikj", eye, ce[:, 1:] - de[:, 1:]).reshape(ny * m, ny)
            Ce = jnp.einsum("ij,k->ijk", eye, em).reshape(ny, ny * m)
        else:
            Ae, Ke, Ce = (jnp.zeros((0, 0), dt), jnp.zeros((0, ny), dt), jnp.zeros((ny, 0), dt))
        ne = Ae.shape[0]
        A = jnp.block([[Ap, jnp.zeros((P * n, ne), dt)], [jnp.zeros((ne, P * n), dt), Ae]])
        B = jnp.concatenate([Bp, jnp.zeros((ne, nu), dt)], axis=0)
        K = jnp.concatenate([jnp.zeros((P * n, ny), dt), Ke], axis=0)
        C = jnp.concatenate([Cp, Ce], axis=1)
        return StateSpace(A, B, C, num[:, :, 0], K, ts=self.ts_, u0=self.u0, y0=self.y0)


def ARX(a, b, *, nk=1, ts: float = 1.0, u0=None, y0=None) -> Polynomial:
    """$A(q) y = B(q) u(t-n_k) + e$; `a` `(ny, na)` diagonal or `(ny, ny, na)` full."""
    return Polynomial(a=a, b=b, nk=nk, ts=ts, u0=u0, y0=y0)


def ARMAX(a, b, c, *, nk=1, ts: float = 1.0, u0=None, y0=None) -> Polynomial:
    """$A(q) y = B(q) u(t-n_k) + C(q) e$."""
    return Polynomial(a=a, b=b, c=c, nk=nk, ts=ts, u0=u0, y0=y0)


def OE(b, f, *, nk=1, ts: float = 1.0, u0=None, y0=None) -> Polynomial:
    """$y = \\frac{B(q)}{F(q)} u(t-n_k) + e$; `f` `(ny, nu, nf)`."""
    return Polynomial(b=b, f=f, nk=nk, ts=ts, u0=u0, y0=y0)


def BoxJenkins(b, c, d, f, *, nk=1, ts: float = 1.0, u0=None, y0=None) -> Polynomial:
    """$y = \\frac{B(q)}{F(q)} u(t-n_k) + \\frac{C(q)}{D(q)} e$."""
    return Polynomial(b=b, c=c, d=d, f=f, nk=nk, ts=ts, u0=u0, y0=y0)


BJ = BoxJenkins

__all__ = ["placed", "Polynomial", "ARX", "ARMAX", "OE", "BoxJenkins", "BJ", "poly_from_reflection",
           "reflection_from_poly", "stabilize", "ar_filter", "ar_matrix_filter", "fir_monic", "lagged",
           "rational_sum", "as_nk", "delay_onehot"]
