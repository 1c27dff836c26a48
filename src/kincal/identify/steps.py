"""What one iteration of a solver method proposes: a trial point, evaluated.

Both methods (:mod:`~kincal.identify.gauss_newton`,
:mod:`~kincal.identify.levenberg_marquardt`) work on the scaled triangle ``A = R D^-1``
of the linearisation (``D`` the column norms, so a step is the same in any units) and
return a :class:`Step`: the point, its residuals and cost, the triangle built there (when
the linearisation reuses trials), the step's scaled length
``max_j |dx_j| / (1 + |x_j|)`` (parameters in m / rad) and, when the method found no
acceptable point, the status that ends the stage.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kincal.identify.status import StageStatus
from kincal.measure.base import CompressedSystem

Array = NDArray[np.float64]


def scaled_step(dx: Array, x: Array) -> float:
    """``max_j |dx_j| / (1 + |x_j|)``: the step relative to the parameters (0 if empty)."""
    return float(np.max(np.abs(dx) / (1.0 + np.abs(x)))) if dx.size else 0.0


@dataclass
class Step:
    """A trial point of one iteration.

    Attributes:
        theta: the full parameter vector there.
        r: its residuals (prior rows included).
        cost: ``1/2 sum w r^2`` there (with the weights of the current point).
        triangle: the triangle built there (with ``r``), or None.
        length: the scaled step ``max_j |dx_j| / (1 + |x_j|)``.
        damping: the Levenberg-Marquardt ``lambda`` after the iteration (0: Gauss-Newton).
        tiny: the step is within ``tol_step`` (its triangle is not built).
        stop: the status ending the stage without taking the step, or None.
    """

    theta: Array
    r: Array
    cost: float
    triangle: CompressedSystem | None
    length: float
    damping: float = 0.0
    tiny: bool = False
    stop: StageStatus | None = None
