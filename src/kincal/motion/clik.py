"""Differential kinematics and closed-loop inverse kinematics (CLIK).

The joint velocity that tracks a desired motion ``x_d(t)`` with error ``e = x_d - x(q)``:

    q_dot = J#(q) (x_dot_d + K e)                     (inverse, pinv, dls, adaptive)
    q_dot = J(q)^T K e                                (transpose, no feed-forward)

with the generalised inverse ``J#`` one of

* ``"inverse"``:   ``J^-1`` (square J; blows up at a singularity);
* ``"pinv"``:      ``J^+`` (Moore-Penrose, from the SVD);
* ``"dls"``:       ``J^T (J J^T + k^2 I)^-1``, constant damping ``k``;
* ``"adaptive"``:  the same with ``k^2 = k_max^2 (1 - (sigma_min / eps)^2)`` when the
  smallest singular value ``sigma_min < eps`` and 0 otherwise (Nakamura & Hanafusa
  1986; Chiaverini 1997): exact inversion away from singularities, damping only near
  one.

Tasks: ``"position"`` uses the 3 x n position rows of the geometric Jacobian and
``e = p_d - p``.  ``"pose"`` adds an orientation error: ``"axis_angle"``:
``e_o = log(R_d R^T)`` (rotation vector) with the geometric Jacobian and feed-forward
``omega_d``; ``"zyz"`` / ``"rpy"``: ``e_o = phi_d - phi`` (minimal angles, wrapped) with
the analytic Jacobian ``J_A = diag(I, E(phi)^-1) J`` and feed-forward
``phi_dot_d = E(phi_d)^-1 omega_d``.

Integration: Euler ``q_{k+1} = q_k + dt q_dot(t_k, q_k)`` or classical 4th-order
Runge-Kutta (``"rk4"``) with the desired motion evaluated at the intermediate times.
Along the path the run records the manipulability ``w = sqrt(det(J J^T))``, the
condition number ``sigma_max / sigma_min`` and the damping used.  Units: s, m, rad.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.motion.trajectory import CartesianMotion, LinePath, TimingLaw, sample_times
from kincal.robots.chain import Robot
from kincal.robots.dh import DHLink, from_dh
from kincal.spatial import log_so3, matrix_to_angles, rate_matrix, wrap_angle

Array = NDArray[np.float64]
Method = Literal["inverse", "transpose", "pinv", "dls", "adaptive"]
METHODS: tuple[Method, ...] = ("inverse", "transpose", "pinv", "dls", "adaptive")
Orientation = Literal["axis_angle", "zyz", "rpy"]
Integrator = Literal["euler", "rk4"]
INTEGRATORS: tuple[Integrator, ...] = ("euler", "rk4")


# ---------------------------------------------------------------------------
# differential kinematics


def generalized_inverse(J: ArrayLike, method: Method = "pinv", damping: float = 0.1,
                        threshold: float = 0.1) -> tuple[Array, Array]:
    """``J#`` for one or many Jacobians (..., m, n) -> (..., n, m), and the ``k^2`` used.

    Args:
        J: Jacobians.
        method: ``"inverse"``, ``"pinv"``, ``"dls"``, ``"adaptive"`` (see the module
            docstring); ``"transpose"`` returns ``J^T``.
        damping: ``k`` for ``"dls"``, ``k_max`` for ``"adaptive"`` [units of J].
        threshold: ``eps`` for ``"adaptive"``: damping starts below this sigma_min.

    Raises:
        KincalError: ``"inverse"`` of a non-square or exactly singular J.
    """
    J = np.asarray(J, dtype=float)
    m = J.shape[-2]
    Jt = np.swapaxes(J, -1, -2)
    lam2 = np.zeros(J.shape[:-2])
    if method == "inverse":
        if J.shape[-1] != m:
            raise KincalError(f"J^-1 needs a square Jacobian, not {m} x {J.shape[-1]}; "
                              "use pinv or dls")
        try:
            return np.linalg.inv(J), lam2
        except np.linalg.LinAlgError:
            raise KincalError("the Jacobian is exactly singular: J^-1 does not exist; "
                              "use dls or adaptive") from None
    if method == "transpose":
        return Jt, lam2
    if method == "pinv":
        return np.linalg.pinv(J), lam2
    if method == "dls":
        lam2 = np.full(J.shape[:-2], float(damping) ** 2)
    elif method == "adaptive":
        smin = np.linalg.svd(J, compute_uv=False)[..., -1]
        ratio = np.minimum(smin / float(threshold), 1.0)
        lam2 = float(damping) ** 2 * (1.0 - ratio**2)
    else:
        raise KincalError(f"unknown inversion {method!r}; use one of {', '.join(METHODS)}")
    A = J @ Jt + lam2[..., None, None] * np.eye(m)
    return Jt @ np.linalg.inv(A), lam2


def manipulability(J: ArrayLike) -> tuple[Array, Array, Array]:
    """Yoshikawa's ``w = sqrt(det(J J^T))``, the condition number and sigma_min, per J."""
    s = np.linalg.svd(np.asarray(J, dtype=float), compute_uv=False)
    w = np.prod(s, axis=-1)
    with np.errstate(divide="ignore"):
        cond = np.where(s[..., -1] > 0, s[..., 0] / s[..., -1], np.inf)
    return w, cond, s[..., -1]


# ---------------------------------------------------------------------------
# CLIK


@dataclass(frozen=True)
class ClikResult:
    """A CLIK run sampled at every step.

    Attributes:
        t: (N,) [s].
        q, qd: (N, n) joint positions and commanded velocities [rad | m, per s].
        pose, pose_desired: (N, 4, 4) actual and desired tool poses.
        error: (N, m) task error ``e`` (m rows: 3 for position, 6 for pose) [m, rad].
        manipulability, condition, sigma_min, damping: (N,) of the task Jacobian
            (``damping`` is the ``k^2`` used).
        method, task, orientation, integrator, dt, gain: the settings.
    """

    t: Array
    q: Array
    qd: Array
    pose: Array
    pose_desired: Array
    error: Array
    manipulability: Array
    condition: Array
    sigma_min: Array
    damping: Array
    method: str
    task: str
    orientation: str
    integrator: str
    dt: float
    gain: Array
    joint_names: tuple[str, ...] = ()
    joint_units: tuple[str, ...] = ()
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def position(self) -> Array:
        return self.pose[:, :3, 3]

    @property
    def position_desired(self) -> Array:
        return self.pose_desired[:, :3, 3]

    @property
    def position_error(self) -> Array:
        """(N,) ``|p_d - p|`` [m]."""
        err: Array = np.linalg.norm(self.position_desired - self.position, axis=1)
        return err

    def path_deviation(self, path: LinePath | None = None) -> Array:
        """(N,) distance of the actual position from the straight segment [m].

        Uses ``meta["segment"]`` (start, end) when no path is given.
        """
        if path is not None:
            a, b = path.start[:3, 3], path.end[:3, 3]
        else:
            a, b = (np.asarray(v) for v in self.meta["segment"])
        d = b - a
        s = np.clip((self.position - a) @ d / (d @ d), 0.0, 1.0)
        dist: Array = np.linalg.norm(self.position - (a + s[:, None] * d), axis=1)
        return dist

    def summary(self) -> dict[str, float | str]:
        """Key numbers: final and peak errors, peak joint velocities, worst conditioning."""
        out: dict[str, float | str] = {
            "method": self.method, "dt_s": self.dt,
            "final_position_error_m": float(self.position_error[-1]),
            "max_position_error_m": float(self.position_error.max()),
            "min_manipulability": float(self.manipulability.min()),
            "max_condition": float(self.condition.max()),
        }
        if "segment" in self.meta:
            out["max_path_deviation_m"] = float(self.path_deviation().max())
        for j, name in enumerate(self.joint_names or [f"q{i + 1}" for i in
                                                      range(self.q.shape[1])]):
            u = self.joint_units[j] if self.joint_units else "rad"
            out[f"max_abs_{name}_dot_{u}_s"] = float(np.abs(self.qd[:, j]).max())
        return out

    def header(self) -> list[str]:
        names = self.joint_names or tuple(f"q{i + 1}" for i in range(self.q.shape[1]))
        units = self.joint_units or ("rad",) * len(names)
        return (["t_s"] + [f"{n}_{u}" for n, u in zip(names, units, strict=True)]
                + [f"{n}_dot_{u}_s" for n, u in zip(names, units, strict=True)]
                + ["x_m", "y_m", "z_m", "x_desired_m", "y_desired_m", "z_desired_m",
                   "position_error_m", "manipulability", "condition", "damping_k2"])

    def to_csv(self, path: str | Path) -> None:
        """Write every sample with units in the header, atomically."""
        from kincal.io import atomic_write_text

        body = np.column_stack([self.t, self.q, self.qd, self.position, self.position_desired,
                                self.position_error, self.manipulability, self.condition,
                                self.damping])
        lines = [",".join(self.header())] + [",".join(f"{v:.12g}" for v in row)
                                             for row in body]
        atomic_write_text(path, "\n".join(lines) + "\n")


def _gain(gain: float | ArrayLike, m: int) -> Array:
    K = np.asarray(gain, dtype=float)
    if K.ndim == 0:
        K = np.full(m, float(K))
    if K.ndim == 1:
        if K.size != m:
            raise KincalError(f"the gain needs 1 or {m} values, got {K.size}")
        K = np.diag(K)
    if K.shape != (m, m) or np.any(np.linalg.eigvalsh(0.5 * (K + K.T)) <= 0):
        raise KincalError("the CLIK gain K must be positive definite")
    return K


_wrap = wrap_angle   # (-pi, pi]


def clik(robot: Robot, motion: CartesianMotion | Callable[[Array], tuple[Array, Array, Array]],
         q0: ArrayLike, dt: float, gain: float | ArrayLike = 50.0, method: Method = "inverse",
         damping: float = 0.1, threshold: float = 0.1,
         task: Literal["position", "pose"] = "position", orientation: Orientation = "axis_angle",
         integrator: Integrator = "euler", duration: float | None = None,
         progress: Callable[[int, int], None] | None = None) -> ClikResult:
    """Closed-loop inverse kinematics along a desired motion.

    Args:
        robot: the arm.
        motion: a :class:`CartesianMotion` (or any callable ``t -> (T_d, twist_d, acc_d)``
            batched over t) giving the desired pose and twist ``[v; omega]`` [m/s, rad/s].
        q0: initial joint values (n,).
        dt: integration step [s].
        gain: K, a scalar, m diagonal values or an (m, m) positive-definite matrix [1/s].
        method: the inversion (see :func:`generalized_inverse`).
        damping: ``k`` (dls) or ``k_max`` (adaptive).
        threshold: ``eps`` (adaptive).
        task: ``"position"`` (3 rows) or ``"pose"`` (6 rows).
        orientation: for ``task="pose"``: ``"axis_angle"``, ``"zyz"`` or ``"rpy"``.
        integrator: ``"euler"`` or ``"rk4"``.
        duration: end time [s] (default: ``motion.duration``).
        progress: called as ``progress(step, steps)`` now and then (for progress bars).

    Returns:
        :class:`ClikResult` with one sample per step, the last at ``duration``.
    """
    if method not in METHODS:
        raise KincalError(f"unknown inversion {method!r}; use one of {', '.join(METHODS)}")
    if task not in ("position", "pose"):
        raise KincalError(f"unknown CLIK task {task!r}; use position or pose")
    if orientation not in ("axis_angle", "zyz", "rpy"):
        raise KincalError(f"unknown orientation error {orientation!r}; use axis_angle, zyz "
                          "or rpy")
    if integrator not in ("euler", "rk4"):
        raise KincalError(f"unknown integrator {integrator!r}; use euler or rk4")
    T_end = duration if duration is not None else getattr(motion, "duration", None)
    if T_end is None:
        raise KincalError("give the CLIK duration for a motion without one")
    m = 3 if task == "position" else 6
    K = _gain(gain, m)
    t = sample_times(float(T_end), dt)
    N, n = t.size, robot.n
    Td, Vd, _ = motion(t)

    def field_at(tk: float, q: Array, cached: tuple[Array, Array] | None = None
                 ) -> tuple[Array, Array, Array, Array, float]:
        """q_dot and the diagnostics at time tk (desired from cache or the motion)."""
        Tdk, vdk = (cached if cached is not None else (lambda r: (r[0][0], r[1][0]))(
            motion(np.array([tk]))))
        T, J, _ = robot.fk_with_jacobians(q[None], joints=True, params=False)
        assert J is not None                      # joints=True: the joint Jacobian is made
        T, Jg = T[0], J[0]
        ep = Tdk[:3, 3] - T[:3, 3]
        if task == "position":
            J, e, ff = Jg[:3], ep, vdk[:3]
        elif orientation == "axis_angle":
            J, ff = Jg, vdk
            e = np.concatenate([ep, log_so3(Tdk[:3, :3] @ T[:3, :3].T)])
        else:
            phi = matrix_to_angles(T[:3, :3], orientation)
            phid = matrix_to_angles(Tdk[:3, :3], orientation)
            E, Ed = rate_matrix(phi, orientation), rate_matrix(phid, orientation)
            if abs(np.linalg.det(E)) < 1e-10 or abs(np.linalg.det(Ed)) < 1e-10:
                raise KincalError(f"the {orientation.upper()} angles are singular at t = "
                                  f"{tk:.4g} s; use orientation='axis_angle'")
            J = np.vstack([Jg[:3], np.linalg.solve(E, Jg[3:])])
            e = np.concatenate([ep, _wrap(phid - phi)])
            ff = np.concatenate([vdk[:3], np.linalg.solve(Ed, vdk[3:])])
        Jsharp, lam2 = generalized_inverse(J, method, damping, threshold)
        qd = Jsharp @ (K @ e) if method == "transpose" else Jsharp @ (ff + K @ e)
        return qd, T, e, J, float(lam2)

    q = np.empty((N, n))
    qd = np.empty((N, n))
    pose = np.empty((N, 4, 4))
    err = np.empty((N, m))
    Js = np.empty((N, m, n))
    lam = np.empty(N)
    q[0] = np.asarray(q0, dtype=float)
    if q[0].shape != (n,):
        raise KincalError(f"q0 needs {n} values, got {np.shape(q0)}")
    every = max(N // 100, 1)
    for k in range(N):                         # time stepping (the ODE's iterations)
        qd[k], pose[k], err[k], Js[k], lam[k] = field_at(t[k], q[k], (Td[k], Vd[k]))
        if not np.all(np.isfinite(qd[k])):
            raise KincalError(f"CLIK diverged at t = {t[k]:.4g} s (non-finite joint velocity)")
        if k + 1 < N:
            h = t[k + 1] - t[k]
            if integrator == "euler":
                q[k + 1] = q[k] + h * qd[k]
            else:
                k2 = field_at(t[k] + h / 2, q[k] + h / 2 * qd[k])[0]
                k3 = field_at(t[k] + h / 2, q[k] + h / 2 * k2)[0]
                k4 = field_at(t[k + 1], q[k] + h * k3, (Td[k + 1], Vd[k + 1]))[0]
                q[k + 1] = q[k] + h / 6 * (qd[k] + 2 * k2 + 2 * k3 + k4)
        if progress is not None and (k % every == 0 or k == N - 1):
            progress(k + 1, N)
    w, cond, smin = manipulability(Js)
    return ClikResult(t, q, qd, pose, Td, err, w, cond, smin, lam, method, task,
                      orientation if task == "pose" else "", integrator, float(dt),
                      np.diag(K).copy(), robot.joint_names, tuple(j.unit for j in robot.joints))


# ---------------------------------------------------------------------------
# the spherical-manipulator report's experiment


SQ2 = math.sqrt(2.0)
SPHERICAL_ARM_D2 = 1.0
SPHERICAL_ARM_P_I = np.array([SQ2 / 4, 1.0, SQ2 / 4])
SPHERICAL_ARM_P_F = np.array([-SQ2 / 2, SQ2 / 2, 0.1])
SPHERICAL_ARM_Q0 = np.array([0.0, math.pi / 4, 0.5])
SPHERICAL_ARM_QF = np.array([math.pi / 4, 0.0, 0.1])
SPHERICAL_ARM_TF = 4.0
SPHERICAL_ARM_DT = 0.002


def spherical_arm_robot() -> Robot:
    """The spherical RRP arm of the spherical-manipulator report from its DH table:
    alpha1 = -90, alpha2 = +90 deg, d2 = 1 m, joint 3 prismatic;
    ``p = [c1 s2 d3 - d2 s1, s1 s2 d3 + d2 c1, c2 d3]``."""
    return from_dh([DHLink(alpha=-math.pi / 2, name="theta1"),
                    DHLink(d=SPHERICAL_ARM_D2, alpha=math.pi / 2, name="theta2"),
                    DHLink(joint="prismatic", name="d3")], name="spherical_rrp_example",
                   meta={"source": "the spherical-manipulator report: d2 = 1 m"})


def spherical_arm_motion(timing: str = "quintic",
                         duration: float = SPHERICAL_ARM_TF) -> CartesianMotion:
    """The straight segment p_i -> p_f in ``duration`` with a rest-to-rest timing law.

    Orientation is not part of the task (3-DOF position task); the path's frames
    keep the identity rotation.
    """
    T0, T1 = np.eye(4), np.eye(4)
    T0[:3, 3], T1[:3, 3] = SPHERICAL_ARM_P_I, SPHERICAL_ARM_P_F
    return CartesianMotion(LinePath(T0, T1), TimingLaw.named(timing, duration))


def run_spherical_arm(method: Method = "inverse", gain: float | ArrayLike = 50.0,
                      damping: float = 0.1, threshold: float = 0.1,
                      dt: float = SPHERICAL_ARM_DT, timing: str = "quintic",
                      integrator: Literal["euler", "rk4"] = "euler",
                      duration: float = SPHERICAL_ARM_TF,
                      progress: Callable[[int, int], None] | None = None) -> ClikResult:
    """The spherical-manipulator report's experiment: the arm follows p_i -> p_f from
    q(0) = [0, pi/4, 0.5] by CLIK.

    The position Jacobian has ``|det J| = d3^2 |s2|``: it is singular at theta2 = 0,
    where the tool touches the cylinder ``rho = sqrt(x^2 + y^2) = d2`` around the first
    axis (``rho^2 = d2^2 + (s2 d3)^2 >= d2^2``; inside it is unreachable).  The straight
    line from p_i (rho = 1.06 m) to p_f (rho = d2, theta2 = 0) passes inside that
    cylinder for s in (0.103, 1), down to rho = 0.870 m: ``J^-1`` blows up where the
    line enters it, damped least squares slides along the wall (0.130 m from the line,
    the least possible) and rejoins the line at p_f.  ``meta["events"]`` holds the
    entry time.
    """
    res = clik(spherical_arm_robot(), spherical_arm_motion(timing, duration), SPHERICAL_ARM_Q0,
               dt, gain, method, damping, threshold, task="position", integrator=integrator,
               progress=progress)
    meta = dict(res.meta)
    rho_d = np.hypot(res.position_desired[:, 0], res.position_desired[:, 1])
    inside = np.flatnonzero(rho_d < SPHERICAL_ARM_D2 * (1 - 1e-9))
    events = [(float(res.t[inside[0]]), "line enters rho < d2")] if inside.size else []
    meta.update(segment=(SPHERICAL_ARM_P_I.tolist(), SPHERICAL_ARM_P_F.tolist()), timing=timing,
                damping_k=damping, threshold=threshold, events=events)
    return _with_meta(res, meta)


def _with_meta(res: ClikResult, meta: dict[str, Any]) -> ClikResult:
    from dataclasses import replace

    return replace(res, meta=meta)


# ---------------------------------------------------------------------------
# plots


def plot_clik(results: Sequence[ClikResult], path: str | Path, title: str = "") -> None:
    """Desired vs actual position, joint positions, joint velocities and conditioning.

    One column per run (e.g. J^-1 and DLS side by side), four rows, saved as PNG.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullLocator, SymmetricalLogLocator

    from kincal.motion.trajectory import _save

    cols = len(results)
    fig, axes = plt.subplots(4, cols, figsize=(5.2 * cols, 11), sharex=True, squeeze=False)
    for c, r in enumerate(results):
        ax = axes[:, c]
        for k, name in enumerate("xyz"):
            line, = ax[0].plot(r.t, r.position[:, k], label=f"{name}")
            ax[0].plot(r.t, r.position_desired[:, k], "--", color=line.get_color(),
                       label=f"{name} desired")
        ax[0].set_ylabel("position [m]")
        ax[0].set_title(f"{r.method}" + (f", k = {r.meta.get('damping_k')}"
                                         if r.method in ("dls", "adaptive") else ""))
        for j, n in enumerate(r.joint_names):
            ax[1].plot(r.t, r.q[:, j], label=f"{n} [{r.joint_units[j]}]")
            ax[2].plot(r.t, r.qd[:, j], label=f"{n} [{r.joint_units[j]}/s]")
        ax[1].set_ylabel("joint position")
        ax[2].set_ylabel("joint velocity")
        ax[3].semilogy(r.t, np.maximum(r.position_error, 1e-16), label="|p_d - p| [m]")
        if "segment" in r.meta:
            ax[3].semilogy(r.t, np.maximum(r.path_deviation(), 1e-16),
                           label="distance from the line [m]")
        ax[3].semilogy(r.t, np.maximum(r.manipulability, 1e-16), label="manipulability")
        ax[3].set_xlabel("t [s]")
        for a, data in zip(ax[:3], (r.position, r.q, r.qd), strict=True):
            if np.abs(data).max() > 50:          # a blow-up: keep the small values readable
                a.set_yscale("symlog", linthresh=1.0)
                a.yaxis.set_major_locator(SymmetricalLogLocator(base=10, linthresh=1.0))
                a.yaxis.get_major_locator().set_params(numticks=7)
                a.yaxis.set_minor_locator(NullLocator())
        for t_ev, label in r.meta.get("events", []):
            for a in ax:
                a.axvline(t_ev, color="k", ls=":", lw=0.8)
            ax[0].annotate(label, (t_ev, 0.02), xycoords=("data", "axes fraction"), fontsize=7,
                           rotation=90, ha="right", va="bottom")
        for a in ax:
            a.grid(True, alpha=0.3)
            a.legend(fontsize=7)
    fig.suptitle(title or "CLIK")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
