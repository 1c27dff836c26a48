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

Evaluation runs over pieces of about :data:`~kincal.measure.base.CHUNK_ROWS` residual
rows (a thousand or so configurations): the chain's Jacobian of a piece is rotated
into the instrument frame with one (3, 3) x (3, P n) product, the cross products are
written out component by component on (P, n) planes, and nothing of size
(N, K, 3, P) besides the output is formed.  :meth:`evaluate_chunks` hands the pieces
out one at a time, so :meth:`kincal.measure.base.StackedProblem.compressed` never
holds the whole Jacobian.

Closed-form initial guesses make the user's first guess unnecessary: the position
model solves the linear problem ``A y + t - R_e m = p_e`` for a general matrix ``A``,
projects ``A`` onto SO(3) and alternates Kabsch registration with a linear solve
for ``t, m``; the pose model solves ``R_e R_t = R_I R_obs`` (AX = YB) by the null space
of its Kronecker form, then the translations linearly.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.measure.base import (
    CHUNK_ROWS,
    MeasurementModel,
    ParamSpec,
    Triangle,
    configuration_slices,
    frame_rotation_axes,
    qr_triangle,
)
from kincal.robots.chain import Robot
from kincal.robots.workspace import ChainWorkspace
from kincal.spatial import frame_from_matrix, log_so3, matrix_from_frame, skew

#: Configurations a position block's closed-form start uses at most (evenly spaced).
GUESS_CONFIGURATIONS = 256

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
    value: Array = U @ D @ Vt
    return value


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
    if s.ndim == 0:                         # one value for all: a read-only view, no copy
        if not (np.isfinite(s) and s > 0):
            raise KincalError(f"{what} must be positive and finite")
        return np.broadcast_to(s, shape)
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


def _marker_order(L: int, K: int) -> NDArray[np.intp]:
    """Natural row (configuration, marker, coordinate) of each row of a piece ordered
    (marker, coordinate, configuration): ``3 K l + 3 k + i`` at position ``(k, i, l)``."""
    return (np.arange(3 * K, dtype=np.intp)[:, None]
            + 3 * K * np.arange(L, dtype=np.intp)[None, :]).reshape(-1)


def _rotate_twists(G: Array, Jp: Array, ws: ChainWorkspace) -> tuple[Array, Array]:
    """``G Jv`` and ``G Jw`` (3, P, n) for the chain's parameter Jacobian ``Jp`` (n, 6, P).

    Computed in the chain's storage order (component, parameter, configuration): one
    (3, 3) x (3, P n) product each.
    """
    n, _, P = Jp.shape
    J6 = Jp.transpose(1, 2, 0)                                    # (6, P, n)
    V, W = ws.array("twists.V", (3, P, n)), ws.array("twists.W", (3, P, n))
    np.matmul(G, J6[:3].reshape(3, -1), out=V.reshape(3, -1))
    np.matmul(G, J6[3:].reshape(3, -1), out=W.reshape(3, -1))
    return V, W


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
        return int(self.q.shape[0])

    def marker_prefixes(self) -> list[str]:
        """``[f"{name}.marker"]`` for one marker, else ``[f"{name}.marker1", ...]``."""
        if self.K == 1:
            return [f"{self.name}.marker"]
        return [f"{self.name}.marker{k + 1}" for k in range(self.K)]

    def measurement_sigma(self) -> Array:
        """Stated standard deviation of each marker position [m]: (N, K)."""
        return self.sigma

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
        out = PositionMeasurement(self.q[rows], self._y[rows], self.sigma[rows], self.name,
                                  self.K)
        out.provenance = self.provenance
        return out

    def num_residuals(self) -> int:
        return int(3 * self.K * self.N)

    def predict(self, robot: Robot, extra: ArrayLike, out: Array | None = None, *,
                workspace: ChainWorkspace | None = None) -> Array:
        """Predicted observations ``y_pred`` (N, K, 3) [m] (in pieces of configurations;
        into ``out`` when given; temporaries from the caller's ``workspace`` when given)."""
        extra = np.asarray(extra, dtype=float)
        H, m = self._left(extra), extra[6:].reshape(self.K, 3)
        if out is None:
            out = np.empty((self.N, self.K, 3))
        ws = ChainWorkspace() if workspace is None else workspace
        for cs in configuration_slices(self.N, 3 * self.K, CHUNK_ROWS):
            L = cs.stop - cs.start
            Y, _, _ = robot.point_jacobian(self.q[cs], m, H, (), out=(
                ws.array("predict.Y", (self.K, 3, L)), ws.array("predict.D", (0, self.K, 3, L)),
                None), workspace=ws)
            out[cs] = Y.transpose(2, 0, 1)
        return out

    @staticmethod
    def _left(extra: Array) -> Array:
        """``T_I^-1`` (4, 4): the instrument's view of the robot's world frame."""
        TI = matrix_from_frame(extra[:6])
        H = np.eye(4)
        H[:3, :3] = TI[:3, :3].T
        H[:3, 3] = -TI[:3, :3].T @ TI[:3, 3]
        return H

    def system_pieces(self, robot: Robot, extra: Array, robot_columns: NDArray[np.intp],
                      own_columns: NDArray[np.intp], rows: int = CHUNK_ROWS, *,
                      robot_out: Callable[[int], Array | None] | None = None,
                      workspace: ChainWorkspace | None = None
                      ) -> Iterator[tuple[slice, NDArray[np.intp] | None, Array, Array, Array]]:
        """The selected columns straight from the chain's point Jacobian.

        The chain runs from the instrument's frame (``H = T_I^-1`` in front of it,
        :meth:`~kincal.robots.chain.Robot.point_jacobian`), so the robot columns
        ``dy / dc`` come out in the instrument frame for the marker itself, configurations
        last: a piece's rows are ordered (marker, coordinate, configuration).  Block
        columns as in :meth:`_fill`: ``-R_I^T`` (translation), ``y x E'_c`` (rotation),
        ``R_I^T R_e`` (marker); every row divided by its ``sigma``.  The robot columns
        are computed into ``robot_out``'s array when it gives one; the pieces' working
        arrays come from ``workspace`` (the caller's; default one for this call).
        """
        extra = np.asarray(extra, dtype=float)
        G, _, m, Ep = self._frames(extra)
        H = self._left(extra)
        K, step = self.K, 3 * self.K
        cols = tuple(int(c) for c in robot_columns)
        own = [int(c) for c in own_columns]
        ws = ChainWorkspace() if workspace is None else workspace
        for cs in configuration_slices(self.N, step, rows):
            L = cs.stop - cs.start
            # working arrays (ws): each piece is folded before the next one is made
            into = None if robot_out is None else robot_out(step * L)
            Y, D, Rot = robot.point_jacobian(
                self.q[cs], m, H, cols, rotation=True,
                out=(ws.array("pieces.Y", (K, 3, L)),
                     ws.array("pieces.D", (len(cols), K, 3, L)) if into is None
                     else into.reshape(len(cols), K, 3, L), ws.array("pieces.Rot", (3, 3, L))),
                workspace=ws)
            wT = (1.0 / self.sigma[cs]).T                         # (K, L)
            y = None
            if any(3 <= c < 6 for c in own):                      # predictions
                y = ws.array("pieces.y", (K, 3, L))
                np.copyto(y, Y)
            Y -= self._y[cs].transpose(1, 2, 0)
            Y *= wT[:, None, :]                                   # whitened residuals
            D *= wT[None, :, None, :]
            Je = ws.array("pieces.Je", (len(own), K, 3, L))
            for j, c in enumerate(own):
                if c < 3:                                         # -R_I^T
                    np.multiply(-G[:, c][None, :, None], wT[:, None, :], out=Je[j])
                elif c < 6:                                       # y x E'_c
                    E = Ep[:, c - 3]
                    for i in range(3):
                        a, b = (i + 1) % 3, (i + 2) % 3
                        np.multiply(y[:, a], E[b], out=Je[j, :, i])  # type: ignore[index]
                        Je[j, :, i] -= y[:, b] * E[a]                # type: ignore[index]
                    Je[j] *= wT[:, None, :]
                else:                                             # R_I^T R_e, marker k
                    k, cc = divmod(c - 6, 3)
                    Je[j] = 0.0
                    np.multiply(Rot[cc], wT[k], out=Je[j, k])     # type: ignore[index]
            yield (slice(step * cs.start, step * cs.stop), _marker_order(L, K), Y.reshape(-1),
                   D.reshape(len(cols), step * L), Je.reshape(len(own), step * L))

    def _frames(self, extra: Array) -> tuple[Array, Array, Array, Array]:
        """Constants of one evaluation: ``R_I^T``, ``t_I``, the markers ``m`` (K, 3) and
        the instrument's rotation axes in its own frame ``E' = R_I^T E`` (columns)."""
        TI = matrix_from_frame(extra[:6])
        G = TI[:3, :3].T
        return G, TI[:3, 3], extra[6:].reshape(self.K, 3), G @ frame_rotation_axes(extra[:6])

    @staticmethod
    def _points(T: Array, frames: tuple[Array, Array, Array, Array]) -> tuple[Array, Array]:
        """``a = R_e m_k`` (tool points relative to the flange, base frame) and
        ``y = R_I^T (p_e + a - t_I)`` (predictions), both (n, K, 3), for frames ``T``."""
        G, tI, m, _ = frames
        a = np.matmul(T[:, None, :3, :3], m[None, :, :, None])[..., 0]  # (n, K, 3)
        d = T[:, None, :3, 3] + a - tI
        return a, d @ G.T

    def evaluate(self, robot: Robot, extra: Array, jacobian: bool = True
                 ) -> tuple[Array, Array | None, Array | None]:
        extra = np.asarray(extra, dtype=float)
        if not jacobian:                      # in place: one (N, K, 3) array
            r = np.empty(self.num_residuals())
            self.residuals_into(robot, extra, r)
            return r, None, None
        M, P = self.num_residuals(), robot.num_params
        r, Jr, Je = np.empty(M), np.empty((M, P)), np.empty((M, 6 + 3 * self.K))
        ws, frames = ChainWorkspace(), self._frames(extra)
        for cs in configuration_slices(self.N, 3 * self.K, CHUNK_ROWS):
            rs = slice(3 * self.K * cs.start, 3 * self.K * cs.stop)
            self._fill(robot, frames, cs, r[rs], Jr[rs], Je[rs], ws)
        return r, Jr, Je

    def residuals_into(self, robot: Robot, extra: Array, out: Array, *,
                       workspace: ChainWorkspace | None = None) -> None:
        """The whitened residuals computed in ``out`` (M,) itself."""
        y = out.reshape(self.N, self.K, 3)
        self.predict(robot, np.asarray(extra, dtype=float), y, workspace=workspace)
        y -= self._y
        y /= self.sigma[:, :, None]

    def evaluate_chunks(self, robot: Robot, extra: Array, rows: int = CHUNK_ROWS
                        ) -> Iterator[tuple[slice, Array, Array, Array]]:
        extra = np.asarray(extra, dtype=float)
        step, P, E = 3 * self.K, robot.num_params, 6 + 3 * self.K
        ws, frames = ChainWorkspace(), self._frames(extra)
        for cs in configuration_slices(self.N, step, rows):
            n = (cs.stop - cs.start) * step
            r, Jr, Je = np.empty(n), np.empty((n, P)), np.empty((n, E))
            self._fill(robot, frames, cs, r, Jr, Je, ws)
            yield slice(step * cs.start, step * cs.stop), r, Jr, Je

    def _fill(self, robot: Robot, frames: tuple[Array, Array, Array, Array], cs: slice,
              r: Array, Jr: Array, Je: Array, ws: ChainWorkspace) -> None:
        """Residuals and Jacobians of configurations ``cs`` into ``r`` (3nK,), ``Jr``
        (3nK, P), ``Je`` (3nK, 6 + 3K) (rows ordered configuration, marker, coordinate).

        With ``a = R_e m_k``, ``y = R_I^T (p_e + a - t_I)`` and the chain's twist columns
        ``[Jv; Jw]``, rotated into the instrument frame (``Jv' = R_I^T Jv``,
        ``Jw' = R_I^T Jw``, ``a' = R_I^T a``):

        * robot: ``dy = Jv' + Jw' x a'``, component-wise
          ``dy_i = Jv'_i + Jw'_j a'_k - Jw'_k a'_j`` for ``(i, j, k)`` cyclic;
        * instrument translation: ``dy/dt_I = -R_I^T``;
        * instrument rotation about axis ``E_c`` (:func:`frame_rotation_axes`):
          ``dy/dw_c = R_I^T ((p - t_I) x E_c) = y x E'_c``, ``E'_c = R_I^T E_c``;
        * marker ``k``: ``dy/dm_k = R_I^T R_e``;

        every row divided by its ``sigma``.
        """
        K = self.K
        T, _, Jp = robot.fk_with_jacobians(self.q[cs], joints=False, params=True, workspace=ws)
        n, P = T.shape[0], robot.num_params
        G, Ep = frames[0], frames[3]                              # R_I^T, R_I^T E
        a, y = self._points(T, frames)
        w = 1.0 / self.sigma[cs]                                  # (n, K)
        np.multiply(y - self._y[cs], w[:, :, None], out=r.reshape(n, K, 3))
        # robot columns: computed as (P, n) planes, written transposed into the rows
        assert Jp is not None                                     # params=True
        V, W = _rotate_twists(G, Jp, ws)
        ar = np.ascontiguousarray((a @ G.T).transpose(1, 2, 0))  # a' (K, 3, n)
        out = Jr.reshape(n, K, 3, P)
        buf, tmp = ws.array("fill.buf", (P, n)), ws.array("fill.tmp", (P, n))
        for k in range(K):
            for i in range(3):
                j, l = (i + 1) % 3, (i + 2) % 3
                np.multiply(W[j], ar[k, l], out=buf)
                np.multiply(W[l], ar[k, j], out=tmp)
                buf -= tmp
                buf += V[i]
                buf *= w[:, k]
                out[:, k, i, :] = buf.T
        # block columns
        ex = Je.reshape(n, K, 3, 6 + 3 * K)
        if K > 1:
            ex[..., 6:] = 0.0
        ex[..., 0:3] = -G
        for i in range(3):
            j, l = (i + 1) % 3, (i + 2) % 3
            ex[..., i, 3:6] = y[..., j, None] * Ep[l] - y[..., l, None] * Ep[j]
        RiRe = G @ T[:, :3, :3]                                   # (n, 3, 3)
        for k in range(K):
            ex[:, k, :, 6 + 3 * k: 9 + 3 * k] = RiRe
        ex *= w[:, :, None, None]

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

        It is a start, so it uses at most :data:`GUESS_CONFIGURATIONS` configurations,
        evenly spaced through the block: the start's error is then the nominal
        model's (millimetres), not the noise's, and the solver refines it on all of
        them.  One pass over those, in pieces, gathers everything (memory independent
        of N): the QR triangle of step 1's system, which also gives that of
        step 2's matrix ``[I, -R_e]`` with its right-hand sides ``p_e`` and ``y_b e_a``
        (the same columns in another order), since ``p_e - R y = p_e - sum_ab R_ab y_b
        e_a`` is linear in ``R``; and the weighted
        moments the Kabsch cross-covariance needs (``sum w y``, ``sum w p_e``,
        ``sum w R_e``, ``sum w y p_e^T``, ``sum w y_a R_e``), since the registered
        points ``p_e + R_e m`` are linear in ``m``.  The iterations then cost nothing.
        """
        N, K = self.N, self.K
        p1, p2 = 12 + 3 * K, 3 + 3 * K
        first = Triangle(p1 + 1)
        rows = (slice(None) if N <= GUESS_CONFIGURATIONS
                else np.arange(GUESS_CONFIGURATIONS) * (N - 1) // (GUESS_CONFIGURATIONS - 1))
        q_all, y_all = self.q[rows], self._y[rows]
        w_all = 1.0 / self.sigma[rows] ** 2                        # (n, K)
        y0, pe0 = self._y[0, 0].copy(), None
        S_w = np.zeros(K)
        S_y, S_pe = np.zeros((K, 3)), np.zeros((K, 3))
        S_R = np.zeros((K, 3, 3))
        S_ype, S_yR = np.zeros((K, 3, 3)), np.zeros((K, 3, 3, 3))
        ws = ChainWorkspace()
        for cs in configuration_slices(len(q_all), 3 * K, CHUNK_ROWS):
            T = robot.fk(q_all[cs])
            Re, pe = T[:, :3, :3], T[:, :3, 3]
            y = y_all[cs]
            n = len(pe)
            ReT = Re.transpose(2, 0, 1)                            # ReT[c, :, a] = Re[:, a, c]
            # the systems' columns as rows (n, K, 3) of B (no transposed copy to fold):
            # step 1: [vec_col(A); t; m_1 .. m_K | p_e]
            B = ws.array("initial_guess.B", (p1 + 1, n, K, 3))
            B[...] = 0.0
            for a in range(3):
                for b in range(3):
                    B[3 * b + a, :, :, a] = y[:, :, b]
                B[9 + a, :, :, a] = 1.0
                B[p1, :, :, a] = pe[:, a, None]
            for k in range(K):
                np.negative(ReT, out=B[12 + 3 * k: 15 + 3 * k, :, k, :])
            first.add_transposed(B.reshape(p1 + 1, -1))
            # Kabsch moments (shifted by one point for accuracy), as matrix products
            if pe0 is None:
                pe0 = pe[0].copy()
            w = w_all[cs]                                          # (n, K)
            ys, ps = y - y0, pe - pe0
            wy = (w[:, :, None] * ys).reshape(n, 3 * K)            # w_ik (y_ik - y_0)
            S_w += w.sum(0)
            S_y += wy.sum(0).reshape(K, 3)
            S_pe += w.T @ ps
            S_R += (w.T @ Re.reshape(n, 9)).reshape(K, 3, 3)
            S_ype += (wy.T @ ps).reshape(K, 3, 3)
            S_yR += (wy.T @ Re.reshape(n, 9)).reshape(K, 3, 3, 3)
        # step 2's matrix [I, -R_e | p_e, y_b e_a] has step 1's columns (t, m, p_e and,
        # as y_b e_a, column 3 b + a of vec_col(A)): its triangle is that of step 1's
        # triangle with the columns in that order (A P = Q (R P))
        order = [*range(9, p1 + 1), *(3 * b + a for a in range(3) for b in range(3))]
        second = Triangle(p2 + 10)
        second.R = qr_triangle(first.R[:, order])
        sol = first.solve(p1)[:, 0]
        R = project_so3(sol[:9].reshape(3, 3, order="F"))
        m = sol[12:].reshape(K, 3)
        t = sol[9:12]
        # z-vectors of step 2's right-hand sides: p_e and y_b e_a
        X = second.solve(p2)                                       # (p2, 10)
        X_pe, X_y = X[:, 0], X[:, 1:].reshape(p2, 3, 3)            # X_y[:, a, b]
        W = S_w.sum()
        assert pe0 is not None
        # the moments as matrices acting on the stacked markers m (3K): the loop is then
        # a few matrix-vector products and one 3x3 SVD per iteration
        X_y2 = X_y.reshape(p2, 9)                                  # acts on R[a, b]
        cs_y = S_y.sum(0) / W
        S_pe1, S_ype1 = S_pe.sum(0) / W, S_ype.sum(0).reshape(9) / W
        S_R2 = S_R.transpose(1, 0, 2).reshape(3, 3 * K) / W         # [b, (k, c)]
        S_yR2 = S_yR.transpose(1, 2, 0, 3).reshape(9, 3 * K) / W    # [(a, b), (k, c)]
        for _ in range(iterations):
            sol = X_pe - X_y2 @ R.reshape(9)
            m = sol[3:].reshape(K, 3)
            # weighted cross-covariance of y and p_e + R_e m_k (normalised weights)
            cs_w = S_pe1 + S_R2 @ sol[3:]
            Hc = (S_ype1 + S_yR2 @ sol[3:]).reshape(3, 3) - np.outer(cs_y, cs_w)
            R_new = project_so3(Hc.T)                              # Kabsch: V D U^T
            t = (cs_w + pe0) - R_new @ (cs_y + y0)
            change = np.linalg.norm(R_new - R)
            R = R_new
            if change < 1e-13:
                break
        TI = np.eye(4)
        TI[:3, :3], TI[:3, 3] = R, t
        return np.concatenate([frame_from_matrix(TI), m.reshape(-1)])


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
        return int(self.q.shape[0])

    def measurement_sigma(self) -> Array:
        """Stated standard deviation of each position [m]: (N,) (orientations:
        ``sigma_orientation`` [rad])."""
        return self.sigma_position

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
        TI = matrix_from_frame(extra[:6])
        Tt = matrix_from_frame(extra[6:12])
        return np.linalg.inv(TI) @ robot.fk(self.q) @ Tt

    def num_residuals(self) -> int:
        return 6 * self.N

    @staticmethod
    def _frames(extra: Array) -> tuple[Array, Array, Array, Array]:
        """Constants of one evaluation: ``T_I``, ``T_t`` and their rotation axes ``E_I``,
        ``E_t`` (:func:`frame_rotation_axes`)."""
        return (matrix_from_frame(extra[:6]), matrix_from_frame(extra[6:12]),
                frame_rotation_axes(extra[:6]), frame_rotation_axes(extra[6:12]))

    def _raw(self, T: Array, frames: tuple[Array, Array, Array, Array], cs: slice
             ) -> tuple[Array, Array, Array, Array]:
        """For frames ``T`` of configurations ``cs``: position errors ``y - p_obs``
        (n, 3) [m], rotation errors ``e = log(R_pred R_obs^T)`` (n, 3) [rad], the target
        offset ``a = R_e t_t`` and the prediction ``y = R_I^T (p_e + a - t_I)`` (n, 3)."""
        TI, Tt = frames[0], frames[1]
        RI, tI = TI[:3, :3], TI[:3, 3]
        Re = T[:, :3, :3]
        a = Re @ Tt[:3, 3]                                         # target origin offset
        y = (T[:, :3, 3] + a - tI) @ RI                            # R_I^T d
        Rp = RI.T @ Re @ Tt[:3, :3]                                # R_pred (n, 3, 3)
        e = log_so3(Rp @ np.swapaxes(self.poses[cs, :3, :3], 1, 2))
        return y - self.poses[cs, :3, 3], e, a, y

    def evaluate(self, robot: Robot, extra: Array, jacobian: bool = True
                 ) -> tuple[Array, Array | None, Array | None]:
        extra = np.asarray(extra, dtype=float)
        if not jacobian:
            dy, e, _, _ = self._raw(robot.fk(self.q), self._frames(extra), slice(None))
            wp, wo = 1.0 / self.sigma_position, 1.0 / self.sigma_orientation
            return np.concatenate([dy * wp[:, None], e * wo[:, None]], 1).reshape(-1), None, None
        M, P = self.num_residuals(), robot.num_params
        r, Jr, Je = np.empty(M), np.empty((M, P)), np.empty((M, 12))
        ws, frames = ChainWorkspace(), self._frames(extra)
        for cs in configuration_slices(self.N, 6, CHUNK_ROWS):
            rs = slice(6 * cs.start, 6 * cs.stop)
            self._fill(robot, frames, cs, r[rs], Jr[rs], Je[rs], ws)
        return r, Jr, Je

    def evaluate_chunks(self, robot: Robot, extra: Array, rows: int = CHUNK_ROWS
                        ) -> Iterator[tuple[slice, Array, Array, Array]]:
        extra = np.asarray(extra, dtype=float)
        P = robot.num_params
        ws, frames = ChainWorkspace(), self._frames(extra)
        for cs in configuration_slices(self.N, 6, rows):
            n = 6 * (cs.stop - cs.start)
            r, Jr, Je = np.empty(n), np.empty((n, P)), np.empty((n, 12))
            self._fill(robot, frames, cs, r, Jr, Je, ws)
            yield slice(6 * cs.start, 6 * cs.stop), r, Jr, Je

    def _fill(self, robot: Robot, frames: tuple[Array, Array, Array, Array], cs: slice,
              r: Array, Jr: Array, Je: Array, ws: ChainWorkspace) -> None:
        """Residuals and Jacobians of configurations ``cs`` into ``r`` (6n,), ``Jr``
        (6n, P), ``Je`` (6n, 12) (rows: position x y z, then rotation, per pose).

        With ``Jv' = R_I^T Jv``, ``Jw' = R_I^T Jw``, ``a' = R_I^T R_e t_t``,
        ``y = R_I^T (p_e + a - t_I)``, ``L = J_l^-1(e)`` (:func:`inverse_left_jacobian_so3`),
        ``E'_c = R_I^T E_c`` (instrument rotation axes) and ``F_c`` the target's:

        * robot: position ``Jv'_i + Jw'_j a'_k - Jw'_k a'_j`` ((i, j, k) cyclic),
          rotation ``L Jw'`` (``R_pred`` turns by ``R_I^T dphi_e``);
        * instrument: position ``[-R_I^T, y x E'_c]``, rotation ``[0, -L E'_c]``;
        * target: position ``[R_I^T R_e, 0]``, rotation ``[0, L R_I^T R_e F_c]``;

        position rows divided by ``sigma_position``, rotation rows by ``sigma_orientation``.
        """
        T, _, Jp = robot.fk_with_jacobians(self.q[cs], joints=False, params=True, workspace=ws)
        n, P = T.shape[0], robot.num_params
        G = frames[0][:3, :3].T                                   # R_I^T
        dy, e, a, y = self._raw(T, frames, cs)
        wp, wo = 1.0 / self.sigma_position[cs], 1.0 / self.sigma_orientation[cs]
        rr = r.reshape(n, 6)
        np.multiply(dy, wp[:, None], out=rr[:, :3])
        np.multiply(e, wo[:, None], out=rr[:, 3:])
        L = inverse_left_jacobian_so3(e)                           # (n, 3, 3)
        assert Jp is not None                                      # params=True
        V, W = _rotate_twists(G, Jp, ws)                           # R_I^T Jv, R_I^T Jw
        ar = np.ascontiguousarray((a @ G.T).T)                    # a' (3, n)
        Lc = np.ascontiguousarray(L.transpose(1, 2, 0))           # (3, 3, n)
        out = Jr.reshape(n, 6, P)
        buf, tmp = ws.array("fill.buf", (P, n)), ws.array("fill.tmp", (P, n))
        for i in range(3):
            j, l = (i + 1) % 3, (i + 2) % 3
            np.multiply(W[j], ar[l], out=buf)
            np.multiply(W[l], ar[j], out=tmp)
            buf -= tmp
            buf += V[i]
            buf *= wp
            out[:, i, :] = buf.T
            np.multiply(W[0], Lc[i, 0], out=buf)
            for c in (1, 2):
                np.multiply(W[c], Lc[i, c], out=tmp)
                buf += tmp
            buf *= wo
            out[:, 3 + i, :] = buf.T
        ex = Je.reshape(n, 6, 12)
        ex[...] = 0.0
        ex[:, :3, 0:3] = -G
        Ep = G @ frames[2]                                        # E'_c as columns
        for i in range(3):
            j, l = (i + 1) % 3, (i + 2) % 3
            ex[:, i, 3:6] = y[:, j, None] * Ep[l] - y[:, l, None] * Ep[j]
        ex[:, 3:, 3:6] = L @ -Ep
        RiRe = G @ T[:, :3, :3]
        ex[:, :3, 6:9] = RiRe
        ex[:, 3:, 9:12] = L @ (RiRe @ frames[3])
        ex[:, :3] *= wp[:, None, None]
        ex[:, 3:] *= wo[:, None, None]

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        frames = self._frames(np.asarray(extra, dtype=float))
        dy, e, _, _ = self._raw(robot.fk(self.q), frames, slice(None))
        return {"position_m": np.linalg.norm(dy, axis=1),
                "orientation_rad": np.linalg.norm(e, axis=1)}

    def initial_guess(self, robot: Robot) -> Array:
        """Instrument and target frames in closed form (AX = YB).

        Rotations: ``R_e,i R_t - R_I R_obs,i = 0`` is linear in ``(vec R_t, vec R_I)``:
        ``[(I kron R_e,i), -(R_obs,i^T kron I)] [vec R_t; vec R_I] = 0``; the right
        singular vector of the smallest singular value, scaled to ``det R_t = 1`` and
        projected onto SO(3).  Translations: ``R_e,i t_t - t_I = R_I p_obs,i - p_e,i``
        by linear least squares.  Both systems are reduced to their QR triangles in one
        pass over the configurations, in pieces (the translations' right-hand side is
        linear in ``R_I``: its ten columns ``-p_e``, ``p_obs,b e_a`` are carried along).
        """
        eye = np.eye(3)
        rot, tra = Triangle(18), Triangle(6 + 10)
        for cs in configuration_slices(self.N, 6, CHUNK_ROWS):
            T = robot.fk(self.q[cs])
            Re, pe = T[:, :3, :3], T[:, :3, 3]
            Ro, po = self.poses[cs, :3, :3], self.poses[cs, :3, 3]
            rot.add(np.concatenate([np.kron(eye[None], Re),
                                    -np.kron(np.swapaxes(Ro, 1, 2), eye[None])],
                                   axis=2).reshape(-1, 18))
            # R_e t_t - t_I = R_I p_obs - p_e: right-hand sides -p_e and p_obs,b e_a
            B = np.zeros((len(Re), 3, 16))
            B[:, :, :3] = Re
            B[:, :, 3:6] = -eye
            B[:, :, 6] = -pe
            for a in range(3):
                B[:, a, 7 + 3 * a: 10 + 3 * a] = po
            tra.add(B.reshape(-1, 16))
        _, _, Vt = np.linalg.svd(rot.R)
        v = Vt[-1]
        X = v[:9].reshape(3, 3, order="F")
        Y = v[9:].reshape(3, 3, order="F")
        det = np.linalg.det(X)
        c = np.sign(det) * abs(det) ** (-1.0 / 3.0) if abs(det) > 1e-300 else 1.0
        Rt, RI = project_so3(c * X), project_so3(c * Y)
        Z = tra.solve(6)                                            # (6, 10)
        sol = Z[:, 0] + Z[:, 1:] @ RI.reshape(9)
        TI, Tt = np.eye(4), np.eye(4)
        TI[:3, :3], TI[:3, 3] = RI, sol[3:]
        Tt[:3, :3], Tt[:3, 3] = Rt, sol[:3]
        return np.concatenate([frame_from_matrix(TI), frame_from_matrix(Tt)])
