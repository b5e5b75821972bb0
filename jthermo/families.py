"""Names shared by the library and the CLI, kept free of JAX so `jthermo --help` stays fast."""

#: model families `jthermo.identify.fit` accepts
MODEL_FAMILIES = ("arx", "armax", "oe", "bj", "ss", "greybox")

#: MATLAB's order of the `orders` tuple (`--orders` on the CLI) for each model family
ORDER_NAMES = {
    "arx": ("na", "nb", "nk"),
    "armax": ("na", "nb", "nc", "nk"),
    "oe": ("nb", "nf", "nk"),
    "bj": ("nb", "nc", "nd", "nf", "nk"),
    "ss": ("n",),
    "greybox": (),
}

#: closed-loop scenarios `jthermo.closedloop.make_scenario` builds (`jthermo simulate --scenario`)
SCENARIO_KINDS = ("tracking", "powder", "print", "preheat", "ensemble", "load")
#: the scenarios of a fitted model's own plant (`closedloop.model_scenario`): `powder` and
#: `print` belong to the virtual printer; `load` (input-referred load steps) to fitted models
MODEL_SCENARIO_KINDS = ("tracking", "load", "preheat", "ensemble")
