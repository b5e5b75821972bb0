"""Estimation: PEM, ARX least squares, subspace initialisation, orders, covariance."""

from .statespace import fit_statespace as fit_statespace
from .subspace import choose_order as choose_order, n4sid as n4sid
