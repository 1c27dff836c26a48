"""How a calibration behaves outside its training region: a region test on the training
data, and a warning when the data leave the rest of the workspace undetermined.

**Region test** (:func:`region_test`).  Random folds hold out poses *inside* the training
region; they say nothing about extrapolation.  The region test holds out a region: with
``c_j`` the middle and ``h_j`` the half-width of joint ``j``'s training range, a pose's
distance from the middle is ``d_i = max_j |q_ij - c_j| / h_j``; the half of the poses with
the smallest ``d_i`` (the *inner* part) is fitted with the calibration's own options, and
the other half (the *outer* part, every pose outside the inner part's joint ranges) is
predicted with that fit's instrument frames, as a same-session validation would.  It
gives, over the outer poses,

* the measured RMS error ``e`` of the inner fit, and the nominal robot's (registered to
  the inner poses) ``e_nom``;
* the inner fit's predicted parameter error ``std`` (:func:`~kincal.identify.accuracy.predict`);
* the growth of the floor with the distance ``d`` outside the training joint ranges
  (:meth:`~kincal.identify.accuracy.TrainingRegion.distance` of the inner fit's region),
  ``g^2 = max(0, mean(e^2) - mean(std^2) - floor^2) / mean(d^2)`` [m]: what neither the
  parameter covariance nor the training floor explains where the model extrapolates
  (:attr:`~kincal.identify.accuracy.AccuracyModel.floor_growth_m`).  The growth is taken
  linear in ``d``: an unmodelled error the parameters absorb inside a region leaves a
  remainder that grows with the distance from it.

On the real data of ``benchmarks/extrapolation.py`` the floor inside under-predicts the
held-out error outside by 1.4-1.7x (TIAGo, UR10): the parameters absorb part of the
unmodelled error inside the region only.

**Extrapolation warning** (:func:`extrapolation_warning`).  The calibrated model's
predicted parameter error over the robot's joint ranges (400 configurations drawn
uniformly in them, 10 % margin) against its unmodelled floor: when the
RMS ``std`` over the grid exceeds both the floor and the nominal robot's RMS error on the
training data (the size of the correction), the training data did not determine the
model for the rest of the workspace (the error there is set by the directions the data
never excited, and a fit can be worse than the nominal robot there).  The region test's
"worse than nominal" (``e > e_nom + floor``) warns too.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.identify.accuracy import AccuracyModel, accuracy_model, predict
from kincal.identify.solver import CalibrationResult
from kincal.measure.instruments.position import PositionMeasurement
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["RegionTest", "region_test", "extrapolation_warning", "inner_half"]

#: Fewest poses in each half of the region test.
MIN_POSES = 8


@dataclass(frozen=True)
class RegionTest:
    """The region test's outcome (module docstring); lengths in metres.

    Attributes:
        inner, outer: poses fitted / predicted.
        measured_rms_m: the inner fit's RMS error on the outer poses.
        predicted_std_rms_m: its predicted parameter error there, ``sqrt(mean std^2)``.
        nominal_rms_m: the nominal robot's RMS error there (registered on the inner poses).
        floor_m: the inner fit's floor (training residuals).
        floor_growth_m: ``g`` [m per training half-range] (module docstring).
    """

    inner: int
    outer: int
    measured_rms_m: float
    predicted_std_rms_m: float
    nominal_rms_m: float
    floor_m: float
    floor_growth_m: float

    @property
    def worse_than_nominal(self) -> bool:
        """The inner fit is worse than the nominal robot on the outer poses by more than
        the floor (the noise and what no parameter explains)."""
        return self.measured_rms_m > self.nominal_rms_m + self.floor_m

    def to_dict(self) -> dict[str, Any]:
        return {"inner": self.inner, "outer": self.outer,
                "measured_rms_m": self.measured_rms_m,
                "predicted_std_rms_m": self.predicted_std_rms_m,
                "nominal_rms_m": self.nominal_rms_m, "floor_m": self.floor_m,
                "floor_growth_m": self.floor_growth_m,
                "worse_than_nominal": self.worse_than_nominal}


def inner_half(q: Array) -> NDArray[np.bool_]:
    """(N,) True for the half of the poses nearest the middle of the joint ranges of ``q``
    (Chebyshev distance in units of each joint's half-range; joints that do not move are
    ignored)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    lo, hi = q.min(axis=0), q.max(axis=0)
    moving = hi - lo > 1e-9
    if not moving.any():
        return np.ones(len(q), dtype=bool)
    c, h = 0.5 * (lo + hi)[moving], 0.5 * (hi - lo)[moving]
    d = np.max(np.abs(q[:, moving] - c) / h, axis=1)
    return np.asarray(d <= np.median(d), dtype=np.bool_)


def _rms(x: Array) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else 0.0


def _errors(robot: Robot, blocks: Sequence[PositionMeasurement], values: Sequence[Array]
            ) -> Array:
    out = [np.ravel(b.errors(robot, v)["position_m"]) for b, v in zip(blocks, values,
                                                                      strict=True)]
    return np.concatenate(out) if out else np.zeros(0)


def region_test(robot: Robot, blocks: Sequence[Any],
                fit: Callable[[list[Any]], CalibrationResult]) -> RegionTest | None:
    """Fit the inner half of the training poses, predict the outer half (module docstring).

    Args:
        robot: the nominal robot.
        blocks: the training blocks; only plain
            :class:`~kincal.measure.instruments.position.PositionMeasurement` blocks are
            tested (None otherwise).
        fit: calibrates a list of blocks with the calibration's own options.

    Returns None when the test does not apply: other blocks, fewer than :data:`MIN_POSES`
    poses in a half, or an inner fit that did not converge.
    """
    from kincal.identify.solver import calibrate

    if not blocks or any(type(b) is not PositionMeasurement for b in blocks):
        return None
    q = np.vstack([b.q for b in blocks])
    inner = inner_half(q)
    if inner.sum() < MIN_POSES or (~inner).sum() < MIN_POSES:
        return None
    cut = np.cumsum([0] + [b.N for b in blocks])
    parts = [(b.subset(np.flatnonzero(inner[a:z])), b.subset(np.flatnonzero(~inner[a:z])))
             for b, a, z in zip(blocks, cut[:-1], cut[1:], strict=True)]
    parts = [(i, o) for i, o in parts if i.N and o.N]
    if not parts:
        return None
    ins, outs = [p[0] for p in parts], [p[1] for p in parts]
    q_out = np.vstack([b.q for b in outs])
    try:
        res = fit(list(ins))
        if not res.converged:
            return None
        model = accuracy_model(res)
        own = [n for b in ins for n in b.parameters().names]
        reg = calibrate(robot, list(ins), free=own, tol_step=1e-12, max_iter=200)
        std = predict(model.with_region(None), res.robot, q_out).std_position_m  # no hull
        e = _errors(res.robot, outs, [res.theta[res.problem.block_slice(b.name)]
                                      for b in ins])
        e_nom = _errors(robot, outs, [reg.theta[reg.problem.block_slice(b.name)]
                                      for b in ins])
    except (KincalError, np.linalg.LinAlgError, ValueError, IndexError):
        return None
    measured, pstd, floor = _rms(e), _rms(std), float(model.floor_m)
    d = model.region.distance(q_out) if model.region is not None else np.zeros(len(q_out))
    d2 = float(np.mean(d**2))
    excess = max(0.0, measured**2 - pstd**2 - floor**2)
    growth = float(np.sqrt(excess / d2)) if d2 > 0 else 0.0
    return RegionTest(int(sum(b.N for b in ins)), int(sum(b.N for b in outs)), measured,
                      pstd, _rms(e_nom), floor, growth)


def extrapolation_warning(model: AccuracyModel, robot: Robot,
                          test: RegionTest | None = None, nominal_rms_m: float = 0.0,
                          samples: int = 400) -> str:
    """A sentence when the calibrated ``robot`` may be worse than nominal outside its
    training region ("" otherwise; module docstring).

    ``std`` over ``samples`` configurations drawn uniformly in the robot's joint ranges
    (shrunk by 10 % at both ends; unlimited revolute joints: +-pi; seed 0) against
    the larger of the floor ``model.floor_m`` and ``nominal_rms_m``, the nominal robot's
    RMS error on the training data (what the calibration corrects); and the region
    ``test``'s verdict.
    """
    from kincal.measure.simulate import random_configurations

    out = []
    if test is not None and test.worse_than_nominal:
        out.append("fitted on the inner half of its training poses, this calibration was "
                   "worse than the nominal robot on the outer half "
                   f"({test.measured_rms_m * 1e3:.3g} mm RMS against "
                   f"{test.nominal_rms_m * 1e3:.3g} mm)")
    try:
        grid = random_configurations(robot, samples, np.random.default_rng(0), margin=0.1)
        std = predict(model.with_region(None), robot, grid).std_position_m    # no hull test
    except KincalError:
        std = np.zeros(0)
    bar = max(float(model.floor_m), float(nominal_rms_m))
    if std.size and _rms(std) > bar:
        out.append(f"over the robot's joint ranges its predicted error is {_rms(std) * 1e3:.3g}"
                   f" mm RMS (up to {float(std.max()) * 1e3:.3g} mm), more than the nominal "
                   f"robot's {bar * 1e3:.3g} mm on the training poses: they leave the rest of "
                   "the workspace undetermined")
    if not out:
        return ""
    return ("extrapolation: " + "; ".join(out) + ". Outside the training joint ranges the "
            "calibrated robot may be worse than the nominal one: validate it there before "
            "use, or measure over the range it will be used in")
