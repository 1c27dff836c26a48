"""Known fixtures: the tool point is placed on pre-calibrated points of the workspace.

A fixture plate (or a set of cones / nests) whose points ``f_j`` [m] are known in the
world frame (measured once, e.g. on a CMM).  Row ``i`` says the tool point sits on
``f_i`` at joint readings ``q_i``::

    e_i = p(q_i) - f_i = 0 (3 components)          residuals e_i / sigma_i

``de/dp = I``.  The only block parameters are the marker ``{name}.marker.x, y, z``
(``marker="own"``; none with ``marker="tool"``).  No instrument frame: the fixture *is*
the world reference, so unlike a tracker the robot's base frame is seen directly.

What fixtures cannot see: only the tool point (not the tool orientation); with the same
fixture point approached in one orientation the marker and the last links trade off --
approach each point in several orientations.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.measure.base import ParamSpec
from kincal.measure.instruments.pointblock import PointBlock
from kincal.robots.chain import Robot

Array = NDArray[np.float64]


class FixtureMeasurement(PointBlock):
    """The tool point on known fixture points.

    Args:
        name: block name (parameter prefix).
        q: (N, n) joint readings [rad / m].
        points: (N, 3) the fixture point of each row in the world frame [m].
        sigma: standard deviation of each coordinate [m] (placement repeatability plus the
            fixture's own uncertainty), scalar or (N,).
        marker: ``"own"`` or ``"tool"`` (see :mod:`.common`).
    """

    def __init__(self, name: str, q: ArrayLike, points: ArrayLike, sigma: ArrayLike,
                 marker: str = "own") -> None:
        self._init_rows("fixture", name, q, points, 3, "points", sigma, marker)

    def own_parameters(self) -> ParamSpec:
        return ParamSpec.empty()

    def observe(self, p: Array, own: Array, jacobian: bool
                ) -> tuple[Array, Array | None, Array | None]:
        if not jacobian:
            return p, None, None
        N = p.shape[0]
        return p, np.broadcast_to(np.eye(3), (N, 3, 3)), np.zeros((N, 3, 0))

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        r = self.evaluate(robot, extra, jacobian=False)[0].reshape(-1, 3)
        return {"position_m": np.linalg.norm(r, axis=1) * self.sigma}
