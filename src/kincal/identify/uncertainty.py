"""How certain is a calibration?  Covariance, Cramér-Rao bound, predicted accuracy.

For whitened residuals ``r = (model - observed) / sigma`` with Jacobian ``J`` (M, p)
over the estimated parameters, the least-squares estimate has, to first order,

    Cov(theta_hat) = sigma0^2 (J^T J)^-1

where ``sigma0^2`` is the variance factor: 1 when the stated sigmas are trusted
(then this is the Cramér-Rao bound for Gaussian noise), or the a-posteriori estimate
``sigma0^2 = r^T r / (M - p)`` (the default of the solver: it makes the reported
uncertainty honest when the stated sigmas are only nominal).  ``(J^T J)^-1`` is
computed from the SVD of ``J`` with unit-norm columns, ``J D^-1 = U S V^T``:
``(J^T J)^-1 = D^-1 V S^-2 V^T D^-1``, which stays accurate for condition numbers
up to ~1e8.

Propagation: a predicted quantity ``y(theta)`` with Jacobian ``G = dy/dtheta`` has
``Cov(y) = G Cov(theta) G^T``; for a predicted position this gives the standard
deviation of its error, ``sqrt(trace Cov(p))`` [m] (the RMS length of the 3-D error).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import IdentifiabilityError, KincalError
from kincal.measure.base import svd_thin

if TYPE_CHECKING:
    from kincal.identify.solver import CalibrationResult

Array = NDArray[np.float64]

__all__ = ["covariance", "standard_errors", "correlation", "cramer_rao",
           "predicted_position_std", "predicted_rms", "inverse_normal_matrix"]


def inverse_normal_matrix(J: ArrayLike, rcond: float = 1e-12) -> Array:
    """``(J^T J)^-1`` through the SVD of the column-scaled ``J``.

    Raises :class:`IdentifiabilityError` if ``J`` is rank deficient (scaled singular
    values below ``rcond`` times the largest); callers pass only identifiable columns.
    """
    J = np.asarray(J, dtype=float)
    p = J.shape[1]
    if p == 0:
        return np.zeros((0, 0))
    D = np.linalg.norm(J, axis=0)
    if np.any(D == 0):
        raise IdentifiabilityError(f"column {int(np.argmin(D))} of the Jacobian is zero: the "
                                   "covariance does not exist")
    _, S, Vt = svd_thin(J / D)
    if S[-1] <= rcond * S[0]:
        raise IdentifiabilityError("the Jacobian is rank deficient: the covariance does not "
                                   "exist (run the identifiability analysis first)")
    W = Vt.T / S
    return (W @ W.T) / np.outer(D, D)


def covariance(J_whitened: ArrayLike, sigma0: float = 1.0) -> Array:
    """Parameter covariance ``sigma0^2 (J^T J)^-1`` [units^2 of the parameters]."""
    return float(sigma0) ** 2 * inverse_normal_matrix(J_whitened)


def cramer_rao(J_whitened: ArrayLike) -> Array:
    """Cramér-Rao bound ``(J^T J)^-1`` for Gaussian noise with the stated sigmas."""
    return inverse_normal_matrix(J_whitened)


def standard_errors(cov: ArrayLike) -> Array:
    """Standard errors ``sqrt(diag(Cov))`` (negative round-off clipped to 0)."""
    return np.sqrt(np.clip(np.diag(np.asarray(cov, dtype=float)), 0.0, None))


def correlation(cov: ArrayLike) -> Array:
    """Correlation matrix ``C_ij / sqrt(C_ii C_jj)`` (0 where a variance is 0)."""
    cov = np.asarray(cov, dtype=float)
    s = standard_errors(cov)
    with np.errstate(invalid="ignore", divide="ignore"):
        C = cov / np.outer(s, s)
    C = np.where(np.outer(s, s) > 0, C, 0.0)
    np.fill_diagonal(C, np.where(s > 0, 1.0, 0.0))
    return C


def _position_block(result: CalibrationResult, block: str | None) -> Any:
    from kincal.measure.models import PoseMeasurement, PositionMeasurement

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
    from kincal.measure.models import PoseMeasurement, PositionMeasurement

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
