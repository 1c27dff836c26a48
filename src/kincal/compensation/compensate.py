"""Compensation: put the real (calibrated) robot on target.

A calibrated model ``f_cal`` describes where the real robot goes; the controller
only knows its nominal model ``f_nom``.  Two ways to use the calibration:

* **joint commands** (the controller accepts joint targets):
  ``q_cmd = f_cal^-1(T_target)``, so that ``f_cal(q_cmd) = T_target``;
* **filtered targets** (the controller accepts only Cartesian targets and runs its
  own nominal IK): send ``T_filtered = f_nom(q_cmd)``.  The controller solves
  ``f_nom^-1(T_filtered) = q_cmd`` and the real robot reaches
  ``f_cal(q_cmd) = T_target``.

The calibrated IK is seeded with the nominal IK solution of the same target (the
configuration branch the controller would pick) unless seeds are given, so the
compensated commands stay on the controller's branch.  Units: metres and radians.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError, UnreachableError
from kincal.motion.ik import check_solutions, solve_ik
from kincal.robots.chain import Robot

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Compensation:
    """Compensated joint commands and filtered targets for N targets.

    Attributes:
        q: (N, n) joint commands [rad / m] with ``f_cal(q) = target``.
        success: (N,) the calibrated IK met its tolerances within the joint limits.
        reason: N strings, ``""`` for successes (why a target failed).
        position_error: (N,) ``|p_target - p_cal(q)|`` [m] (independent FK check).
        orientation_error: (N,) ``|log(R_target R_cal(q)^T)|`` [rad] (0 for position
            targets).
        filtered: (N, 4, 4) ``f_nom(q)``, the targets to send to a nominal controller,
            or None when no nominal model was given.
        correction: (N,) ``|p_filtered - p_target|`` [m], the size of the compensation.
        mask: ``"pose"`` or ``"position"``.
        jump: (N,) ``max_j |q_j - q0_j|`` [rad / m] between the command and its seed (the
            nominal IK solution): large values mean the calibrated IK left the controller's
            configuration branch (near a singularity or a joint limit).
        q_nominal: (N, n) the nominal IK solutions (what an uncompensated controller
            commands), when the nominal model was given.
        fallback: (N,) targets sent uncompensated (:func:`fall_back_to_nominal`).
    """

    q: Array
    success: NDArray[np.bool_]
    reason: list[str]
    position_error: Array
    orientation_error: Array
    filtered: Array | None
    correction: Array | None
    mask: str
    jump: Array
    q_nominal: Array | None = None
    fallback: NDArray[np.bool_] | None = None

    #: A seed-to-command distance [rad or m] above which a target changed branch.
    BRANCH_JUMP = 0.5

    @property
    def branch_changes(self) -> NDArray[np.intp]:
        """Indices of targets whose command left the seed's configuration branch."""
        return np.flatnonzero(self.success & (self.jump > self.BRANCH_JUMP))

    def __len__(self) -> int:
        return int(self.q.shape[0])

    def __repr__(self) -> str:
        n, ok = len(self), int(np.sum(self.success))
        size = ""
        if self.correction is not None and ok:
            c = self.correction[self.success] * 1e3
            size = (f", compensation RMS {float(np.sqrt(np.mean(c**2))):.4g} mm, "
                    f"max {float(np.max(c)):.4g} mm")
        back = "" if self.fallback is None else f", {int(np.sum(self.fallback))} sent nominal"
        return (f"Compensation({ok}/{n} {self.mask} targets compensated{size}, "
                f"{len(self.branch_changes)} branch changes{back})")

    def _repr_html_(self) -> str:
        """Notebook display: the headline and the targets that failed, with why."""
        from kincal.io import html_table

        bad = np.flatnonzero(~self.success)
        rows = [[int(i), self.reason[i]] for i in bad[:20]]
        return html_table(["target", "why it failed"], rows, repr(self))


def _check_compatible(calibrated: Robot, nominal: Robot) -> None:
    if calibrated.joint_names != nominal.joint_names:
        raise KincalError(f"the calibrated robot {calibrated.name!r} has joints "
                          f"{', '.join(calibrated.joint_names)} but the nominal robot "
                          f"{nominal.name!r} has {', '.join(nominal.joint_names)}")


def compensate(calibrated: Robot, targets: ArrayLike, nominal: Robot | None = None,
               q0: ArrayLike | None = None, mask: str | None = None,
               tol_position: float = 1e-10, tol_orientation: float = 1e-10,
               max_iter: int = 100, restarts: int = 5,
               rng: np.random.Generator | int | None = None) -> Compensation:
    """Joint commands (and filtered targets) that put the calibrated robot on target.

    ``q = IK_cal(T_target)`` (seeded with ``q0`` or with ``IK_nom(T_target)``), then
    ``T_filtered = FK_nom(q)``.

    Args:
        calibrated: the calibrated robot (the real one, as identified).
        targets: poses (N, 4, 4) or positions (N, 3) in the robot's base frame [m].
        nominal: the controller's nominal model; needed for filtered targets.
        q0: (N, n) or (n,) IK seeds [rad / m]; default the nominal IK solutions.
        mask: ``"pose"`` or ``"position"``; default from the shape of ``targets``.
        tol_position: IK position tolerance [m].
        tol_orientation: IK orientation tolerance [rad].
        max_iter: passed to :func:`kincal.motion.ik.solve_ik`.
        restarts: passed to :func:`kincal.motion.ik.solve_ik`.
        rng: passed to :func:`kincal.motion.ik.solve_ik`.
    """
    T = np.asarray(targets, dtype=float)
    if T.ndim == 2 and T.shape == (4, 4):
        T = T[None]
    if mask is None:
        mask = "pose" if T.ndim == 3 else "position"
    if mask not in ("pose", "position"):
        raise KincalError(f"unknown compensation mask {mask!r}; use 'pose' or 'position'")
    if mask == "pose" and (T.ndim != 3 or T.shape[1:] != (4, 4)):
        raise KincalError(f"pose targets must have shape (N, 4, 4); got {T.shape}")
    if mask == "position":
        T = T[:, :3, 3] if T.ndim == 3 else T
        if T.ndim != 2 or T.shape[1] != 3:
            raise KincalError(f"position targets must have shape (N, 3); got {T.shape}")
    if nominal is not None:
        _check_compatible(calibrated, nominal)
    from_nominal = q0 is None and nominal is not None
    if q0 is None and nominal is not None:
        q0 = solve_ik(nominal, T, mask=mask, tol_position=tol_position,
                      tol_orientation=tol_orientation, max_iter=max_iter, restarts=restarts,
                      rng=rng).q
    seeds = None if q0 is None else np.broadcast_to(np.asarray(q0, dtype=float),
                                                    (len(T), calibrated.n))
    sol = solve_ik(calibrated, T, q0=seeds, mask=mask, tol_position=tol_position,
                   tol_orientation=tol_orientation, max_iter=max_iter, restarts=restarts,
                   rng=rng)
    ep, eo = check_solutions(calibrated, T, sol.q, mask=mask)
    filtered = correction = None
    if nominal is not None:
        filtered = nominal.fk(sol.q)
        p_t = T[:, :3, 3] if mask == "pose" else T
        correction = np.linalg.norm(filtered[:, :3, 3] - p_t, axis=1)
    jump = np.zeros(len(T)) if seeds is None else np.max(np.abs(sol.q - seeds), axis=1)
    q_nom = np.asarray(q0, dtype=float) if from_nominal else None
    return Compensation(sol.q, np.asarray(sol.success, bool), list(sol.reason), ep, eo,
                        filtered, correction, mask, jump, q_nom)


def fall_back_to_nominal(comp: Compensation, calibrated: Robot, nominal: Robot,
                         targets: ArrayLike, where: ArrayLike) -> Compensation:
    """``comp`` with the targets ``where`` (N,) sent uncompensated: the nominal IK solution
    as the joint command and the target itself as the filtered target (the controller's
    nominal model puts the robot where it would without a calibration).

    Used where the calibrated model is predicted worse than the nominal one
    (:func:`kincal.identify.accuracy.predict`).  ``position_error`` /
    ``orientation_error`` of those targets become the calibrated model's estimate of
    the nominal command's error.
    """
    where = np.asarray(where, dtype=bool)
    T = np.asarray(targets, dtype=float)
    if T.ndim == 2 and T.shape == (4, 4):
        T = T[None]
    if comp.mask == "position" and T.ndim == 3:
        T = T[:, :3, 3]
    if not where.any():
        return replace(comp, fallback=where)
    qn = comp.q_nominal
    if qn is None:
        qn = solve_ik(nominal, T, mask=comp.mask, q0=comp.q).q
    q = comp.q.copy()
    q[where] = qn[where]
    ep, eo = check_solutions(calibrated, T, q, mask=comp.mask)
    filtered = comp.filtered
    correction = comp.correction
    if filtered is not None:
        filtered = filtered.copy()
        filtered[where] = nominal.fk(q[where])
        p_t = T[:, :3, 3] if comp.mask == "pose" else T
        correction = np.linalg.norm(filtered[:, :3, 3] - p_t, axis=1)
    return replace(comp, q=q, position_error=ep, orientation_error=eo, filtered=filtered,
                   correction=correction, fallback=where)


def require_all(comp: Compensation, source: str | None = None,
                lines: NDArray[np.intp] | None = None) -> None:
    """Raise one :class:`UnreachableError` line naming the first failed target, if any."""
    bad = np.flatnonzero(~comp.success)
    if bad.size == 0:
        return
    i = int(bad[0])
    where = f"line {int(lines[i])}" if lines is not None else f"target {i}"
    raise UnreachableError(f"{where}: the calibrated robot cannot reach this target "
                           f"({comp.reason[i]}); {bad.size} of {len(comp)} targets failed",
                           source=source)
