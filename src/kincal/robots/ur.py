"""Universal Robots calibration files: the controller's ``calibration.conf`` and ROS's
kinematics YAML.

**calibration.conf** (the controller's factory calibration, section ``[mounting]``)::

    delta_theta = [ 2.0e-05, 0.968, -1.857, 0.889, 5.7e-05, -7.5e-05]
    delta_a = [ ... ]            # m
    delta_d = [ ... ]            # m
    delta_alpha = [ ... ]        # rad

holds per-joint corrections to the nominal standard-DH table (``theta_offset[i] +=
delta_theta[i]``, ``a[i] += delta_a[i]``, ...).  Joints 2, 3 and 4 are parallel, so
the factory fit may slide their frames far along the axes: ``delta_d`` of hundreds of
metres that cancel (``d2 + d3 + d4`` stays near its nominal value).  The forward
kinematics is still exact.

**kinematics YAML** (``Universal_Robots_ROS2_Description/config/<ur>/default_kinematics.yaml``,
written by the ROS driver's calibration extraction): per joint ``{x, y, z, roll, pitch,
yaw}``, the joint's URDF ``<origin>`` relative to the previous joint's frame (``Trans(x,
y, z) Rz(yaw) Ry(pitch) Rx(roll)``), the joint turning about its frame's z.  The
shoulder origin is relative to ``base_link_inertia`` (= the DH base frame); the last
frame (``wrist_3_link``) is the flange (``tool0``: the description's ``flange`` and
``tool0`` rotations compose to the identity).

Writing (:func:`kinematics_yaml`) places every joint frame where it is physically
useful: the calibrated joint axis is known, but a frame may slide along its axis and
turn about it without changing the kinematics (``Rz(q)`` commutes with ``Tz(s) Rz(phi)``).
Each frame is put at the point of its axis nearest the nominal model's joint frame, with
its x axis nearest the nominal x axis, so every origin stays within millimetres of the
nominal one instead of the hundreds of metres a literal DH-to-URDF conversion gives; the
forward kinematics round-trips to 1e-12 m.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np
import yaml
from numpy.typing import NDArray

from kincal.errors import RobotFileError
from kincal.io import read_text
from kincal.robots.chain import ChainBuilder, Robot
from kincal.spatial import inverse, matrix_to_rpy, rotz, xyzrpy_to_matrix

Array = NDArray[np.float64]

__all__ = ["KINEMATICS_LINKS", "UR_MODELS", "hash_kept", "joint_frames", "kinematics_yaml",
           "read_calibration_conf", "read_kinematics_yaml"]

#: The kinematics YAML's keys, one per joint, base to tip.
KINEMATICS_LINKS = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
#: The built-in UR models (``kincal robots``), smallest first within each series.
UR_MODELS = ("ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e", "ur20", "ur30")
_KEYS = ("x", "y", "z", "roll", "pitch", "yaw")
_NUM = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"


def _check_ur(nominal: Robot, source: str) -> None:
    if nominal.n != 6 or nominal.meta.get("convention") != "standard_dh":
        raise RobotFileError(f"the nominal robot {nominal.name!r} must be a 6-joint standard-DH "
                             "robot (a built-in UR: "
                             f"{', '.join(UR_MODELS)})",
                             source=source)


def read_calibration_conf(path: str | os.PathLike[str], nominal: Robot) -> Robot:
    """The calibrated robot of a UR controller's ``calibration.conf`` on its nominal model.

    Every ``delta_*`` list must have 6 numbers; its values are added to the nominal DH
    table (m, rad).  Errors name the file, line and key.
    """
    source = str(path)
    _check_ur(nominal, source)
    text = read_text(path, "UR calibration file", RobotFileError)
    deltas: dict[str, list[float]] = {}
    for lineno, line in enumerate(text.splitlines(), 1):
        body = line.split("#", 1)[0]
        m = re.match(r"\s*(delta_(?:theta|a|d|alpha))\s*=\s*\[(.*)\]\s*$", body)
        if m is None:
            if re.match(r"\s*delta_", body):
                raise RobotFileError(f"line {lineno}: {body.strip()!r} is not 'delta_x = "
                                     "[6 numbers]'", source=source)
            continue
        parts = [p.strip() for p in m.group(2).split(",")]
        if len(parts) != 6 or not all(re.fullmatch(_NUM, p) for p in parts):
            raise RobotFileError(f"line {lineno}: {m.group(1)} needs 6 numbers, got "
                                 f"[{m.group(2).strip()}]", source=source)
        deltas[m.group(1)] = [float(p) for p in parts]
    missing = [k for k in ("delta_theta", "delta_a", "delta_d", "delta_alpha") if k not in deltas]
    if missing:
        raise RobotFileError(f"no {', '.join(missing)} (a UR calibration.conf has delta_theta, "
                             "delta_a, delta_d and delta_alpha)", source=source)
    values = nominal.params()
    for i in range(6):
        values[f"theta_offset[{i + 1}]"] += deltas["delta_theta"][i]
        values[f"a[{i + 1}]"] += deltas["delta_a"][i]
        values[f"d[{i + 1}]"] += deltas["delta_d"][i]
        values[f"alpha[{i + 1}]"] += deltas["delta_alpha"][i]
    robot = nominal.with_params(values).with_name(f"{nominal.name}_calibrated")
    meta = dict(robot.meta)
    meta["source"] = f"{nominal.name} with the factory calibration of {Path(source).name}"
    return Robot(robot.name, robot.ets, robot.joints, robot.param_names, robot.param_values,
                 robot.param_units, robot.param_roles, meta)


def read_kinematics_yaml(path: str | os.PathLike[str], nominal: Robot | None = None) -> Robot:
    """A robot from a ROS kinematics YAML (``kinematics: {shoulder: {x, ...}, ...}``).

    The chain is, per joint, ``Tx Ty Tz Rz(yaw) Ry(pitch) Rx(roll)`` with the parameters
    ``<link>.x .y .z .yaw .pitch .roll``, then ``Rz(q)``.  Joint names and limits are the
    nominal robot's when given (else UR's names, unlimited).
    """
    source = str(path)
    try:
        data = yaml.safe_load(read_text(path, "UR calibration file", RobotFileError))
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark else ""
        raise RobotFileError(f"{where}invalid YAML", source=source) from None
    kin = data.get("kinematics") if isinstance(data, dict) else None
    if not isinstance(kin, dict):
        raise RobotFileError("no 'kinematics:' mapping", source=source)
    b = ChainBuilder(f"{Path(source).stem}")
    b.frame("base")
    names = list(nominal.joint_names) if nominal is not None else [
        "shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
    lim = nominal.joint_limits if nominal is not None else np.full((6, 2), [-np.inf, np.inf])
    for k, link in enumerate(KINEMATICS_LINKS):
        entry = kin.get(link)
        if not isinstance(entry, dict):
            raise RobotFileError(f"field 'kinematics.{link}' is missing", source=source)
        v = {}
        for key in _KEYS:
            x = entry.get(key)
            if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
                raise RobotFileError(f"field 'kinematics.{link}.{key}' must be a number, got "
                                     f"{x!r}", source=source)
            v[key] = float(x)
        j = b.joint(names[k], "revolute", float(lim[k, 0]), float(lim[k, 1]))
        for kind, key, role in (("Tx", "x", "length"), ("Ty", "y", "length"),
                                ("Tz", "z", "length"), ("Rz", "yaw", "angle"),
                                ("Ry", "pitch", "angle"), ("Rx", "roll", "angle")):
            b.transform(kind, f"{link}.{key}", v[key], role=role)
        b.transform("Rz", None, 0.0, joint=j)
    b.frame("tool")
    meta = {"source": f"ROS kinematics YAML {Path(source).name}"}
    if isinstance(kin.get("hash"), str):            # the robot's calibration checksum
        meta["ur_hash"] = kin["hash"]
    if nominal is not None and "controller" in nominal.meta:
        meta["controller"] = nominal.meta["controller"]
    return b.build(meta=meta)


def joint_frames(robot: Robot, after_slide: bool = False) -> Array:
    """(6, 4, 4) the frame in which each joint turns about z, at q = 0, in the base frame.

    Works on any chain whose joints are ``Rz`` factors (standard DH, the kinematics YAML
    chain): the frame is the running product of the elementary transforms before the
    joint's factor.  With ``after_slide``, after the factor and the ``Tz`` right after it
    (standard DH's ``Rz(theta) Tz(d)``: the frame ur_description puts each joint at).
    """
    from kincal.robots.chain import elementary_matrix

    out = []
    T = np.eye(4)
    pending = False
    for et in robot.ets:
        c = float(robot.param_values[et.param]) if et.param >= 0 else et.constant
        if pending and (et.kind != "Tz" or et.joint >= 0):
            out.append(T.copy())
            pending = False
        if et.joint >= 0:
            if et.kind != "Rz" or et.scale != 1.0:
                raise RobotFileError(f"robot {robot.name!r}: joint {robot.joints[et.joint].name} "
                                     "is not a rotation about its frame's z")
            if after_slide:
                pending = True
            else:
                out.append(T.copy())
        T = T @ elementary_matrix(et.kind, c)
        if pending and et.kind == "Tz" and et.joint < 0:
            out.append(T.copy())
            pending = False
    if pending:
        out.append(T.copy())
    if len(out) != 6:
        raise RobotFileError(f"robot {robot.name!r} has {len(out)} joints, a UR has 6")
    tail = inverse(out[-1]) @ robot.fk(np.zeros(robot.n))
    if not (np.allclose(tail[:3, 2], [0, 0, 1], atol=1e-12)
            and np.allclose(tail[:2, 3], 0, atol=1e-12)):
        raise RobotFileError(f"robot {robot.name!r}: its flange is not on the last joint's axis "
                             "with z along it (a tool frame?); the kinematics YAML ends at the "
                             "flange")
    return np.array(out)


def _nearest(F: Array, N: Array) -> Array:
    """``F Tz(s) Rz(phi)`` with its origin nearest N's origin and its x nearest N's x."""
    z = F[:3, 2]
    s = float(np.dot(N[:3, 3] - F[:3, 3], z))
    xn = inverse(F)[:3, :3] @ N[:3, 0]
    phi = math.atan2(xn[1], xn[0])
    G = F.copy()
    G[:3, 3] = F[:3, 3] + s * z
    G[:3, :3] = F[:3, :3] @ rotz(phi)
    return G


def kinematics_yaml(robot: Robot, nominal: Robot, hash_text: str | None = None) -> str:
    """The ROS kinematics YAML of ``robot``, frames placed nearest ``nominal``'s (module
    docstring).  The joint readings are unchanged: each joint's zero stays where the
    robot has it (its encoder offset is folded into the next origin's yaw).

    ``hash``: ``hash_text``, else the one read with the robot (``meta["ur_hash"]``, a
    round trip of an unchanged file), else ``calib_kincal_<name>``.  The UR driver
    compares it with the robot's own calibration checksum (:func:`hash_kept`)."""
    _check_ur(nominal, nominal.name)
    F = joint_frames(robot)
    N = joint_frames(nominal, after_slide=True)
    G = [_nearest(F[k], N[k]) for k in range(6)]
    # the offset of joint k: G_k = F_k Tz Rz(phi_k) and F_k already contains Rz(c_k) of the
    # DH offset; the chain is G_0 Rz(q_1) (G_0^-1 G_1) Rz(q_2) ... and the end frame is
    # G_5 Rz(q_6) (G_5^-1 E) with E the end frame at q = 0.  The URDF-style YAML has no tail
    # after the last joint, so the last frame's turn and slide must vanish: keep G_5 = E
    # (the flange), which lies on axis 6 by construction.
    G[5] = robot.fk(np.zeros(robot.n))
    doc_lines = ["kinematics:"]
    prev = np.eye(4)
    for link, Gk in zip(KINEMATICS_LINKS, G, strict=True):
        O = inverse(prev) @ Gk
        roll, pitch, yaw = matrix_to_rpy(O[:3, :3])
        vals = dict(zip(_KEYS, (*O[:3, 3], roll, pitch, yaw), strict=True))
        doc_lines.append(f"  {link}:")
        doc_lines += [f"    {k}: {_num(vals[k])}" for k in _KEYS]
        prev = Gk
    kept = robot.meta.get("ur_hash")
    hash_text = hash_text or (kept if isinstance(kept, str) else None)
    doc_lines.append(f"  hash: {hash_text or 'calib_kincal_' + robot.name}")
    return "\n".join(doc_lines) + "\n"


def hash_kept(text: str) -> bool:
    """Whether a kinematics YAML ``text`` keeps a factory hash (``calib_<checksum>``) rather
    than kincal's ``calib_kincal_<name>``."""
    m = re.search(r"^\s*hash:\s*(\S+)", text, re.MULTILINE)
    return m is not None and not m.group(1).startswith("calib_kincal_")


def _num(v: float) -> str:
    v = float(v)
    if v == 0.0:
        return "0"
    return repr(v)


def check_round_trip(robot: Robot, text: str, nominal: Robot, q: Array) -> float:
    """Largest position difference [m] between ``robot`` and the YAML ``text`` at q."""
    import tempfile

    with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as f:
        f.write(text)
    try:
        back = read_kinematics_yaml(f.name, nominal)
    finally:
        os.unlink(f.name)
    return float(np.max(np.abs(back.fk(q) - robot.fk(q))[:, :3, 3]))


def frame_matrix_of(entry: dict[str, float]) -> Array:
    """``Trans(x, y, z) Rz(yaw) Ry(pitch) Rx(roll)`` of a kinematics YAML entry."""
    return xyzrpy_to_matrix(np.array([entry[k] for k in ("x", "y", "z", "roll", "pitch",
                                                         "yaw")]))

