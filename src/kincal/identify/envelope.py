"""The envelope a calibrated robot carries: where it was trained, how accurate it is, and
what it was made from, so that every later use can say when it extrapolates.

An :class:`Envelope` holds

* the **accuracy model** (:class:`~kincal.identify.accuracy.AccuracyModel`): the
  covariance of what was identified, the unmodelled floor, the manufacturing
  tolerances (the nominal robot's predicted error) and the **training region** (joint
  ranges and the convex hull of the measured point's positions);
* the **data** it came from: file names, their SHA-256 hashes and row counts;
* the **calibrated robot** as kincal estimated it (its YAML robot document, in the
  parametrisation the covariance is over): the robot that carries the envelope may be
  written in another one (a URDF, an elementary-transform chain) but must have the same
  joints and the same forward kinematics, within :data:`SAME_KINEMATICS` m / rad at
  configurations spread over the training joint ranges; a robot whose parameters were
  changed after calibrating is not the one the envelope describes;
* the date (UTC, ISO 8601) and the kincal version.

It travels with the robot as ``robot.meta["calibration"]``: the YAML robot file's
``calibration:`` section; for a URDF (or a UR kinematics file) the sidecar
``NAME.envelope.yaml`` next to it (:func:`kincal.robots.files.write_envelope_sidecar`),
read by :func:`kincal.robots.files.load_serial_robot`.  :func:`envelope_of` reads it back and
checks it against the robot (one line for a corrupted or mismatched section).
:func:`predict_with_envelope` gives the predicted error at any configurations and
:func:`outside_line` the loud sentence a command prints when it is used outside the
training region.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from kincal._version import __version__
from kincal.errors import KincalError
from kincal.identify.accuracy import AccuracyModel, Prediction, predict
from kincal.robots.chain import Robot

__all__ = ["ENVELOPE_FORMAT", "SAME_KINEMATICS", "DataFile", "Envelope", "file_sha256",
           "make_envelope", "envelope_of", "with_envelope", "robot_and_accuracy",
           "predict_with_envelope", "outside_line"]

#: Version of the ``calibration:`` section's layout.
ENVELOPE_FORMAT = 1
#: Largest difference of position [m] and rotation [rad] of two files of one robot.
SAME_KINEMATICS = 1e-6


@dataclass(frozen=True)
class DataFile:
    """A file the calibration was made from: its name, SHA-256 (hex) and row count."""

    name: str
    sha256: str
    rows: int | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"file": self.name, "sha256": self.sha256, "rows": self.rows}


def file_sha256(path: str | os.PathLike[str]) -> str:
    """The SHA-256 of a file's bytes, hex ("" when it cannot be read)."""
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    except OSError:
        return ""
    return h.hexdigest()


@dataclass(frozen=True)
class Envelope:
    """What a calibrated robot carries so that a later user can trust it (module docstring).

    Attributes:
        accuracy: the calibration's accuracy model with its training region.
        robot: the calibrated robot, in the parametrisation the covariance is over
            (the one to predict with).
        robot_doc: its YAML robot document (:func:`kincal.robots.files.robot_to_dict`).
        data: the training files.
        created: the date of the calibration (UTC, ISO 8601).
        kincal_version: the version of kincal that made it.
    """

    accuracy: AccuracyModel
    robot: Robot
    robot_doc: Mapping[str, Any]
    data: tuple[DataFile, ...] = ()
    created: str = ""
    kincal_version: str = __version__

    def to_dict(self) -> dict[str, Any]:
        """The ``calibration:`` section (plain YAML/JSON values, SI units)."""
        acc = self.accuracy.to_dict()
        acc.pop("note", None)
        return {"format": ENVELOPE_FORMAT, "created": self.created,
                "kincal_version": self.kincal_version,
                "data": [d.to_dict() for d in self.data],
                "accuracy_model": acc, "robot": dict(self.robot_doc),
                "note": "written by kincal calibrate: the training region (joint ranges [rad, "
                        "m], workspace hull [m]), the accuracy model (covariance of the "
                        "estimated parameters [m, rad], unmodelled floor [m], tolerances), "
                        "the data it came from, the calibrated robot (robot:); kincal warns "
                        "when the robot is used outside the region. Remove this section if "
                        "you change the robot."}

    @staticmethod
    def from_dict(doc: Any, source: str = "robot file") -> Envelope:
        """Back from :meth:`to_dict`; one-line :class:`KincalError` naming ``source``."""
        where = "its calibration: section"
        if not isinstance(doc, Mapping):
            raise KincalError(f"{where} is not a mapping", source=source)
        fmt = doc.get("format")
        if fmt != ENVELOPE_FORMAT:
            raise KincalError(f"{where} has format {fmt!r}, this kincal reads format "
                              f"{ENVELOPE_FORMAT} (written by another version?)", source=source)
        try:
            robot_doc = doc["robot"]
            if not isinstance(robot_doc, Mapping):
                raise TypeError("robot is not a mapping")
            data = tuple(DataFile(str(d["file"]), str(d["sha256"]),
                                  None if d.get("rows") is None else int(d["rows"]))
                         for d in doc.get("data") or [])
            acc_doc = doc["accuracy_model"]
            if not isinstance(acc_doc, Mapping):
                raise TypeError("accuracy_model is not a mapping")
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise KincalError(f"{where} is not readable ({exc.__class__.__name__}: {exc})",
                              source=source) from None
        acc = AccuracyModel.from_dict(acc_doc, source)
        _check_shapes(acc, source)
        from kincal.robots.files import robot_from_dict

        try:
            twin = robot_from_dict(dict(robot_doc), source)
        except KincalError as exc:
            raise KincalError(f"{where}: its robot is not readable ({exc})") from None
        if not isinstance(twin, Robot):
            raise KincalError(f"{where}: its robot is not a serial robot", source=source)
        missing = [n for n in acc.parameters if n not in twin.param_names]
        if missing:
            raise KincalError(f"{where}: its accuracy model has parameter {missing[0]!r} "
                              "that its robot lacks", source=source)
        reg = acc.region
        if reg is not None and tuple(reg.joint_names) != tuple(twin.joint_names):
            raise KincalError(f"{where}: its training region is for other joints "
                              f"({', '.join(reg.joint_names)})", source=source)
        return Envelope(acc, twin, dict(robot_doc), data, str(doc.get("created", "")),
                        str(doc.get("kincal_version", "")))

    def check(self, robot: Robot, source: str = "robot file") -> None:
        """Raise one line when the envelope does not describe ``robot``: other joints, or
        other forward kinematics (parameters changed after calibrating)."""
        if tuple(robot.joint_names) != tuple(self.robot.joint_names):
            raise KincalError("its calibration: section is for another robot (joints "
                              f"{', '.join(self.robot.joint_names)}, not "
                              f"{', '.join(robot.joint_names)})", source=source)
        reg = self.accuracy.region
        lo = reg.joint_min if reg is not None else -np.ones(robot.n)
        hi = reg.joint_max if reg is not None else np.ones(robot.n)
        k = np.arange(1, 17)[:, None] * np.sqrt(np.arange(2, robot.n + 2))[None, :]
        q = lo + (hi - lo) * np.mod(k, 1.0)          # spread over the ranges, deterministic
        Ta, Tb = robot.fk(q), self.robot.fk(q)
        dp = float(np.max(np.linalg.norm(Ta[:, :3, 3] - Tb[:, :3, 3], axis=1)))
        dr = float(np.max(np.abs(Ta[:, :3, :3] - Tb[:, :3, :3])))
        if dp > SAME_KINEMATICS or dr > SAME_KINEMATICS:
            raise KincalError(
                f"its calibration: section does not match the robot (forward kinematics "
                f"differ by {dp * 1e3:.3g} mm / {dr:.3g} rad over the training region: "
                "changed after calibrating? remove the section to use the robot without "
                "it)", source=source)


def _check_shapes(acc: AccuracyModel, source: str) -> None:
    """Array shapes and finiteness of an accuracy model read from a file."""
    p = len(acc.parameters)
    reg = acc.region
    bad = ""
    if acc.covariance.shape != (p, p) or not np.all(np.isfinite(acc.covariance)):
        bad = "covariance"
    elif reg is not None and (reg.joint_min.shape != (len(reg.joint_names),)
                              or reg.joint_max.shape != (len(reg.joint_names),)):
        bad = "joint ranges"
    elif reg is not None and reg.hull is not None and (reg.hull.ndim != 2
                                                       or reg.hull.shape[1] != 3):
        bad = "hull"
    elif not np.isfinite(acc.floor_m) or acc.floor_m < 0:
        bad = "floor"
    if bad:
        raise KincalError(f"its calibration: section has an unreadable {bad}", source=source)


def make_envelope(accuracy: AccuracyModel, robot: Robot,
                  data: Sequence[str | os.PathLike[str]] = (),
                  rows: Sequence[int | None] | None = None,
                  created: str | None = None) -> Envelope:
    """The :class:`Envelope` of a calibrated ``robot`` from its accuracy model and its
    training files (hashed here); ``created`` defaults to now (UTC)."""
    if created is None:
        created = _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat()
    counts = list(rows) if rows is not None else [None] * len(data)
    files = tuple(DataFile(Path(p).name, file_sha256(p), n)
                  for p, n in zip(data, counts, strict=True))
    from kincal.robots.files import robot_to_dict

    bare = with_envelope(robot, None)
    return Envelope(accuracy, bare, robot_to_dict(bare), files, created, __version__)


def with_envelope(robot: Robot, envelope: Envelope | None) -> Robot:
    """``robot`` carrying ``envelope`` in ``meta["calibration"]`` (None: without one)."""
    import dataclasses

    meta = {k: v for k, v in robot.meta.items()
            if k not in ("calibration", "calibration_source")}
    if envelope is not None:
        meta["calibration"] = envelope.to_dict()
    return dataclasses.replace(robot, meta=meta)


def envelope_of(robot: Robot, source: str | None = None) -> Envelope | None:
    """The envelope ``robot`` carries (checked against it), or None (no section).

    ``source`` names the file in the one-line errors (default: the robot's name).
    """
    doc = robot.meta.get("calibration")
    if doc is None:
        return None
    src = source or str(robot.meta.get("calibration_source") or robot.name)
    env = Envelope.from_dict(doc, src)
    env.check(robot, src)
    return env


def robot_and_accuracy(robot: Robot) -> tuple[Robot, AccuracyModel | None]:
    """The robot to compute with and the accuracy model of the envelope it carries:
    ``(envelope robot, its accuracy model)`` (same kinematics, the parametrisation of the
    covariance), or ``(robot, None)`` without an envelope."""
    env = envelope_of(robot)
    if env is None:
        return robot, None
    return env.robot, env.accuracy


def predict_with_envelope(robot: Robot, q: ArrayLike, nominal: Robot | None = None,
                          point: ArrayLike | None = None) -> Prediction | None:
    """The predicted error of ``robot`` at configurations ``q`` (N, n) from the envelope it
    carries (:func:`kincal.identify.accuracy.predict`), or None without one."""
    env = envelope_of(robot)
    if env is None:
        return None
    return predict(env.accuracy, env.robot, q, nominal=nominal, point=point)


def outside_line(pred: Prediction, what: str = "poses", robot: str = "the robot",
                 unit: tuple[float, str] = (1e3, "mm")) -> str | None:
    """One loud sentence when some configurations lie outside the training region, e.g.
    "12 of 40 poses lie outside the training region of motoman_right (joint ranges or
    workspace hull): the calibration extrapolates there, predicted error up to 3.1 mm
    (nominal 2.0 mm)"; None when all lie inside."""
    out = pred.outside
    k = int(np.sum(out))
    if not k:
        return None
    f, u = unit
    text = (f"{k} of {len(out)} {what} lie outside the training region of {robot} (joint "
            f"ranges or workspace hull): the calibration extrapolates there, predicted "
            f"error up to {pred.predicted_m[out].max() * f:.3g} {u}")
    if pred.nominal_predicted_m is not None:
        text += f" (nominal {pred.nominal_predicted_m[out].max() * f:.3g} {u})"
    return text
