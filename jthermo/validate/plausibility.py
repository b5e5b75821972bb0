"""Physical plausibility of a fitted thermal model: the checks live in
`jthermo.models.plausibility` (the fit chooses among plausible candidates with them); this
module keeps the validation layer's name for them."""

from ..models.plausibility import (  # noqa: F401
    MAX_SAMPLES, MAX_WORK, MIN_SAMPLES, NOISE_SIGMAS, RELATIVE_FLOOR, TIME_CONSTANTS, check_fit,
    plausibility, step_responses, window, window_length,
)
