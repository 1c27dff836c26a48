"""Trajectories: timing laws, Cartesian and joint-space paths, and the Trajectory value.

A *timing law* maps time ``t in [0, T]`` to a path parameter ``s in [0, 1]`` with
``s(0) = 0``, ``s(T) = 1`` and rest at both ends (``s'(0) = s'(T) = 0``):

* cubic:    ``s = 3 tau^2 - 2 tau^3``               (``tau = t / T``)
* quintic:  ``s = 10 tau^3 - 15 tau^4 + 6 tau^5``  (also ``s'' = 0`` at both ends)
* trapezoidal velocity: constant acceleration ``a`` for ``t_a``, cruise at ``v``,
  constant deceleration; from limits on the path's speed and acceleration.

A *path* gives the pose as a function of ``s`` with its first two derivatives as
twists ``[dp/ds; omega/ds]`` in the base frame: straight lines and circular arcs, the
orientation interpolated by slerp ``R(s) = R0 exp(s [w]x)``, ``w = log(R0^T R1)``
(body frame), whose angular rate ``omega/ds = R0 w`` is constant.  A *motion* is a
path paced by a timing law: ``x_dot = x' s_dot``, ``x_ddot = x'' s_dot^2 + x' s_ddot``.

Joint-space trajectories interpolate ``q`` directly (one timing law for all joints,
a trapezoid synchronised to the slowest joint, or splines through via points).
Cartesian trajectories get their joint values from the batched IK of
:mod:`kincal.ik`, solved in consecutive chunks seeded from the previous chunk so the
solution stays on one branch, then ``q_dot = J^+ x_dot`` and
``q_ddot = J^+ (x_ddot - J_dot q_dot)``.  Units: s, m, rad.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError, UnreachableError
from kincal.robots.chain import Robot
from kincal.spatial import exp_so3, log_so3, matrix_to_rpy, pose_error

Array = NDArray[np.float64]
TimingKind = Literal["cubic", "quintic", "trapezoidal", "linear"]


# ---------------------------------------------------------------------------
# timing laws


@dataclass(frozen=True)
class TimingLaw:
    """Normalised timing ``s(t)`` from 0 to 1 over ``[0, duration]``.

    Attributes:
        kind: ``"cubic"``, ``"quintic"``, ``"trapezoidal"`` or ``"linear"`` (constant
            speed, not at rest at the ends).
        duration: T [s].
        t_acc: trapezoidal only: acceleration (and deceleration) time [s].
        s_dot_max: trapezoidal only: cruise rate of s [1/s].
    """

    kind: TimingKind
    duration: float
    t_acc: float = 0.0
    s_dot_max: float = 0.0

    def __post_init__(self) -> None:
        if not (self.duration > 0 and math.isfinite(self.duration)):
            raise KincalError(f"a timing law needs a positive duration, got {self.duration}")
        if self.kind not in ("cubic", "quintic", "trapezoidal", "linear"):
            raise KincalError(f"unknown timing law {self.kind!r}; use cubic, quintic, "
                              "trapezoidal or linear")

    def __call__(self, t: ArrayLike) -> tuple[Array, Array, Array]:
        """``(s, s_dot [1/s], s_ddot [1/s^2])`` at times t (clamped to [0, T])."""
        T = self.duration
        tt = np.clip(np.asarray(t, dtype=float), 0.0, T)
        tau = tt / T
        if self.kind == "cubic":
            return (tau**2 * (3 - 2 * tau), 6 * tau * (1 - tau) / T, (6 - 12 * tau) / T**2)
        if self.kind == "quintic":
            return (tau**3 * (10 - 15 * tau + 6 * tau**2), 30 * tau**2 * (1 - tau)**2 / T,
                    60 * tau * (1 - tau) * (1 - 2 * tau) / T**2)
        if self.kind == "linear":
            return tau, np.full_like(tau, 1 / T), np.zeros_like(tau)
        ta, v = self.t_acc, self.s_dot_max
        a = v / ta
        rise, fall = tt < ta, tt > T - ta
        s = np.where(rise, 0.5 * a * tt**2,
                     np.where(fall, 1 - 0.5 * a * (T - tt)**2, v * (tt - 0.5 * ta)))
        sd = np.where(rise, a * tt, np.where(fall, a * (T - tt), v))
        sdd = np.where(rise, a, np.where(fall, -a, 0.0))
        return s, sd, sdd


def cubic(duration: float) -> TimingLaw:
    """Cubic rest-to-rest law ``s = 3 tau^2 - 2 tau^3`` over ``duration`` [s]."""
    return TimingLaw("cubic", float(duration))


def quintic(duration: float) -> TimingLaw:
    """Quintic law ``s = 10 tau^3 - 15 tau^4 + 6 tau^5`` (zero end velocity and acceleration)."""
    return TimingLaw("quintic", float(duration))


def trapezoidal(length: float, v_max: float, a_max: float,
                duration: float | None = None) -> TimingLaw:
    """Trapezoidal velocity law for a path of ``length`` (m or rad) within limits.

    Minimum time: if ``length >= v_max^2 / a_max``, ``t_a = v_max / a_max`` and
    ``T = length / v_max + t_a``; otherwise the profile is a triangle with
    ``t_a = sqrt(length / a_max)``, ``T = 2 t_a``.  With a longer ``duration`` the cruise
    speed drops to ``v = (a T - sqrt(a^2 T^2 - 4 a L)) / 2`` at the same acceleration.

    Raises:
        KincalError: non-positive limits or length, or a duration shorter than the
            minimum time.
    """
    L, v, a = float(length), float(v_max), float(a_max)
    if not (L > 0 and v > 0 and a > 0):
        raise KincalError("a trapezoidal law needs a positive length, v_max and a_max")
    if L >= v * v / a:
        ta, T = v / a, L / v + v / a
    else:
        ta = math.sqrt(L / a)
        T, v = 2 * ta, a * ta
    if duration is not None:
        if duration < T * (1 - 1e-12):
            raise KincalError(f"a trapezoidal move of {L:g} needs at least {T:.6g} s with "
                              f"v_max = {v_max:g}, a_max = {a_max:g}; {duration:g} s asked")
        T = float(duration)
        v = (a * T - math.sqrt(max(a * a * T * T - 4 * a * L, 0.0))) / 2
        ta = v / a
    return TimingLaw("trapezoidal", T, t_acc=ta, s_dot_max=v / L)


def timing_law(kind: str, duration: float | None = None, length: float = 1.0,
               v_max: float | None = None, a_max: float | None = None) -> TimingLaw:
    """A timing law by name (for the CLI): cubic, quintic, linear need ``duration``;
    trapezoidal needs ``v_max`` and ``a_max`` (and uses ``duration`` when given)."""
    if kind == "trapezoidal":
        if v_max is None or a_max is None:
            raise KincalError("the trapezoidal law needs --v-max and --a-max")
        return trapezoidal(length, v_max, a_max, duration)
    if duration is None:
        raise KincalError(f"the {kind} law needs a duration")
    return TimingLaw(kind, float(duration))  # type: ignore[arg-type]


def cubic_coefficients(q0: ArrayLike, q1: ArrayLike, v0: ArrayLike, v1: ArrayLike,
                       T: float) -> Array:
    """Coefficients ``c (4, n)`` of ``q(t) = sum_k c_k t^k`` with given end positions/velocities.

    ``c0 = q0, c1 = v0, c2 = (3 dq - (2 v0 + v1) T) / T^2, c3 = (-2 dq + (v0 + v1) T) / T^3``.
    """
    q0, q1, v0, v1 = (np.asarray(x, dtype=float) for x in (q0, q1, v0, v1))
    dq = q1 - q0
    return np.stack([q0, v0, (3 * dq - (2 * v0 + v1) * T) / T**2,
                     (-2 * dq + (v0 + v1) * T) / T**3])


def quintic_coefficients(q0: ArrayLike, q1: ArrayLike, v0: ArrayLike, v1: ArrayLike,
                         a0: ArrayLike, a1: ArrayLike, T: float) -> Array:
    """Coefficients ``c (6, n)`` of the quintic meeting end positions, velocities, accelerations.

    Solves the 6 boundary equations in closed form:
    ``c3 = (20 dq - (8 v1 + 12 v0) T - (3 a0 - a1) T^2) / (2 T^3)``,
    ``c4 = (-30 dq + (14 v1 + 16 v0) T + (3 a0 - 2 a1) T^2) / (2 T^4)``,
    ``c5 = (12 dq - 6 (v1 + v0) T + (a1 - a0) T^2) / (2 T^5)``.
    """
    q0, q1, v0, v1, a0, a1 = (np.asarray(x, dtype=float) for x in (q0, q1, v0, v1, a0, a1))
    dq = q1 - q0
    return np.stack([q0, v0, a0 / 2,
                     (20 * dq - (8 * v1 + 12 * v0) * T - (3 * a0 - a1) * T**2) / (2 * T**3),
                     (-30 * dq + (14 * v1 + 16 * v0) * T + (3 * a0 - 2 * a1) * T**2)
                     / (2 * T**4),
                     (12 * dq - 6 * (v1 + v0) * T + (a1 - a0) * T**2) / (2 * T**5)])


def polyval(c: Array, t: ArrayLike) -> tuple[Array, Array, Array]:
    """Position, velocity and acceleration (N, n) of polynomial coefficients ``c (K, n)``."""
    t = np.asarray(t, dtype=float)[:, None]
    k = np.arange(c.shape[0])
    pw = t[..., None] ** k                                   # (N, 1, K)
    p = np.einsum("nok,kj->nj", pw, c)
    v = np.einsum("nok,kj->nj", pw[..., :-1], c[1:] * k[1:, None])
    a = np.einsum("nok,kj->nj", pw[..., :-2], c[2:] * (k[2:] * (k[2:] - 1))[:, None])
    return p, v, a


def sample_times(duration: float, dt: float) -> Array:
    """``0, dt, 2 dt, ...`` up to and including ``duration`` [s]."""
    if not (dt > 0):
        raise KincalError(f"the time step must be positive, got {dt}")
    n = int(math.floor(duration / dt + 1e-9))
    t = np.arange(n + 1) * dt
    if duration - t[-1] > 1e-9 * max(dt, 1.0):
        t = np.append(t, duration)
    return t


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
    meta: dict = field(default_factory=dict)

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


def _save(fig: object, path: str | Path) -> None:
    """Save a matplotlib figure atomically as PNG."""
    import io

    from kincal.io import atomic_write_bytes

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)  # type: ignore[attr-defined]
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
# Cartesian paths


class CartesianPath(Protocol):
    """A geometric path ``T(s)``, ``s in [0, 1]``."""

    def at(self, s: ArrayLike) -> tuple[Array, Array, Array]:
        """Poses (N, 4, 4) and twists ``dX/ds``, ``d2X/ds2`` (N, 6) in the base frame."""
        ...

    @property
    def length(self) -> float:
        """Length of the position path [m] (for trapezoidal timing)."""
        ...


def _slerp(R0: Array, R1: Array, s: Array) -> tuple[Array, Array]:
    """``R(s) = R0 exp(s [w]x)``, ``w = log(R0^T R1)``; returns R(s) and ``omega/ds = R0 w``."""
    w = log_so3(R0.T @ R1)
    return R0 @ exp_so3(s[:, None] * w), R0 @ w


@dataclass(frozen=True)
class LinePath:
    """Straight segment from pose ``start`` to pose ``end`` (4, 4), orientation by slerp.

    ``p(s) = p0 + s (p1 - p0)``, ``p' = p1 - p0``, ``p'' = 0``; ``omega' = R0 w``, ``alpha = 0``.
    """

    start: Array
    end: Array

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end[:3, 3] - self.start[:3, 3]))

    @property
    def angle(self) -> float:
        """Rotation angle from start to end orientation [rad]."""
        return float(np.linalg.norm(log_so3(self.start[:3, :3].T @ self.end[:3, :3])))

    def at(self, s: ArrayLike) -> tuple[Array, Array, Array]:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        R, w = _slerp(self.start[:3, :3], self.end[:3, :3], s)
        dp = self.end[:3, 3] - self.start[:3, 3]
        T = np.tile(np.eye(4), (s.size, 1, 1))
        T[:, :3, :3] = R
        T[:, :3, 3] = self.start[:3, 3] + s[:, None] * dp
        d1 = np.tile(np.concatenate([dp, w]), (s.size, 1))
        return T, d1, np.zeros_like(d1)


@dataclass(frozen=True)
class ArcPath:
    """Circular arc about ``centre`` and unit ``axis`` through ``angle``, orientation by slerp.

    ``p(s) = c + Rot(n, s theta) (p0 - c)``; ``p' = theta n x (p - c)``;
    ``p'' = theta^2 n x (n x (p - c))``.  The orientation goes from ``R_start`` to
    ``R_end`` by slerp, independently of the arc.
    """

    centre: Array
    axis: Array
    angle: float
    start: Array
    R_end: Array

    @property
    def radius(self) -> float:
        r = self.start[:3, 3] - self.centre
        return float(np.linalg.norm(r - self.axis * (self.axis @ r)))

    @property
    def length(self) -> float:
        return abs(self.angle) * self.radius

    def at(self, s: ArrayLike) -> tuple[Array, Array, Array]:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        n, th = self.axis, self.angle
        r0 = self.start[:3, 3] - self.centre
        r = (exp_so3(np.outer(s * th, n)) @ r0)
        R, w = _slerp(self.start[:3, :3], self.R_end, s)
        T = np.tile(np.eye(4), (s.size, 1, 1))
        T[:, :3, :3] = R
        T[:, :3, 3] = self.centre + r
        v = th * np.cross(n, r)
        a = th**2 * np.cross(n, np.cross(n, r))
        d1 = np.concatenate([v, np.tile(w, (s.size, 1))], 1)
        d2 = np.concatenate([a, np.zeros((s.size, 3))], 1)
        return T, d1, d2


def arc_through(start: ArrayLike, via: ArrayLike, end: ArrayLike) -> ArcPath:
    """The circular arc from pose ``start`` through point ``via`` (3,) to pose ``end``.

    The centre is the circumcentre of the three points; the arc runs from the start
    point through ``via`` to the end point.  Raises for collinear points.
    """
    T0, T1 = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    a, b, c = T0[:3, 3], np.asarray(via, dtype=float), T1[:3, 3]
    u, v = b - a, c - a
    nrm = np.cross(u, v)
    nn = float(nrm @ nrm)
    if nn < 1e-18 * max(float(u @ u) * float(v @ v), 1e-300):
        raise KincalError("the arc's start, via and end points are collinear (or coincide)")
    centre = a + (np.cross(nrm, u) * (v @ v) + np.cross(v, nrm) * (u @ u)) / (2 * nn)
    axis = nrm / math.sqrt(nn)
    r0, r1 = a - centre, c - centre
    angle = math.atan2(float(axis @ np.cross(r0, r1)), float(r0 @ r1))
    if angle <= 0:
        angle += 2 * math.pi       # through the via point, counter-clockwise about the axis
    return ArcPath(centre, axis, angle, T0, T1[:3, :3])


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
                         mask: str | Sequence[bool] = "pose", chunk: int = 50,
                         kind: str = "line", tol: float = 1e-9) -> Trajectory:
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
    from kincal.ik import parse_mask, solve_ik

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
    cat = (lambda a: None if a is None else np.concatenate(a))  # noqa: E731
    first = parts[0]
    return Trajectory(np.concatenate(t), np.concatenate(q), np.concatenate(qd),
                      np.concatenate(qdd), first.joint_names, first.joint_units, cat(xs),
                      cat(xds), cat(xdds), kind="path" if len(parts) > 1 else first.kind)


def cartesian_via(robot: Robot, poses: Sequence[ArrayLike], q0: ArrayLike, dt: float,
                  timing: str = "quintic", durations: Sequence[float] | None = None,
                  v_max: float | None = None, a_max: float | None = None,
                  mask: str | Sequence[bool] = "pose") -> Trajectory:
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
