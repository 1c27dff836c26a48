"""Trajectories: the Trajectory value and the builders of joint-space and Cartesian ones.

Timing laws (``s(t)`` from 0 to 1: cubic, quintic, trapezoidal) and joint polynomials
live in :mod:`kincal.motion.timing`; Cartesian paths (``T(s)``: lines, arcs, slerp) in
:mod:`kincal.motion.paths`; both are re-exported here, so ``from kincal.motion.trajectory import
LinePath, quintic`` keeps working.

A *motion* is a path paced by a timing law: ``x_dot = x' s_dot``,
``x_ddot = x'' s_dot^2 + x' s_ddot``.

Joint-space trajectories interpolate ``q`` directly (one timing law for all joints,
a trapezoid synchronised to the slowest joint, or splines through via points).
Cartesian trajectories get their joint values from the batched IK of
:mod:`kincal.motion.ik`, solved in consecutive chunks seeded from the previous chunk so the
solution stays on one branch, then ``q_dot = J^+ x_dot`` and
``q_ddot = J^+ (x_ddot - J_dot q_dot)``.  Units: s, m, rad.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError, UnreachableError
from kincal.motion.paths import ArcPath, CartesianPath, LinePath, arc_through
from kincal.motion.timing import (
    TimingKind,
    TimingLaw,
    cubic,
    cubic_coefficients,
    polyval,
    quintic,
    quintic_coefficients,
    sample_times,
    timing_law,
    trapezoidal,
)
from kincal.robots.chain import Robot
from kincal.spatial import matrix_to_rpy, pose_error

if TYPE_CHECKING:                 # types only: matplotlib loads lazily
    from matplotlib.figure import Figure

Array = NDArray[np.float64]

__all__ = [
    # the value and its builders
    "Trajectory", "joint_trajectory", "synchronized_trapezoidal", "via_trajectory",
    "CartesianMotion", "cartesian_trajectory", "line_motion", "concatenate", "cartesian_via",
    # re-exported from kincal.motion.timing
    "TimingKind", "TimingLaw", "cubic", "quintic", "trapezoidal", "timing_law",
    "cubic_coefficients", "quintic_coefficients", "polyval", "sample_times",
    # re-exported from kincal.motion.paths
    "CartesianPath", "LinePath", "ArcPath", "arc_through",
]


# ---------------------------------------------------------------------------
# the Trajectory value


@dataclass(frozen=True)
class Trajectory:
    """Sampled motion of a robot: joint values and, for Cartesian ones, tool poses.

    Attributes:
        t: (N,) times [s].
        q, qd, qdd: (N, n) joint positions [rad | m], velocities [/s], accelerations [/s^2].
        joint_names, joint_units: per joint (``"rad"`` or ``"m"``).
        x: (N, 4, 4) tool poses, or None for joint-space trajectories.
        xd, xdd: (N, 6) twists ``[v; omega]`` and their derivatives ``[a; alpha]`` in the
            base frame [m/s, rad/s, m/s^2, rad/s^2], or None.
        kind: ``"joint"``, ``"line"``, ``"arc"`` or ``"path"``.
    """

    t: Array
    q: Array
    qd: Array
    qdd: Array
    joint_names: tuple[str, ...]
    joint_units: tuple[str, ...]
    x: Array | None = None
    xd: Array | None = None
    xdd: Array | None = None
    kind: str = "joint"
    meta: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    @property
    def position(self) -> Array | None:
        """(N, 3) tool positions [m] for Cartesian trajectories."""
        return None if self.x is None else self.x[:, :3, 3]

    def __repr__(self) -> str:
        return (f"Trajectory({self.kind}, {len(self)} samples over {self.duration:g} s, "
                f"{self.q.shape[1]} joints)")

    def header(self) -> list[str]:
        """CSV column names with units: ``t_s, q1_rad, ..., q1_dot_rad_s, ..., q1_ddot_rad_s2``."""
        pairs = list(zip(self.joint_names, self.joint_units, strict=True))
        cols = (["t_s"] + [f"{n}_{u}" for n, u in pairs] + [f"{n}_dot_{u}_s" for n, u in pairs]
                + [f"{n}_ddot_{u}_s2" for n, u in pairs])
        if self.x is not None:
            cols += ["x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad",
                     "vx_m_s", "vy_m_s", "vz_m_s", "wx_rad_s", "wy_rad_s", "wz_rad_s"]
        return cols

    def table(self) -> Array:
        """The CSV body as an (N, columns) array, in :meth:`header` order."""
        parts = [self.t[:, None], self.q, self.qd, self.qdd]
        if self.x is not None and self.xd is not None:
            parts += [self.x[:, :3, 3], matrix_to_rpy(self.x[:, :3, :3]), self.xd]
        return np.concatenate(parts, 1)

    def to_csv(self, path: str | Path) -> None:
        """Write the trajectory as CSV with units in the header, atomically."""
        from kincal.io import atomic_write_text

        lines = [",".join(self.header())]
        lines += [",".join(f"{v:.12g}" for v in row) for row in self.table()]
        atomic_write_text(path, "\n".join(lines) + "\n")

    def plot(self, path: str | Path, title: str | None = None) -> None:
        """Plot q, q_dot, q_ddot (and the tool position) against time to a PNG."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        rows = 4 if self.x is not None else 3
        fig, axes = plt.subplots(rows, 1, figsize=(8, 2.4 * rows), sharex=True)
        names = self.joint_names
        for ax, data, what in zip(axes, (self.q, self.qd, self.qdd),
                                  ("position", "velocity", "acceleration"), strict=False):
            for j, n in enumerate(names):
                ax.plot(self.t, data[:, j], label=f"{n} [{self.joint_units[j]}]")
            ax.set_ylabel(f"joint {what}")
            ax.grid(True, alpha=0.3)
        axes[0].legend(fontsize=7, ncol=min(len(names), 6))
        if self.x is not None:
            for k, c in enumerate("xyz"):
                axes[3].plot(self.t, self.x[:, k, 3], label=f"{c} [m]")
            axes[3].set_ylabel("tool position")
            axes[3].legend(fontsize=7)
            axes[3].grid(True, alpha=0.3)
        axes[-1].set_xlabel("t [s]")
        fig.suptitle(title or repr(self))
        fig.tight_layout()
        _save(fig, path)
        plt.close(fig)


def _save(fig: Figure, path: str | Path) -> None:
    """Save a matplotlib figure atomically as PNG."""
    import io

    from kincal.io import atomic_write_bytes

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    atomic_write_bytes(path, buf.getvalue())


def _joint_meta(robot: Robot | None, n: int) -> tuple[tuple[str, ...], tuple[str, ...]]:
    if robot is None:
        return tuple(f"q{i + 1}" for i in range(n)), ("rad",) * n
    return robot.joint_names, tuple(j.unit for j in robot.joints)


# ---------------------------------------------------------------------------
# joint space


def joint_trajectory(q_start: ArrayLike, q_end: ArrayLike, timing: TimingLaw, dt: float,
                     robot: Robot | None = None) -> Trajectory:
    """Straight line in joint space: ``q(t) = q0 + s(t) (q1 - q0)`` sampled every ``dt``."""
    q0, q1 = np.asarray(q_start, dtype=float), np.asarray(q_end, dtype=float)
    if q0.shape != q1.shape or q0.ndim != 1:
        raise KincalError(f"start and end joint vectors differ in shape: {q0.shape}, {q1.shape}")
    t = sample_times(timing.duration, dt)
    s, sd, sdd = timing(t)
    dq = q1 - q0
    names, units = _joint_meta(robot, q0.size)
    return Trajectory(t, q0 + s[:, None] * dq, sd[:, None] * dq, sdd[:, None] * dq, names,
                      units, kind="joint", meta={"timing": timing.kind})


def synchronized_trapezoidal(q_start: ArrayLike, q_end: ArrayLike, v_max: ArrayLike,
                             a_max: ArrayLike) -> TimingLaw:
    """One trapezoidal law for all joints, within every joint's velocity/acceleration limit.

    With ``q = q0 + s dq``, joint i moves at ``s_dot |dq_i|``; the law on s uses
    ``s_dot <= min_i v_i / |dq_i|`` and ``s_ddot <= min_i a_i / |dq_i|`` (limits per unit:
    rad/s or m/s, rad/s^2 or m/s^2), so the slowest joint sets the time.
    """
    dq = np.abs(np.asarray(q_end, dtype=float) - np.asarray(q_start, dtype=float))
    v = np.broadcast_to(np.asarray(v_max, dtype=float), dq.shape)
    a = np.broadcast_to(np.asarray(a_max, dtype=float), dq.shape)
    if np.any(v <= 0) or np.any(a <= 0):
        raise KincalError("joint velocity and acceleration limits must be positive")
    moving = dq > 0
    if not moving.any():
        raise KincalError("start and end joint values are equal: nothing to move")
    return trapezoidal(1.0, float(np.min(v[moving] / dq[moving])),
                       float(np.min(a[moving] / dq[moving])))


def via_trajectory(points: ArrayLike, times: ArrayLike, dt: float,
                   method: Literal["spline", "cubic"] = "spline",
                   robot: Robot | None = None) -> Trajectory:
    """Joint trajectory through via points, at rest at the first and last.

    * ``"spline"``: the C2 cubic spline with zero end velocities (continuous acceleration).
    * ``"cubic"``: one cubic per segment with via velocities from the slopes
      ``d_k = (q_k - q_{k-1}) / (t_k - t_{k-1})``: ``v_k = (d_k + d_{k+1}) / 2`` when the
      slopes have the same sign, else 0 (continuous velocity).

    Args:
        points: (K, n) joint values at the via points, K >= 2.
        times: (K,) strictly increasing times [s], ``times[0]`` usually 0.
    """
    P = np.asarray(points, dtype=float)
    tk = np.asarray(times, dtype=float)
    if P.ndim != 2 or P.shape[0] < 2 or tk.shape != (P.shape[0],):
        raise KincalError("via points need shape (K, n), K >= 2, with one time per point")
    if np.any(np.diff(tk) <= 0):
        raise KincalError("via-point times must increase strictly")
    t = tk[0] + sample_times(tk[-1] - tk[0], dt)
    if method == "spline":
        from scipy.interpolate import CubicSpline

        cs = CubicSpline(tk, P, bc_type="clamped", axis=0)
        q, qd, qdd = cs(t), cs(t, 1), cs(t, 2)
    elif method == "cubic":
        d = np.diff(P, axis=0) / np.diff(tk)[:, None]
        v = np.zeros_like(P)
        same = np.sign(d[:-1]) == np.sign(d[1:])
        v[1:-1] = np.where(same, 0.5 * (d[:-1] + d[1:]), 0.0)
        seg = np.clip(np.searchsorted(tk, t, side="right") - 1, 0, len(tk) - 2)
        q, qd, qdd = (np.empty((t.size, P.shape[1])) for _ in range(3))
        for k in range(len(tk) - 1):            # loop over segments, vectorised inside
            m = seg == k
            c = cubic_coefficients(P[k], P[k + 1], v[k], v[k + 1], tk[k + 1] - tk[k])
            q[m], qd[m], qdd[m] = polyval(c, t[m] - tk[k])
    else:
        raise KincalError(f"unknown via-point method {method!r}; use spline or cubic")
    names, units = _joint_meta(robot, P.shape[1])
    return Trajectory(t, q, qd, qdd, names, units, kind="joint", meta={"via": method})


# ---------------------------------------------------------------------------
# Cartesian motions


@dataclass(frozen=True)
class CartesianMotion:
    """A path paced by a timing law: the desired pose and its rates at any time.

    ``x(t) = X(s(t))``, ``x_dot = X' s_dot``, ``x_ddot = X'' s_dot^2 + X' s_ddot``.
    """

    path: CartesianPath
    timing: TimingLaw

    @property
    def duration(self) -> float:
        return self.timing.duration

    def __call__(self, t: ArrayLike) -> tuple[Array, Array, Array]:
        """Poses (N, 4, 4), twists (N, 6) [m/s, rad/s] and their rates (N, 6) at times t."""
        s, sd, sdd = self.timing(np.atleast_1d(np.asarray(t, dtype=float)))
        T, d1, d2 = self.path.at(s)
        return T, d1 * sd[:, None], d2 * (sd**2)[:, None] + d1 * sdd[:, None]


def cartesian_trajectory(robot: Robot, motion: CartesianMotion, q0: ArrayLike, dt: float,
                         mask: str | Sequence[bool] | NDArray[np.bool_] = "pose",
                         chunk: int = 50, kind: str = "line", tol: float = 1e-9) -> Trajectory:
    """Sample a Cartesian motion every ``dt`` and solve the joints by batched IK.

    The samples are solved in consecutive chunks of ``chunk``; each chunk's starts are
    the previous chunk's last solution moved by the first-order prediction
    ``dq = J^+ e`` toward each sample (one branch all along).  Joint rates:
    ``q_dot = J^+ x_dot``, ``q_ddot = J^+ (x_ddot - J_dot q_dot)`` on the masked rows, with
    ``J_dot q_dot`` from central differences of ``J`` along ``q_dot``.

    Raises:
        UnreachableError: a sample cannot be reached (its time and the IK's reason).
        KincalError: the joint solution jumps between samples (a branch switch).
    """
    from kincal.motion.ik import parse_mask, solve_ik

    m = parse_mask(mask)
    t = sample_times(motion.duration, dt)
    X, Xd, Xdd = motion(t)
    N = t.size
    q = np.empty((N, robot.n))
    seed = np.asarray(q0, dtype=float)
    rows = np.flatnonzero(m)
    for s0 in range(0, N, chunk):              # loop over chunks; each chunk is batched
        sl = slice(s0, min(s0 + chunk, N))
        T_seed, J_seed, _ = robot.fk_with_jacobians(seed[None], joints=True, params=False)
        assert J_seed is not None                 # joints=True: the joint Jacobian is made
        e = pose_error(X[sl], T_seed[0])[:, rows]
        starts = seed + e @ np.linalg.pinv(J_seed[0][rows]).T
        sol = solve_ik(robot, X[sl], q0=starts, mask=m, tol_position=tol,
                       tol_orientation=tol, restarts=0)
        if not sol.success.all():
            i = int(np.flatnonzero(~sol.success)[0])
            raise UnreachableError(f"the path cannot be followed at t = {t[s0 + i]:.4g} s: "
                                   f"{sol.reason[i]}")
        q[sl] = sol.q
        seed = sol.q[-1]
    jump = np.abs(np.diff(q, axis=0)).max(axis=1) if N > 1 else np.zeros(0)
    typical = np.median(jump) if jump.size else 0.0
    if jump.size and jump.max() > max(20 * typical, 1e-6) and jump.max() > 0.05:
        k = int(np.argmax(jump))
        raise KincalError(f"the joint solution jumps by {jump.max():.3g} between t = "
                          f"{t[k]:.4g} s and {t[k + 1]:.4g} s (a singularity or branch switch "
                          "on the path)")
    qd, qdd = _joint_rates(robot, q, Xd[:, rows], Xdd[:, rows], rows)
    names, units = _joint_meta(robot, robot.n)
    return Trajectory(t, q, qd, qdd, names, units, x=X, xd=Xd, xdd=Xdd, kind=kind,
                      meta={"timing": motion.timing.kind})


def _joint_rates(robot: Robot, q: Array, xd: Array, xdd: Array,
                 rows: NDArray[np.intp]) -> tuple[Array, Array]:
    """``q_dot = J^+ x_dot`` and ``q_ddot = J^+ (x_ddot - J_dot q_dot)`` (masked rows)."""
    J = robot.jacobian(q)[:, rows]
    Jp = np.linalg.pinv(J)
    qd = np.einsum("nij,nj->ni", Jp, xd)
    h = 1e-6
    Jdot_qd = np.einsum("nij,nj->ni", (robot.jacobian(q + h * qd)[:, rows]
                                       - robot.jacobian(q - h * qd)[:, rows]) / (2 * h), qd)
    qdd = np.einsum("nij,nj->ni", Jp, xdd - Jdot_qd)
    return qd, qdd


def line_motion(start: ArrayLike, end: ArrayLike, timing: TimingLaw | str = "quintic",
                duration: float | None = None, v_max: float | None = None,
                a_max: float | None = None) -> CartesianMotion:
    """A straight line between two poses (4, 4) with a timing law (object or name)."""
    path = LinePath(np.asarray(start, dtype=float), np.asarray(end, dtype=float))
    law = timing if isinstance(timing, TimingLaw) else timing_law(
        timing, duration, path.length, v_max, a_max)
    return CartesianMotion(path, law)


def concatenate(parts: Sequence[Trajectory]) -> Trajectory:
    """Join trajectories end to start (the first sample of each later part is dropped)."""
    if not parts:
        raise KincalError("nothing to concatenate")
    t, q, qd, qdd = [parts[0].t], [parts[0].q], [parts[0].qd], [parts[0].qdd]
    xs = [parts[0].x] if parts[0].x is not None else None
    xds = [parts[0].xd] if parts[0].xd is not None else None
    xdds = [parts[0].xdd] if parts[0].xdd is not None else None
    offset = parts[0].t[-1]
    for p in parts[1:]:
        t.append(p.t[1:] - p.t[0] + offset)
        q.append(p.q[1:])
        qd.append(p.qd[1:])
        qdd.append(p.qdd[1:])
        for acc, arr in ((xs, p.x), (xds, p.xd), (xdds, p.xdd)):
            if acc is not None:
                if arr is None:
                    raise KincalError("cannot join joint-space and Cartesian trajectories")
                acc.append(arr[1:])
        offset = t[-1][-1] if t[-1].size else offset
    first = parts[0]
    return Trajectory(np.concatenate(t), np.concatenate(q), np.concatenate(qd),
                      np.concatenate(qdd), first.joint_names, first.joint_units, _joined(xs),
                      _joined(xds), _joined(xdds), kind="path" if len(parts) > 1 else first.kind)


def _joined(arrays: list[Array] | None) -> Array | None:
    """The arrays end to end, or None for a trajectory without that quantity."""
    return None if arrays is None else np.concatenate(arrays)


def cartesian_via(robot: Robot, poses: Sequence[ArrayLike], q0: ArrayLike, dt: float,
                  timing: str = "quintic", durations: Sequence[float] | None = None,
                  v_max: float | None = None, a_max: float | None = None,
                  mask: str | Sequence[bool] | NDArray[np.bool_] = "pose") -> Trajectory:
    """Straight segments through via poses, at rest at each via point, joined in time."""
    if len(poses) < 2:
        raise KincalError("a Cartesian path needs at least two poses")
    parts: list[Trajectory] = []
    q_start = np.asarray(q0, dtype=float)
    for k in range(len(poses) - 1):
        dur = None if durations is None else durations[k]
        mo = line_motion(poses[k], poses[k + 1], timing, dur, v_max, a_max)
        tr = cartesian_trajectory(robot, mo, q_start, dt, mask=mask, kind="line")
        parts.append(tr)
        q_start = tr.q[-1]
    return concatenate(parts)
