"""Position and pose measurement models (laser tracker, motion capture, CMM).

Both models observe a frame or point fixed on the robot's tool from an instrument
whose frame ``T_I = (R_I, t_I)`` is unknown.  ``T_I`` is the pose of the instrument
frame in the robot's world (base) frame, parametrised like the robot's own base
frame: ``{name}.x .y .z .rz .ry .rx`` with ``T_I = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)``
[m, rad].

:class:`PositionMeasurement` - K points (markers, reflectors) on the tool:

    y_pred[i, k] = R_I^T (p_e(q_i) + R_e(q_i) m_k - t_I)        [m]
    r = (y_pred - y_obs) / sigma                                  (whitened)

with ``(R_e, p_e)`` the robot's tool frame and ``m_k`` the marker in the tool frame
(``{name}.marker.x .y .z``; with K > 1 markers ``{name}.marker1.x`` ...).

:class:`PoseMeasurement` - a target frame ``T_t`` on the tool (``{name}.target.x ...
.rx``), measured as ``T_obs = T_I^-1 T_e(q) T_t``; residual per pose

    r = [(p_pred - p_obs) / sigma_p ; log(R_pred R_obs^T) / sigma_o]

(position [m] then rotation vector [rad], both in the instrument frame).

Jacobians are analytic.  The robot part uses the chain's parameter Jacobian
``[dp_e; dphi_e]`` (base frame); a point ``a = R_e m`` on the tool moves by
``dp_e + dphi_e x a``.  Rotating the instrument frame by ``omega`` (``dR_I = [omega]x R_I``)
moves the observation by ``R_I^T ((p - t_I) x omega)``.  For the orientation residual
``e = log(R_pred R_obs^T)``, a left perturbation ``R_pred -> exp(delta) R_pred`` changes
``e`` by ``J_l^-1(e) delta`` (the inverse left Jacobian of SO(3)).

Closed-form initial guesses make the user's first guess unnecessary: the position
model solves the linear problem ``A y + t - R_e m = p_e`` for a general matrix ``A``,
projects ``A`` onto SO(3) and alternates Kabsch registration with a linear solve
for ``t, m``; the pose model solves ``R_e R_t = R_I R_obs`` (AX = YB) by the null space
of its Kronecker form, then the translations linearly.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.measure.base import (
    MeasurementModel,
    ParamSpec,
    frame_matrix,
    frame_rotation_axes,
    frame_values,
    lstsq,
)
from kincal.robots.chain import Robot
from kincal.spatial import log_so3, skew

Array = NDArray[np.float64]

__all__ = ["PositionMeasurement", "PoseMeasurement", "kabsch", "inverse_left_jacobian_so3"]


# --------------------------------------------------------------------------- helpers
def kabsch(source: Array, target: Array, weights: Array | None = None) -> tuple[Array, Array]:
    """Rigid registration: ``R, t`` minimising ``sum w ||R source + t - target||^2``.

    ``source``, ``target``: (M, 3) points [m].  SVD of the weighted cross-covariance,
    with the sign of the last singular vector fixed so that ``det R = +1``.
    """
    w = np.ones(len(source)) if weights is None else np.asarray(weights, dtype=float)
    w = w / w.sum()
    cs, ct = w @ source, w @ target
    H = ((source - cs) * w[:, None]).T @ (target - ct)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    return R, ct - R @ cs


def project_so3(A: Array) -> Array:
    """The rotation nearest to the 3x3 matrix ``A`` (Frobenius norm), ``det = +1``."""
    U, _, Vt = np.linalg.svd(A)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt


def inverse_left_jacobian_so3(phi: Array) -> Array:
    """``J_l^-1(phi) = I - [phi]x / 2 + (1/t^2 - (1 + cos t) / (2 t sin t)) [phi]x^2``.

    ``log(exp(delta) exp(phi)) = phi + J_l^-1(phi) delta + O(delta^2)``; (..., 3) ->
    (..., 3, 3), with the series ``1/12 + t^2/720`` for small ``t = |phi|``.
    """
    phi = np.asarray(phi, dtype=float)
    t = np.linalg.norm(phi, axis=-1)
    K = skew(phi)
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    with np.errstate(invalid="ignore", divide="ignore"):
        big = 1.0 / ts**2 - (1.0 + np.cos(ts)) / (2.0 * ts * np.sin(ts))
    c = np.where(small, 1.0 / 12.0 + t**2 / 720.0, big)
    return np.eye(3) - 0.5 * K + c[..., None, None] * (K @ K)


def _sigma(sigma: ArrayLike, shape: tuple[int, ...], what: str) -> Array:
    s = np.asarray(sigma, dtype=float)
    try:
        s = np.broadcast_to(s.reshape(s.shape + (1,) * (len(shape) - s.ndim)), shape).copy()
    except ValueError:
        raise KincalError(f"{what}: shape {np.shape(sigma)} does not fit the measurements "
                          f"{shape}") from None
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise KincalError(f"{what} must be positive and finite")
    return s


def _check_q(q: ArrayLike, name: str) -> Array:
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if q.ndim != 2:
        raise KincalError(f"measurements {name!r}: joint readings must be (N, n)")
    if not np.all(np.isfinite(q)):
        row = int(np.argwhere(~np.isfinite(q))[0, 0])
        raise KincalError(f"measurements {name!r}: joint reading in row {row} is not finite")
    return q


# --------------------------------------------------------------------------- position
class PositionMeasurement(MeasurementModel):
    """Positions of K points on the tool measured in an instrument frame.

    Args:
        q: (N, n) joint readings [rad / m].
        positions: (N, 3), or (N, K, 3) for K markers per pose: observed points in
            the instrument frame [m].
        sigma: standard deviation of each coordinate [m]: scalar, (N,) or (N, K).
        name: the block's name, prefix of its parameters.
        markers: number of markers K when ``positions`` is (N, 3) (must be 1).

    Parameters (in this order): ``{name}.x .y .z .rz .ry .rx`` (instrument frame in
    the robot base frame, role ``instrument``) and ``{name}.marker.x .y .z`` (or
    ``marker1`` ... ``markerK``; the points in the tool frame, role ``tool_point``).
    """

    def __init__(self, q: ArrayLike, positions: ArrayLike, sigma: ArrayLike = 1e-5,
                 name: str = "tracker", markers: int = 1) -> None:
        self.name = str(name)
        self.q = _check_q(q, self.name)
        y = np.asarray(positions, dtype=float)
        if y.ndim == 2:
            if markers != 1:
                raise KincalError(f"measurements {self.name!r}: {markers} markers need "
                                  "positions of shape (N, K, 3)")
            y3 = y[:, None, :]
        elif y.ndim == 3:
            y3 = y
            if markers not in (1, y.shape[1]):
                raise KincalError(f"measurements {self.name!r}: positions have {y.shape[1]} "
                                  f"markers, markers={markers}")
        else:
            raise KincalError(f"measurements {self.name!r}: positions must be (N, 3) or "
                              f"(N, K, 3), got {y.shape}")
        if y3.shape[0] != self.q.shape[0] or y3.shape[2] != 3:
            raise KincalError(f"measurements {self.name!r}: {self.q.shape[0]} joint rows but "
                              f"positions of shape {y.shape}")
        if not np.all(np.isfinite(y3)):
            row = int(np.argwhere(~np.isfinite(y3))[0, 0])
            raise KincalError(f"measurements {self.name!r}: position in row {row} is not finite")
        self.positions = y
        self._y = y3
        self.K = y3.shape[1]
        self.sigma = _sigma(sigma, y3.shape[:2], f"measurements {self.name!r}: sigma")

    # ------------------------------------------------------------------ contract
    @property
    def N(self) -> int:
        return self.q.shape[0]

    def marker_prefixes(self) -> list[str]:
        """``[f"{name}.marker"]`` for one marker, else ``[f"{name}.marker1", ...]``."""
        if self.K == 1:
            return [f"{self.name}.marker"]
        return [f"{self.name}.marker{k + 1}" for k in range(self.K)]

    def parameters(self) -> ParamSpec:
        spec = ParamSpec.frame(self.name)
        for p in self.marker_prefixes():
            spec = spec + ParamSpec.point(p)
        return spec

    def residual_owner(self) -> NDArray[np.intp]:
        return np.repeat(np.arange(self.N, dtype=np.intp), 3 * self.K)

    def subset(self, rows: ArrayLike) -> PositionMeasurement:
        """A block with the same name holding only ``rows`` (for cross-validation)."""
        rows = np.asarray(rows)
        return PositionMeasurement(self.q[rows], self._y[rows], self.sigma[rows], self.name,
                                   self.K)

    def predict(self, robot: Robot, extra: ArrayLike) -> Array:
        """Predicted observations ``y_pred`` (N, K, 3) [m]."""
        return self._predict(robot, np.asarray(extra, dtype=float), False)[0]

    def _predict(self, robot: Robot, extra: Array, jac: bool
                 ) -> tuple[Array, Array, Array, Array | None]:
        T, _, Jp = robot.fk_with_jacobians(self.q, joints=False, params=jac)
        TI = frame_matrix(extra[:6])
        m = extra[6:].reshape(self.K, 3)
        a = np.einsum("nij,kj->nki", T[:, :3, :3], m)            # R_e m_k   (N, K, 3)
        d = T[:, None, :3, 3] + a - TI[:3, 3]                     # p - t_I   (N, K, 3)
        y = d @ TI[:3, :3]                                        # R_I^T d
        return y, d, a, (T, Jp) if jac else None  # type: ignore[return-value]

    def evaluate(self, robot: Robot, extra: Array, jacobian: bool = True
                 ) -> tuple[Array, Array | None, Array | None]:
        extra = np.asarray(extra, dtype=float)
        y, d, a, aux = self._predict(robot, extra, jacobian)
        w = 1.0 / self.sigma[:, :, None]                          # (N, K, 1)
        r = ((y - self._y) * w).reshape(-1)
        if not jacobian:
            return r, None, None
        T, Jp = aux  # type: ignore[misc]
        N, K, P = self.N, self.K, robot.num_params
        RI = frame_matrix(extra[:6])[:3, :3]
        # robot: dp = Jv + Jw x a, dy = R_I^T dp
        Jv, Jw = Jp[:, :3, :], Jp[:, 3:, :]
        dp = Jv[:, None] + np.cross(Jw[:, None], a[:, :, :, None], axis=2)  # (N, K, 3, P)
        Jr = np.einsum("ji,nkjp->nkip", RI, dp) * w[..., None]
        Je = np.zeros((N, K, 3, 6 + 3 * K))
        Je[:, :, :, 0:3] = -RI.T
        E = frame_rotation_axes(extra[:6])                        # (3, 3) axes rz, ry, rx
        Je[:, :, :, 3:6] = np.einsum("ji,nkjc->nkic", RI, np.cross(d[..., None], E[None, None],
                                                                     axis=2))
        RiRe = np.einsum("ji,njl->nil", RI, T[:, :3, :3])         # R_I^T R_e  (N, 3, 3)
        for k in range(K):
            Je[:, k, :, 6 + 3 * k: 9 + 3 * k] = RiRe
        Je *= w[..., None]
        return r, Jr.reshape(N * K * 3, P), Je.reshape(N * K * 3, 6 + 3 * K)

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        y = self.predict(robot, extra)
        e = np.linalg.norm(y - self._y, axis=-1)
        return {"position_m": e[:, 0] if self.K == 1 else e}

    # ------------------------------------------------------------------ initial guess
    def initial_guess(self, robot: Robot, iterations: int = 20) -> Array:
        """Instrument frame and markers in closed form (no user guess needed).

        1. Linear least squares for a general matrix ``A``, ``t`` and the markers
           ``m_k`` in ``A y_ik + t - R_e(q_i) m_k = p_e(q_i)`` (3 equations per point,
           ``12 + 3K`` unknowns); ``A`` projected onto SO(3).
        2. Alternate a linear solve for ``t, m`` (``R`` fixed) with a Kabsch
           registration of the predicted points ``p_e + R_e m_k`` onto ``y``.

        If the tool orientations do not vary enough to separate ``m`` from ``t``
        the minimum-norm solution is taken (markers near the tool origin).
        """
        T = robot.fk(self.q)
        Re, pe = T[:, :3, :3], T[:, :3, 3]
        N, K = self.N, self.K
        y = self._y
        # (N, K, 3, 12 + 3K) system in [vec_col(A); t; m_1 .. m_K]
        Mx = np.zeros((N, K, 3, 12 + 3 * K))
        eye = np.eye(3)
        for j in range(3):
            Mx[:, :, :, 3 * j: 3 * j + 3] = y[:, :, j, None, None] * eye
        Mx[:, :, :, 9:12] = eye
        for k in range(K):
            Mx[:, k, :, 12 + 3 * k: 15 + 3 * k] = -Re
        rhs = np.broadcast_to(pe[:, None, :], (N, K, 3))
        sol = lstsq(Mx.reshape(-1, 12 + 3 * K), rhs.reshape(-1))
        R = project_so3(sol[:9].reshape(3, 3, order="F"))
        m = sol[12:].reshape(K, 3)
        t = sol[9:12]
        for _ in range(iterations):
            # linear solve for t, m with R fixed: t - R_e m_k = p_e - R y
            A = np.zeros((N, K, 3, 3 + 3 * K))
            A[:, :, :, :3] = eye
            for k in range(K):
                A[:, k, :, 3 + 3 * k: 6 + 3 * k] = -Re
            b = pe[:, None, :] - y @ R.T
            sol = lstsq(A.reshape(-1, 3 + 3 * K), b.reshape(-1))
            m = sol[3:].reshape(K, 3)
            world = pe[:, None, :] + np.einsum("nij,kj->nki", Re, m)
            R_new, t = kabsch(y.reshape(-1, 3), world.reshape(-1, 3),
                              1.0 / self.sigma.reshape(-1) ** 2)
            change = np.linalg.norm(R_new - R)
            R = R_new
            if change < 1e-13:
                break
        TI = np.eye(4)
        TI[:3, :3], TI[:3, 3] = R, t
        return np.concatenate([frame_values(TI), m.reshape(-1)])


# --------------------------------------------------------------------------- pose
class PoseMeasurement(MeasurementModel):
    """Full poses of a target frame on the tool measured in an instrument frame.

    Args:
        q: (N, n) joint readings [rad / m].
        poses: (N, 4, 4) measured target frames in the instrument frame [m].
        sigma_position: standard deviation of each position coordinate [m], scalar or (N,).
        sigma_orientation: standard deviation of each rotation-vector component [rad].
        name: the block's name, prefix of its parameters.

    Parameters: ``{name}.x .y .z .rz .ry .rx`` (instrument frame, role ``instrument``)
    and ``{name}.target.x .y .z .rz .ry .rx`` (target frame in the tool frame, role
    ``target``).  Residuals per pose: ``[dp / sigma_p; log(R_pred R_obs^T) / sigma_o]``.
    """

    def __init__(self, q: ArrayLike, poses: ArrayLike, sigma_position: ArrayLike = 1e-5,
                 sigma_orientation: ArrayLike = 1e-5, name: str = "tracker") -> None:
        self.name = str(name)
        self.q = _check_q(q, self.name)
        P = np.asarray(poses, dtype=float)
        if P.ndim != 3 or P.shape[1:] != (4, 4) or P.shape[0] != self.q.shape[0]:
            raise KincalError(f"measurements {self.name!r}: poses must be (N, 4, 4) with "
                              f"N = {self.q.shape[0]}, got {P.shape}")
        if not np.all(np.isfinite(P)):
            row = int(np.argwhere(~np.isfinite(P))[0, 0])
            raise KincalError(f"measurements {self.name!r}: pose in row {row} is not finite")
        self.poses = P
        N = self.q.shape[0]
        self.sigma_position = _sigma(sigma_position, (N,), f"{self.name}: sigma_position")
        self.sigma_orientation = _sigma(sigma_orientation, (N,),
                                        f"{self.name}: sigma_orientation")

    @property
    def N(self) -> int:
        return self.q.shape[0]

    def parameters(self) -> ParamSpec:
        return ParamSpec.frame(self.name) + ParamSpec.frame(f"{self.name}.target", role="target")

    def residual_owner(self) -> NDArray[np.intp]:
        return np.repeat(np.arange(self.N, dtype=np.intp), 6)

    def subset(self, rows: ArrayLike) -> PoseMeasurement:
        """A block with the same name holding only ``rows``."""
        rows = np.asarray(rows)
        return PoseMeasurement(self.q[rows], self.poses[rows], self.sigma_position[rows],
                               self.sigma_orientation[rows], self.name)

    def predict(self, robot: Robot, extra: ArrayLike) -> Array:
        """Predicted target poses in the instrument frame (N, 4, 4)."""
        extra = np.asarray(extra, dtype=float)
        TI = frame_matrix(extra[:6])
        Tt = frame_matrix(extra[6:12])
        return np.linalg.inv(TI) @ robot.fk(self.q) @ Tt

    def _raw(self, robot: Robot, extra: Array, jac: bool) -> tuple[Array, Array, tuple]:
        T, _, Jp = robot.fk_with_jacobians(self.q, joints=False, params=jac)
        TI, Tt = frame_matrix(extra[:6]), frame_matrix(extra[6:12])
        RI, tI = TI[:3, :3], TI[:3, 3]
        Re = T[:, :3, :3]
        a = Re @ Tt[:3, 3]                                         # target origin offset
        d = T[:, :3, 3] + a - tI
        y = d @ RI                                                 # R_I^T d
        Rp = RI.T @ Re @ Tt[:3, :3]                                # R_pred (N, 3, 3)
        e = log_so3(Rp @ np.swapaxes(self.poses[:, :3, :3], 1, 2))
        return y - self.poses[:, :3, 3], e, (T, Jp, RI, Re, a, d)

    def evaluate(self, robot: Robot, extra: Array, jacobian: bool = True
                 ) -> tuple[Array, Array | None, Array | None]:
        extra = np.asarray(extra, dtype=float)
        dy, e, (T, Jp, RI, Re, a, d) = self._raw(robot, extra, jacobian)
        wp, wo = 1.0 / self.sigma_position, 1.0 / self.sigma_orientation
        r = np.concatenate([dy * wp[:, None], e * wo[:, None]], 1).reshape(-1)
        if not jacobian:
            return r, None, None
        N, P = self.N, robot.num_params
        L = inverse_left_jacobian_so3(e)                           # (N, 3, 3)
        Jv, Jw = Jp[:, :3, :], Jp[:, 3:, :]
        Jr = np.empty((N, 6, P))
        Jr[:, :3] = np.einsum("ji,njp->nip", RI, Jv + np.cross(Jw, a[:, :, None], axis=1))
        Jr[:, 3:] = L @ np.einsum("ji,njp->nip", RI, Jw)
        Je = np.zeros((N, 6, 12))
        Je[:, :3, 0:3] = -RI.T
        EI = frame_rotation_axes(extra[:6])
        Je[:, :3, 3:6] = np.einsum("ji,njc->nic", RI, np.cross(d[:, :, None], EI[None], axis=1))
        Je[:, 3:, 3:6] = L @ (-RI.T @ EI)
        RiRe = np.einsum("ji,njl->nil", RI, Re)
        Je[:, :3, 6:9] = RiRe
        Je[:, 3:, 9:12] = L @ (RiRe @ frame_rotation_axes(extra[6:12]))
        wv = np.concatenate([np.repeat(wp[:, None], 3, 1), np.repeat(wo[:, None], 3, 1)], 1)
        Jr *= wv[:, :, None]
        Je *= wv[:, :, None]
        return r, Jr.reshape(6 * N, P), Je.reshape(6 * N, 12)

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        dy, e, _ = self._raw(robot, np.asarray(extra, dtype=float), False)
        return {"position_m": np.linalg.norm(dy, axis=1),
                "orientation_rad": np.linalg.norm(e, axis=1)}

    def initial_guess(self, robot: Robot) -> Array:
        """Instrument and target frames in closed form (AX = YB).

        Rotations: ``R_e,i R_t - R_I R_obs,i = 0`` is linear in ``(vec R_t, vec R_I)``:
        ``[(I kron R_e,i), -(R_obs,i^T kron I)] [vec R_t; vec R_I] = 0``; the right
        singular vector of the smallest singular value, scaled to ``det R_t = 1`` and
        projected onto SO(3).  Translations: ``R_e,i t_t - t_I = R_I p_obs,i - p_e,i``
        by linear least squares.
        """
        T = robot.fk(self.q)
        Re, pe = T[:, :3, :3], T[:, :3, 3]
        Ro, po = self.poses[:, :3, :3], self.poses[:, :3, 3]
        eye = np.eye(3)
        M = np.concatenate([np.kron(eye[None], Re),
                            -np.kron(np.swapaxes(Ro, 1, 2), eye[None])], axis=2).reshape(-1, 18)
        _, _, Vt = np.linalg.svd(np.linalg.qr(M, mode="r"))
        v = Vt[-1]
        X = v[:9].reshape(3, 3, order="F")
        Y = v[9:].reshape(3, 3, order="F")
        det = np.linalg.det(X)
        c = np.sign(det) * abs(det) ** (-1.0 / 3.0) if abs(det) > 1e-300 else 1.0
        Rt, RI = project_so3(c * X), project_so3(c * Y)
        B = np.zeros((len(Re), 3, 6))
        B[:, :, :3] = Re
        B[:, :, 3:] = -eye
        rhs = po @ RI.T - pe
        sol = lstsq(B.reshape(-1, 6), rhs.reshape(-1))
        TI, Tt = np.eye(4), np.eye(4)
        TI[:3, :3], TI[:3, 3] = RI, sol[3:]
        Tt[:3, :3], Tt[:3, 3] = Rt, sol[:3]
        return np.concatenate([frame_values(TI), frame_values(Tt)])
