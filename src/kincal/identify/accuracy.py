"""Accuracy of a calibrated model where it is used: the parameter covariance propagated
to predicted positions, the unmodelled floor, and where the model extrapolates.

A predicted quantity ``y(theta)`` with Jacobian ``G = dy/dtheta`` has
``Cov(y) = G Cov(theta) G^T``; for a predicted position this gives the standard
deviation of its error, ``sqrt(trace Cov(p))`` [m] (the RMS length of the 3-D error).

:class:`AccuracyModel` is what a calibration knows about its own accuracy, stored in the
result JSON (``accuracy_model``) so that ``validate``, ``compensate`` and ``filter`` can
use it later; :func:`predict` evaluates it at any configurations:

* **what the training instrument would measure** (default, when the calibration had a
  position block): ``y(q) = R_I^T (p_e(q) + R_e(q) m - t_I)`` with the estimated frame
  ``(R_I, t_I)`` and first marker ``m``; ``G = dy/dtheta`` over the estimated robot,
  frame and marker parameters (the block's own analytic Jacobian), ``C`` their
  covariance, ``std_position = sqrt(trace(G C G^T))`` [m].  In the robot's base frame a
  marker that the data tie only to the instrument frame is uncertain by centimetres
  (Motoman: the hand barely turns), while what the instrument sees is known to microns:
  the instrument's view is the one held-out measurements check;
* a **TCP** ``P(q) = p_e(q) + R_e(q) m`` in the base frame (``point=`` given; without an
  instrument, the marker / probe / target): ``G = [J_v - [R m]x J_w | R]`` over the
  estimated robot parameters (and ``m``'s estimated coordinates), marginal covariance;
  the orientation's ``sqrt(trace(J_w C J_w^T))`` [rad] over the robot parameters;
* the **floor**: what no parameter explains (noise, unmodelled effects), from the
  cross-validation residuals of ``--select auto`` / ``--cross-validate``,
  ``floor^2 = max(0, CV_RMS^2 - mean_i std_i^2)`` over the training configurations;
  without them, from the training residuals, ``floor^2 = RMS_train^2 M / (M - p)`` (the
  leverage correction, ``M`` residuals, ``p`` estimated parameters).  The predicted RMS
  error at a configuration is ``sqrt(std^2 + floor^2)``;
* the **floor outside the training region** (``floor_growth_m``): what no parameter
  explains grows where the model extrapolates, since the estimated parameters absorb
  part of the unmodelled error inside the region only (real data: held-out poses outside
  the region are 1.4-1.7x worse than the parameter covariance and the training floor
  predict, TIAGo and UR10 in ``benchmarks/extrapolation.py``).  At a distance ``d``
  outside the training joint ranges (:meth:`TrainingRegion.distance`, in training
  half-ranges) the floor is ``sqrt(floor^2 + (g d)^2)``; the growth ``g`` [m per
  half-range] is measured on the training data themselves by a *region test*
  (:mod:`kincal.identify.extrapolation`): fit the inner half of the poses, predict the
  outer half, ``g^2 = max(0, mean e^2 - mean std^2 - floor^2) / mean d^2`` over the outer
  poses (``e`` their measured error, ``std`` the inner fit's predicted parameter error,
  ``d`` their distance from the inner fit's region).  Linear growth is an assumption:
  on the real splits it gives predicted / measured 0.8-1.2 outside, on simulated
  robots with a cyclic joint error the unmodelled term is over-predicted by up to 2x
  far out (it saturates); a constant floor under-predicted by up to 4x there;
* the **training region**: the joint ranges of the training data and the convex hull of
  the measured point's training positions; outside it the model extrapolates
  (``outside_joint_ranges``, ``outside_hull``);
* against the **nominal model**: in the instrument's view, each robot with the
  instrument registered to it (``d = y_cal(q) - y_nom(q)``, when the model has the
  nominal registration), else at the TCP in the base frame (``d = P_cal(q) - P_nom(q)``,
  robot parameters): the calibration's correction ``d`` estimates the nominal model's
  error, and the calibrated model is predicted *worse than nominal* where
  ``|d_hat| < sqrt(2) std``: the correction is no larger than its own uncertainty;
* the **nominal model's predicted error**: its manufacturing tolerances ``s_j``
  propagated to the point, ``sqrt(sum_j s_j^2 |G_j|^2 + floor^2)``
  (:func:`nominal_spread`); a tolerance-based spread that cannot explode where the
  calibrated model extrapolates (files without tolerances: ``|d_hat|^2 - std^2``).

:func:`predicted_position_std` (through a measurement block, the instrument frame
included) and :func:`predicted_rms` are the older, block-level forms.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.identify.solver import CalibrationResult
from kincal.identify.uncertainty import propagated_variance
from kincal.measure.base import HasProbe, MeasurementModel
from kincal.measure.instruments.pose import PoseMeasurement
from kincal.measure.instruments.position import PositionMeasurement
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["predicted_position_std", "predicted_rms", "TrainingRegion", "AccuracyModel",
           "Prediction", "accuracy_model", "predict", "floor_from_training",
           "floor_from_cross_validation", "predict_spread",
           "nominal_spread"]


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


def _fk_and_param_jacobian(robot: Robot, q: Array) -> tuple[Array, Array]:
    """``(T, Jp)``: the poses (N, 4, 4) and the parameter Jacobian (N, 6, P) at ``q``."""
    T, _, Jp = robot.fk_with_jacobians(q, joints=False, params=True)
    if Jp is None:
        raise KincalError(f"robot {robot.name!r} returned no parameter Jacobian")
    return T, Jp


def _jacobians_of(block: MeasurementModel, robot: Robot, extra: Array
                  ) -> tuple[Array, Array, Array]:
    """``(r, J_robot, J_block)`` of ``block`` at the robot and its parameters ``extra``."""
    r, Jr, Je = block.evaluate(robot, extra, jacobian=True)
    if Jr is None or Je is None:
        raise KincalError(f"block {block.name!r} returned no Jacobian")
    return r, Jr, Je


def _position_jacobian(result: CalibrationResult, q_eval: ArrayLike,
                       point: ArrayLike | None, block: str | None) -> Array:
    """d(predicted position)/d(estimated params): (M, 3, p)."""
    q = np.atleast_2d(np.asarray(q_eval, dtype=float))
    prob = result.problem
    est = [prob.names.index(n) for n in result.estimated]
    robot = result.robot
    if point is not None:
        m = np.asarray(point, dtype=float).reshape(3)
        T, Jp = _fk_and_param_jacobian(robot, q)
        a = T[:, :3, :3] @ m
        G = Jp[:, :3, :] + np.cross(Jp[:, 3:, :], a[:, :, None], axis=1)
        full = np.zeros((len(q), 3, len(prob.names)))
        full[:, :, : prob.num_robot] = G
        return full[:, :, est]
    b = _position_block(result, block)
    sl = prob.block_slice(b.name)
    extra = result.theta[sl]
    dummy: MeasurementModel
    if isinstance(b, PositionMeasurement):
        dummy = PositionMeasurement(q, np.zeros((len(q), b.K, 3)) if b.K > 1
                                    else np.zeros((len(q), 3)), 1.0, b.name, b.K)
        rows = 3 * b.K
    else:
        dummy = PoseMeasurement(q, np.tile(np.eye(4), (len(q), 1, 1)), 1.0, 1.0, b.name)
        rows = 6
    _, Jr, Je = _jacobians_of(dummy, robot, extra)
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
    return np.sqrt(np.clip(propagated_variance(G, C), 0.0, None))


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
        s = b.measurement_sigma()
        noise_std = float(np.sqrt(np.mean(np.asarray(s) ** 2))) * result.sigma0
    return float(np.sqrt(np.mean(std**2) + 3.0 * noise_std**2))


# --------------------------------------------------------------------------- the model
@dataclass(frozen=True)
class TrainingRegion:
    """Where the training data put the robot.

    Attributes:
        joint_names: the robot's joints.
        joint_min, joint_max: (n,) the training joint ranges [rad / m].
        hull: (H, 3) vertices of the convex hull of the measured point's training
            positions in the base frame [m], or None (fewer than 4 points off a plane).
    """

    joint_names: tuple[str, ...]
    joint_min: Array
    joint_max: Array
    hull: Array | None = None

    def outside_joint_ranges(self, q: ArrayLike) -> NDArray[np.bool_]:
        """(N,) True where some joint lies outside its training range."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        outside = (q < self.joint_min - 1e-9) | (q > self.joint_max + 1e-9)
        return np.asarray(np.any(outside, axis=1), dtype=np.bool_)

    def distance(self, q: ArrayLike) -> Array:
        """(N,) how far configurations lie outside the training joint ranges, in units
        of each joint's training half-range ``h_j`` (at least 0.01 rad / m):
        ``max_j excess_j / h_j``, ``excess_j`` joint ``j``'s distance from its range taken
        modulo ``2 pi`` (a revolute joint a turn away is at the same angle; prismatic
        strokes are far below 2 pi m); 0 inside."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        lo, hi = self.joint_min, self.joint_max
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        off = np.abs(np.remainder(q - mid + np.pi, 2 * np.pi) - np.pi)
        excess = np.where(half >= np.pi, 0.0, np.maximum(off - half, 0.0))
        if not q.shape[1]:
            return np.zeros(len(q))
        return np.asarray(np.max(excess / np.maximum(half, 1e-2), axis=1), dtype=float)

    def outside_hull(self, p: ArrayLike) -> NDArray[np.bool_]:
        """(N,) True where a point lies outside the training hull (False without one)."""
        p = np.atleast_2d(np.asarray(p, dtype=float))
        if self.hull is None:
            return np.zeros(len(p), dtype=bool)
        from scipy.spatial import Delaunay

        return np.asarray(Delaunay(self.hull).find_simplex(p) < 0)

    def to_dict(self) -> dict[str, Any]:
        return {"joint_names": list(self.joint_names), "joint_min": self.joint_min.tolist(),
                "joint_max": self.joint_max.tolist(),
                "hull": None if self.hull is None else self.hull.tolist()}

    @staticmethod
    def from_points(joint_names: Sequence[str], q: ArrayLike, p: ArrayLike
                    ) -> TrainingRegion:
        """The region of configurations ``q`` (N, n) whose measured points are ``p``."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        p = np.atleast_2d(np.asarray(p, dtype=float))
        hull = None
        if len(p) >= 4:
            from scipy.spatial import ConvexHull, QhullError

            try:
                hull = p[ConvexHull(p).vertices]
            except (QhullError, ValueError):
                hull = None
        return TrainingRegion(tuple(joint_names), q.min(axis=0), q.max(axis=0), hull)


@dataclass(frozen=True)
class AccuracyModel:
    """What a calibration knows about its own accuracy (module docstring).

    Attributes:
        parameters: the estimated robot parameters the covariance is over.
        covariance: (p, p) their covariance [m, rad].
        point: (3,) the measured point in the flange (robot tool) frame [m].
        point_parameters: names of the point's estimated coordinates (``x y z`` order,
            None for a coordinate that was not estimated).
        point_covariance: (3, 3) covariance of the point's coordinates (0 where fixed).
        cross_covariance: (p, 3) covariance of the robot parameters with the point.
        floor_m: the unmodelled floor (RMS length of the 3-D error) [m].
        floor_source: ``"cross-validation"`` or ``"training residuals"``.
        region: the :class:`TrainingRegion`.
        floor_growth_m: growth ``g`` of the floor with the distance outside the training
            joint ranges [m per training half-range] (the region test's,
            :func:`kincal.identify.extrapolation.region_test`); None when unknown (0).
        instrument: the training session's instrument, for predictions of what it would
            measure: ``{"block": name, "values": its frame and marker (9) [m, rad],
            "nine": their names, "parameters": the estimated robot and block parameters,
            "covariance": over them, "nominal_values": the frame and marker registered to
            the nominal robot (for the comparison with it)}``; None when the calibration
            had no position block.
        tolerances: ``{robot parameter: manufacturing tolerance}`` [m, rad], the spread of
            the nominal robot's parameters about the real ones (its predicted error), or
            None (older result files).
    """

    parameters: tuple[str, ...]
    covariance: Array
    point: Array
    point_parameters: tuple[str | None, ...] = (None, None, None)
    point_covariance: Array = field(default_factory=lambda: np.zeros((3, 3)))
    cross_covariance: Array | None = None
    floor_m: float = 0.0
    floor_source: str = "training residuals"
    region: TrainingRegion | None = None
    instrument: Mapping[str, Any] | None = None
    floor_growth_m: float | None = None
    tolerances: Mapping[str, float] | None = None

    def floor_at(self, q: ArrayLike) -> Array:
        """(N,) the unmodelled floor at configurations ``q`` [m]:
        ``sqrt(floor^2 + (g d)^2)``, ``d`` their distance outside the training joint
        ranges (:meth:`TrainingRegion.distance`), ``g`` :attr:`floor_growth_m`."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        g = float(self.floor_growth_m or 0.0)
        d = self.region.distance(q) if self.region is not None and g > 0 else \
            np.zeros(len(q))
        return np.sqrt(float(self.floor_m) ** 2 + (g * d) ** 2)

    def __repr__(self) -> str:
        where = (f", training region over {len(self.region.joint_names)} joints"
                 if self.region is not None else "")
        return (f"AccuracyModel({len(self.parameters)} parameters, unmodelled floor "
                f"{self.floor_m * 1e3:.3g} mm from {self.floor_source}{where})")

    def _repr_html_(self) -> str:
        """Notebook display: what the model holds, one row each."""
        from kincal.io import html_table

        rows: list[list[str]] = [
            ["estimated parameters", str(len(self.parameters))],
            ["unmodelled floor [mm]", f"{self.floor_m * 1e3:.4g}"],
            ["floor from", self.floor_source],
            ["measured point in the flange frame [mm]",
             ", ".join(f"{v * 1e3:.4g}" for v in np.asarray(self.point).tolist())],
            ["training joints", ", ".join(self.region.joint_names)
             if self.region is not None else "-"]]
        return html_table(["", ""], rows, repr(self))

    def to_dict(self) -> dict[str, Any]:
        """The result JSON's ``accuracy_model`` (SI).  ``parameters`` / ``covariance`` /
        ``joint_*`` are the robot parameters alone (what ``kincal filter`` reads)."""
        reg = self.region
        cross = (np.zeros((len(self.parameters), 3)) if self.cross_covariance is None
                 else self.cross_covariance)
        return {"parameters": list(self.parameters), "covariance": self.covariance.tolist(),
                "joint_names": list(reg.joint_names) if reg else [],
                "joint_min": reg.joint_min.tolist() if reg else [],
                "joint_max": reg.joint_max.tolist() if reg else [],
                "hull_m": None if reg is None or reg.hull is None else reg.hull.tolist(),
                "point_m": self.point.tolist(), "point_parameters": list(self.point_parameters),
                "point_covariance": self.point_covariance.tolist(),
                "cross_covariance": cross.tolist(), "floor_m": self.floor_m,
                "floor_source": self.floor_source,
                "floor_growth_m": self.floor_growth_m,
                "instrument": None if self.instrument is None else {
                    "block": self.instrument["block"],
                    "values": list(map(float, self.instrument["values"])),
                    "nine": list(self.instrument["nine"]),
                    "nominal_values": None if self.instrument.get("nominal_values") is None
                    else list(map(float, self.instrument["nominal_values"])),
                    "parameters": list(self.instrument["parameters"]),
                    "covariance": np.asarray(self.instrument["covariance"]).tolist()},
                "tolerances": None if self.tolerances is None else {
                    str(k): float(v) for k, v in self.tolerances.items()},
                "note": "covariance of the estimated robot parameters and of the measured "
                        "point in the flange frame (m, rad); joint ranges (rad, m) and hull "
                        "(m, base frame) of the training data; floor: the unmodelled RMS "
                        "error (m)"}

    @staticmethod
    def from_dict(doc: Mapping[str, Any], source: str = "result") -> AccuracyModel:
        """Back from :meth:`to_dict` (one-line errors naming ``source``)."""
        try:
            names = tuple(doc["parameters"])
            C = np.asarray(doc["covariance"], dtype=float).reshape(len(names), len(names))
            hull = doc.get("hull_m")
            region = TrainingRegion(tuple(doc["joint_names"]),
                                    np.asarray(doc["joint_min"], dtype=float),
                                    np.asarray(doc["joint_max"], dtype=float),
                                    None if hull is None else np.asarray(hull, dtype=float))
            cross = doc.get("cross_covariance")
            tols = doc.get("tolerances")
            return AccuracyModel(
                names, C, np.asarray(doc.get("point_m", [0.0, 0.0, 0.0]), dtype=float),
                tuple(doc.get("point_parameters", (None, None, None))),
                np.asarray(doc.get("point_covariance", np.zeros((3, 3))), dtype=float),
                None if cross is None else np.asarray(cross, dtype=float).reshape(-1, 3),
                float(doc.get("floor_m", 0.0)), str(doc.get("floor_source", "")), region,
                doc.get("instrument"),
                None if doc.get("floor_growth_m") is None else float(doc["floor_growth_m"]),
                None if tols is None else {str(k): float(v) for k, v in dict(tols).items()})
        except (KeyError, TypeError, ValueError) as exc:
            raise KincalError(f"its accuracy_model is not readable ({exc.__class__.__name__}: "
                              f"{exc})", source=source) from None

    def with_floor(self, floor_m: float, source: str) -> AccuracyModel:
        import dataclasses

        return dataclasses.replace(self, floor_m=float(floor_m), floor_source=source)

    def with_floor_growth(self, growth_m: float | None) -> AccuracyModel:
        import dataclasses

        return dataclasses.replace(self, floor_growth_m=None if growth_m is None
                                   else float(growth_m))

    def with_region(self, region: TrainingRegion | None) -> AccuracyModel:
        import dataclasses

        return dataclasses.replace(self, region=region)


@dataclass
class Prediction:
    """The calibrated model's predicted accuracy at N configurations (module docstring).

    Attributes:
        std_position_m: (N,) from the parameter covariance [m].
        std_orientation_rad: (N,) of the flange orientation [rad].
        predicted_m: (N,) ``sqrt(std^2 + floor^2)``: the expected RMS error [m] (the
            floor grows outside the training joint ranges, :meth:`AccuracyModel.floor_at`).
        outside_joint_ranges, outside_hull: (N,) where the model extrapolates.
        correction_m: (N,) ``|P_cal - P_nom|`` [m] (None without a nominal robot).
        nominal_predicted_m: (N,) the nominal model's expected error [m] (or None):
            ``sqrt(min(|d_hat|^2 - std^2, s_tol^2) + floor^2)``, the correction the
            calibration makes there bounded by the tolerances propagated
            (:func:`nominal_spread`, ``s_tol``).
        worse_than_nominal: (N,) ``|d_hat| < sqrt(2) std`` (False without a nominal).
        position_m: (N, 3) the measured point predicted by the calibrated model [m].
    """

    std_position_m: Array
    std_orientation_rad: Array
    predicted_m: Array
    outside_joint_ranges: NDArray[np.bool_]
    outside_hull: NDArray[np.bool_]
    position_m: Array
    correction_m: Array | None = None
    nominal_predicted_m: Array | None = None
    worse_than_nominal: NDArray[np.bool_] = field(
        default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def outside(self) -> NDArray[np.bool_]:
        """Outside the joint ranges or the hull."""
        return self.outside_joint_ranges | self.outside_hull

    def __repr__(self) -> str:
        n = len(self.predicted_m)
        top = float(np.max(self.predicted_m, initial=0.0)) * 1e3
        return (f"Prediction({n} configurations: predicted position error up to {top:.3g} mm, "
                f"{int(np.sum(self.outside))} outside the training region)")

    def _repr_html_(self) -> str:
        """Notebook display: :meth:`summary`'s sentences under the headline."""
        from html import escape

        items = "".join(f"<li>{escape(s)}</li>" for s in self.summary())
        return f"<p>{escape(repr(self))}</p><ul>{items}</ul>"

    def summary(self, what: str = "poses",
                unit: tuple[float, str] = (1e3, "mm")) -> list[str]:
        """Sentences: how many configurations lie outside the training region and the
        predicted errors there, e.g. "412 of 587 poses lie outside the training joint
        ranges; predicted error there up to 8 mm, nominal 3 mm".

        ``unit`` is (factor from metres, name) of the lengths printed: ``(1e3, "mm")`` by
        default, ``(1.0, "m")`` for a console in SI units (``--si``).
        """
        f, u = unit
        n = len(self.predicted_m)
        out = []
        for mask, where in ((self.outside_joint_ranges, "outside the training joint ranges"),
                            (self.outside_hull & ~self.outside_joint_ranges,
                             "inside the joint ranges but outside the training workspace "
                             "hull")):
            k = int(mask.sum())
            if not k:
                continue
            text = (f"{k} of {n} {what} lie {where}; predicted error there up to "
                    f"{self.predicted_m[mask].max() * f:.3g} {u}")
            if self.nominal_predicted_m is not None:
                text += f", nominal {self.nominal_predicted_m[mask].max() * f:.3g} {u}"
            out.append(text)
        inside = ~self.outside
        if inside.any():
            out.append(f"{int(inside.sum())} of {n} {what} inside the training region: "
                       f"predicted error up to {self.predicted_m[inside].max() * f:.3g} {u}")
        worse = int(np.sum(self.worse_than_nominal))
        if worse:
            out.append(f"{worse} of {n} {what}: the calibrated model is predicted worse than "
                       "the nominal one (its correction is no larger than its uncertainty)")
        return out

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "std_position_m": self.std_position_m, "std_orientation_rad":
            self.std_orientation_rad, "predicted_m": self.predicted_m,
            "outside_joint_ranges": self.outside_joint_ranges,
            "outside_hull": self.outside_hull}
        if self.correction_m is not None:
            d.update({"correction_m": self.correction_m,
                      "nominal_predicted_m": self.nominal_predicted_m,
                      "worse_than_nominal": self.worse_than_nominal})
        return d


def _point_of(result: CalibrationResult) -> tuple[Array, list[int | None]]:
    """The measured point in the flange frame and the indices (into ``result.names``) of
    its coordinates: the first block's marker / probe / target ``x y z``."""
    names = list(result.names)
    for b in result.problem.blocks:
        spec = b.parameters()
        for n, role in zip(spec.names, spec.roles, strict=True):
            if role in ("tool_point", "target") and n.endswith(".x"):
                prefix = n[:-2]
                idx = [names.index(f"{prefix}.{c}") if f"{prefix}.{c}" in names else None
                       for c in "xyz"]
                value = np.array([result.theta[i] if i is not None else 0.0 for i in idx])
                return value, idx
            if role == "tool_point" and n.endswith(".l"):
                i = names.index(n)
                return np.array([0.0, 0.0, result.theta[i]]), [None, None, i]
        probe = b.probe if isinstance(b, HasProbe) else None
        if probe is not None and probe.mode == "vector" and probe.value:
            return np.asarray(probe.value, dtype=float), [None, None, None]
        if probe is not None and probe.mode == "length" and probe.value:
            return np.array([0.0, 0.0, probe.value[0]]), [None, None, None]
    return np.zeros(3), [None, None, None]


def floor_from_training(result: CalibrationResult) -> float:
    """``RMS_train^2 M / (M - p)`` (square root) [m]: the training position error with
    the leverage correction (module docstring); 0 when there is no redundancy."""
    errs = result.errors()
    pooled = [np.ravel(e[k]) for e in errs.values() for k in ("position_m", "coincidence_m")
              if k in e]
    if not pooled:
        return 0.0
    e = np.concatenate(pooled)
    M = result.residuals.size
    p = len(result.estimated)
    if M <= p:
        return float(np.sqrt(np.mean(e**2)))
    return float(np.sqrt(np.mean(e**2) * M / (M - p)))


def floor_from_cross_validation(model: AccuracyModel, robot: Robot, q_train: ArrayLike,
                                cv_rms: float) -> float:
    """``sqrt(max(0, CV_RMS^2 - mean std^2))`` [m] over the training configurations."""
    std = predict(model, robot, q_train).std_position_m
    return float(np.sqrt(max(0.0, cv_rms**2 - float(np.mean(std**2)))))


def accuracy_model(result: CalibrationResult, point: ArrayLike | None = None) -> AccuracyModel:
    """The :class:`AccuracyModel` of a calibration: covariance of the estimated robot
    parameters and of the measured point (``point`` given: that TCP, known), the training
    region of the measured point, and the floor from the training residuals (replace it
    with :func:`floor_from_cross_validation` when cross-validation ran)."""
    names = list(result.names)
    robot = result.robot
    est = list(result.estimated)
    pos = {n: k for k, n in enumerate(est)}
    rob = [n for n in est if n in robot.param_names]
    C = np.asarray(result.covariance, dtype=float)
    ri = [pos[n] for n in rob]
    if point is None:
        m, idx = _point_of(result)
    else:
        m, idx = np.asarray(point, dtype=float).reshape(3), [None, None, None]
    pk = [pos.get(names[i]) if i is not None else None for i in idx]
    Cpp = np.zeros((3, 3))
    Crp = np.zeros((len(rob), 3))
    for a, ka in enumerate(pk):
        if ka is None:
            continue
        Crp[:, a] = C[ri, ka] if ri else 0.0
        for b, kb in enumerate(pk):
            if kb is not None:
                Cpp[a, b] = C[ka, kb]
    readings = [getattr(b, "q", None) for b in result.problem.blocks]
    qs = [np.asarray(bq, dtype=float) for bq in readings
          if bq is not None and np.ndim(bq) == 2 and np.shape(bq)[1] == robot.n]
    q = np.vstack(qs) if qs else np.zeros((0, robot.n))
    model = AccuracyModel(tuple(rob), C[np.ix_(ri, ri)] if ri else np.zeros((0, 0)), m,
                          tuple(names[i] if i is not None and pk[k] is not None else None
                                for k, i in enumerate(idx)), Cpp, Crp,
                          floor_from_training(result), "training residuals",
                          instrument=_instrument_of(result) if point is None else None)
    if len(q):
        model = model.with_region(TrainingRegion.from_points(robot.joint_names, q,
                                                             _points(robot, q, m)))
    return model


def _instrument_of(result: CalibrationResult) -> dict[str, Any] | None:
    """The first position block's frame and first marker, and the covariance of the
    estimated robot parameters with the estimated ones of those (:class:`AccuracyModel`)."""
    names = list(result.names)
    pos = {n: k for k, n in enumerate(result.estimated)}
    for b in result.problem.blocks:
        inner = b
        while not isinstance(inner, PositionMeasurement) and hasattr(inner, "inner"):
            inner = inner.inner
        if not isinstance(inner, PositionMeasurement):
            continue
        spec = inner.parameters()
        nine = list(spec.names[:9])                      # frame (6) and the first marker
        if any(n not in names for n in nine):
            continue
        values = [float(result.theta[names.index(n)]) for n in nine]
        est = [n for n in result.estimated if n in result.robot.param_names or n in nine]
        k = [pos[n] for n in est]
        C = np.asarray(result.covariance, dtype=float)[np.ix_(k, k)]
        return {"block": inner.name, "values": values, "parameters": est, "covariance": C,
                "nine": nine}
    return None


def _points(robot: Robot, q: Array, m: Array) -> Array:
    T = robot.fk(np.atleast_2d(q))
    return T[:, :3, 3] + T[:, :3, :3] @ m


def predict(model: AccuracyModel, robot: Robot, q: ArrayLike, nominal: Robot | None = None,
            point: ArrayLike | None = None) -> Prediction:
    """The calibrated ``robot``'s predicted accuracy at configurations ``q`` (N, n).

    Args:
        model: the calibration's :class:`AccuracyModel` (:func:`accuracy_model`, or
            :meth:`AccuracyModel.from_dict` of a result JSON).
        robot: the calibrated robot (its parameters hold the estimates).
        q: (N, n) or (n,) joint values [rad / m].
        nominal: the nominal robot, for the comparison with it.
        point: a TCP in the flange frame [m] instead of the measured point (its
            coordinates then count as known).

    Returns a :class:`Prediction` (module docstring for the formulas).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if q.shape[1] != robot.n:
        raise KincalError(f"predicted accuracy: {q.shape[1]} joint values per configuration, "
                          f"robot {robot.name!r} has {robot.n}")
    missing = [n for n in model.parameters if n not in robot.param_names]
    if missing:
        raise KincalError(f"predicted accuracy: robot {robot.name!r} has no parameter "
                          f"{missing[0]!r} of the accuracy model")
    known = point is not None
    m = np.asarray(point, dtype=float).reshape(3) if known else model.point
    T, Jp = _fk_and_param_jacobian(robot, q)
    J = Jp[:, :, robot.param_indices(list(model.parameters))] if model.parameters else \
        np.zeros((len(q), 6, 0))
    R = T[:, :3, :3]
    a = R @ m
    G = J[:, :3, :] - np.cross(a[:, :, None], J[:, 3:, :], axis=1)
    C = model.covariance
    var = propagated_variance(G, C)
    if not known:
        Cpp = model.point_covariance
        Crp = model.cross_covariance if model.cross_covariance is not None else \
            np.zeros((len(model.parameters), 3))
        var = var + propagated_variance(R, Cpp) \
            + 2.0 * np.einsum("nik,nik->n", G @ Crp, R)
    std = np.sqrt(np.clip(var, 0.0, None))
    std_tcp = std
    y = None
    inst = model.instrument
    if not known and inst is not None:
        std, y = _instrument_std(inst, robot, q)
    Jw = J[:, 3:, :]
    std_w = np.sqrt(np.clip(propagated_variance(Jw, C), 0.0, None))
    P = T[:, :3, 3] + a
    reg = model.region
    out_j = reg.outside_joint_ranges(q) if reg is not None else np.zeros(len(q), bool)
    # the hull is of the measured point's training positions: test that point, whatever
    # TCP the prediction is for (a target's TCP may lie centimetres off the marker)
    P_meas = T[:, :3, 3] + R @ model.point
    out_h = reg.outside_hull(P_meas) if reg is not None else np.zeros(len(q), bool)
    floor = model.floor_at(q)
    pred = Prediction(std, std_w, np.sqrt(std**2 + floor**2), out_j, out_h,
                      P if y is None else y, worse_than_nominal=np.zeros(len(q), dtype=bool))
    if nominal is not None:
        if y is not None and inst is not None and inst.get("nominal_values") is not None:
            # in the instrument's view: each robot with the instrument registered to it
            y_nom = _instrument_view(inst, nominal, q, inst["nominal_values"])
            d, s = np.linalg.norm(y - y_nom, axis=1), std
        else:
            d, s = np.linalg.norm(_points(nominal, q, m) - P, axis=1), std_tcp
        pred.correction_m = d
        registered = inst if y is not None and inst is not None and \
            inst.get("nominal_values") is not None else None
        # the nominal robot's error: the correction the calibration makes here (what it
        # knows where it is trusted), never more than the tolerances allow anywhere
        # (far from the data the correction is the calibration's own extrapolation)
        spread = np.sqrt(np.clip(d**2 - s**2, 0.0, None))
        bound = nominal_spread(model, nominal, q, m, registered)
        if bound is not None:                   # older files carry no tolerances
            spread = np.minimum(spread, bound)
        pred.nominal_predicted_m = np.sqrt(spread**2 + float(model.floor_m) ** 2)
        pred.worse_than_nominal = d < math.sqrt(2.0) * s
    return pred


def predict_spread(model: AccuracyModel, robot: Robot, q: ArrayLike, groups: ArrayLike
                   ) -> Array:
    """(N,) predicted RMS distance of the measured point from the mean of its group [m]:
    what an artifact's held-out *spread* (seatings of one socket about their mean) is.

    ``P_i = p_e(q_i) + R_e(q_i) m``; with ``G_i = dP_i / d(theta, m)`` over the estimated
    robot parameters and the point's estimated coordinates, ``C`` their covariance and
    ``n`` the size of configuration ``i``'s group,
    ``spread_i^2 = (G_i - mean_group G) C (G_i - mean_group G)^T + floor_i^2 (1 - 1/n)``:
    what moves every seating of a socket alike (base, socket position) does not spread it.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    g = np.asarray(groups).reshape(-1)
    if len(g) != len(q):
        raise KincalError(f"predicted spread: {len(g)} group labels for {len(q)} "
                          "configurations")
    T, Jp = _fk_and_param_jacobian(robot, q)
    J = Jp[:, :, robot.param_indices(list(model.parameters))] if model.parameters else \
        np.zeros((len(q), 6, 0))
    R = T[:, :3, :3]
    G = np.concatenate([J[:, :3, :] - np.cross((R @ model.point)[:, :, None], J[:, 3:, :],
                                               axis=1), R], axis=2)
    p = len(model.parameters)
    cross = model.cross_covariance if model.cross_covariance is not None else \
        np.zeros((p, 3))
    C = np.block([[model.covariance, cross], [cross.T, model.point_covariance]])
    floor = model.floor_at(q)
    var = np.zeros(len(q))
    for label in np.unique(g):
        k = g == label
        D = G[k] - G[k].mean(axis=0)
        var[k] = propagated_variance(D, C) + floor[k] ** 2 * (1.0 - 1.0 / k.sum())
    return np.sqrt(np.clip(var, 0.0, None))


def nominal_spread(model: AccuracyModel, nominal: Robot, q: ArrayLike,
                   point: ArrayLike, registered: Mapping[str, Any] | None = None
                   ) -> Array | None:
    """The nominal robot's predicted position error from its tolerances [m], (N,), or None
    when ``model`` carries no tolerances.

    The real robot's parameters lie about the nominal ones with standard deviations
    ``s_j`` (the manufacturing tolerances, :mod:`kincal.identify.tolerances`): a
    parameter error ``dtheta ~ N(0, diag s^2)``.

    * In the robot's base frame, at the point ``m`` (flange frame):
      ``E|dP|^2 = sum_j s_j^2 |G_j|^2`` with ``G = J_v - [R m]x J_w`` the position
      Jacobian over those parameters.
    * ``registered`` (:attr:`AccuracyModel.instrument` with ``nominal_values``) and at
      least 4 configurations distinct to 1 mrad: what the instrument sees of the nominal robot,
      its frame and marker registered to it on these configurations (the "before
      (re-registered)" of a held-out file): with ``B = J_theta diag(s)`` the stacked
      (3N, k) observation Jacobian over the toleranced parameters and ``J_phi`` (3N, 9)
      over the frame and marker, the registration removes ``J_phi J_phi^+ B``, so
      ``E|e_i|^2`` is the sum of squares of the 3 rows of pose ``i`` of
      ``(I - J_phi J_phi^+) B``.  (Registered on the training data instead, the
      spread far from it would grow with the registration's own extrapolation, which
      is the instrument's, not the nominal robot's.)

    Parameters without a tolerance (the base and tool frames) add nothing.  The spread
    is bounded by what the tolerances allow wherever the robot is: it cannot explode
    where a calibration extrapolates.
    """
    tols = {n: float(v) for n, v in (model.tolerances or {}).items()
            if n in nominal.param_names and np.isfinite(v) and v > 0}
    if model.tolerances is None:
        return None
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if not tols:
        return np.zeros(len(q))
    names = list(tols)
    s = np.array([tols[n] for n in names])
    if registered is not None and len(np.unique(q.round(3), axis=0)) >= 4:
        block = PositionMeasurement(q, np.zeros((len(q), 3)), 1.0, str(registered["block"]))
        _, Jr, Je = _jacobians_of(block, nominal,
                                  np.asarray(registered["nominal_values"], dtype=float))
        B = Jr[:, nominal.param_indices(names)] * s
        E = B - Je[:, :9] @ np.linalg.lstsq(Je[:, :9], B, rcond=None)[0]
        return np.asarray(np.sqrt(np.sum(E.reshape(len(q), 3, -1) ** 2, axis=(1, 2))),
                          dtype=float)
    T, Jp = _fk_and_param_jacobian(nominal, q)
    J = Jp[:, :, nominal.param_indices(names)]
    a = T[:, :3, :3] @ np.asarray(point, dtype=float).reshape(3)
    G = J[:, :3, :] - np.cross(a[:, :, None], J[:, 3:, :], axis=1)
    return np.asarray(np.sqrt(np.sum((G * s) ** 2, axis=(1, 2))), dtype=float)


def _instrument_view(inst: Mapping[str, Any], robot: Robot, q: Array, values: Any) -> Array:
    """What the instrument of ``inst`` sees of ``robot`` at ``q`` with its frame and marker
    ``values`` (9): (N, 3) [m]."""
    block = PositionMeasurement(q, np.zeros((len(q), 3)), 1.0, str(inst["block"]))
    return block.evaluate(robot, np.asarray(values, dtype=float), jacobian=False)[0
                                                                               ].reshape(-1, 3)


def _instrument_std(inst: Mapping[str, Any], robot: Robot, q: Array) -> tuple[Array, Array]:
    """The std of what the training instrument would measure at ``q`` [m], through the
    robot, its frame and its marker (``inst``: :attr:`AccuracyModel.instrument`), and the
    predicted observations (N, 3) in the instrument frame."""
    name = str(inst["block"])
    block = PositionMeasurement(q, np.zeros((len(q), 3)), 1.0, name)
    values = np.asarray(inst["values"], dtype=float)
    r, Jr, Je = _jacobians_of(block, robot, values)
    nine = list(inst.get("nine") or block.parameters().names)
    cols = []
    for n in inst["parameters"]:
        if n in nine:
            cols.append(Je[:, nine.index(n)])
        elif n in robot.param_names:
            cols.append(Jr[:, robot.param_index(n)])
        else:
            raise KincalError(f"predicted accuracy: no parameter {n!r} in robot "
                              f"{robot.name!r} or instrument {name!r}")
    G = np.stack(cols, axis=1).reshape(len(q), 3, -1) if cols else np.zeros((len(q), 3, 0))
    var = propagated_variance(G, inst["covariance"])
    return np.sqrt(np.clip(var, 0.0, None)), r.reshape(len(q), 3)
