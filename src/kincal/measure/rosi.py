"""ROS-Industrial kinematic-calibration observations (YAML), read as recorded.

The ``industrial_calibration`` kinematic calibration examples store their observations
as one YAML map, one entry per observation (the key is a time stamp)::

    '1593701755':
      camera_joints: []
      pose: {qw: 0.31, qx: -0.18, qy: -0.65, qz: -0.67, x: -0.53, y: -0.77, z: 0.94}
      target_joints: [-0.523, 0.0002]

``target_joints`` are the joint values of the chain that carries the target (rad / m, in
the robot's joint order), ``pose`` the target frame in the camera frame (m, unit
quaternion).  With a static camera (``camera_joints`` empty) this is kincal's ``pose``
instrument: ``T_obs = T_I^-1 T_e(q) T_t``, the camera frame ``T_I`` and the target on the
tool ``T_t`` estimated.  A moving camera (``camera_joints`` not empty) is refused.

Standard deviations come from the file's options as for any pose file (``sigma: 0.5mm``,
``sigma_rot: 0.1deg`` in a setup file; default 1e-5: 0.01 mm and 1e-5 rad).
Every error names the file and the YAML line of the observation.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from kincal.errors import MeasurementFileError
from kincal.io import read_text
from kincal.measure.base import Provenance
from kincal.measure.files import MeasurementTable, file_tags
from kincal.measure.instruments.pose import PoseMeasurement
from kincal.measure.instruments.position import UNNAMED, scalar_sigma, tag_sigma
from kincal.measure.orientation import QUATERNION_COLUMNS, pose_rotations
from kincal.spatial import homogeneous

__all__ = ["read_rosi_observations", "is_rosi_observations"]

_POSE_KEYS = ("x", "y", "z", *QUATERNION_COLUMNS)


def _load(path: str | os.PathLike[str]) -> Any:
    import yaml

    src = str(path)
    text = read_text(path, "observation file", MeasurementFileError)
    try:
        return yaml.compose(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else 1
        raise MeasurementFileError(f"line {line}: not YAML ({getattr(exc, 'problem', exc)})",
                                   source=src) from None


def is_rosi_observations(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is a YAML map whose first entry has ``target_joints`` and ``pose``."""
    import yaml

    try:
        data = yaml.safe_load(read_text(path, "observation file", MeasurementFileError))
    except (yaml.YAMLError, MeasurementFileError):
        return False
    if not isinstance(data, dict) or not data:
        return False
    first = next(iter(data.values()))
    return isinstance(first, dict) and "target_joints" in first and "pose" in first


def _number(node: Any, what: str, src: str) -> float:
    line = node.start_mark.line + 1
    try:
        v = float(node.value)
    except (TypeError, ValueError):
        raise MeasurementFileError(f"line {line}: {what}: {node.value!r} is not a number",
                                   source=src) from None
    if not np.isfinite(v):
        raise MeasurementFileError(f"line {line}: {what} is not finite", source=src)
    return v


def _entry(key: Any, node: Any, n: int, src: str) -> tuple[list[float], dict[str, float]]:
    """The joint values and pose numbers of one observation (one error line if bad)."""
    import yaml

    line = key.start_mark.line + 1
    if not isinstance(node, yaml.MappingNode):
        raise MeasurementFileError(f"line {line}: observation {key.value!r} is not a map "
                                   "(target_joints, camera_joints, pose)", source=src)
    fields = {k.value: v for k, v in node.value}
    for need in ("target_joints", "pose"):
        if need not in fields:
            raise MeasurementFileError(f"line {line}: observation {key.value!r} has no "
                                       f"{need}", source=src)
    cam = fields.get("camera_joints")
    if isinstance(cam, yaml.SequenceNode) and cam.value:
        raise MeasurementFileError(f"line {cam.start_mark.line + 1}: camera_joints: a moving "
                                   "camera is not supported (only a static camera, [])",
                                   source=src)
    tj = fields["target_joints"]
    if not isinstance(tj, yaml.SequenceNode):
        raise MeasurementFileError(f"line {tj.start_mark.line + 1}: target_joints is not a "
                                   "list", source=src)
    q = [_number(v, "target_joints", src) for v in tj.value]
    if len(q) != n:
        raise MeasurementFileError(f"line {tj.start_mark.line + 1}: {len(q)} target_joints, "
                                   f"but the robot has {n} joints", source=src)
    pose = fields["pose"]
    if not isinstance(pose, yaml.MappingNode):
        raise MeasurementFileError(f"line {pose.start_mark.line + 1}: pose is not a map of "
                                   "x, y, z, qw, qx, qy, qz", source=src)
    pf = {k.value: v for k, v in pose.value}
    missing = [k for k in _POSE_KEYS if k not in pf]
    if missing:
        raise MeasurementFileError(f"line {pose.start_mark.line + 1}: pose has no "
                                   f"{missing[0]!r} (x, y, z in m; qw, qx, qy, qz)", source=src)
    return q, {k: _number(pf[k], f"pose.{k}", src) for k in _POSE_KEYS}


def read_rosi_observations(path: str | os.PathLike[str], robot: Any,
                           name: str | None = None) -> list[PoseMeasurement]:
    """One :class:`~kincal.measure.instruments.pose.PoseMeasurement` from a ROS-I
    observation YAML (see the module text); the file's options (``sigma_mm=...``) come
    from :func:`kincal.measure.files.tag_overrides`, as for a CSV."""
    import yaml

    src = str(path)
    root = _load(path)
    if not isinstance(root, yaml.MappingNode) or not root.value:
        raise MeasurementFileError("line 1: not a map of observations (stamp: {target_joints,"
                                   " camera_joints, pose})", source=src)
    rows, lines, qs = [], [], []
    for key, node in root.value:
        q, pose = _entry(key, node, robot.n, src)
        qs.append(q)
        rows.append(pose)
        lines.append(key.start_mark.line + 1)
    values = {k: np.array([r[k] for r in rows]) for k in _POSE_KEYS}
    tags = file_tags(path, "")
    t = MeasurementTable(src, tags, np.array(qs, dtype=float), values,
                         {**{c: "m" for c in "xyz"}, **{c: "1" for c in QUATERNION_COLUMNS}},
                         np.array(lines, dtype=np.intp), [], {k: k for k in _POSE_KEYS}, 1,
                         ["read as a ROS-Industrial observation YAML (target_joints rad, "
                          "pose m and quaternion)"])
    R, _ = pose_rotations(t)
    P = homogeneous(R, np.stack([values[c] for c in "xyz"], axis=1))
    block = PoseMeasurement(t.q, P, sigma_position=scalar_sigma(None, tag_sigma(t, "sigma")),
                            sigma_orientation=scalar_sigma(None, tag_sigma(t, "sigma_rot")),
                            name=name or tags.get("name") or UNNAMED)
    block.provenance = Provenance(src, t)
    return [block]
