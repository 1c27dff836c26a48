"""Compensation of a target list, with the predicted accuracy and the fallback to nominal.

For targets ``T_i`` (N, 4, 4) poses or (N, 3) positions [m] the calibrated robot's IK
gives joint commands ``q_i`` with ``FK_cal(q_i) = T_i``
(:func:`kincal.compensation.compensate.compensate`); with the controller's nominal robot
the filtered targets are ``FK_nominal(q_i)``.  Given the calibration's accuracy model, the
predicted accuracy at every ``q_i`` is added, and with ``fallback="nominal"`` each target
where the calibrated model is predicted worse than the nominal one is sent uncompensated
(nominal IK joints, the target itself as filtered target).  Nothing is returned unless
every target is reached (:class:`~kincal.errors.UnreachableError` names the first one).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.compensation.compensate import (
    Compensation,
    compensate,
    fall_back_to_nominal,
    require_all,
)
from kincal.errors import KincalError
from kincal.identify.accuracy import AccuracyModel, Prediction, predict
from kincal.robots.chain import Robot

FALLBACKS: tuple[str, ...] = ("none", "nominal")


@dataclass(frozen=True)
class CompensationRun:
    """Joint commands for a target list and, if an accuracy model was given, the
    predicted accuracy at them.

    ``compensation`` holds the commands (``q`` [rad / m]), the residual errors and the
    filtered targets; ``predicted`` is ``None`` without an accuracy model; ``targets`` and
    ``output`` are the file names reported in :meth:`to_dict` (``None`` if not from files).
    """

    robot: str
    joint_names: tuple[str, ...]
    compensation: Compensation
    predicted: Prediction | None
    targets: str | None = None
    output: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON document of ``kincal compensate --json`` (arrays as numpy arrays)."""
        comp = self.compensation
        doc: dict[str, Any] = {
            "robot": self.robot, "targets": self.targets, "mask": comp.mask,
            "branch_changes": comp.branch_changes,
            "q": comp.q, "position_error_m": comp.position_error,
            "orientation_error_rad": comp.orientation_error,
            "joint_names": list(self.joint_names), "output": self.output}
        if comp.filtered is not None:
            doc["filtered"] = comp.filtered
            doc["correction_m"] = comp.correction
        if self.predicted is not None:
            doc["predicted"] = self.predicted.to_dict()
            doc["fallback_nominal"] = (comp.fallback if comp.fallback is not None
                                       else np.zeros(len(comp), dtype=bool))
        return doc


def compensate_targets(calibrated: Robot, targets: ArrayLike, *,
                       nominal: Robot | None = None,
                       seeds: ArrayLike | None = None,
                       accuracy: AccuracyModel | None = None,
                       fallback: Literal["none", "nominal"] = "none",
                       source: str | None = None,
                       lines: NDArray[np.intp] | None = None,
                       output: str | None = None) -> CompensationRun:
    """Compensate ``targets`` on the ``calibrated`` robot, predict, and fall back.

    Args:
        calibrated: the calibrated (real) robot.
        targets: (N, 4, 4) poses or (N, 3) positions [m].
        nominal: the controller's nominal robot (filtered targets, IK branch, fallback).
        seeds: (N, n) joint seeds for the IK [rad / m], or ``None``.
        accuracy: the calibration's accuracy model; adds the predicted accuracy.
        fallback: ``"nominal"`` sends the targets predicted worse than nominal
            uncompensated (needs ``nominal`` and ``accuracy``); ``"none"`` keeps them.
        source, lines: the targets file and its line numbers, for the error message.
        output: the joint-command file name, reported in :meth:`CompensationRun.to_dict`.
    """
    if fallback not in FALLBACKS:
        raise KincalError(f"fallback: {fallback!r} is not none or nominal")
    if fallback == "nominal" and (nominal is None or accuracy is None):
        raise KincalError("fallback nominal needs the nominal robot and the accuracy model")
    comp = compensate(calibrated, targets, nominal=nominal, q0=seeds)
    require_all(comp, source, lines)
    pred = None
    if accuracy is not None:
        pred = predict(accuracy, calibrated, comp.q, nominal=nominal, point=np.zeros(3))
        if fallback == "nominal" and nominal is not None:
            comp = fall_back_to_nominal(comp, calibrated, nominal, np.asarray(targets),
                                        pred.worse_than_nominal)
    return CompensationRun(robot=calibrated.name, joint_names=tuple(calibrated.joint_names),
                           compensation=comp, predicted=pred, targets=source, output=output)
