"""The ``position`` instrument (laser tracker, motion capture, CMM): model, file, simulator.

The model observes K points (markers, reflectors) fixed on the robot's tool from an
instrument whose frame ``T_I = (R_I, t_I)`` is unknown.  ``T_I`` is the pose of the
instrument frame in the robot's world (base) frame, parametrised like the robot's own
base frame: ``{name}.x .y .z .rz .ry .rx`` with ``T_I = Trans(x, y, z) Rz(rz) Ry(ry)
Rx(rx)`` [m, rad] (the 6-DOF variant is :mod:`.pose`).  :class:`PositionMeasurement`:

    y_pred[i, k] = R_I^T (p_e(q_i) + R_e(q_i) m_k - t_I)        [m]
    r = (y_pred - y_obs) / sigma                                  (whitened)

with ``(R_e, p_e)`` the robot's tool frame and ``m_k`` the marker in the tool frame
(``{name}.marker.x .y .z``; with K > 1 markers ``{name}.marker1.x`` ...).

Jacobians are analytic.  The robot part uses the chain's parameter Jacobian
``[dp_e; dphi_e]`` (base frame); a point ``a = R_e m`` on the tool moves by
``dp_e + dphi_e x a``.  Rotating the instrument frame by ``omega`` (``dR_I = [omega]x R_I``)
moves the observation by ``R_I^T ((p - t_I) x omega)``.

Evaluation runs over pieces of about :data:`~kincal.measure.base.CHUNK_ROWS` residual
rows (a thousand or so configurations): the chain's Jacobian of a piece is rotated
into the instrument frame with one (3, 3) x (3, P n) product, the cross products are
written out component by component on (P, n) planes, and nothing of size
(N, K, 3, P) besides the output is formed.  :meth:`evaluate_chunks` hands the pieces
out one at a time, so :meth:`kincal.measure.base.StackedProblem.compressed` never
holds the whole Jacobian.

The closed-form initial guess makes the user's first guess unnecessary: it solves the
linear problem ``A y + t - R_e m = p_e`` for a general matrix ``A``, projects ``A`` onto
SO(3) and alternates Kabsch registration with a linear solve for ``t, m``.

File columns (instrument ``position``): joints, ``x y z`` (one point) or
``x1 y1 z1 ... xK yK zK``, optional per-row ``sigma`` (or ``sigma1 ... sigmaK``)
[length]; without them the tag ``sigma_<unit>=`` or :data:`DEFAULT_SIGMA`.

Simulation: :func:`simulate_positions` measures the configurations you give with a
tracker placed where you say; :func:`simulate_position_experiment` (the plug-in behind
``kincal simulate -i position``) draws the configurations uniformly inside the limits
(shrunk by a margin), places the instrument 1.5-2.5 m from the robot base with a random
heading and the markers within ~0.1 m of the tool origin, then calls it.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError, MeasurementFileError
from kincal.measure.base import (
    CHUNK_ROWS,
    MeasurementModel,
    ParamSpec,
    Provenance,
    Triangle,
    configuration_slices,
    frame_rotation_axes,
    qr_triangle,
)
from kincal.measure.files import (
    Field,
    MeasurementTable,
    read_table,
    tag_quantities,
    tag_quantity,
    write_table,
)
from kincal.measure.instruments.common import (
    check_configurations,
    project_so3,
    rotate_twists,
    sigma_array,
)
from kincal.measure.instruments.csvio import one_block
from kincal.measure.instruments.placement import truth_values
from kincal.measure.registry import Instrument, register
from kincal.measure.simulate import random_configurations
from kincal.robots.chain import Robot
from kincal.robots.workspace import ChainWorkspace
from kincal.spatial import frame_from_matrix, matrix_from_frame

#: Configurations a position block's closed-form start uses at most (evenly spaced).
GUESS_CONFIGURATIONS = 256

Array = NDArray[np.float64]

__all__ = ["PositionMeasurement", "simulate_positions", "simulate_position_experiment",
           "read_position", "write_position"]


# --------------------------------------------------------------------------- helpers


def _marker_order(L: int, K: int) -> NDArray[np.intp]:
    """Natural row (configuration, marker, coordinate) of each row of a piece ordered
    (marker, coordinate, configuration): ``3 K l + 3 k + i`` at position ``(k, i, l)``."""
    return (np.arange(3 * K, dtype=np.intp)[:, None]
            + 3 * K * np.arange(L, dtype=np.intp)[None, :]).reshape(-1)


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
        self.q = check_configurations(q, self.name)
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
        self.sigma = sigma_array(sigma, y3.shape[:2], f"measurements {self.name!r}: sigma")

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
        V, W = rotate_twists(G, Jp, ws)
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


# --------------------------------------------------------------------------- file columns
#: Name of the block of a position / pose file that names no instrument (``name=`` tag or
#: a setup file's ``name:``): its parameters are ``instrument.x`` ... (it may be a laser
#: tracker, a motion-capture system, a CMM: the file does not say).
UNNAMED = "instrument"


#: Default standard deviation when a file has no sigma column [m] / [rad].
DEFAULT_SIGMA = 1e-5


POSITION_FIELDS = (
    Field(r"[xyz]", "length", "x, y, z (one point)"),
    Field(r"[xyz]\d+", "length", "x1, y1, z1, x2, ... (several points)"),
    Field(r"sigma\d*", "length", "sigma or sigma1.. (standard deviation per row)"),
)


#: Simulation options every tracker-like instrument takes.
TRACKER_OPTIONS: dict[str, tuple[object, str]] = {
    "name": ("tracker", "block name (prefix of the instrument's parameters)"),
    "margin": (0.05, "fraction of each joint range kept away from the limits"),
}


def file_units(units: Mapping[str, str] | None) -> tuple[str, str]:
    """The ``(length, angle)`` units asked of a writer (default ``("m", "rad")``)."""
    u = dict(units or {})
    return u.get("length", "m"), u.get("angle", "rad")


def tag_sigma(t: MeasurementTable, key: str) -> float:
    """The file's stated standard deviation for rows without a sigma column: tag
    ``sigma_<unit>`` (``sigma_mm=0.5``; ``sigma_rot_<angle unit>`` for orientations),
    else :data:`DEFAULT_SIGMA`."""
    dim = "angle" if key == "sigma_rot" else "length"
    value = tag_quantity(tag_quantities(t.tags, t.path), key, dim, t.path, DEFAULT_SIGMA)
    if not value > 0:
        raise t.error(f"tag {key}: a standard deviation must be positive", 1)
    return value


def scalar_sigma(s: Array | None, default: float) -> Array | float:
    """A sigma column as one number when every row states the same; ``default`` without."""
    if s is None:
        return default
    return float(s[0]) if np.all(s == s[0]) else s


def check_positive(t: MeasurementTable, base: str) -> None:
    """Raise naming the file line of the first non-positive value of column ``base``."""
    v = t.values.get(base)
    if v is not None and np.any(v <= 0):
        i = int(np.argmax(v <= 0))
        raise t.error(f"column {t.columns[base]}: a standard deviation must be positive",
                      int(t.lines[i]))


def marker_positions(t: MeasurementTable) -> tuple[Array, Array | None]:
    """Positions (N, 3) or (N, K, 3) and sigma (N,) / (N, K) from a position table."""
    numbered = sorted({int(m.group(1)) for b in t.values
                       if (m := re.fullmatch(r"[xyz](\d+)", b))})
    single = any(b in t.values for b in ("x", "y", "z"))
    if single and numbered:
        raise t.error("both x, y, z and numbered marker columns (x1, ...): use one scheme")
    if not single and not numbered:
        raise t.error("no position columns (x, y, z or x1, y1, z1, ...)")
    if single:
        for c in "xyz":
            if c not in t.values:
                raise t.error(f"missing column {c!r} (with its unit, e.g. {c}_mm)")
        y = np.stack([t.values[c] for c in "xyz"], axis=1)
    else:
        if numbered != list(range(1, len(numbered) + 1)):
            raise t.error(f"markers must be numbered 1..K; got {numbered}")
        for k in numbered:
            for c in "xyz":
                if f"{c}{k}" not in t.values:
                    raise t.error(f"marker {k} lacks column {c}{k!s}")
        y = np.stack([np.stack([t.values[f"{c}{k}"] for c in "xyz"], axis=1)
                      for k in numbered], axis=1)
    K = 1 if single else len(numbered)
    sig_cols = sorted(b for b in t.values if re.fullmatch(r"sigma\d+", b))
    for b in sig_cols + ["sigma"]:
        check_positive(t, b)
    if sig_cols:
        want = [f"sigma{k + 1}" for k in range(K)]
        if sig_cols != sorted(want) or "sigma" in t.values:
            raise t.error(f"per-marker sigma columns must be {', '.join(want)} (or one sigma)")
        sigma: Array | None = np.stack([t.values[w] for w in want], axis=1)
    else:
        sigma = t.values.get("sigma")
    return y, sigma


def write_position(blocks: Sequence[Any], path: str | Path,
                   units: Mapping[str, str] | None = None, robot: Any = None) -> None:
    """Write one :class:`PositionMeasurement` as a ``position`` CSV (atomically).

    ``units``: ``{"length": "m"|"mm"|..., "angle": "rad"|"deg"|...}`` (default SI).
    """
    b = one_block(blocks, "position")
    length, angle = file_units(units)
    y = np.asarray(b.positions, dtype=float)
    y3 = y[:, None, :] if y.ndim == 2 else y
    K = y3.shape[1]
    sig = np.asarray(b.sigma, dtype=float).reshape(len(b.q), K)
    obs: list[tuple[str, Array, str]] = []
    for k in range(K):
        tag = "" if K == 1 else str(k + 1)
        obs += [(f"{c}{tag}", y3[:, k, i], "length") for i, c in enumerate("xyz")]
    if K == 1 or np.allclose(sig, sig[:, :1], rtol=1e-12, atol=0):
        obs.append(("sigma", sig[:, 0], "length"))
    else:
        obs += [(f"sigma{k + 1}", sig[:, k], "length") for k in range(K)]
    write_table(path, b.q, obs, robot, {"instrument": "position", "name": b.name},
                angle_unit=angle, length_unit=length,
                comments=[f"{len(b.q)} measurements of {K} point(s); sigma = standard "
                          "deviation of each coordinate"])


def read_position(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
                  ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    """Read a ``position`` CSV into one :class:`PositionMeasurement` (SI units)."""
    t = read_table(path, robot, POSITION_FIELDS, units, ignore)
    y, sigma = marker_positions(t)
    K = 1 if y.ndim == 2 else y.shape[1]
    block = PositionMeasurement(t.q, y, sigma=scalar_sigma(sigma, tag_sigma(t, "sigma")),
                                name=name or t.tags.get("name") or UNNAMED, markers=K)
    block.provenance = Provenance(str(path), t)
    return [block]


# --------------------------------------------------------------------------- simulation
#: Configurations simulated per piece (a performance setting; results do not depend on it).
_PIECE = 1 << 14


def instrument_matrix(instrument: ArrayLike | None) -> Array:
    """``T_I`` (4, 4) of frame values ``(x, y, z, rz, ry, rx)`` [m, rad]; None: identity."""
    if instrument is None:
        return np.eye(4)
    return matrix_from_frame(np.asarray(instrument, dtype=float).reshape(6))


def simulate_positions(true_robot: Robot, q: ArrayLike, rng: np.random.Generator | None,
                       noise_std: float, instrument: ArrayLike | None = None,
                       markers: ArrayLike | None = None, name: str = "tracker",
                       sigma: float | None = None) -> PositionMeasurement:
    """Points on the true robot's tool measured by a virtual tracker.

    ``y = T_I^-1 T(q) m_k + noise``, noise ~ N(0, noise_std^2) per coordinate.

    Args:
        true_robot: the robot that "really" moves.
        q: (N, n) configurations (you give them; the ``position`` plug-in
            :func:`simulate_position_experiment` draws its own).
        rng: draws the noise; None for exact data (then ``noise_std`` must be 0 and no
            random number is drawn).
        noise_std: standard deviation of each coordinate [m] (0 for exact data).
        instrument: tracker pose in the robot's world frame, ``(x, y, z, rz, ry, rx)``
            [m, rad] (:data:`kincal.spatial.FRAME_FIELDS`, the order of the estimated
            ``{name}.*`` block parameters); default identity.
        markers: (3,) or (K, 3) points in the tool frame [m]; default the tool origin.
        name: the block's name.
        sigma: the standard deviation the block states; default ``noise_std`` (or
            1e-5 m when ``noise_std`` is 0).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if rng is None and noise_std != 0:
        raise KincalError("simulate_positions: noise_std > 0 needs a random generator (rng)")
    m = np.zeros((1, 3)) if markers is None else np.asarray(markers, dtype=float)
    single = m.ndim == 1
    m = m.reshape(-1, 3)
    left = np.linalg.inv(instrument_matrix(instrument))
    K = m.shape[0]
    y = np.empty((len(q), K, 3))
    # in pieces of configurations (memory independent of N); the noise is drawn piece
    # by piece along the first axis, the same numbers as one draw of y's shape
    for start in range(0, len(q), _PIECE):
        cs = slice(start, min(len(q), start + _PIECE))
        Y, _, _ = true_robot.point_jacobian(q[cs], m, left, ())
        y[cs] = Y.transpose(2, 0, 1)
        if rng is not None:
            y[cs] += noise_std * rng.standard_normal((cs.stop - cs.start, K, 3))
    s = sigma if sigma is not None else (noise_std if noise_std > 0 else 1e-5)
    if single or m.shape[0] == 1:
        return PositionMeasurement(q, y[:, 0], s, name)
    return PositionMeasurement(q, y, s, name, markers=m.shape[0])


def random_tracker_frame(rng: np.random.Generator) -> Array:
    """A plausible instrument frame ``(x, y, z, rz, ry, rx)``: 1.5-2.5 m away, any heading."""
    az = rng.uniform(-np.pi, np.pi)
    dist = rng.uniform(1.5, 2.5)
    pos = [dist * np.cos(az), dist * np.sin(az), rng.uniform(-0.2, 0.6)]
    ang = [rng.uniform(-np.pi, np.pi), rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)]
    return np.array(pos + ang)


def simulate_position_experiment(true_robot: Robot, rng: np.random.Generator, n_poses: int,
                                 noise: float, markers: int = 1, name: str = "tracker",
                                 margin: float = 0.05, truth: Mapping[str, float] | None = None
                                 ) -> tuple[list[MeasurementModel], dict[str, float]]:
    """The ``position`` plug-in: draw the poses and the set-up, then measure them.

    Draws ``n_poses`` configurations (:func:`random_configurations`), places the
    instrument 1.5-2.5 m from the base with any heading (:func:`random_tracker_frame`) and
    ``markers`` points within ~0.1 m of the tool origin, and measures them with
    :func:`simulate_positions`: ``y_ik = R_I^T (p_e(q_i) + R_e(q_i) m_k - t_I) + noise``,
    ``noise ~ N(0, noise^2)`` per coordinate [m] (none drawn when ``noise`` is 0).
    ``truth`` reuses a previous placement (held-out data).

    Returns ``([PositionMeasurement], {parameter name: true value})``.
    """
    K = int(markers)
    if K < 1:
        raise MeasurementFileError("option markers must be >= 1")
    q = random_configurations(true_robot, n_poses, rng, margin)
    probe = PositionMeasurement(q[:1], np.zeros((1, K, 3)) if K > 1 else np.zeros((1, 3)),
                                name=name, markers=K)
    names = probe.parameters().names
    if truth is not None:
        values = truth_values(truth, names)
    else:
        values = np.concatenate([random_tracker_frame(rng),
                                 rng.uniform(-0.08, 0.08, 3 * K) + np.tile([0, 0, 0.05], K)])
    m = values[6:].reshape(K, 3)
    block = simulate_positions(true_robot, q, rng if noise > 0 else None, noise,
                               instrument=values[:6], markers=m if K > 1 else m[0], name=name)
    return [block], dict(zip(names, values.tolist(), strict=True))


POSITION = register(Instrument(
    name="position",
    description="points on the tool in an instrument frame (laser tracker, motion capture)",
    simulate=simulate_position_experiment, write=write_position, read=read_position,
    options={"markers": (1, "number of points measured on the tool per pose"),
             **TRACKER_OPTIONS},
    noise_unit="m"))
