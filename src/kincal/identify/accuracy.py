"""Accuracy of a calibrated model where it is used: the parameter covariance propagated
to predicted positions.

A predicted quantity ``y(theta)`` with Jacobian ``G = dy/dtheta`` has
``Cov(y) = G Cov(theta) G^T``; for a predicted position this gives the standard
deviation of its error, ``sqrt(trace Cov(p))`` [m] (the RMS length of the 3-D error).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.identify.solver import CalibrationResult
from kincal.measure.models import PoseMeasurement, PositionMeasurement

Array = NDArray[np.float64]

__all__ = ["predicted_position_std", "predicted_rms"]


def _position_block(result: CalibrationResult, block: str | None) -> Any:
    blocks = result.problem.blocks
    if block is not None:
        b = result.problem.block(block)
    else:
        cands = [b for b in blocks if isinstance(b, PositionMeasurement | PoseMeasurement)]
        if not cands:
            raise KincalError("no position or pose measurement block to predict through; "
                              "pass point= to predict the tool point in the base frame")
        b = cands[0]
    if not isinstance(b, PositionMeasurement | PoseMeasurement):
        raise KincalError(f"block {b.name!r} does not measure positions")
    return b


def _position_jacobian(result: CalibrationResult, q_eval: ArrayLike,
                       point: ArrayLike | None, block: str | None) -> Array:
    """d(predicted position)/d(estimated params): (M, 3, p)."""
    q = np.atleast_2d(np.asarray(q_eval, dtype=float))
    prob = result.problem
    est = [prob.names.index(n) for n in result.estimated]
    robot = result.robot
    if point is not None:
        m = np.asarray(point, dtype=float).reshape(3)
        T, _, Jp = robot.fk_with_jacobians(q, joints=False, params=True)
        a = T[:, :3, :3] @ m
        G = Jp[:, :3, :] + np.cross(Jp[:, 3:, :], a[:, :, None], axis=1)
        full = np.zeros((len(q), 3, len(prob.names)))
        full[:, :, : prob.num_robot] = G
        return full[:, :, est]
    b = _position_block(result, block)
    sl = prob.block_slice(b.name)
    extra = result.theta[sl]
    if isinstance(b, PositionMeasurement):
        dummy = PositionMeasurement(q, np.zeros((len(q), b.K, 3)) if b.K > 1
                                    else np.zeros((len(q), 3)), 1.0, b.name, b.K)
        rows = 3 * b.K
    else:
        dummy = PoseMeasurement(q, np.tile(np.eye(4), (len(q), 1, 1)), 1.0, 1.0, b.name)
        rows = 6
    _, Jr, Je = dummy.evaluate(robot, extra, jacobian=True)
    full = np.zeros((Jr.shape[0], len(prob.names)))
    full[:, : prob.num_robot] = Jr
    full[:, sl] = Je
    full = full.reshape(len(q), rows, -1)
    if isinstance(b, PositionMeasurement):
        full = full.reshape(len(q) * b.K, 3, -1)
    else:
        full = full[:, :3]
    return full[:, :, est]


def predicted_position_std(result: CalibrationResult, q_eval: ArrayLike,
                           point: ArrayLike | None = None, block: str | None = None) -> Array:
    """Standard deviation of predicted positions at ``q_eval`` from the parameter covariance.

    ``std_i = sqrt(trace(G_i Cov G_i^T))`` [m]: the RMS length of the 3-D error of the
    predicted position caused by the uncertainty of the estimated parameters.

    * ``point`` given ((3,) in the tool frame [m]): the point's position in the robot
      base frame, through the robot parameters only;
    * otherwise the observation of a position/pose ``block`` (default: the first one)
      in its instrument frame, through the robot *and* the block's parameters (the
      frames from training, as in a held-out validation).  With K markers the result
      has one row per (configuration, marker).

    Returns:
        (M,) standard deviations [m].
    """
    G = _position_jacobian(result, q_eval, point, block)
    C = result.covariance
    return np.sqrt(np.clip(np.einsum("mip,pq,miq->m", G, C, G), 0.0, None))


def predicted_rms(result: CalibrationResult, q_eval: ArrayLike, block: str | None = None,
                  noise_std: float | None = None) -> float:
    """Predicted RMS position error of held-out measurements at ``q_eval`` [m].

    ``sqrt(mean_i std_i^2 + 3 s^2)``: the parameter uncertainty propagated to the
    observations (:func:`predicted_position_std`) plus the measurement noise, ``s``
    = ``noise_std`` or the block's stated sigma times the solver's ``sigma0`` (RMS
    over its rows).  This is the floor a validation RMS should approach.
    """
    std = predicted_position_std(result, q_eval, block=block)
    if noise_std is None:
        b = _position_block(result, block)
        s = getattr(b, "sigma", getattr(b, "sigma_position", None))
        noise_std = float(np.sqrt(np.mean(np.asarray(s) ** 2))) * result.sigma0
    return float(np.sqrt(np.mean(std**2) + 3.0 * noise_std**2))
