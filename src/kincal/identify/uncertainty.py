"""How certain is a calibration?  Covariance, Cramér-Rao bound, standard errors.

For whitened residuals ``r = (model - observed) / sigma`` with Jacobian ``J`` (M, p)
over the estimated parameters, the least-squares estimate has, to first order,

    Cov(theta_hat) = sigma0^2 (J^T J)^-1

where ``sigma0^2`` is the variance factor: 1 when the stated sigmas are trusted
(then this is the Cramér-Rao bound for Gaussian noise), or the a-posteriori estimate
``sigma0^2 = r^T r / (M - p)`` (the default of the solver: it makes the reported
uncertainty honest when the stated sigmas are only nominal).  ``(J^T J)^-1`` is
computed from the SVD of ``J`` with unit-norm columns, ``J D^-1 = U S V^T``:
``(J^T J)^-1 = D^-1 V S^-2 V^T D^-1``, which stays accurate for condition numbers
up to ~1e8.

Propagating the covariance to predicted positions is
:mod:`kincal.identify.accuracy`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import IdentifiabilityError
from kincal.measure.base import svd_thin

Array = NDArray[np.float64]

__all__ = ["covariance", "standard_errors", "correlation", "cramer_rao",
           "inverse_normal_matrix", "propagated_variance"]


def inverse_normal_matrix(J: ArrayLike, rcond: float = 1e-12) -> Array:
    """``(J^T J)^-1`` through the SVD of the column-scaled ``J``.

    Raises :class:`IdentifiabilityError` if ``J`` is rank deficient (scaled singular
    values below ``rcond`` times the largest); callers pass only identifiable columns.
    """
    J = np.asarray(J, dtype=float)
    p = J.shape[1]
    if p == 0:
        return np.zeros((0, 0))
    D = np.linalg.norm(J, axis=0)
    if np.any(D == 0):
        raise IdentifiabilityError(f"column {int(np.argmin(D))} of the Jacobian is zero: the "
                                   "covariance does not exist")
    _, S, Vt = svd_thin(J / D)
    if S[-1] <= rcond * S[0]:
        raise IdentifiabilityError("the Jacobian is rank deficient: the covariance does not "
                                   "exist (run the identifiability analysis first)")
    W = Vt.T / S
    return (W @ W.T) / np.outer(D, D)


def covariance(J_whitened: ArrayLike, sigma0: float = 1.0) -> Array:
    """Parameter covariance ``sigma0^2 (J^T J)^-1`` [units^2 of the parameters]."""
    return float(sigma0) ** 2 * inverse_normal_matrix(J_whitened)


def cramer_rao(J_whitened: ArrayLike) -> Array:
    """Cramér-Rao bound ``(J^T J)^-1`` for Gaussian noise with the stated sigmas."""
    return inverse_normal_matrix(J_whitened)


def standard_errors(cov: ArrayLike) -> Array:
    """Standard errors ``sqrt(diag(Cov))`` (negative round-off clipped to 0)."""
    out: Array = np.sqrt(np.clip(np.diag(np.asarray(cov, dtype=float)), 0.0, None))
    return out


def correlation(cov: ArrayLike) -> Array:
    """Correlation matrix ``C_ij / sqrt(C_ii C_jj)`` (0 where a variance is 0)."""
    cov = np.asarray(cov, dtype=float)
    s = standard_errors(cov)
    with np.errstate(invalid="ignore", divide="ignore"):
        C = cov / np.outer(s, s)
    C = np.where(np.outer(s, s) > 0, C, 0.0)
    np.fill_diagonal(C, np.where(s > 0, 1.0, 0.0))
    return C


def propagated_variance(G: ArrayLike, cov: ArrayLike) -> Array:
    """``trace(G_n C G_n^T)`` for every leading index ``n``: the summed variance of the
    quantities ``y_n = G_n theta`` (``G`` (..., r, p), ``C`` (p, p)) -> (...).

    One matrix product ``G C`` and a row-wise dot, ``sum_iq (G C)_iq G_iq``: a three-way
    ``einsum`` of the same sum is evaluated term by term, several times slower.
    """
    G = np.asarray(G, dtype=float)
    out: Array = np.einsum("...ip,...ip->...", G @ np.asarray(cov, dtype=float), G)
    return out
