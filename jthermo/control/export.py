"""Controllers as code a printer runs: plain coefficient tables (`tables`, `to_json`) and a
dependency-free C99 header + source (`to_c`) with one step function,

    void NAME_init(NAME_state *s, const double *y0, const double *r0);
    void NAME_step(NAME_state *s, const double *y, const double *r, const double *schedule,
                   double *u);

double precision, no allocation, the state in a caller-owned struct, saturation to [0, 1] and
anti-windup exactly as the JAX controller does them (the same operations in the same order:
a closed-loop replay matches to ~1e-15). `schedule` is the event row of
`closedloop.Scenario.s` (`[recoat, exposure 1..N]`; may be NULL for controllers without a
schedule feed-forward, and means no events for those with one).

Exported families: `DiagonalPI` (every anti-windup and discretisation, set-point weight $b$),
`DiagonalPID` (`pid_relay`: filtered derivative on the measurement, clamping, $b$), `DecoupledPI` and
`MIMOPI` (as the MIMO PI law $u = u_0 + K_p e + I$, $I \\mathrel{+}= K_i e$, back-calculation),
`LQG` (observer, integrators, reference model; the gains of its current weights), and
`ScheduleFF` around a MIMO PI or an LQG.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError, ControlError
from ._base import U_MAX, U_MIN
from .decoupled import DecoupledPI
from .lqg import LQG
from .mimo_pi import MIMOPI, mimo_from
from .pi import DiagonalPI
from .relay import DiagonalPID
from .schedule_ff import ScheduleFF

FORMAT = "jthermo-controller-tables/1"


def _arr(x) -> np.ndarray:
    return np.asarray(x, np.float64)


def _feedback_tables(ctrl) -> dict:
    if isinstance(ctrl, DecoupledPI):
        ctrl = mimo_from(ctrl)
    if isinstance(ctrl, MIMOPI):
        kp, ki = ctrl.gains()
        return {"kind": "mimo_pi", "ts": ctrl.ts, "n": ctrl.zones,
                "tables": {"Kp": _arr(kp), "Ki": _arr(ki), "u0": _arr(ctrl.u0)}}
    if isinstance(ctrl, DiagonalPI):
        tt = ctrl.tt if ctrl.tt is not None else None
        t = {"kp": _arr(ctrl.kp), "ti": _arr(ctrl.ti), "u0": _arr(ctrl.u0), "b": _arr(ctrl.b)}
        if ctrl.antiwindup == "backcalc":
            t["tt"] = _arr(jnp.sqrt(ctrl.ti * ctrl.ts)) if tt is None else np.full(ctrl.zones, tt)
        return {"kind": "diagonal_pi", "ts": ctrl.ts, "n": ctrl.zones, "tables": t,
                "antiwindup": ctrl.antiwindup, "method": ctrl.method,
                "u_min": ctrl.u_min, "u_max": ctrl.u_max}
    if isinstance(ctrl, DiagonalPID):
        t = {"kp": _arr(ctrl.kp), "ti": _arr(ctrl.ti), "td": _arr(ctrl.td), "u0": _arr(ctrl.u0),
             "b": _arr(ctrl.b)}
        return {"kind": "diagonal_pid", "ts": ctrl.ts, "n": ctrl.zones, "tables": t,
                "n_filter": ctrl.n_filter, "u_min": ctrl.u_min, "u_max": ctrl.u_max}
    if isinstance(ctrl, LQG):
        g = ctrl.gains()
        A, B = _arr(ctrl.A), _arr(ctrl.B)
        Lx = _arr(g.Lx)
        # the observer's start, x0 = (I - A + B Lx)^-1 B L0 (y0 - y_op): one matrix
        P0 = np.linalg.solve(np.eye(A.shape[0]) - A + B @ Lx, B @ _arr(g.L0))
        alpha = _arr(1.0 - jnp.exp(-ctrl.ts / ctrl.tau_r))
        return {"kind": "lqg", "ts": ctrl.ts, "n": int(B.shape[1]), "nx": int(A.shape[0]),
                "ny": int(ctrl.C.shape[0]),
                "tables": {"A": A, "B": B, "C": _arr(ctrl.C), "Lx": Lx, "Li": _arr(g.Li),
                           "L0": _arr(g.L0), "M": _arr(g.M), "P0": P0, "u_op": _arr(ctrl.u_op),
                           "y_op": _arr(ctrl.y_op), "b0": _arr(ctrl.b0), "alpha": alpha}}
    raise ControlError(f"export: no code export for {type(ctrl).__name__} (exported: "
                       "DiagonalPI, DiagonalPID, DecoupledPI, MIMOPI, LQG, ScheduleFF around "
                       "MIMOPI/LQG)")


def tables(ctrl) -> dict:
    """The controller as plain coefficient tables: `{"format", "kind", "ts", "n", "tables":
    {name: array}, ...}` (`"feedforward"`: the schedule FIR taps, when there is one)."""
    if isinstance(ctrl, ScheduleFF):
        out = _feedback_tables(ctrl.feedback)
        h_rec, h_las = ctrl.effective_taps()
        out["feedforward"] = {"taps": ctrl.taps, "n_schedule": ctrl.n_schedule,
                              "h_recoat": _arr(h_rec), "h_laser": _arr(h_las)}
    else:
        out = _feedback_tables(ctrl)
    for name, a in list(out["tables"].items()) + list((out.get("feedforward") or {}).items()):
        if isinstance(a, np.ndarray) and not np.all(np.isfinite(a)):
            raise ControlError(f"export: coefficient table `{name}` is not finite")
    return {"format": FORMAT, **out}


def to_json(ctrl, path) -> Path:
    """Write `tables(ctrl)` as JSON (arrays as nested lists, row-major)."""
    t = tables(ctrl)

    def plain(x):
        if isinstance(x, np.ndarray):
            return x.tolist()
        if isinstance(x, dict):
            return {k: plain(v) for k, v in x.items()}
        return x

    path = Path(path)
    path.write_text(json.dumps(plain(t), indent=1) + "\n", encoding="utf-8")
    return path


# ------------------------------------------------------------------------------- C code


def _num(v: float) -> str:
    return repr(float(v)) if math.isfinite(v) else "0.0"


def _c_table(name: str, a: np.ndarray) -> str:
    vals = ", ".join(_num(v) for v in np.asarray(a, np.float64).ravel()) or "0.0"
    size = max(1, int(np.asarray(a).size))
    return f"static const double {name}[{size}] = {{{vals}}};"


def _matvec(out: str, M: str, rows: str, cols: str, v: str, acc: str = "=") -> str:
    """`out[i] (acc) sum_j M[i*cols+j] v[j]` as a C loop (the sum from 0, left to right)."""
    return (f"for (int i = 0; i < {rows}; ++i) {{ double t = 0.0; "
            f"for (int j = 0; j < {cols}; ++j) t += {M}[i*{cols}+j] * {v}[j]; "
            f"{out}[i] {acc} t; }}")


def _pi_code(t: dict, p: str) -> tuple[str, str, str]:
    """(state fields, init body, step body) of the PI laws; `uadd` holds the feed-forward."""
    if t["kind"] == "mimo_pi":
        fields = f"double integ[{p}_NU];"
        init = f"for (int i = 0; i < {p}_NU; ++i) s->integ[i] = 0.0;"
        step = f"""double e[{p}_NU], kpe[{p}_NU], kie[{p}_NU];
    for (int i = 0; i < {p}_NU; ++i) e[i] = r[i] - y[i];
    {_matvec("kie", "Ki", f"{p}_NU", f"{p}_NU", "e")}
    {_matvec("kpe", "Kp", f"{p}_NU", f"{p}_NU", "e")}
    for (int i = 0; i < {p}_NU; ++i) {{
        double integ = s->integ[i] + kie[i];
        double v = u0[i] + kpe[i] + integ;
        u[i] = clip(v + uadd[i], {_num(U_MIN)}, {_num(U_MAX)});
        s->integ[i] = integ + (clip(v, {_num(U_MIN)}, {_num(U_MAX)}) - v);
    }}"""
        return fields, init, step
    lo, hi = _num(t["u_min"]), _num(t["u_max"])
    inc = "0.5 * ki * (e + s->err[i])" if t["method"] == "tustin" else "ki * e"
    if t["antiwindup"] == "clamp":
        upd = (f"int wind = (v > {hi} && inc > 0.0) || (v < {lo} && inc < 0.0);\n"
               f"        s->integ[i] = wind ? s->integ[i] : itry;")
    elif t["antiwindup"] == "backcalc":
        upd = f"s->integ[i] = itry + ({_num(t['ts'])} / tt[i]) * (u[i] - v);"
    else:
        upd = "s->integ[i] = itry;"
    fields = f"double integ[{p}_NU]; double err[{p}_NU]; double yref[{p}_NU];"
    init = (f"for (int i = 0; i < {p}_NU; ++i) {{ s->integ[i] = 0.0; "
            f"s->err[i] = (r0 ? r0[i] - y0[i] : 0.0); s->yref[i] = y0[i]; }}")
    step = f"""for (int i = 0; i < {p}_NU; ++i) {{
        double e = r[i] - y[i];
        double ki = kp[i] * {_num(t['ts'])} / ti[i];
        double inc = {inc};
        double itry = s->integ[i] + inc;
        double v = u0[i] + uadd[i] + kp[i] * (e - (1.0 - b[i]) * (r[i] - s->yref[i])) + itry;
        u[i] = clip(v, {lo}, {hi});
        {upd}
        s->err[i] = e;
    }}"""
    return fields, init, step


def _pid_code(t: dict, p: str) -> tuple[str, str, str]:
    """(state fields, init body, step body) of `DiagonalPID`: the same operations in the same
    order as its `step` (the derivative filter, the set-point weight, clamping)."""
    lo, hi, ts = _num(t["u_min"]), _num(t["u_max"]), _num(t["ts"])
    fields = (f"double integ[{p}_NU]; double deriv[{p}_NU]; double yprev[{p}_NU]; "
              f"double yref[{p}_NU];")
    init = (f"for (int i = 0; i < {p}_NU; ++i) {{ s->integ[i] = 0.0; s->deriv[i] = 0.0; "
            f"s->yprev[i] = y0[i]; s->yref[i] = y0[i]; }}")
    step = f"""for (int i = 0; i < {p}_NU; ++i) {{
        double e = r[i] - y[i];
        double inc = kp[i] * ({ts} / ti[i]) * e;
        double tf = td[i] / {_num(t['n_filter'])};
        double d = (tf * s->deriv[i] - kp[i] * td[i] * (y[i] - s->yprev[i])) / (tf + {ts});
        double itry = s->integ[i] + inc;
        double v = u0[i] + uadd[i] + kp[i] * (e - (1.0 - b[i]) * (r[i] - s->yref[i])) + itry + d;
        int wind = (v > {hi} && inc > 0.0) || (v < {lo} && inc < 0.0);
        u[i] = clip(v, {lo}, {hi});
        s->integ[i] = wind ? s->integ[i] : itry;
        s->deriv[i] = d;
        s->yprev[i] = y[i];
    }}"""
    return fields, init, step


def _lqg_code(t: dict, p: str) -> tuple[str, str, str]:
    fields = f"double x[{p}_NX]; double xi[{p}_NY]; double rm[{p}_NY];"
    init = f"""double dy[{p}_NY];
    for (int i = 0; i < {p}_NY; ++i) {{ dy[i] = y0[i] - y_op[i]; s->xi[i] = 0.0; s->rm[i] = y0[i]; }}
    {_matvec("s->x", "P0", f"{p}_NX", f"{p}_NY", "dy")}"""
    step = f"""double innov[{p}_NY], cx[{p}_NY], xf[{p}_NX], ref[{p}_NY], lag[{p}_NY];
    double l0r[{p}_NU], lxx[{p}_NU], lix[{p}_NU], du[{p}_NU], ax[{p}_NX], bu[{p}_NX];
    {_matvec("cx", "C", f"{p}_NY", f"{p}_NX", "s->x")}
    for (int i = 0; i < {p}_NY; ++i) innov[i] = y[i] - y_op[i] - cx[i];
    {_matvec("xf", "M", f"{p}_NX", f"{p}_NY", "innov")}
    for (int i = 0; i < {p}_NX; ++i) xf[i] = s->x[i] + xf[i];
    for (int i = 0; i < {p}_NY; ++i) {{ lag[i] = r[i] - s->rm[i]; ref[i] = r[i] - b0[i] * lag[i] - y_op[i]; }}
    {_matvec("l0r", "L0", f"{p}_NU", f"{p}_NY", "ref")}
    {_matvec("lxx", "Lx", f"{p}_NU", f"{p}_NX", "xf")}
    {_matvec("lix", "Li", f"{p}_NU", f"{p}_NY", "s->xi")}
    double req[{p}_NU];
    for (int i = 0; i < {p}_NU; ++i) {{
        req[i] = u_op[i] + uadd[i] + l0r[i] - lxx[i] - lix[i];
        u[i] = clip(req[i], {_num(U_MIN)}, {_num(U_MAX)});
        du[i] = u[i] - u_op[i];
    }}
    for (int i = 0; i < {p}_NY; ++i) {{
        double e = r[i] - y[i];
        int hold = (req[i] > {_num(U_MAX)} && e > 0.0) || (req[i] < {_num(U_MIN)} && e < 0.0);
        s->xi[i] = hold ? s->xi[i] : s->xi[i] + {_num(t['ts'])} * e;
        s->rm[i] = s->rm[i] + alpha[i] * lag[i];
    }}
    {_matvec("ax", "A", f"{p}_NX", f"{p}_NX", "xf")}
    {_matvec("bu", "B", f"{p}_NX", f"{p}_NU", "du")}
    for (int i = 0; i < {p}_NX; ++i) s->x[i] = ax[i] + bu[i];"""
    return fields, init, step


def to_c(ctrl, out_dir, name: str = "jthermo_ctrl") -> tuple[Path, Path]:
    """Write `out_dir/NAME.h` and `out_dir/NAME.c` (C99, no dependency but `<stddef.h>`;
    `NAME_state_size()` gives `sizeof(NAME_state)` to foreign-function callers).

    **Returns:** the paths of the header and the source.
    """
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,62}", name):
        raise ConfigError(f"export: name must be a C identifier, got {name!r}")
    t = tables(ctrl)
    p = name.upper()
    ff = t.get("feedforward")
    if t["kind"] == "lqg":
        dims = {"NU": t["n"], "NY": t["ny"], "NX": t["nx"]}
        fields, init, step = _lqg_code(t, p)
        if ff:   # the observer predicts with the feedback's part of u (`schedule_ff`)
            step += f"""
    double bff[{p}_NX];
    {_matvec("bff", "B", f"{p}_NX", f"{p}_NU", "uadd")}
    for (int i = 0; i < {p}_NX; ++i) s->x[i] = s->x[i] - bff[i];"""
        if t["ny"] != t["n"]:
            raise ControlError("export: the LQG must have as many outputs as inputs")
    else:
        dims = {"NU": t["n"], "NY": t["n"]}
        fields, init, step = (_pid_code if t["kind"] == "diagonal_pid" else _pi_code)(t, p)
    dims["NS"] = ff["n_schedule"] if ff else 0
    if ff:
        dims["TAPS"] = ff["taps"]
        fields += f" double events[{p}_TAPS * {p}_NS];"
        init += f"\n    for (int k = 0; k < {p}_TAPS * {p}_NS; ++k) s->events[k] = 0.0;"
    tabs = {k: v for k, v in t["tables"].items()}
    if ff:
        tabs.update(h_recoat=ff["h_recoat"], h_laser=ff["h_laser"])
    defines = "\n".join(f"#define {p}_{k} {v}" for k, v in dims.items())
    header = f"""/* {name}.h: a {t['kind']}{' + schedule feed-forward' if ff else ''} controller exported by jthermo.
 * Sample time {_num(t['ts'])} s; y, r in degC; u a power fraction in [0, 1].
 * schedule: {p}_NS doubles per sample [recoat, exposure 1..N] (NULL: no events). */
#ifndef {p}_H
#define {p}_H
#include <stddef.h>
{defines}
#define {p}_TS {_num(t['ts'])}

typedef struct {{ {fields} }} {name}_state;

void {name}_init({name}_state *s, const double *y0, const double *r0);
void {name}_step({name}_state *s, const double *y, const double *r, const double *schedule,
                 double *u);
size_t {name}_state_size(void);   /* sizeof({name}_state), for foreign-function callers */
#endif
"""
    if ff:
        ffcode = f"""/* shift the event history (newest first) and take the FIR of it */
    for (int k = {p}_TAPS - 1; k > 0; --k)
        for (int c = 0; c < {p}_NS; ++c) s->events[k * {p}_NS + c] = s->events[(k - 1) * {p}_NS + c];
    for (int c = 0; c < {p}_NS; ++c) s->events[c] = schedule ? schedule[c] : 0.0;
    for (int i = 0; i < {p}_NU; ++i) {{
        double a = 0.0, b = 0.0;
        for (int k = 0; k < {p}_TAPS; ++k) {{
            a += s->events[k * {p}_NS] * h_recoat[k * {p}_NU + i];
            b += h_laser[k * {p}_NU + i] * s->events[k * {p}_NS + 1 + i];
        }}
        uadd[i] = a + b;
    }}"""
    else:
        ffcode = f"(void)schedule;\n    for (int i = 0; i < {p}_NU; ++i) uadd[i] = 0.0;"
    table_code = "\n".join(_c_table(k, v) for k, v in tabs.items())
    source = f"""/* {name}.c: generated by jthermo (`jthermo export`); do not edit. */
#include <stddef.h>
#include "{name}.h"

{table_code}

static double clip(double v, double lo, double hi) {{ return v < lo ? lo : (v > hi ? hi : v); }}

void {name}_init({name}_state *s, const double *y0, const double *r0) {{
    (void)y0; (void)r0;
    {init}
}}

size_t {name}_state_size(void) {{ return sizeof({name}_state); }}

void {name}_step({name}_state *s, const double *y, const double *r, const double *schedule,
                 double *u) {{
    double uadd[{p}_NU];
    {ffcode}
    {step}
}}
"""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    h, c = out / f"{name}.h", out / f"{name}.c"
    h.write_text(header, encoding="utf-8")
    c.write_text(source, encoding="utf-8")
    return h, c
