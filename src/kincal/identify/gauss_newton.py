"""One Gauss-Newton iteration: the lecture's iterative linearised least squares.

``dphi = pinv(Phi) dr``, ``phi <- phi + dphi``: with the scaled triangle ``A = R D^-1 =
U S V^T`` of the weighted problem and ``g = U^T z``, the step is

    dx = -D^-1 V diag(1 / S_k) g        (singular values below 1e-12 S_max dropped),

taken without a line search (the stage then linearises again there).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from kincal.identify.linearisation import Linearisation, half_weighted_ss
from kincal.identify.status import StageStatus
from kincal.identify.steps import Step, scaled_step

Array = NDArray[np.float64]


def gauss_newton_step(lin: Linearisation, A: Array, Ds: Array, z: Array, est: Sequence[int],
                      w: Array, tol_step: float) -> Step:
    """The Gauss-Newton step from ``lin.theta`` over the columns ``est``, evaluated.

    ``A`` is the scaled triangle ``R D^-1`` (``Ds`` the scale ``D``), ``z`` the triangle's
    right-hand side.  The trial's triangle is built unless the step is within
    ``tol_step`` (it then ends the stage).  ``stop`` is ``GAUSS_NEWTON_DIVERGED`` when the
    cost there is not finite.
    """
    U, S, Vt = np.linalg.svd(A)
    g = U.T @ z
    kept = S > S[0] * 1e-12
    dz = -Vt[kept].T @ (g[kept] / S[kept])
    dx = dz / Ds
    theta = lin.theta
    new = theta.copy()
    new[est] += dx
    length = scaled_step(dx, theta[est])
    tiny = length <= tol_step
    triangle, r = lin.trial(new, w, est, build=not tiny)
    cost = half_weighted_ss(r, w)
    stop = None if np.isfinite(cost) else StageStatus.GAUSS_NEWTON_DIVERGED
    return Step(new, r, cost, triangle, length, 0.0, tiny, stop)
