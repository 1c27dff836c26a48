"""Robust losses as iteratively reweighted least squares, one weight per measurement.

With ``e_i = sqrt(mean_k r_ik^2)`` the RMS whitened residual of measurement ``i`` (all
residuals of one point / pose share a weight) and ``c = loss_scale * s``, ``s`` a robust
scale (the median of ``e_i`` divided by its value for Gaussian noise, so ``s ~ 1`` when the
stated sigmas are right): Huber ``w = min(1, c / e)``, Cauchy ``w = 1 / (1 + (e / c)^2)``;
loss ``"linear"`` weighs every residual 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.special import gammaincinv

from kincal.measure.base import StackedProblem

Array = NDArray[np.float64]
#: measurement index per residual row
IndexArray = NDArray[np.integer[Any]]


def robust_weights(r: Array, ids: IndexArray | None, dims: Array | None, loss: str,
                   loss_scale: float, n_fixed: int = 0) -> Array:
    """Per-residual IRLS weights from per-measurement RMS whitened residuals.

    The last ``n_fixed`` residuals (prior rows) always weigh 1 and do not enter the
    robust scale.  For ``loss="linear"`` every weight is 1 and the result is a read-only
    view (``ids``, ``dims`` are not needed and may be None).
    """
    if loss == "linear":                  # all ones: a read-only view, no (M,) array
        return np.broadcast_to(np.float64(1.0), np.shape(r))
    assert ids is not None and dims is not None
    if n_fixed:
        w = np.ones_like(r)
        w[:-n_fixed] = robust_weights(r[:-n_fixed], ids, dims, loss, loss_scale)
        return w
    sq = np.bincount(ids, weights=r * r, minlength=len(dims))
    e = np.sqrt(sq / dims)
    # Gaussian reference: median of sqrt(chi2_d / d); the chi-square median with d degrees
    # of freedom is 2 P^-1(d/2, 1/2) (P the regularised lower incomplete gamma function)
    ref = np.sqrt(2.0 * gammaincinv(dims / 2.0, 0.5) / dims)
    s = float(np.median(e / ref))
    if not np.isfinite(s) or s <= 0:
        return np.ones_like(r)
    c = loss_scale * s
    with np.errstate(divide="ignore"):
        if loss == "huber":
            w = np.where(e <= c, 1.0, c / np.maximum(e, 1e-300))
        else:
            w = 1.0 / (1.0 + (e / c) ** 2)
    return np.asarray(w[ids], dtype=np.float64)


@dataclass(frozen=True)
class RobustLoss:
    """A loss with what its weights need: the measurement of every residual row.

    Attributes:
        loss: ``"linear"``, ``"huber"`` or ``"cauchy"``.
        scale: the threshold in units of the robust residual scale.
        ids: measurement index per residual row (None for ``"linear"``).
        dims: residual rows per measurement (None for ``"linear"``).
    """

    loss: str
    scale: float
    ids: IndexArray | None = None
    dims: Array | None = None

    @classmethod
    def of(cls, prob: StackedProblem, loss: str, scale: float) -> RobustLoss:
        """The loss over ``prob``'s measurements (ids and sizes only for a robust one)."""
        ids = prob.measurement_ids() if loss != "linear" else None
        dims = np.bincount(ids).astype(float) if ids is not None else None
        return cls(loss, scale, ids, dims)

    @property
    def linear(self) -> bool:
        """Every weight is 1 whatever the residuals."""
        return self.loss == "linear"

    def weights(self, r: Array, n_fixed: int = 0) -> Array:
        """:func:`robust_weights` of ``r`` (the last ``n_fixed`` rows weigh 1)."""
        return robust_weights(r, self.ids, self.dims, self.loss, self.scale, n_fixed)

    def uniform(self, size: int) -> Array:
        """All-ones weights of ``size`` rows (a read-only view)."""
        return np.broadcast_to(np.float64(1.0), (size,))
