"""Validation of a robot on held-out files: what ``kincal validate`` does, as a library call.

:func:`validate_on_files` evaluates a robot (and optionally the nominal robot, the
"before" column) on held-out blocks with the protocols of
:func:`kincal.workflow.flow.validate_blocks`; given the result JSON of ``kincal
calibrate``, the instrument frames and markers, the nominal robot's registration and
the predicted accuracy come from it; without it, the predicted accuracy and the training
region come from the envelope the calibrated robot carries
(:mod:`kincal.identify.envelope`), and :attr:`HeldOutValidation.warnings` says loudly
which files it extrapolates on.  The errors are physical (m, rad); the pooled
figures are :func:`kincal.report.metrics.error_metrics` of all files' errors together.
:meth:`HeldOutValidation.to_dict` is the JSON document of ``kincal validate --json``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from kincal.identify.accuracy import AccuracyModel
from kincal.measure.base import MeasurementModel
from kincal.report.metrics import error_metrics, merge_errors
from kincal.robots.chain import Robot
from kincal.workflow.heldout import BEFORE_DEFINITION, HeldOutFile

__all__ = ["HeldOutValidation", "validate_on_files"]


@dataclasses.dataclass(frozen=True)
class HeldOutValidation:
    """A robot's errors on held-out files.

    Attributes:
        robot: the validated robot's name.
        files: one :class:`~kincal.workflow.heldout.HeldOutFile` per block.
        compared_before: a nominal robot was evaluated too (each file's ``before``).
        accuracy: the calibration's accuracy model (from the result JSON), or None.
        extras: ``{parameter: value}`` of the result JSON (instrument frames and
            markers of the same session), or None.
        iso9283: the ISO 9283 figures per file (``kincal validate --iso9283``), or None.
        accuracy_from: where the accuracy model came from: ``"result"`` (the result
            JSON), ``"robot"`` (the envelope the calibrated robot carries) or ``""``.
    """

    robot: str
    files: list[HeldOutFile]
    compared_before: bool = False
    accuracy: AccuracyModel | None = None
    extras: dict[str, float] | None = None
    iso9283: dict[str, Any] | None = None
    accuracy_from: str = ""

    @property
    def warnings(self) -> list[str]:
        """One loud sentence per file with poses outside the training region."""
        from kincal.identify.envelope import outside_line

        out = []
        for f in self.files:
            if f.prediction is not None:
                line = outside_line(f.prediction, "poses", self.robot)
                if line:
                    out.append(f"{f.file}: {line}")
        return out

    def to_dict(self) -> dict[str, Any]:
        """The JSON document of ``kincal validate --json``: the pooled metrics (after and,
        with a nominal robot, before), each file's metrics and, with an accuracy model,
        each file's predicted accuracy and the poses outside the calibrated region."""
        files = self.files
        doc: dict[str, Any] = {"robot": self.robot,
                               "overall": error_metrics(merge_errors([f.after for f in files])),
                               "files": {f.block.source_label: f.metrics() for f in files},
                               "before_definition": BEFORE_DEFINITION}
        if self.iso9283 is not None:
            doc["iso9283"] = self.iso9283
        if self.compared_before:
            doc["overall_before"] = error_metrics(merge_errors([f.before for f in files]))
        if self.accuracy is not None:
            doc["accuracy_from"] = self.accuracy_from
            doc["warnings"] = self.warnings
            doc["predicted"] = {f.block.source_label: {
                "outside_joint_ranges": f.prediction.outside_joint_ranges,
                "outside_hull": f.prediction.outside_hull, **f.prediction.to_dict()}
                for f in files if f.prediction is not None}
        return doc


def validate_on_files(robot: Robot, blocks: Sequence[MeasurementModel],
                      before: Robot | None = None, result: str | Path | None = None,
                      validation_frames: str = "auto") -> HeldOutValidation:
    """Errors of ``robot`` (and of the nominal ``before``) on held-out ``blocks``.

    Args:
        robot: the robot to validate (usually a calibrated one).
        blocks: the held-out measurements, one block per file.
        before: the nominal robot, evaluated by the same protocol.
        result: the result JSON of ``kincal calibrate``: its instrument frames and
            markers, the nominal robot's registration and (if present) the accuracy model;
            without it, the accuracy model of the envelope ``robot`` carries (if any).
        validation_frames: ``"training"`` (the result's frames, no refit), ``"register"``
            (frames refitted on each file), ``"auto"`` (training with a result).
    """
    from kincal.workflow.flow import (
        accuracy_from_result,
        extras_from_result,
        result_document,
        validate_blocks,
    )

    extras = extras_from_result(result) if result else None
    doc_in = result_document(result) if result else {}
    accuracy, source, model_robot = None, "", robot
    if isinstance(doc_in.get("accuracy_model"), dict):
        accuracy, source = accuracy_from_result(str(result), robot), "result"
    elif not result:
        from kincal.identify.envelope import envelope_of

        env = envelope_of(robot)
        if env is not None:
            accuracy, source = env.accuracy, "robot"
            model_robot = env.robot
    files = validate_blocks(robot, blocks, before, extras, validation_frames,
                            extras_from_result(result, "before") if result else None,
                            accuracy if model_robot is robot else None)
    if accuracy is not None and model_robot is not robot:    # the envelope's own robot
        from kincal.identify.accuracy import predict

        for f in files:
            q = getattr(f.block, "q", None)
            if "position_m" in f.after and q is not None:
                f.prediction = predict(accuracy, model_robot, q, nominal=before)
                f.point_errors = np.asarray(f.after["position_m"]).reshape(len(q), -1)[:, 0]
    return HeldOutValidation(robot.name, files, before is not None, accuracy, extras,
                             accuracy_from=source)
