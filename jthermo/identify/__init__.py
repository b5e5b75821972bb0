"""Estimation: PEM, ARX least squares, subspace initialisation, orders, covariance.

Modules, bottom up: `arx`, `pem`, `lm` (solvers and least squares), `operating_point`, `result`
(`FitResult`, the family registry), `subspace`, `polynomial`, `statespace`, `greybox` (the
fitters), `orders` (order selection), `fit` (the dispatcher `fit`).
"""

from .statespace import fit_statespace as fit_statespace
from .subspace import choose_order as choose_order, n4sid as n4sid
from .arx import arx_ls as arx_ls
from .fit import FitResult as FitResult, fit as fit, fit_polynomial as fit_polynomial
from .greybox import fit_greybox as fit_greybox
from .lm import masked_lm as masked_lm
from .orders import estimate_delays as estimate_delays, select_orders as select_orders
from .pem import PEMResult as PEMResult, minimize as minimize, minimize_many as minimize_many
