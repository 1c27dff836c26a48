"""Virtual robots and virtual instruments: the truth a calibration can be tested against.

* :func:`random_configurations` draws joint configurations uniformly inside the
  joint limits (shrunk by a margin).
* :func:`perturb_robot` makes the "true" robot: the nominal parameters plus Gaussian
  errors whose standard deviation depends on each parameter's role and unit.
* the virtual instruments that measure the true robot live with their instruments:
  :func:`~kincal.measure.instruments.position.simulate_positions`,
  :func:`~kincal.measure.instruments.pose.simulate_poses` and every plug-in simulator
  in :mod:`kincal.measure.instruments`.

All randomness comes from the ``numpy.random.Generator`` passed in.  SI units.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["random_configurations", "perturb_robot"]


def random_configurations(robot: Robot, n: int, rng: np.random.Generator,
                          margin: float = 0.05) -> Array:
    """``n`` configurations drawn uniformly within the joint limits: (n, robot.n).

    Each joint range ``[lo, hi]`` is shrunk by ``margin * (hi - lo)`` at both ends.
    Revolute joints without limits use ``[-pi, pi]``; a prismatic joint without
    limits is an error (there is no natural stroke to draw from).
    """
    lim = robot.joint_limits.copy()
    for j, joint in enumerate(robot.joints):
        if not (np.isfinite(lim[j, 0]) and np.isfinite(lim[j, 1])):
            if joint.kind == "prismatic":
                raise KincalError(f"prismatic joint {joint.name!r} of robot {robot.name!r} has "
                                  "no limits; give it limits to draw configurations from")
            lo = lim[j, 0] if np.isfinite(lim[j, 0]) else -np.pi
            hi = lim[j, 1] if np.isfinite(lim[j, 1]) else np.pi
            lim[j] = (max(lo, -np.pi), min(hi, np.pi)) if lo < hi else (-np.pi, np.pi)
    span = lim[:, 1] - lim[:, 0]
    lo = lim[:, 0] + margin * span
    hi = lim[:, 1] - margin * span
    out = rng.random((int(n), robot.n))         # lo + (hi - lo) u, in place
    out *= hi - lo
    out += lo
    return out


def perturb_robot(robot: Robot, rng: np.random.Generator, length_std: float = 1e-3,
                  angle_std: float = float(np.deg2rad(0.05)),
                  offset_std: float = float(np.deg2rad(0.1)),
                  base_std: tuple[float, float] = (1e-3, float(np.deg2rad(0.1))),
                  tool_std: tuple[float, float] = (1e-3, float(np.deg2rad(0.1))),
                  names: Sequence[str] | None = None) -> Robot:
    """The "true" robot: nominal parameters plus Gaussian errors by role.

    Standard deviation per parameter (role, unit):

    ======================  ========================
    offset, rad             ``offset_std`` (encoder zero)
    offset, m (prismatic)   ``length_std``
    length / angle, m       ``length_std``
    length / angle, rad     ``angle_std``
    base, m / rad           ``base_std[0]`` / ``base_std[1]``
    tool, m / rad           ``tool_std[0]`` / ``tool_std[1]``
    ======================  ========================

    Args:
        names: only these parameters are perturbed (default: all).
    """
    std = np.empty(robot.num_params)
    for i, (role, unit) in enumerate(zip(robot.param_roles, robot.param_units, strict=True)):
        lin = unit == "m"
        if role == "base":
            std[i] = base_std[0] if lin else base_std[1]
        elif role == "tool":
            std[i] = tool_std[0] if lin else tool_std[1]
        elif role == "offset":
            std[i] = length_std if lin else offset_std
        else:
            std[i] = length_std if lin else angle_std
    mask = np.zeros(robot.num_params, dtype=bool)
    mask[robot.param_indices(names)] = True
    delta = np.where(mask, std * rng.standard_normal(robot.num_params), 0.0)
    return robot.with_params(robot.param_values + delta)


