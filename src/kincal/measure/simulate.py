"""Virtual robots and virtual instruments: the truth a calibration can be tested against.

* :func:`random_configurations` draws joint configurations uniformly inside the
  joint limits (shrunk by a margin).
* :func:`perturb_robot` makes the "true" robot: the nominal parameters plus Gaussian
  errors whose standard deviation depends on each parameter's role and unit.
* :func:`simulate_positions` / :func:`simulate_poses` measure the true robot with a
  virtual tracker placed at ``instrument`` and return the measurement blocks of
  :mod:`kincal.measure.models`, with Gaussian noise added.

All randomness comes from the ``numpy.random.Generator`` passed in.  SI units.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.measure.models import PoseMeasurement, PositionMeasurement
from kincal.robots.chain import Robot
from kincal.spatial import exp_so3, matrix_from_frame

Array = NDArray[np.float64]

__all__ = ["random_configurations", "perturb_robot", "simulate_positions", "simulate_poses"]


#: Configurations simulated per piece (a performance setting; results do not depend on it).
_PIECE = 1 << 14


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


def _instrument(instrument: ArrayLike | None) -> Array:
    if instrument is None:
        return np.eye(4)
    return matrix_from_frame(np.asarray(instrument, dtype=float).reshape(6))


def simulate_positions(true_robot: Robot, q: ArrayLike, rng: np.random.Generator,
                       noise_std: float, instrument: ArrayLike | None = None,
                       markers: ArrayLike | None = None, name: str = "tracker",
                       sigma: float | None = None) -> PositionMeasurement:
    """Points on the true robot's tool measured by a virtual tracker.

    ``y = T_I^-1 T(q) m_k + noise``, noise ~ N(0, noise_std^2) per coordinate.

    Args:
        true_robot: the robot that "really" moves.
        q: (N, n) configurations.
        noise_std: standard deviation of each coordinate [m] (0 for exact data).
        instrument: tracker pose in the robot's world frame, ``(x, y, z, rz, ry, rx)``
            [m, rad] (:data:`kincal.spatial.FRAME_FIELDS`, the order of the estimated
            ``{name}.*`` block parameters); default identity.
        markers: (3,) or (K, 3) points in the tool frame [m]; default the tool origin.
        name: the block's name.
        sigma: the standard deviation the block states; default ``noise_std`` (or
            1e-5 m when ``noise_std`` is 0).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    m = np.zeros((1, 3)) if markers is None else np.asarray(markers, dtype=float)
    single = m.ndim == 1
    m = m.reshape(-1, 3)
    left = np.linalg.inv(_instrument(instrument))
    K = m.shape[0]
    y = np.empty((len(q), K, 3))
    # in pieces of configurations (memory independent of N); the noise is drawn piece
    # by piece along the first axis, the same numbers as one draw of y's shape
    for start in range(0, len(q), _PIECE):
        cs = slice(start, min(len(q), start + _PIECE))
        Y, _, _ = true_robot.point_jacobian(q[cs], m, left, ())
        y[cs] = Y.transpose(2, 0, 1)
        y[cs] += noise_std * rng.standard_normal((cs.stop - cs.start, K, 3))
    s = sigma if sigma is not None else (noise_std if noise_std > 0 else 1e-5)
    if single or m.shape[0] == 1:
        return PositionMeasurement(q, y[:, 0], s, name)
    return PositionMeasurement(q, y, s, name, markers=m.shape[0])


def simulate_poses(true_robot: Robot, q: ArrayLike, rng: np.random.Generator,
                   noise_position_std: float, noise_orientation_std: float,
                   instrument: ArrayLike | None = None, target: ArrayLike | None = None,
                   name: str = "tracker", sigma_position: float | None = None,
                   sigma_orientation: float | None = None) -> PoseMeasurement:
    """Target frames on the true robot's tool measured by a virtual 6-DOF tracker.

    ``T_obs = T_I^-1 T(q) T_t`` then perturbed: position + N(0, noise_position_std^2)
    per coordinate, rotation ``exp([n]x) R`` with ``n ~ N(0, noise_orientation_std^2)``
    per component [rad].

    Args:
        instrument, target: ``(x, y, z, rz, ry, rx)`` [m, rad]
            (:data:`kincal.spatial.FRAME_FIELDS`, the order of the estimated block
            parameters); default identity.
        sigma_position, sigma_orientation: stated standard deviations; default the
            noise (or 1e-5 when the noise is 0).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    TI = _instrument(instrument)
    Tt = _instrument(target)
    T = np.linalg.inv(TI) @ true_robot.fk(q) @ Tt
    N = len(q)
    T[:, :3, 3] += noise_position_std * rng.standard_normal((N, 3))
    T[:, :3, :3] = exp_so3(noise_orientation_std * rng.standard_normal((N, 3))) @ T[:, :3, :3]
    sp = sigma_position if sigma_position is not None else (noise_position_std or 1e-5)
    so = sigma_orientation if sigma_orientation is not None else (noise_orientation_std or 1e-5)
    return PoseMeasurement(q, T, sp, so, name)


def frame_of(values: ArrayLike) -> Array:
    """Homogeneous matrix of block frame values ``(x, y, z, rz, ry, rx)``."""
    return matrix_from_frame(np.asarray(values, dtype=float))
