"""Held joints: a joint that never moves during a calibration, fixed at a stated value.

A tool changer, a locked gripper mount or an axis the cell never uses is a joint of the
robot file but not of the calibration: its measurement files have no column for it, or
one that never changes.  :func:`hold_joints` returns the robot without those joints:
in the chain ``E_k = X(c_k + s_k q_j)`` of a held joint ``j`` the joint variable is
replaced by its value ``v``,

    E_k = X(c_k) X(s_k v)

(two transforms about the same axis add up), so the named constant ``c_k`` (the joint's
offset or origin) stays a parameter and every other joint keeps its parameters and
order.  ``robot.meta["held_joints"]`` records ``{name: v}`` [rad / m] (and
``meta["held_joint_kinds"]`` their kinds); the measurement
file reader skips (and checks) columns of held joints.

Layer rule: part of :mod:`kincal.robots`; imports the chain and the shared root modules.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Mapping

from kincal.errors import KincalError
from kincal.robots.chain import ElementaryTransform, Robot

__all__ = ["hold_joints", "held_joints"]


def held_joints(robot: object) -> dict[str, float]:
    """``{joint name: value}`` [rad / m] of the joints held in ``robot`` (``{}`` if none)."""
    meta = getattr(robot, "meta", None) or {}
    return {str(k): float(v) for k, v in dict(meta.get("held_joints") or {}).items()}


def hold_joints(robot: Robot, values: Mapping[str, float], source: str | None = None
                ) -> Robot:
    """``robot`` with the joints in ``values`` held at those values [rad / m].

    Args:
        robot: a serial robot.
        values: ``{joint name: value}``; a value outside the joint's limits is an error.
        source: where ``values`` came from, for messages (``"setup.yaml: hold"``).

    Returns a new :class:`~kincal.robots.chain.Robot` with ``n - len(values)`` joints and
    the same parameters; ``meta["held_joints"]`` lists every held joint.
    """
    if not values:
        return robot
    where = source or "hold"
    index = {j.name: i for i, j in enumerate(robot.joints)}
    for name, v in values.items():
        if name not in index:
            close = difflib.get_close_matches(str(name), list(index), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else \
                f" (joints: {', '.join(index)})"
            raise KincalError(f"{where}: robot {robot.name!r} has no joint {name!r}{hint}")
        j = robot.joints[index[name]]
        if not math.isfinite(v):
            raise KincalError(f"{where}: {name}: the value must be finite")
        if not j.lower - 1e-12 <= v <= j.upper + 1e-12:
            unit, f = ("deg", 180 / math.pi) if j.kind == "revolute" else ("mm", 1e3)
            raise KincalError(f"{where}: {name} = {v * f:.6g} {unit} is outside its limits "
                              f"[{j.lower * f:.6g}, {j.upper * f:.6g}] {unit}")
    if len(values) >= robot.n:
        raise KincalError(f"{where}: holding every joint of {robot.name!r} leaves nothing to "
                          "move")
    held = {index[n]: float(v) for n, v in values.items()}
    keep = [i for i in range(robot.n) if i not in held]
    renumber = {old: new for new, old in enumerate(keep)}
    ets: list[ElementaryTransform] = []
    for et in robot.ets:
        if et.joint in held:
            ets.append(dataclasses.replace(et, joint=-1))
            ets.append(ElementaryTransform(et.kind, -1, et.scale * held[et.joint]))
        elif et.joint >= 0:
            ets.append(dataclasses.replace(et, joint=renumber[et.joint]))
        else:
            ets.append(et)
    meta = {**dict(robot.meta),
            "held_joints": {**held_joints(robot),
                            **{robot.joints[i].name: v for i, v in held.items()}},
            "held_joint_kinds": {**dict(robot.meta.get("held_joint_kinds") or {}),
                                 **{robot.joints[i].name: robot.joints[i].kind for i in held}}}
    return dataclasses.replace(robot, ets=tuple(ets),
                               joints=tuple(robot.joints[i] for i in keep), meta=meta)
