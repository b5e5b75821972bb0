"""Model families: polynomial (ARX, ARMAX, OE, BJ), innovations state space, grey-box bed."""

from ._base import AbstractModel as AbstractModel, StateSpace as StateSpace, is_stable as is_stable
from .greybox import BedModel as BedModel, ExtendedBedModel as ExtendedBedModel
from .statespace import InnovationsSS as InnovationsSS
from .polynomial import (
    ARMAX as ARMAX, ARX as ARX, BJ as BJ, OE as OE, BoxJenkins as BoxJenkins,
    Polynomial as Polynomial,
)
from .envelope import (
    Envelope as Envelope, check_reachable as check_reachable,
    equilibrium_input as equilibrium_input, steady_gains as steady_gains,
    steady_output as steady_output,
)
