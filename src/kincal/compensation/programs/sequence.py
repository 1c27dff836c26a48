"""Targets that take part of their value from the previous position (KRL partial
aggregates such as ``LIN {X 0, Y 0, Z 100}``).

The controller fills the components an aggregate leaves out with those of the previous
position: the previous motion's target, expressed in this motion's tool and base frames
(KSS programming manual, PTP / LIN target points).  :func:`resolve_partials` does the
same, in program order, so that the target can be filtered as a whole pose;
:func:`partial_residual` says how far the filtered program still is from the filtered
pose, since at run time the left-out components come from the previous target as the
filtered program writes it (the difference of the corrections of two targets).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from kincal.compensation.programs.base import Array, Frames, ProgramTarget, Slot
from kincal.robots.chain import Robot
from kincal.robots.controller import ControllerMap
from kincal.spatial import inverse, log_so3

FramesOf = Callable[[Any, ProgramTarget, Frames], tuple[Array, Array]]


def _with_values(t: ProgramTarget, values: Mapping[str, float]) -> ProgramTarget:
    """A copy of ``t`` whose numbers are ``values`` (same frames, configuration)."""
    c = ProgramTarget(t.name, t.file, t.line, t.column, t.kind,
                      {k: Slot(0, 0, "", float(v)) for k, v in values.items()},
                      t.config, t.tool_key, t.base_key)
    return c


def _flange(prog: Any, t: ProgramTarget, pose_of: Callable[[ProgramTarget], Array],
            frames_of: FramesOf, frames: Frames, at: tuple[Any, Any]) -> Array:
    """The flange pose [m] of pose target ``t`` in the frames it had at that motion."""
    keep = t.tool_key, t.base_key
    t.tool_key, t.base_key = at
    try:
        user, tool = frames_of(prog, t, frames)
    finally:
        t.tool_key, t.base_key = keep
    return user @ pose_of(t) @ inverse(tool)


def _frames_key(fr: Any) -> tuple[Any, Any]:
    return (fr.tool, fr.base)


def resolve_partials(prog: Any, targets: Sequence[ProgramTarget], nominal: Robot,
                     cmap: ControllerMap, frames: Frames, joint_keys: Sequence[str],
                     pose_of: Callable[[ProgramTarget], Array],
                     pose_values: Callable[[ProgramTarget, Array], dict[str, float]],
                     frames_of: FramesOf, offline_joints: bool) -> None:
    """Set ``extra["resolved"]`` (the left-out components) of every target with
    ``extra["missing"]``, from its ``extra["previous"]``: ``(target, frames)`` of the
    previous motion or a string saying why it is not known (then the target gets a note,
    or, an axis target whose joints stay as taught, is kept)."""
    done: set[int] = set()

    def resolve(t: ProgramTarget, depth: int = 0) -> bool:
        if id(t) in done:
            return "resolved" in t.extra
        done.add(id(t))
        prev = t.extra.get("previous")
        missing = list(t.extra["missing"])
        given = [k for k in t.slots if k not in ("s", "t")]
        why = ""
        if t.note:
            return False
        if isinstance(prev, str) or prev is None:
            why = f"the previous position is not known ({prev})"
        else:
            pt, pfr = prev
            if "missing" in pt.extra and (depth > 50 or not resolve(pt, depth + 1)):
                why = f"the previous position ({pt.name}) is not known"
            elif t.kind == "joints" and offline_joints:
                why = "--joint-targets offline rewrites the previous axis values"
            elif t.kind == "joints":
                if pt.kind == "joints":
                    v = dict(zip(joint_keys, pt.values(joint_keys), strict=True))
                    t.extra["resolved"] = {k: v[k] for k in missing}
                else:
                    why = "it follows a Cartesian target (its axis values are not written)"
            else:
                if pt.kind == "joints":
                    F = nominal.fk(cmap.to_model(pt.values(joint_keys)))
                else:
                    F = _flange(prog, pt, pose_of, frames_of, frames, _frames_key(pfr))
                same = pt.kind == "pose" and _frames_key(pfr) == (t.tool_key, t.base_key)
                if same:
                    t.extra["resolved"] = {k: float(pt.values([k])[0]) for k in missing}
                else:
                    user, tool = frames_of(prog, t, frames)
                    t.extra["resolved"] = dict.fromkeys(missing, 0.0)
                    if pt.kind == "pose":    # angles near the previous target's own
                        t.extra["resolved"].update(
                            {k: float(pt.values([k])[0]) for k in missing})
                    full = pose_values(t, inverse(user) @ F @ tool)
                    t.extra["resolved"] = {k: full[k] for k in missing}
        if why:
            if t.kind == "joints" and not offline_joints:
                t.note = ("partial axis target, taught on the robot: kept ("
                          f"{', '.join(missing).upper()} keep their values)")
                t.extra["kept"] = True
            else:
                t.note = (f"partial aggregate ({', '.join(given).upper()}): "
                          f"{', '.join(missing).upper()} come from the previous position "
                          f"at run time, and {why}")
            return False
        return True

    for t in targets:
        if "missing" in t.extra and t.used:
            resolve(t)


def run_time_values(prog: Any, t: ProgramTarget, new: Mapping[int, dict[str, float]],
                    pose_of: Callable[[ProgramTarget], Array],
                    pose_values: Callable[[ProgramTarget, Array], dict[str, float]],
                    frames_of: FramesOf, frames: Frames, depth: int = 0) -> dict[str, float]:
    """All components of target ``t`` as the controller has them at run time in the
    filtered program: its own as rewritten (``new``, by target id), the left-out ones
    from the previous target as it is at run time (recursively, for a chain of partial
    targets)."""
    mine = {k: float(t.slots[k].value) for k in t.slots}
    mine.update(new.get(id(t), {}))
    if "missing" not in t.extra:
        return mine
    pt, pfr = t.extra["previous"]
    if pt.kind == "joints" or depth > 50:
        return {**t.extra["resolved"], **mine}
    pvals = run_time_values(prog, pt, new, pose_of, pose_values, frames_of, frames, depth + 1)
    if _frames_key(pfr) == (t.tool_key, t.base_key):
        missing = {k: pvals[k] for k in t.extra["missing"]}
    else:
        F = _flange(prog, _with_values(pt, pvals), pose_of, frames_of, frames,
                    _frames_key(pfr))
        user, tool = frames_of(prog, t, frames)
        full = pose_values(t, inverse(user) @ F @ tool)
        missing = {k: full[k] for k in t.extra["missing"]}
    return {**missing, **mine}


def run_time_pose(prog: Any, t: ProgramTarget, new: Mapping[int, dict[str, float]],
                  pose_of: Callable[[ProgramTarget], Array],
                  pose_values: Callable[[ProgramTarget, Array], dict[str, float]],
                  frames_of: FramesOf, frames: Frames) -> Array:
    """The pose (user frame, [m]) the controller assembles at run time for the partial
    target ``t`` of the filtered program (:func:`run_time_values`)."""
    return pose_of(_with_values(t, run_time_values(prog, t, new, pose_of, pose_values,
                                                   frames_of, frames)))


def pose_distance(A: Array, B: Array) -> tuple[float, float]:
    """``|p_A - p_B|`` [mm] and the angle between the rotations [deg] of two poses."""
    dp = float(np.linalg.norm(A[:3, 3] - B[:3, 3]) * 1e3)
    dr = float(np.degrees(np.linalg.norm(log_so3(A[:3, :3] @ B[:3, :3].T))))
    return dp, dr
