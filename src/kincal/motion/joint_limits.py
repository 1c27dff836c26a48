"""Joint limits as arrays, and configurations inside them.

* :func:`limit_arrays` - lower and upper limits (n,) and which joints are revolute;
* :func:`default_q0` - mid-range of the limits, the first start of every IK target;
* :func:`random_q` - uniform configurations inside the limits;
* :func:`project_to_limits` - bring configurations inside the limits (revolute joints
  shifted by 2 pi k when that fits, else clipped).

Units: rad for revolute joints, m for prismatic ones.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["limit_arrays", "default_q0", "random_q", "project_to_limits"]


def limit_arrays(robot: Robot) -> tuple[Array, Array, NDArray[np.bool_]]:
    """Lower and upper joint limits (n,) [rad / m] and which joints are revolute."""
    lim = robot.joint_limits
    rev = np.array([j.kind == "revolute" for j in robot.joints])
    return lim[:, 0], lim[:, 1], rev


def default_q0(robot: Robot) -> Array:
    """Mid-range of the joint limits; for a half-open range its finite end, or 0 [rad / m]."""
    lo, hi, _ = limit_arrays(robot)
    both = np.isfinite(lo) & np.isfinite(hi)
    mid = np.where(both, 0.5 * (np.where(both, lo, 0) + np.where(both, hi, 0)), 0.0)
    mid = np.where(np.isfinite(lo) & ~np.isfinite(hi), np.maximum(np.nan_to_num(lo), 0.0), mid)
    return np.where(~np.isfinite(lo) & np.isfinite(hi), np.minimum(np.nan_to_num(hi), 0.0), mid)


def random_q(robot: Robot, size: int, rng: np.random.Generator) -> Array:
    """Uniform joint values inside the limits; unlimited sides span pi rad or 1 m."""
    lo, hi, rev = limit_arrays(robot)
    span = np.where(rev, np.pi, 1.0)
    a = np.where(np.isfinite(lo), lo, np.where(np.isfinite(hi), hi - 2 * span, -span))
    b = np.where(np.isfinite(hi), hi, a + 2 * span)
    return rng.uniform(a, b, size=(size, robot.n))


def project_to_limits(q: Array, lo: Array, hi: Array, rev: NDArray[np.bool_]) -> Array:
    """Bring ``q`` inside ``[lo, hi]``: shift revolute joints by 2 pi k if that fits, else clip."""
    outside = (q < lo) | (q > hi)
    if not np.any(outside):
        return q
    with np.errstate(invalid="ignore"):
        shifted = lo + np.mod(q - lo, 2 * np.pi)
    use = outside & rev & (shifted <= hi)
    return np.clip(np.where(use, shifted, q), lo, hi)
