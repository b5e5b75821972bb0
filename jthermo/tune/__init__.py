"""End-to-end gradient tuning of controllers over vmapped closed-loop rollouts.

The closed-loop cost over B disturbance rollouts of each test scenario, on one plant or on a
plant ensemble, is differentiated with `eqx.filter_value_and_grad` with respect to every
inexact array leaf of the controller, and minimised with optax Adam in one jitted `make_step`,
or with L-BFGS (`optimiser="lbfgs"`: two-loop recursion and a weak-Wolfe line search, an
optimistix minimiser stepped one compiled evaluation of the fixed batch's cost at a time,
`lbfgs.WolfeLBFGS`, `optimiser.minimise`); the loop over
iterations and the progress report stay outside jit.

The rollouts run on a lean path (`rollout_terms`): one `lax.scan` per rollout that accumulates
the cost terms and the measured-output MSE in its carry, so no `(B, T, n)` trajectory is stored.

Robust objective (`tune(..., normalise=True)`, the default): for every plant $p$ and scenario
$k$, the mean cost $J_{pk}$ and the measured MSE $m_{pk}$ are divided by the best value any
reference design reaches there (the start and, e.g., every classical design), and

$f = \\overline{\\rho^J} + \\overline{\\rho^m}
 + \\tau \\big(\\log \\sum e^{\\rho^m/\\tau} - \\log n\\big)$,
$\\rho^J = \\log J_{pk}/J^*_{pk}$, $\\rho^m = \\log m_{pk}/m^*_{pk}$

is minimised: the mean relative improvement plus a soft maximum of the relative MSE that stops
any scenario (or plant) from being sacrificed for another. A final guard checks the iterates
kept along the way on *validation* seeds (distinct from the training seeds and from
`HELD_OUT`) and returns the best one that beats the references' MSE in every scenario on
every plant without raising the total cost; when none does it returns the starting controller.

Parameters stay valid by construction: every leaf whose entries are all positive at the start
(gains, integral times, filter time constants, LQ weights) is optimised in log space,
$\\theta = e^{z}$, so it stays positive and Adam's steps are relative; other leaves (e.g. a
decoupling matrix with signs) are optimised as they are. Non-finite gradients are zeroed, and
only finite iterates are kept, so tuning never hands back a NaN or diverging controller.

Robustness in the cost (`ms_weight` > 0, PI families): a smooth peak sensitivity on the
design model, penalised above the guard's `ms_max` (`sensitivity.ms_penalty`).
"""

from .optimiser import TuneResult as TuneResult, minimise as minimise
from .terms import (
    batch_terms as batch_terms, group_batch as group_batch, rollout_terms as rollout_terms,
    simulate_terms as simulate_terms,
)
from .training import (
    DURATION as DURATION, HELD_OUT as HELD_OUT, SCENARIOS as SCENARIOS,
    VALIDATION as VALIDATION, batch_cost as batch_cost, make_batches as make_batches,
    plant_ensemble as plant_ensemble, robust_objective as robust_objective, tune as tune,
)
from .report import (
    evaluate as evaluate, printer_model as printer_model, tune_report as tune_report,
    CLASSICAL as CLASSICAL, classical_designs as classical_designs, robustness as robustness,
    held_out_terms as held_out_terms,
)
from .own import (
    OWN_SCENARIOS as OWN_SCENARIOS, classical_at as classical_at, judge as judge,
    tune_own_plant as tune_own_plant,
)
