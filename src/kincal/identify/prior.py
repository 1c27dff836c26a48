"""Gaussian priors on parameters: the MAP problem's extra rows and its noise scale.

``prior={name or pattern: s}`` adds, for every *estimated* parameter it names, the
pseudo-observation ``(theta_j - c_j) / s_j`` to the whitened residuals (``c_j`` the
parameter's value before calibration), so the minimiser is the maximum a-posteriori
estimate under ``theta_j ~ N(c_j, s_j^2)``.  :class:`WithPrior` is the stacked problem with
those rows after the measurements'; :func:`noise_scale` the measurements' ``sigma0`` at a
MAP solution,

    sigma0^2 = sum_i w_i r_i^2 / (M - p_eff),
    p_eff = p - sum_j [(J_a^T J_a)^-1]_jj sigma0^2 / s_j^2,

(``J_a`` the augmented whitened Jacobian); :func:`data_only_std` the standard errors the
measurements alone give, ``sigma0 sqrt(diag (J^T J)^-1)``.  See
:mod:`kincal.identify.solver` ("Prior") for how the solver weighs them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from kincal.errors import IdentifiabilityError, KincalError
from kincal.identify.names import match_names
from kincal.identify.robust import RobustLoss
from kincal.identify.uncertainty import inverse_normal_matrix, standard_errors
from kincal.measure.base import CompressedSystem, StackedProblem
from kincal.robots.chain import Robot

Array = NDArray[np.float64]


class WithPrior:
    """A stacked problem with prior rows ``(theta_j - c_j) / s_j`` appended (j in ``idx``).

    Offers the two methods the iteration uses (``residuals``, ``compressed``); with an
    empty ``idx`` it is the problem itself.
    """

    def __init__(self, prob: StackedProblem, idx: Sequence[int], sigma: Array,
                 center: Array) -> None:
        self.prob = prob
        self.idx = np.asarray(idx, dtype=np.intp)
        self.inv = 1.0 / np.asarray(sigma, dtype=float)
        self.center = center[self.idx]
        # the measurements' triangles (no prior rows) of the last two builds, by theta
        self._data: list[tuple[Array, CompressedSystem]] = []

    @property
    def rows(self) -> int:
        return len(self.idx)

    def _prior(self, theta: Array) -> Array:
        return (theta[self.idx] - self.center) * self.inv

    def residuals(self, theta: Array) -> Array:
        """The measurements' residuals with the prior rows after them (one vector)."""
        if not self.rows:
            return self.prob.residuals(theta)
        r = self.prob.residuals(theta, spare_rows=self.rows)
        r[-self.rows:] = self._prior(theta)
        return r

    def compressed(self, theta: Array, weights: Array, columns: Sequence[int]
                   ) -> CompressedSystem:
        """The weighted problem over ``columns`` as a QR triangle: the measurements
        compressed piece by piece (:meth:`StackedProblem.compressed`), then the prior
        rows folded in (``weights``: measurements, then prior rows, which have 1)."""
        M = len(weights) - self.rows
        # the residual vector has room for the prior rows: extend writes them, no copy
        data = self.prob.compressed(theta, weights[:M], columns, spare_rows=self.rows)
        if self.rows:
            self._data = [*self._data[-1:], (theta.copy(), dataclasses.replace(data, r=None))]
        return self.extend(data, theta)

    def num_residuals(self) -> int:
        """Measurement residuals and prior rows."""
        return self.prob.num_residuals() + self.rows

    def measurements_at(self, theta: Array) -> CompressedSystem | None:
        """The measurements' own triangle (no prior rows, without ``r``) of a recent
        :meth:`compressed` at ``theta``, if there was one."""
        for t, c in self._data:
            if np.array_equal(t, theta):
                return c
        return None

    def extend(self, c: CompressedSystem, theta: Array) -> CompressedSystem:
        """The measurements' triangle ``c`` with the prior rows (weight 1) folded in."""
        if not self.rows:
            return c
        pos = {int(j): k for k, j in enumerate(c.columns)}
        A = np.zeros((self.rows, len(pos)))
        for k, j in enumerate(self.idx):
            A[k, pos[int(j)]] = self.inv[k]
        prior = self._prior(theta)
        out = dataclasses.replace(c, r=None).with_rows(A, prior)
        if c.r is None:
            return out
        M = self.prob.num_residuals()
        if c.r.size == M + self.rows:          # room left for the prior rows (compressed)
            r = c.r
            r[M:] = prior
        else:
            r = np.concatenate([c.r, prior])
        return dataclasses.replace(out, r=r)


def tolerance_prior(robot: Robot, prob: StackedProblem, which: str) -> dict[str, float]:
    """``prior="tolerances"``: ``{name: tolerance}`` of the problem's robot parameters."""
    from kincal.identify.tolerances import resolve_tolerances

    if which != "tolerances":
        raise KincalError(f"prior must be a mapping {{name: sigma}}, 'tolerances' or None; "
                          f"got {which!r}")
    meta = getattr(robot, "meta", {}) or {}
    return resolve_tolerances(prob.names, prob.units, prob.roles,
                              meta.get("tolerances"), None).prior()


def prior_sigmas(names: Sequence[str], prior: Mapping[str, float] | None) -> dict[int, float]:
    """``{parameter index: sigma}`` from ``{name or pattern: sigma}`` (later keys win)."""
    out: dict[int, float] = {}
    for pattern, sigma in (prior or {}).items():
        s = float(sigma)
        if not (np.isfinite(s) and s > 0):
            raise KincalError(f"prior standard deviation of {pattern!r} must be positive and "
                              f"finite, got {sigma!r}")
        for i in match_names(names, pattern):
            out[i] = s
    return out


def noise_scale(aug: WithPrior, r: Array, data: CompressedSystem, theta: Array,
                loss: RobustLoss) -> tuple[float | None, float | None]:
    """The measurements' noise scale ``sigma0`` at a MAP solution, and ``p_eff``.

    ``sigma0^2 = sum w r^2 / (M - p_eff)`` over the measurement rows,
    ``p_eff = p - sum_j [(J_a^T J_a)^-1]_jj (scale / s_j)^2`` (``J_a``: ``data`` with the
    prior rows of ``aug``, whose weights are ``scale / s_j``, the scale they were weighed
    with).  None when there is no
    redundancy left.
    """
    M = len(r) - aug.rows
    w = loss.weights(r, aug.rows)[:M]
    ss = float(np.sum(w * r[:M] ** 2))
    try:
        inv = inverse_normal_matrix(aug.extend(data, theta).R)
    except IdentifiabilityError:
        return None, None
    pos = {int(j): k for k, j in enumerate(data.columns)}
    shrink = sum(inv[pos[int(j)], pos[int(j)]] * aug.inv[k] ** 2
                 for k, j in enumerate(aug.idx))
    p_eff = len(data.columns) - float(shrink)
    if M - p_eff <= 0 or ss <= 0:
        return None, p_eff
    return float(np.sqrt(ss / (M - p_eff))), p_eff


def data_only_std(R: Array, sigma0: float) -> Array:
    """``sigma0 sqrt(diag (R^T R)^-1)``: the standard errors the measurements alone give
    (inf for parameters in a direction they cannot see)."""
    try:
        return sigma0 * standard_errors(inverse_normal_matrix(R))
    except IdentifiabilityError:
        D = np.linalg.norm(R, axis=0)
        D = np.where(D > 0, D, 1.0)
        _, S, Vt = np.linalg.svd(R / D, full_matrices=False)
        ok = S > S[0] * 1e-12 if S.size else S > 0
        var = np.sum((Vt[ok].T / S[ok]) ** 2, axis=1)
        blind = np.any(np.abs(Vt[~ok]) > 1e-8, axis=0)
        return np.where(blind, np.inf, sigma0 * np.sqrt(var) / D)
