"""The virtual printer's design model for `jthermo simulate`: `tune.printer_model` run as one
stored program, and a stand-in of its shapes on which the run program compiles early.

On a cold cache `simulate` compiles two programs, the design model's and the closed loop's;
`prepare_in_background` overlaps them: a controller designed on `shape_model(printer)` has
the real one's structure, so `closedloop.prepare_run` compiles for it while
`stored_printer_model` computes the real model.
"""

from __future__ import annotations

from .common import require

#: the array fields of the `StateSpace` that `tune.printer_model` returns
_MODEL_FIELDS = ("A", "B", "C", "D", "K", "Bw", "u0", "w0", "y0")


def _printer_model_fields(printer) -> dict:
    """The arrays of `tune.printer_model(printer)` (plain arrays: an exported program's
    output), its `ts` being the printer's."""
    tune = require("jthermo.tune", "the printer's design model")
    model = tune.printer_model(printer)
    return {f: getattr(model, f) for f in _MODEL_FIELDS}


def stored_printer_model(printer):
    """`tune.printer_model(printer)` as one compiled program: called eagerly it dispatches
    many small ones, each traced, lowered and looked up in the cache on every run. It runs
    once, so it is compiled with `runtime.one_shot()` options (-O0), and traced once per
    cache (`stored.exported_call`). Its numbers are a function of the printer and the
    source: kept in the cache too (`stored.cached_arrays`), a warm process neither loads
    nor runs the program."""
    from ..models import StateSpace
    from ..stored import cached_arrays

    fields = cached_arrays(_printer_model_fields, (printer,), printer_model_program)
    return StateSpace(**fields, ts=printer.ts)


def printer_model_program(printer) -> dict:
    """`_printer_model_fields(printer)` run as its exported, -O0 compiled program."""
    import equinox as eqx

    from ..runtime import one_shot
    from ..stored import exported_call

    opts = one_shot()
    return exported_call(_printer_model_fields, (printer,),
                         eqx.filter_jit(_printer_model_fields, compiler_options=opts),
                         compiler_options=opts)


#: families whose controller structure depends on the design model's values, not only its
#: shapes (IMC's static `inverse`: whether the model's zeros are stable): not prepared early
PREPARE_SKIP = ("imc",)


def shape_model(printer):
    """A stand-in for `stored_printer_model(printer)` with its shapes, dtypes and sample time (a
    stable diagonal plant): a controller designed on it has the real one's
    structure, so `closedloop.prepare_run` can compile for it before the real design."""
    import jax
    import numpy as np

    from ..models import StateSpace

    nx, nu, ny = printer.n_states, printer.n_inputs, printer.n_outputs
    # placed on the device as they are (`jnp.asarray` of a NumPy array compiles a small program)
    a = jax.device_put((0.9 * np.eye(nx), 0.1 * np.eye(nx, nu), np.eye(ny, nx),
                        np.zeros((ny, nu)), np.zeros((nx, ny)), np.zeros((nx, 0)),
                        np.full(nu, 0.5), np.zeros(0), np.zeros(ny)))
    return StateSpace(*a[:5], ts=printer.ts, Bw=a[5], u0=a[6], w0=a[7], y0=a[8])


def prepare_in_background(cl, kind: str, family: str, printer, kwargs: dict):
    """A started thread that designs `family` on `shape_model(printer)` and compiles `run`'s
    program for it (`closedloop.prepare_run`): on a cold cache the compile overlaps the
    design model's (`stored_printer_model`). The caller joins it before `run`; a failure there
    only leaves the compile to `run`."""
    import threading

    def work():
        try:
            from ..control.design import design

            proto = design(family, shape_model(printer))
            cl.prepare_run(kind, proto, printer, rollouts=kwargs["rollouts"],
                           duration=kwargs["duration"])
        except Exception:  # noqa: BLE001  (an optimisation only: `run` compiles what it needs)
            pass

    thread = threading.Thread(target=work, name="jthermo-prepare-run", daemon=True)
    thread.start()
    return thread
