"""Model validation: fit %, residual tests, spectral estimates, responses, poles/zeros, RGA,
physical plausibility (does a heater step move each sensor the way heat does).

Works with any `AbstractModel`; everything linear goes through the model's own `simulate`,
`predict`, `frequency_response`, `step_response` and `dcgain`, and the state space only where
a structural property (transmission zeros) needs it. Mirrors MATLAB's `compare`, `resid`,
`spa`, `bode`, `pzmap` and `stepinfo` (Ljung 1999, ch. 16).

Array results of the reporting functions are NumPy (host side, for JSON and plots);
`fit_percent`, `rga` and `information_criteria` are plain `jnp` and work under `jit`.
"""

from .simulation import (
    compare as compare, correlations as correlations,
    estimate_initial_state as estimate_initial_state, fit_percent as fit_percent,
    level_offset_notes as level_offset_notes, level_offsets as level_offsets,
    residual_tests as residual_tests,
)
from .properties import (
    bode as bode, information_criteria as information_criteria, poles_zeros as poles_zeros,
    rga as rga, spectral_estimate as spectral_estimate, steady_state_rga as steady_state_rga,
    step_info as step_info,
)
from .plausibility import check_fit as check_fit, plausibility as plausibility

__all__ = [
    "bode",
    "check_fit",
    "compare",
    "correlations",
    "estimate_initial_state",
    "fit_percent",
    "information_criteria",
    "level_offset_notes",
    "level_offsets",
    "plausibility",
    "poles_zeros",
    "residual_tests",
    "rga",
    "spectral_estimate",
    "steady_state_rga",
    "step_info",
]
