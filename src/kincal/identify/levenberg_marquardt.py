"""One Levenberg-Marquardt iteration with Marquardt's column scaling.

``(J^T J + lambda D^2) dx = -J^T r``: with the scaled triangle ``A = R D^-1 = U S V^T``
and ``g = U^T z`` the damped step is ``dx = -D^-1 V diag(S_k / (S_k^2 + lambda)) g`` and
the reduction the linear model predicts is
``pred = 1/2 (|g|^2 - sum_k (g_k lambda / (S_k^2 + lambda))^2)``.  The gain ratio
``rho = (cost - cost_new) / pred`` decides: a step is accepted when ``rho > 1e-4``;
``lambda / 10`` when ``rho > 0.75``, ``lambda * 2`` when ``rho < 0.25``; a rejected step
multiplies ``lambda`` by ``nu = 2, 4, 8 ...`` (starting value ``1e-3 S_max^2``).  The
first iteration of a stage, and every one after a very successful step (``rho > 0.75``),
first tries the undamped Gauss-Newton step (a triangular solve when ``A`` is safely
nonsingular) and keeps it when ``rho > 0.25``.  A trial within ``tol_step`` ends the
stage whether it is taken or not: every more damped one is shorter still.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_triangular
from scipy.linalg.lapack import dtrcon

from kincal.identify.linearisation import Linearisation, half_weighted_ss
from kincal.identify.status import StageStatus
from kincal.identify.steps import Step, scaled_step
from kincal.identify.stopping import no_further_decrease

Array = NDArray[np.float64]

#: Largest number of trial steps in one iteration.
MAX_TRIALS = 60


@dataclass
class Damping:
    """The damping state carried from one iteration of a stage to the next.

    Attributes:
        lam: Marquardt's ``lambda`` (negative: not yet set, ``1e-3 S_max^2`` at the
            first iteration).
        nu: the factor of the next increase after a rejected step.
        good: the last step was very successful (``rho > 0.75``): try Gauss-Newton first.
    """

    lam: float = -1.0
    nu: float = 2.0
    good: bool = True


def triangular_step(A: Array, z: Array) -> Array | None:
    """The undamped step ``-A^-1 z`` for the upper-triangular ``A`` (p, p) when ``A`` is
    safely nonsingular, else None.

    "Safely": LAPACK's estimate of the reciprocal 1-norm condition number above
    ``1e-9 p``, so that the 2-norm condition number (at most ``p`` times the 1-norm one)
    stays three orders below the ``1e12`` at which the SVD step drops singular values:
    the step is then the SVD step with every singular value kept.
    """
    p = A.shape[0]
    if p == 0:
        return None
    rcond, info = dtrcon(A)
    if info != 0 or not rcond > 1e-9 * p:
        return None
    dx = np.asarray(solve_triangular(A, -z, check_finite=False), dtype=np.float64)
    return dx if np.all(np.isfinite(dx)) else None


class _DampedSteps:
    """The damped steps of one linearisation: the SVD of ``A`` made once, when needed."""

    def __init__(self, A: Array, z: Array) -> None:
        U, S, Vt = np.linalg.svd(A)
        self.g = U.T @ z
        self.S, self.Vt = S, Vt
        self.S2 = S * S
        self.keep = S > S[0] * 1e-12

    def step(self, lam: float, Ds: Array) -> tuple[Array, float]:
        """``(dx, predicted reduction)`` for the damping ``lam``."""
        S, S2, keep, g = self.S, self.S2, self.keep, self.g
        f = np.where(keep, S / np.where(keep, S2 + lam, 1.0), 0.0)
        dx = -(self.Vt.T @ (f * g)) / Ds
        pred = 0.5 * float(np.sum(g * g) - np.sum(
            np.where(keep, g * lam / (S2 + lam), g) ** 2))
        return dx, pred


def _update(damping: Damping, rho: float) -> None:
    """Marquardt's rule after an accepted damped step, with a fast decrease: a weakly
    determined direction (small singular value) is only reached once lambda is below
    it."""
    damping.good = rho > 0.75
    if rho > 0.75:
        damping.lam = max(damping.lam / 10.0, 1e-300)
    elif rho < 0.25:
        damping.lam *= 2.0
    damping.nu = 2.0


def levenberg_marquardt_step(lin: Linearisation, damping: Damping, A: Array, Ds: Array,
                             z: Array, est: Sequence[int], w: Array, cost: float,
                             tol_step: float) -> Step:
    """The accepted trial of one iteration from ``lin.theta`` over the columns ``est``.

    ``A = R D^-1`` (``Ds`` the scale ``D``), ``z`` the triangle's right-hand side, ``cost``
    the cost at ``lin.theta``; ``damping`` is updated.  The first trial's triangle is built
    (the first trial is usually taken).  ``stop``: ``NO_FURTHER_DECREASE`` (``lambda`` too
    large for any decrease), ``DAMPING_FAILED`` (no acceptable step in ``MAX_TRIALS``),
    ``NO_DESCENT_STEP`` (a step within ``tol_step`` that does not lower the cost).
    """
    if damping.lam < 0:
        S0 = float(np.linalg.svd(A, compute_uv=False)[0]) if A.size else 1.0
        damping.lam = 1e-3 * S0**2
        damping.good = True                 # the first trial is the Gauss-Newton step
    theta = lin.theta
    damped: _DampedSteps | None = None
    # After a very successful step, first try the undamped Gauss-Newton step: in a long
    # curved valley (a weakly determined direction) it saves many iterations.
    try_gn = damping.good
    first = True
    for _ in range(MAX_TRIALS):
        undamped = triangular_step(A, z) if try_gn and damped is None else None
        if undamped is not None:
            dx = undamped / Ds
            pred = 0.5 * float(z @ z)
        else:
            if damped is None:
                damped = _DampedSteps(A, z)
            dx, pred = damped.step(0.0 if try_gn else damping.lam, Ds)
        new = theta.copy()
        new[est] += dx
        length = scaled_step(dx, theta[est])
        tiny = length <= tol_step
        triangle, r = lin.trial(new, w, est, build=first and not tiny)
        first = False
        c_new = half_weighted_ss(r, w)
        rho = (cost - c_new) / pred if pred > 0 else (0.0 if c_new > cost else 1.0)
        step = Step(new, r, c_new, triangle, length, damping.lam, tiny)
        if try_gn:
            try_gn = False
            if np.isfinite(c_new) and rho > 0.25:
                damping.good = rho > 0.75
                return _no_descent(step, cost)
            if tiny:
                return _no_descent(step, cost)
            continue
        if np.isfinite(c_new) and rho > 1e-4:
            _update(damping, rho)
            step.damping = damping.lam
            return _no_descent(step, cost)
        if tiny:
            return _no_descent(step, cost)
        damping.lam *= damping.nu
        damping.nu *= 2.0
        if no_further_decrease(pred, cost, damping.lam):
            step.damping, step.stop = damping.lam, StageStatus.NO_FURTHER_DECREASE
            return step
    step.stop = StageStatus.DAMPING_FAILED
    return step


def _no_descent(step: Step, cost: float) -> Step:
    """The trial that ends the trials: a step within ``tol_step`` (accepted or not) is
    taken only if it lowers the cost at all, else the stage ends where it is
    (``NO_DESCENT_STEP``)."""
    if step.tiny and not (np.isfinite(step.cost) and step.cost < cost):
        step.stop = StageStatus.NO_DESCENT_STEP
    return step
