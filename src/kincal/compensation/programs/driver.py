"""Filter a whole program: read it, filter its targets, write the numbers back.

:func:`filter_program` is what ``kincal filter`` runs.  Per dialect it needs the
target's pose in its user frame, its user (base) and tool frames, the conversion of
axis values to model joints (:class:`~kincal.robots.controller.ControllerMap`), and
back.  The result holds the new text of every file and one :class:`TargetReport` per
target.  Units: the program's own (mm / deg, m / rad for URScript) in the files; SI
inside.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from kincal.compensation.filter import (
    FilterResult,
    TargetRequest,
    filter_targets,
    nominal_solutions,
)
from kincal.compensation.programs.base import (
    Array,
    Frames,
    ProgramTarget,
    Slot,
    render,
)
from kincal.errors import KincalError
from kincal.motion.ik_closed_form import NotThisFamily
from kincal.motion.ik_wrist import ik_spherical_wrist
from kincal.robots.chain import Robot
from kincal.robots.controller import ControllerMap, controller_map
from kincal.spatial import inverse

if TYPE_CHECKING:
    from kincal.identify.accuracy import AccuracyModel

DIALECTS = ("krl", "rapid", "urscript", "fanuc-ls")
_SUFFIX = {".src": "krl", ".dat": "krl", ".mod": "rapid", ".modx": "rapid", ".prg": "rapid",
           ".sys": "rapid", ".sysx": "rapid",
           ".script": "urscript", ".urscript": "urscript", ".ls": "fanuc-ls"}
_VENDOR = {"krl": "kuka", "rapid": "abb", "urscript": "ur", "fanuc-ls": "fanuc"}


def dialect_of(path: str | Sequence[str], dialect: str = "auto") -> str:
    """The dialect named, or the one the file's suffix says (a folder or several files:
    RAPID modules, the one language read as a set of files)."""
    if dialect != "auto":
        if dialect not in DIALECTS:
            raise KincalError(f"option --dialect: unknown dialect {dialect!r}; use auto, "
                              f"{', '.join(DIALECTS)}")
        if not isinstance(path, str) and len(path) > 1 and dialect != "rapid":
            raise KincalError(f"a {dialect} program is one file; several files are read "
                              "together only as RAPID modules")
        return dialect
    if not isinstance(path, str):
        kinds = {dialect_of(p) for p in path}
        if kinds != {"rapid"}:
            raise KincalError("several program files are read together only as RAPID "
                              f"modules (.mod, .modx, .sys, .prg), not {sorted(kinds)}")
        return "rapid"
    if Path(path).is_dir():
        return "rapid"
    d = _SUFFIX.get(Path(path).suffix.lower())
    if d is None:
        raise KincalError(f"cannot tell the program language from the suffix "
                          f"{Path(path).suffix!r}; give --dialect {'|'.join(DIALECTS)}",
                          source=path)
    return d


@dataclass
class TargetReport:
    """One row of the per-target table."""

    name: str
    file: str
    line: int
    kind: str
    status: str              # filtered | unchanged | not filtered | unused | kept | partial
    shift_mm: float
    shift_deg: float
    predicted_std_mm: float
    warnings: list[str]
    reason: str
    index: int | None = None     # row of the FilterResult (None: not filtered at all)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "file": self.file, "line": self.line, "kind": self.kind,
                "status": self.status, "shift_mm": self.shift_mm, "shift_deg": self.shift_deg,
                "predicted_std_mm": None if math.isnan(self.predicted_std_mm)
                else self.predicted_std_mm, "warnings": self.warnings, "reason": self.reason}


@dataclass
class FilteredProgram:
    """New file texts (input path -> text) and the per-target reports; ``program`` is the
    program's path, ``robot`` / ``nominal`` the names of the calibrated and the
    controller's robot."""

    dialect: str
    texts: dict[str, str]
    originals: dict[str, str]
    reports: list[TargetReport]
    result: FilterResult | None
    program: str = ""
    robot: str = ""
    nominal: str = ""

    @property
    def failed(self) -> list[TargetReport]:
        return [r for r in self.reports if r.status == "not filtered"]

    def to_dict(self, outputs: Sequence[str] = ()) -> dict[str, Any]:
        """The JSON document of ``kincal filter --json`` (``outputs``: the written files)."""
        return {"program": self.program, "dialect": self.dialect, "robot": self.robot,
                "nominal": self.nominal, "outputs": list(outputs),
                "targets": [r.to_dict() for r in self.reports]}


@dataclass
class DialectOps:
    """What the driver needs from a dialect."""

    read: Callable[[Any], Any]            # path(s) -> object with .texts, .targets
    pose_of: Callable[[ProgramTarget], Array]          # user-frame pose [m]
    pose_values: Callable[[ProgramTarget, Array], dict[str, float]]
    joint_keys: tuple[str, ...]
    frames: Callable[[Any, ProgramTarget, Frames], tuple[Array, Array]]   # (user, tool)
    digits: Callable[[Any, str], int]                  # (program, slot key) -> min decimals
    config_values: Callable[[ProgramTarget, Array, Array], dict[str, float]]
    pad: bool = False


def _numbered_frames(prog: Any, t: ProgramTarget, fr: Frames) -> tuple[Array, Array]:
    """(user, tool) of a target whose frames are numbers of the frames file (KRL, FANUC)."""
    origin = f"{t.name} ({Path(t.file).name}:{t.line})"
    return fr.get("base", t.base_key, origin), fr.get("tool", t.tool_key, origin)


def _ops(dialect: str) -> DialectOps:
    if dialect == "krl":
        from kincal.compensation.programs import krl

        return DialectOps(krl.read_krl, krl.pose_of, krl.pose_values,
                          ("a1", "a2", "a3", "a4", "a5", "a6"), _numbered_frames,
                          lambda p, k: krl.digits(k),
                          krl.config_values)
    if dialect == "rapid":
        from kincal.compensation.programs import rapid

        return DialectOps(rapid.read_rapid, rapid.pose_of, rapid.pose_values,
                          rapid.JOINT_KEYS, rapid.frames, rapid.digits, rapid.config_values)
    if dialect == "urscript":
        from kincal.compensation.programs import urscript

        return DialectOps(urscript.read_urscript, urscript.pose_of, urscript.pose_values,
                          urscript.JOINT_KEYS, urscript.frames, lambda p, k: 7,
                          urscript.config_values)
    from kincal.compensation.programs import fanuc

    return DialectOps(fanuc.read_ls, fanuc.pose_of, fanuc.pose_values, fanuc.JOINT_KEYS,
                      _numbered_frames, lambda p, k: 0,         # the file's 3 decimals
                      fanuc.config_values, pad=True)


def read_program(path: str | Sequence[str], dialect: str = "auto") -> tuple[str, Any]:
    """``(dialect, program)``: the program read by its dialect's reader (bad content is a
    one-line :class:`~kincal.compensation.programs.base.ProgramError`)."""
    d = dialect_of(path, dialect)
    return d, _ops(d).read(path)


def _previous_joints(t: ProgramTarget, ops: DialectOps, prog: Any, frames: Frames,
                     nominal: Robot, cmap: ControllerMap, fallback: Array | None,
                     depth: int = 0) -> Array | None:
    """The nominal controller's joints at the target before ``t`` in program order
    (``t.extra["after"]``): where a controller without configuration monitoring starts
    from.  A joint target gives its axes; a pose target its nominal solution, on its own
    configuration or, unmonitored too, nearest to the one before it."""
    prev = t.extra.get("after")
    if not isinstance(prev, ProgramTarget) or prev.note or not prev.slots or depth > 50:
        return fallback
    if prev.kind == "joints":
        return cmap.to_model(prev.values(ops.joint_keys))
    try:
        user, tool = ops.frames(prog, prev, frames)
    except KincalError:
        return fallback
    seed = _previous_joints(prev, ops, prog, frames, nominal, cmap, fallback, depth + 1)
    F = user @ ops.pose_of(prev) @ inverse(tool)
    if "after" in prev.extra and seed is not None:
        return nearest_branch(nominal, F, seed)
    start = np.zeros(nominal.n) if seed is None else seed
    fixed = _prescribed_joints(prev, cmap, nominal.n)
    q, ok, _ = nominal_solutions(nominal, cmap, F[None], [prev.config], start[None],
                                 None if fixed is None else fixed[None])
    return q[0] if ok[0] else fallback


def nearest_branch(robot: Robot, F: Array, q_prev: Array) -> Array:
    """The joint solution of flange pose F (4, 4) [m] closest to ``q_prev`` (n,) [rad]:
    every closed-form branch, each joint moved by whole turns towards ``q_prev`` where the
    limits allow, the least ``|q - q_prev|``; what a controller with configuration
    monitoring off reaches.  ``q_prev`` itself when the robot has no closed form or F is
    out of reach (the numerical IK seeded there then decides)."""
    try:
        sol = ik_spherical_wrist(robot, F[None])
    except NotThisFamily:
        return q_prev
    cands = sol.q[0][sol.reachable[0]]
    if not len(cands):
        return q_prev
    turn = 2 * math.pi
    moved = cands + turn * np.round((q_prev - cands) / turn)
    lim = robot.joint_limits
    inside = (moved >= lim[:, 0] - 1e-9) & (moved <= lim[:, 1] + 1e-9)
    moved = np.where(inside, moved, cands)
    ok = np.all((moved >= lim[:, 0] - 1e-9) & (moved <= lim[:, 1] + 1e-9), axis=1)
    if not ok.any():
        return q_prev
    dist = np.where(ok, np.linalg.norm(moved - q_prev, axis=1), np.inf)
    return np.asarray(moved[int(np.argmin(dist))], dtype=float)


def _requests(prog: Any, ops: DialectOps, frames: Frames, nominal: Robot, cmap: ControllerMap,
              ) -> tuple[dict[int, int], list[TargetRequest], list[tuple[Array, Array]],
                         dict[int, str]]:
    """The filter's requests for the program's used targets: ``(row of each target,
    requests, (user, tool) per request, reasons of targets whose frames are unknown)``."""
    rows: dict[int, int] = {}
    requests: list[TargetRequest] = []
    tools: list[tuple[Array, Array]] = []
    refused: dict[int, str] = {}
    last_joints: Array | None = None
    for t in prog.targets:
        if t.kind == "joints" and not t.note and t.slots:
            last_joints = cmap.to_model(t.values(ops.joint_keys))
        if t.note or not t.used:
            continue
        if t.kind == "joints":
            q = cmap.to_model(t.values(ops.joint_keys))
            rows[id(t)] = len(requests)
            requests.append(TargetRequest("joints", joints=q, seed=q))
            tools.append((np.eye(4), np.eye(4)))
            continue
        try:
            user, tool = ops.frames(prog, t, frames)
        except KincalError as exc:           # this target cannot be filtered; the rest can
            refused[id(t)] = str(exc)
            continue
        F = user @ ops.pose_of(t) @ inverse(tool)
        seed = last_joints
        fixed = _prescribed_joints(t, cmap, nominal.n)
        if fixed is not None and seed is not None:
            seed = np.where(np.isnan(fixed), seed, fixed)
        if "seed_axes" in t.extra:          # URScript get_inverse_kin(pose, qnear=q)
            seed = last_joints = cmap.to_model(t.extra["seed_axes"])
        if "after" in t.extra:          # monitoring off: the branch nearest the previous target
            before = _previous_joints(t, ops, prog, frames, nominal, cmap, last_joints)
            seed = None if before is None else nearest_branch(nominal, F, before)
        rows[id(t)] = len(requests)
        requests.append(TargetRequest("pose", flange=F, config=t.config, seed=seed, tool=tool,
                                      fixed=fixed))
        tools.append((user, tool))
    return rows, requests, tools, refused


def _prescribed_joints(t: ProgramTarget, cmap: ControllerMap, n: int) -> Array | None:
    """(n,) model joints a pose target prescribes through a controller axis it also
    carries (NaN: free), or None: RAPID's ``eax_a`` of a 7-axis ABB arm (the arm angle,
    axis 7), mapped by the joint map to the model joint it alone drives."""
    given = [k for k, name in enumerate(cmap.axes) if name == "eax_a" and name in t.slots]
    if not given:
        return None
    fixed = np.full(n, np.nan)
    for k in given:
        for j in np.flatnonzero(cmap.matrix[:, k]).tolist():
            if np.count_nonzero(cmap.matrix[j]) == 1:
                fixed[j] = (cmap.matrix[j, k] * t.slots[cmap.axes[k]].value * cmap.scale
                            + cmap.offset[j])
    return fixed


def _unfiltered_report(t: ProgramTarget, refused: dict[int, str]) -> TargetReport:
    """The row of a target the filter did not see: unused, kept or not filtered."""
    status = "unused" if not t.used else "not filtered"
    if t.note and (t.note.startswith(("relative", "used by a relative"))
                   or t.extra.get("kept")):
        status = "kept"
    reason = refused.get(id(t)) or t.note or "not used by any motion"
    return TargetReport(t.name, t.file, t.line, t.kind, status, 0.0, 0.0, math.nan, [], reason)


def filter_program(path: str | Sequence[str], calibrated: Robot, nominal: Robot,
                   dialect: str = "auto", frames: Frames | None = None,
                   offline_joints: bool = False, accuracy: AccuracyModel | None = None
                   ) -> FilteredProgram:
    """Filter every target of the program at ``path`` (module docstring): one file, or
    for RAPID several modules or a folder of them."""
    if not isinstance(path, str) and len(path) == 1:
        path = path[0]
    d = dialect_of(path, dialect)
    ops = _ops(d)
    prog = ops.read(path)
    frames = frames or Frames({}, {})
    cmap = controller_map(nominal, _VENDOR[d])
    extra_axes = tuple(a for a in cmap.axes[len(ops.joint_keys):] if d == "rapid")
    if extra_axes == ("eax_a",):          # a 7-axis ABB arm: axis 7 is eax_a
        ops = replace(ops, joint_keys=ops.joint_keys + extra_axes)
        for t in prog.targets:
            if t.kind == "joints" and t.slots and "eax_a" not in t.slots and not t.note:
                t.note = ("a jointtarget of a 7-axis arm without axis 7 (its eax_a is 9E9 "
                          "or missing)")
    if cmap.vendor and cmap.vendor != _VENDOR[d]:
        raise KincalError(f"robot {nominal.name!r} has a {cmap.vendor} controller, but the "
                          f"program is {d}")
    if any("missing" in t.extra for t in prog.targets):
        from kincal.compensation.programs.sequence import resolve_partials

        resolve_partials(prog, prog.targets, nominal, cmap, frames, ops.joint_keys,
                         ops.pose_of, ops.pose_values, ops.frames, offline_joints)
    rows, requests, tools, refused = _requests(prog, ops, frames, nominal, cmap)
    result = filter_targets(calibrated, nominal, requests, offline_joints, accuracy, cmap) \
        if requests else None
    edits: dict[str, dict[int, tuple[Slot, float, int]]] = {f: {} for f in prog.texts}
    reports: list[TargetReport] = []
    written: dict[int, dict[str, float]] = {}
    for t in prog.targets:
        if id(t) not in rows:
            reports.append(_unfiltered_report(t, refused))
            continue
        assert result is not None
        i = rows[id(t)]
        ok = bool(result.ok[i])
        status = "filtered" if result.changed[i] else ("not filtered" if not ok else "unchanged")
        reason = result.reason[i]
        if t.kind == "joints" and not offline_joints and ok:
            status = "kept"
            reason = ("a joint target: taught axis values need no filtering "
                      "(--joint-targets offline corrects offline-programmed ones)")
        warnings = list(result.warnings[i])
        if ok and t.extra.get("warning"):
            warnings.append(str(t.extra["warning"]))
        reports.append(TargetReport(t.name, t.file, t.line, t.kind, status,
                                    float(result.shift_position[i] * 1e3),
                                    float(math.degrees(result.shift_rotation[i])),
                                    float(result.predicted_std[i] * 1e3), warnings, reason, i))
        if not result.changed[i]:
            continue
        if t.kind == "pose":
            user, tool = tools[i]
            T_user = inverse(user) @ result.flange[i] @ tool
            new = ops.pose_values(t, T_user)
            if "after" not in t.extra:       # monitoring off: the configuration is not read
                axes_now = cmap.to_axes(result.joints[i])
                new.update(ops.config_values(t, axes_now, result.signs[i]))
        else:
            axes = cmap.to_axes(result.joints[i])
            new = dict(zip(ops.joint_keys, axes, strict=True))
        new = {k: float(v) for k, v in new.items() if k in t.slots}   # partial: its own
        written[id(t)] = new
        for key, value in new.items():
            slot = t.slots[key]
            edits[t.file][slot.start] = (slot, value, ops.digits(prog, key))
    if result is not None:
        _partial_status(prog, ops, reports, written, tools, frames, calibrated, nominal,
                        result)
    texts = {f: render(text, edits[f], pad=ops.pad) for f, text in prog.texts.items()}
    name = path if isinstance(path, str) else ", ".join(path)
    return FilteredProgram(d, texts, dict(prog.texts), reports, result, name,
                           calibrated.name, nominal.name)


#: A partial target whose run-time pose is this close to its filtered pose [mm, deg]
#: (the written numbers' resolution) counts as filtered; farther, its status is
#: ``partial`` with the distance in the reason.
PARTIAL_TOLERANCE = (1e-3, 1e-4)


def _partial_status(prog: Any, ops: DialectOps, reports: list[TargetReport],
                    written: dict[int, dict[str, float]], tools: list[tuple[Array, Array]],
                    frames: Frames, calibrated: Robot, nominal: Robot,
                    result: FilterResult) -> None:
    """A filtered partial target takes its left-out components from the previous target
    at run time (:mod:`~kincal.compensation.programs.sequence`): where the real robot,
    at the nominal controller's joints for that assembled pose, misses the target by more
    than :data:`PARTIAL_TOLERANCE`, its status is ``partial`` with the distance."""
    from kincal.compensation.filter import refine
    from kincal.compensation.programs.sequence import pose_distance, run_time_pose

    for t, r in zip(prog.targets, reports, strict=True):
        if r.index is None or t.kind != "pose" or id(t) not in written or \
                "resolved" not in t.extra:
            continue
        i = r.index
        user, tool = tools[i]
        P = run_time_pose(prog, t, written, ops.pose_of, ops.pose_values, ops.frames, frames)
        q, ok = refine(nominal, (user @ P @ inverse(tool))[None], result.joints[i][None])
        real = inverse(user) @ calibrated.fk(q[0]) @ tool
        dp, dr = pose_distance(real, ops.pose_of(t))
        if not ok[0] or dp > PARTIAL_TOLERANCE[0] or dr > PARTIAL_TOLERANCE[1]:
            given = ", ".join(k for k in t.slots if k not in ("s", "t")).upper()
            r.status = "partial"
            r.reason = (f"partial aggregate: {given} rewritten, "
                        f"{', '.join(t.extra['missing']).upper()} come from the previous "
                        f"position at run time: the robot misses the target by {dp:.4f} mm "
                        f"/ {dr:.4f} deg (write the aggregate in full to filter it)")
