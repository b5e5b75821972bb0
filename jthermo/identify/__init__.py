"""Estimation: PEM, ARX least squares, subspace initialisation, orders, covariance."""
