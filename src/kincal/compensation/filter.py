"""Filtering robot-program targets through a calibrated model.

A controller that knows only the nominal model ``f_nom`` moves to a Cartesian target
``T`` by solving ``f_nom(q) = T`` on the configuration the program asks for.  The
real robot is ``f_cal``.  For every Cartesian target (the robot's flange pose in its
base frame, ``F = U T_target Tool^-1`` with the target's user and tool frames):

1. ``q_nom``: the nominal solution on the asked configuration (closed form, all
   branches, then :meth:`~kincal.compensation.configuration.Configurator.select`), or,
   where the program gives no configuration (or the robot has no closed form), the
   nominal numerical IK seeded by ``seeds`` (the branch of the nominal solution);
2. ``q = f_cal^-1(F)`` seeded with ``q_nom`` (:func:`kincal.compensation.compensate.compensate`);
3. the filtered target ``F' = f_nom(q)``: the controller's IK on the same configuration
   gives back ``q``, and the real robot reaches ``f_cal(q) = F``.

Joint targets (axis values taught on the real robot) stay as they are; as
offline-programmed ones (computed with the nominal model) they become
``q' = f_cal^-1(f_nom(q))`` on the same branch.

On a robot without configuration rules (no closed form: 7-axis arms, wrist offsets)
the calibrated joints must be the continuous continuation of the nominal ones
(:func:`~kincal.compensation.configuration.continuation_problems`), else the target is
"configuration changed" and left unchanged.  A target may prescribe joints (a 7-axis
ABB arm's axis 7, RAPID's ``eax_a``): both solutions keep them.

Warnings per target: unreachable (left unchanged), branch change (the calibrated
solution has another configuration than asked: the controller would not reproduce
it), near a singularity (shoulder, elbow or wrist margin below
:data:`SINGULARITY_MARGINS`), joint limit (within :data:`LIMIT_MARGIN` of one),
outside the calibrated region (with the calibration's
:class:`~kincal.identify.accuracy.AccuracyModel`: a joint outside the training ranges or
the TCP outside the training workspace hull, :func:`~kincal.identify.accuracy.predict`),
where each target also gets the predicted position std of its TCP.  Units: m, rad.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from kincal.compensation.compensate import _check_compatible, compensate
from kincal.compensation.configuration import (
    Configuration,
    Configurator,
    continuation_problems,
)
from kincal.motion.ik import solve_ik
from kincal.motion.ik_closed_form import NotThisFamily
from kincal.motion.ik_wrist import check_wrist_family, ik_spherical_wrist
from kincal.robots.chain import Robot
from kincal.robots.controller import ControllerMap, controller_map
from kincal.spatial import log_so3

Array = NDArray[np.float64]

if TYPE_CHECKING:
    from kincal.identify.accuracy import AccuracyModel

#: Singularity margins: wrist centre within 20 mm of axis 1, elbow within 2 deg of
#: stretched or folded (|Y| / r3 = sine of that angle), wrist within 2 deg of aligned.
SINGULARITY_MARGINS = (0.020, math.sin(math.radians(2.0)), math.sin(math.radians(2.0)))
#: Robots without configuration rules: a correction that turns a joint by more than this
#: [rad] (calibration corrections move joints by tenths of a degree) is near a singularity.
SINGULAR_SWING = math.radians(5.0)
#: A joint within this distance of a limit [rad] is flagged.
LIMIT_MARGIN = math.radians(2.0)



@dataclass
class TargetRequest:
    """One program target to filter.

    Attributes:
        kind: ``"pose"`` (``flange`` set) or ``"joints"`` (``joints`` set).
        flange: (4, 4) the flange pose the target asks for, in the robot base frame [m].
        joints: (n,) model joint values [rad].
        config: the configuration the program asks for, or None.
        seed: (n,) model joints the controller would start from (the previous joint
            target), or None.
        tool: (4, 4) the tool frame (flange to TCP), to measure shifts at the TCP.
        fixed: (n,) model joint values [rad] the target prescribes (NaN: free), e.g. a
            7-axis ABB arm's axis 7 from the robtarget's eax_a: the nominal and the
            calibrated solution keep them, the other joints are solved.
    """

    kind: str
    flange: Array | None = None
    joints: Array | None = None
    config: Configuration | None = None
    seed: Array | None = None
    tool: Array = field(default_factory=lambda: np.eye(4))
    fixed: Array | None = None


@dataclass
class FilterResult:
    """Per target: the filtered flange pose or joints, the shift and the warnings.

    Attributes:
        changed: (N,) the target is rewritten.
        ok: (N,) the target could be filtered (False: left unchanged, ``reason`` says why).
        flange: (N, 4, 4) filtered flange poses [m] (pose targets; identity otherwise).
        joints: (N, n) filtered model joints [rad] (joint targets; the calibrated solution
            for pose targets).
        q_nominal: (N, n) the nominal controller's solution on the asked branch [rad].
        shift_position: (N,) ``|p'_tcp - p_tcp|`` [m].
        shift_rotation: (N,) rotation angle between the filtered and the original TCP [rad].
        predicted_std: (N,) predicted position std of the calibrated model there [m], or NaN.
        reason: why a target was not filtered (``""`` when ok).
        warnings: per target, short warning names.
        signs: (N, 3) shoulder, elbow, wrist signs of the calibrated solution (0 where the
            robot has no configuration rules): what the rewritten target's configuration
            says, together with the axis values in ``joints``.
    """

    changed: NDArray[np.bool_]
    ok: NDArray[np.bool_]
    flange: Array
    joints: Array
    q_nominal: Array
    shift_position: Array
    shift_rotation: Array
    predicted_std: Array
    reason: list[str]
    warnings: list[list[str]]
    signs: Array


def refine(robot: Robot, F: Array, q0: Array, tol: float = 1e-11, max_iter: int = 20,
           free: NDArray[np.bool_] | None = None, max_move: float = 0.5
           ) -> tuple[Array, NDArray[np.bool_]]:
    """Newton's method for ``f(q) = F`` from a nearby ``q0`` (N, n), batched.

    ``q <- q + J(q)^-1 e(q)`` with ``e = [p_F - p(q); log(R_F R(q)^T)]`` and ``J`` the
    geometric Jacobian (base frame): quadratic convergence from the nominal solution,
    which is millimetres away.  Returns ``(q, converged)``: converged when ``|e_p| <= tol``
    [m] and ``|e_o| <= tol`` [rad]; a singular or diverging row, or one that moved more
    than ``max_move`` [rad] from ``q0``, is not converged.  ``free`` (n,) selects the
    joints that move (six of them; the others keep their ``q0`` values, e.g. a 7-axis
    ABB arm's axis 7 given by the program).
    """
    from kincal.spatial import pose_error

    cols = np.ones(robot.n, bool) if free is None else np.asarray(free, bool)

    q = np.array(q0, dtype=float)
    done = np.zeros(len(q), bool)
    for _ in range(max_iter):
        todo = np.flatnonzero(~done)
        if todo.size == 0:
            break
        T = robot.fk(q[todo])
        e = pose_error(F[todo], T)
        small = (np.linalg.norm(e[:, :3], axis=1) <= tol) & (np.linalg.norm(e[:, 3:], axis=1)
                                                               <= tol)
        done[todo[small]] = True
        move = todo[~small]
        if move.size == 0:
            break
        J = robot.jacobian(q[move])[:, :, cols]
        try:
            dq = np.linalg.solve(J, e[~small][:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            break
        step = np.zeros((move.size, robot.n))
        step[:, cols] = np.clip(dq, -0.2, 0.2)
        q[move] += step
    ok = done & np.all(np.isfinite(q), axis=1) & (np.max(np.abs(q - q0), axis=1) < max_move)
    return q, ok


def _closed_form(robot: Robot) -> bool:
    try:
        check_wrist_family(robot)
    except NotThisFamily:
        return False
    return True


def _unreachable_words(who: str, why: str, miss: float = math.nan) -> str:
    """``unreachable by WHO: WHY`` said once (the IK's own reason may already start with
    ``unreachable:``), with how far the best solution stayed from the target [mm] when the
    reason does not say it."""
    why = why.strip()
    if why.lower().startswith("unreachable"):
        why = why[len("unreachable"):].lstrip(" :;,-")
    far = (f"; the closest solution misses it by {miss * 1e3:.3g} mm"
           if math.isfinite(miss) and miss > 0 and not re.search(r"\d\s*m+\b", why) else "")
    return f"unreachable by {who}: {why or 'no joint solution found'}{far}"


def _in_intervals(cmap: ControllerMap, q: Array, conf: Configuration | None) -> bool:
    """Whether the model joints q (n,) [rad] have the axis intervals of ``conf`` (ABB's
    quadrants of axes 1, 4, 6, ...): the part of a configuration any chain has."""
    if conf is None or not conf.intervals:
        return True
    ax = cmap.to_axes(q[None])[0] * cmap.scale
    return all(lo - 1e-9 <= ax[k] <= hi + 1e-9 for k, (lo, hi) in conf.intervals.items())


def _fixed_solutions(nominal: Robot, cmap: ControllerMap, F: Array,
                     confs: Sequence[Configuration | None], seeds: Array, fixed: Array
                     ) -> tuple[Array, NDArray[np.bool_], list[str]]:
    """The nominal joints of targets that prescribe some joints (``fixed`` (N, n), NaN
    free; six free joints): Newton on the free joints from the seed, then from the middle
    of the limits, the first solution inside the limits and the configuration's axis
    intervals; batched over the targets that free the same joints."""
    N, n = fixed.shape
    q = np.zeros((N, n))
    ok = np.zeros(N, bool)
    reason = [""] * N
    lim = nominal.joint_limits
    free_all = np.isnan(fixed)
    counts = free_all.sum(axis=1)
    for i in np.flatnonzero(counts != 6):
        reason[i] = (f"unreachable: {n - int(counts[i])} prescribed joints leave "
                     f"{int(counts[i])} free, the pose needs 6")
    six = counts == 6
    for mask in np.unique(free_all[six], axis=0):      # one batch per set of free joints
        rows = np.flatnonzero(six & np.all(free_all == mask, axis=1))
        for start in (seeds, np.broadcast_to(lim.mean(axis=1), (N, n))):
            todo = rows[~ok[rows]]
            if not todo.size:
                break
            q0 = np.where(mask, start[todo], fixed[todo])
            qi, conv = refine(nominal, F[todo], q0, max_iter=100, free=mask, max_move=np.inf)
            inside = np.all((qi >= lim[:, 0] - 1e-9) & (qi <= lim[:, 1] + 1e-9), axis=1)
            good = conv & inside & np.array([_in_intervals(cmap, qi[j], confs[int(i)])
                                             for j, i in enumerate(todo)], dtype=bool)
            q[todo[good]], ok[todo[good]] = qi[good], True
    for i in np.flatnonzero(six & ~ok):
        conf = confs[int(i)]
        reason[i] = ("unreachable: no joint solution with the prescribed "
                     + ", ".join(nm for nm, f in zip(nominal.joint_names, free_all[i],
                                                     strict=True) if not f)
                     + (f" and configuration {conf.text}" if conf is not None else "")
                     + " inside the joint limits found from the previous joints")
    return q, ok, reason


def nominal_solutions(nominal: Robot, cmap: ControllerMap, F: Array,
                      confs: Sequence[Configuration | None], seeds: Array,
                      fixed: Array | None = None
                      ) -> tuple[Array, NDArray[np.bool_], list[str]]:
    """The nominal controller's joints for flange poses F (N, 4, 4): ``(q, ok, reason)``;
    ``fixed`` (N, n): joints a target prescribes (NaN: free), :func:`_fixed_solutions`."""
    N = len(F)
    q = np.zeros((N, nominal.n))
    ok = np.zeros(N, bool)
    reason = [""] * N
    pinned = (np.zeros(N, bool) if fixed is None
              else np.any(~np.isnan(fixed), axis=1))
    if pinned.any():
        assert fixed is not None
        pin = [int(i) for i in np.flatnonzero(pinned)]
        qp, okp, rp = _fixed_solutions(nominal, cmap, F[pin], [confs[i] for i in pin],
                                       seeds[pin], fixed[pin])
        q[pin], ok[pin] = qp, okp
        for k, i in enumerate(pin):
            reason[i] = rp[k]
    asked = np.array([c is not None for c in confs], bool) & ~pinned
    if not (_closed_form(nominal) and cmap.vendor in ("kuka", "abb", "fanuc")):
        asked[:] = False               # no closed form: every target by the numerical IK
    if asked.any():
        idx = [int(i) for i in np.flatnonzero(asked)]
        sol = ik_spherical_wrist(nominal, F[idx])
        conf = Configurator.of(nominal, cmap)
        qs, found = conf.select(sol.q, sol.reachable, [confs[i] for i in idx])
        q[idx], ok[idx] = qs, found
        any_branch: list[bool] = np.any(sol.reachable, axis=1).tolist()
        for i, f, anyr in zip(idx, found.tolist(), any_branch, strict=True):
            asked_conf = confs[i]
            if not f and asked_conf is not None:
                reason[i] = (f"unreachable: no joint solution with configuration "
                             f"{asked_conf.text} inside the joint limits" if anyr else
                             "unreachable: outside the robot's workspace")
    rest = np.flatnonzero(~asked & ~pinned)
    if rest.size:
        num = solve_ik(nominal, F[rest], q0=seeds[rest], mask="pose", tol_position=1e-10,
                       tol_orientation=1e-10)
        q[rest], ok[rest] = num.q, num.success
        for k, i in enumerate(rest.tolist()):
            if not num.success[k]:
                reason[i] = _unreachable_words("the nominal robot", num.reason[k],
                                               float(num.position_error[k]))
    return q, ok, reason


@dataclass
class _Targets:
    """The requests as arrays: flange poses (pose targets; for offline joint targets the
    nominal model's pose of their joints), joints, which are poses, the seeds and the
    asked configurations."""

    flange: Array
    joints: Array
    pose: NDArray[np.bool_]
    seeds: Array
    confs: list[Configuration | None]
    tools: Array
    fixed: Array


def _as_arrays(nominal: Robot, requests: Sequence[TargetRequest], offline_joints: bool
               ) -> _Targets:
    """Stack the requests (:class:`_Targets`)."""
    N, n = len(requests), nominal.n
    flange_in = np.tile(np.eye(4), (N, 1, 1))
    joints_in = np.zeros((N, n))
    pose = np.array([r.kind == "pose" for r in requests], bool)
    for i, r in enumerate(requests):
        if r.kind == "pose" and r.flange is not None:
            flange_in[i] = r.flange
        elif r.joints is not None:
            joints_in[i] = r.joints
    if offline_joints:
        jt = np.flatnonzero(~pose)
        flange_in[jt] = nominal.fk(joints_in[jt])
    seeds = np.array([r.seed if r.seed is not None else
                      (r.joints if r.kind == "joints" and r.joints is not None else
                       np.clip(np.zeros(n), nominal.joint_limits[:, 0], nominal.joint_limits[:, 1]))
                      for r in requests]).reshape(N, n)
    confs: list[Configuration | None] = [r.config if r.kind == "pose" else None for r in requests]
    tools = np.array([r.tool for r in requests]).reshape(N, 4, 4)
    fixed = np.full((N, n), np.nan)
    for i, r in enumerate(requests):
        if r.kind == "pose" and r.fixed is not None:
            fixed[i] = r.fixed
    return _Targets(flange_in, joints_in, pose, seeds, confs, tools, fixed)


def _nominal_joints(nominal: Robot, cmap: ControllerMap, t: _Targets, work: NDArray[np.intp],
                    ok: NDArray[np.bool_], reason: list[str]) -> Array:
    """Step 1: the nominal controller's joints of the targets ``work`` (the others keep
    their joints); marks the ones it cannot reach in ``ok`` / ``reason``."""
    q_nom = t.joints.copy()
    if work.size:
        w_confs = [t.confs[i] for i in work.tolist()]
        seeds_w = t.seeds[work].copy()
        jt_mask = ~t.pose[work]
        seeds_w[jt_mask] = t.joints[work][jt_mask]
        qn, okn, rn = nominal_solutions(nominal, cmap, t.flange[work], w_confs, seeds_w,
                                        t.fixed[work])
        q_nom[work], ok[work] = qn, okn
        for k, i in enumerate(work.tolist()):
            reason[i] = rn[k]
    return q_nom


def _calibrated_joints(calibrated: Robot, nominal: Robot, flange: Array, q_nom: Array,
                       solve: NDArray[np.intp], ok: NDArray[np.bool_], reason: list[str],
                       fixed: Array | None = None) -> Array:
    """Step 2: ``q = f_cal^-1(F)`` for the targets ``solve``, Newton from the nominal
    joints, the general IK where Newton does not converge; marks a target the calibrated
    robot cannot reach, or reaches only beyond a joint limit, in ``ok`` / ``reason``.
    Targets with prescribed joints (``fixed`` rows not all NaN) keep them: Newton on the
    free joints only."""
    q_cal = q_nom.copy()
    if fixed is not None and solve.size:
        pinned = np.any(~np.isnan(fixed[solve]), axis=1)
        for i in solve[pinned].tolist():
            free = np.isnan(fixed[i])
            qi, conv = refine(calibrated, flange[i][None], q_nom[i][None], free=free)
            if not conv[0]:     # near a singularity: let it go further, step 3 judges it
                qi, conv = refine(calibrated, flange[i][None], q_nom[i][None], free=free,
                                  max_iter=100, max_move=np.inf)
            q_cal[i] = qi[0]
            if not conv[0]:
                ok[i] = False
                reason[i] = ("unreachable by the calibrated robot: no solution near the "
                             "nominal joints with the prescribed axes")
        _beyond_limits(calibrated, q_cal, solve[pinned], ok, reason)
        solve = solve[~pinned]
    if not solve.size:
        return q_cal
    q_new, conv = refine(calibrated, flange[solve], q_nom[solve])
    q_cal[solve] = q_new
    lost = np.flatnonzero(~conv)
    if lost.size:                      # far from the nominal solution: the general IK
        comp = compensate(calibrated, flange[solve[lost]], nominal=nominal,
                          q0=q_nom[solve[lost]])
        q_cal[solve[lost]] = comp.q
        for k, i in enumerate(solve[lost].tolist()):
            if not comp.success[k]:
                ok[i] = False
                reason[i] = _unreachable_words("the calibrated robot", comp.reason[k])
    _beyond_limits(calibrated, q_cal, solve, ok, reason)
    return q_cal


def _beyond_limits(calibrated: Robot, q_cal: Array, solve: NDArray[np.intp],
                   ok: NDArray[np.bool_], reason: list[str]) -> None:
    """A calibrated solution beyond a joint limit is not filtered."""
    lim = calibrated.joint_limits
    outside = np.any((q_cal[solve] < lim[:, 0] - 1e-9) | (q_cal[solve] > lim[:, 1] + 1e-9),
                     axis=1)
    for i in solve[outside & ok[solve]].tolist():
        ok[i] = False
        reason[i] = "joint limits: the calibrated robot would need a joint beyond its limit"


def _configuration_checks(conf_obj: Configurator, nominal: Robot, t: _Targets, q_nom: Array,
                          q_cal: Array, good: NDArray[np.intp], work: NDArray[np.intp],
                          ok: NDArray[np.bool_], reason: list[str], warnings: list[list[str]],
                          signs: Array, flange_out: Array) -> NDArray[np.intp]:
    """Step 3 where the robot has configuration rules: the calibrated solution's signs
    (into ``signs``); a target on another branch than asked is refused (its flange pose
    restored), one without an asked configuration warned of; singularity margins.
    Returns the targets still good."""
    signs[good] = conf_obj.signs(q_cal[good])
    want = np.array([[c.shoulder, c.elbow, c.wrist] if c is not None else [0, 0, 0]
                     for c in (t.confs[i] for i in good.tolist())], float).reshape(-1, 3)
    free = ~want.any(axis=1)
    want[free] = conf_obj.signs(q_nom[good][free])
    same = np.all((want == 0) | (signs[good] == want), axis=1)
    for k in np.flatnonzero(~same).tolist():
        i = int(good[k])
        asked = t.confs[i]
        if asked is not None:       # the controller would not reproduce it
            ok[i] = False
            reason[i] = (f"the calibrated robot cannot reach it on configuration "
                         f"{asked.text} (its nearest solution is on another branch: "
                         "near a singularity or the workspace boundary)")
        else:
            warnings[i].append("branch change")
    good = good[same | np.array([t.confs[i] is None for i in good.tolist()], bool)]
    flange_out[work[~ok[work]]] = t.flange[work[~ok[work]]]
    m = conf_obj.margins(q_cal[good])
    L = check_wrist_family(nominal)
    r3 = math.hypot(L[2].a, L[3].d)
    near = (m[:, 0] < SINGULARITY_MARGINS[0]) | (m[:, 1] / r3 < SINGULARITY_MARGINS[1]) \
        | (m[:, 2] < SINGULARITY_MARGINS[2])
    for k in np.flatnonzero(near).tolist():
        warnings[int(good[k])].append("near a singularity")
    return good


def _continuation_checks(nominal: Robot, t: _Targets, q_nom: Array, q_cal: Array,
                         good: NDArray[np.intp], work: NDArray[np.intp], ok: NDArray[np.bool_],
                         reason: list[str], flange_out: Array, warnings: list[list[str]]
                         ) -> NDArray[np.intp]:
    """Step 3 for a robot without configuration rules (no closed form, e.g. a 7-axis arm):
    the calibrated joints must be the continuous continuation of the nominal ones
    (:func:`~kincal.compensation.configuration.continuation_problems`, on the free joints
    of targets that prescribe some); a target whose corrected joints left the branch is
    not filtered ("configuration changed"), its flange pose restored.  One that continues
    it but turns a joint by more than :data:`SINGULAR_SWING` for a calibration-sized
    correction is near a singularity (two axes nearly aligned trade a large turn).
    Returns the targets still good."""
    free = np.isnan(t.fixed[good])
    problems = [""] * len(good)
    for mask in np.unique(free, axis=0):
        rows = np.flatnonzero(np.all(free == mask, axis=1))
        found = continuation_problems(nominal, q_nom[good[rows]], q_cal[good[rows]], mask)
        for k, words in zip(rows.tolist(), found, strict=True):
            problems[k] = words
    for k, words in enumerate(problems):
        if words:
            i = int(good[k])
            ok[i] = False
            reason[i] = words
    flange_out[work[~ok[work]]] = t.flange[work[~ok[work]]]
    good = good[ok[good]]
    swing = np.max(np.abs(q_cal[good] - q_nom[good]), axis=1) if good.size else np.zeros(0)
    for k in np.flatnonzero(swing > SINGULAR_SWING).tolist():
        warnings[int(good[k])].append("near a singularity")
    return good


def _tcp_shifts(t: _Targets, flange_out: Array, offline_joints: bool) -> tuple[Array, Array]:
    """``|p'_tcp - p_tcp|`` [m] and the rotation angle between the filtered and the original
    TCP [rad] per target (zero for joint targets left as taught)."""
    tcp_in, tcp_out = t.flange @ t.tools, flange_out @ t.tools
    shift_p = np.linalg.norm(tcp_out[:, :3, 3] - tcp_in[:, :3, 3], axis=1)
    shift_r = np.linalg.norm(log_so3(tcp_out[:, :3, :3] @ np.swapaxes(tcp_in[:, :3, :3], 1, 2)),
                             axis=1)
    if not offline_joints:
        jt = np.flatnonzero(~t.pose)
        shift_p[jt] = 0.0
        shift_r[jt] = 0.0
    return shift_p, shift_r


def filter_targets(calibrated: Robot, nominal: Robot, requests: Sequence[TargetRequest],
                   offline_joints: bool = False, accuracy: AccuracyModel | None = None,
                   cmap: ControllerMap | None = None) -> FilterResult:
    """Filter program targets through the calibrated model (module docstring).

    Args:
        calibrated: the real robot as identified.
        nominal: the controller's model (its ``controller`` section says the vendor).
        requests: the targets, in program order.
        offline_joints: correct joint targets too (they were computed with the nominal
            model); by default they stay (taught on the real robot).
        accuracy: the calibration's accuracy model (:func:`~kincal.identify.accuracy.
            accuracy_model`, or ``AccuracyModel.from_dict`` of a result JSON): each
            target's predicted position std at its TCP and the outside-the-region flag.
        cmap: the controller map; default the nominal robot's.
    """
    _check_compatible(calibrated, nominal)
    cmap = cmap or controller_map(nominal)
    N = len(requests)
    t = _as_arrays(nominal, requests, offline_joints)
    pose = t.pose
    work = np.flatnonzero(pose | offline_joints)
    ok = np.ones(N, bool)
    reason = [""] * N
    q_nom = _nominal_joints(nominal, cmap, t, work, ok, reason)
    q_cal = _calibrated_joints(calibrated, nominal, t.flange, q_nom, work[ok[work]], ok, reason,
                               t.fixed)
    flange_out = t.flange.copy()
    good = work[ok[work]]
    flange_out[good] = nominal.fk(q_cal[good])
    warnings: list[list[str]] = [[] for _ in range(N)]
    conf_obj = Configurator.of(nominal, cmap) if (
        _closed_form(nominal) and cmap.vendor in ("kuka", "abb", "fanuc")) else None
    signs = np.zeros((N, 3))
    if good.size and conf_obj is not None:
        good = _configuration_checks(conf_obj, nominal, t, q_nom, q_cal, good, work, ok,
                                     reason, warnings, signs, flange_out)
    elif good.size:
        good = _continuation_checks(nominal, t, q_nom, q_cal, good, work, ok, reason,
                                    flange_out, warnings)
    lim = calibrated.joint_limits
    if good.size:
        close = np.any((q_cal[good] - lim[:, 0] < LIMIT_MARGIN)
                       | (lim[:, 1] - q_cal[good] < LIMIT_MARGIN), axis=1)
        for k in np.flatnonzero(close).tolist():
            warnings[int(good[k])].append("joint limit")
    _joint_targets_beyond(nominal, t, ok, reason)
    for i in np.flatnonzero(~ok).tolist():
        warnings[i].append("unreachable" if "reach" in reason[i] else "not filtered")
    joints_out = t.joints.copy()
    joints_out[pose] = q_cal[pose]
    jt = np.flatnonzero(~pose)
    if offline_joints:
        joints_out[jt[ok[jt]]] = q_cal[jt[ok[jt]]]
        flange_out[jt] = nominal.fk(joints_out[jt])
    shift_p, shift_r = _tcp_shifts(t, flange_out, offline_joints)
    changed = ok & (pose | offline_joints) & ((shift_p > 1e-9) | (shift_r > 1e-9))
    std = np.full(N, np.nan)
    if accuracy is not None and good.size:
        s, outside = tcp_accuracy(accuracy, calibrated, q_cal[good], t.tools[good][:, :3, 3])
        std[good] = s
        for k in np.flatnonzero(outside).tolist():
            warnings[int(good[k])].append("outside the calibrated region")
    return FilterResult(changed, ok, flange_out, joints_out, q_nom, shift_p, shift_r, std,
                        reason, warnings, signs)


def _joint_targets_beyond(nominal: Robot, t: _Targets, ok: NDArray[np.bool_],
                          reason: list[str]) -> None:
    """A joint target beyond the robot's limits (taught or offline) is not filtered: the
    robot cannot take it, so the program (or the robot file) is wrong; its reason names
    the joint, its value and the limits (:func:`kincal.measure.data_checks.limit_problems`)."""
    from kincal.measure.data_checks import limit_problems

    for i in np.flatnonzero(~t.pose).tolist():
        found = limit_problems(nominal, t.joints[i][None], "target")
        if found:
            ok[i] = False
            reason[i] = "; ".join(p.words for p in found)


def tcp_accuracy(accuracy: AccuracyModel, calibrated: Robot, q: Array, tcp: Array
                 ) -> tuple[Array, NDArray[np.bool_]]:
    """The predicted position std [m] of each TCP (N, 3) in the flange frame at joints
    ``q`` (N, n), and whether the configuration lies outside the calibrated region
    (:func:`kincal.identify.accuracy.predict` with ``point=`` the TCP, one propagation
    per distinct TCP)."""
    from kincal.identify.accuracy import predict

    q = np.atleast_2d(np.asarray(q, dtype=float))
    tcp = np.asarray(tcp, dtype=float).reshape(len(q), 3)
    std = np.zeros(len(q))
    outside = np.zeros(len(q), dtype=bool)
    for m in np.unique(tcp, axis=0):
        rows = np.all(tcp == m, axis=1)
        pred = predict(accuracy, calibrated, q[rows], point=m)
        std[rows] = pred.std_position_m
        outside[rows] = pred.outside
    return std, outside
