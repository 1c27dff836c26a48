"""Shared pieces of the instrument models: the tool point, instrument frames, labels.

Conventions used by every instrument of :mod:`kincal.measure.instruments`:

* **World frame** = the frame the robot's ``base.*`` parameters are expressed in.
* **Tool point** ``p(q) = p_e(q) + R_e(q) m``: a marker (retro-reflector, probe tip,
  target) fixed on the tool, ``T_e = (R_e, p_e)`` the robot's end frame *including* its
  ``tool.*`` frame.  ``m`` is either the block's own parameters ``{name}.marker.x/y/z``
  (``marker="own"``, the default, like ``PositionMeasurement``) or zero
  (``marker="tool"``: the measured point *is* the robot's tool origin, so the robot's
  ``tool.x/y/z`` act as the marker).  Use ``marker="tool"`` on every block that sees the
  same physical marker to fuse instruments on one point.
* **Instrument frame** ``T_s = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)`` (world <- instrument),
  six parameters ``{name}.{station}.x, y, z, rz, ry, rx`` [m, rad], the order of the
  robot's base/tool frames.  A world point ``p`` seen from it is ``R_s^T (p - t_s)``.

Derivatives (all analytic):

* ``dp/d(robot) = v + w x (R_e m)`` from the parameter twists ``[v; w]`` of
  :meth:`Robot.fk_with_jacobians`; ``dp/dm = R_e``.
* For a rotation angle ``k`` of the instrument frame, ``dR_s = [a_k]x R_s d(angle)`` with
  the world axes ``a_rz = e_z``, ``a_ry = Rz e_y``, ``a_rx = Rz Ry e_x``; hence
  ``d(R_s^T (p - t))/d(angle_k) = R_s^T ((p - t) x a_k)`` and ``d/dt = -R_s^T``.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.measure.base import ParamSpec, Triangle, configuration_slices
from kincal.robots.chain import Robot
from kincal.robots.workspace import ChainWorkspace
from kincal.spatial import FRAME_FIELDS, frame_from_matrix, homogeneous, rotx, roty, rotz, skew

Array = NDArray[np.float64]


FRAME_UNITS = ("m", "m", "m", "rad", "rad", "rad")
MARKER_MODES = ("own", "tool")


# ---------------------------------------------------------------------------- specs
def concat_specs(specs: Sequence[ParamSpec]) -> ParamSpec:
    """Concatenate parameter specs in order."""
    specs = [s for s in specs if len(s)]
    if not specs:
        return ParamSpec.empty()
    return ParamSpec(tuple(n for s in specs for n in s.names),
                     np.concatenate([s.values for s in specs]),
                     tuple(u for s in specs for u in s.units),
                     tuple(r for s in specs for r in s.roles))


def frame_spec(prefix: str, values: ArrayLike | None = None, role: str = "instrument"
               ) -> ParamSpec:
    """Six parameters ``{prefix}.x, y, z, rz, ry, rx`` [m, rad] of a frame."""
    v = np.zeros(6) if values is None else np.asarray(values, dtype=float)
    return ParamSpec(tuple(f"{prefix}.{f}" for f in FRAME_FIELDS), v, FRAME_UNITS, (role,) * 6)


def marker_spec(block: str, values: ArrayLike | None = None) -> ParamSpec:
    """The marker point ``{block}.marker.x, y, z`` [m] in the tool frame."""
    v = np.zeros(3) if values is None else np.asarray(values, dtype=float)
    return ParamSpec(tuple(f"{block}.marker.{f}" for f in "xyz"), v, ("m",) * 3,
                     ("tool_point",) * 3)


def check_marker_mode(marker: str) -> str:
    if marker not in MARKER_MODES:
        raise KincalError(f"unknown marker mode {marker!r}; use 'own' (the block's "
                          "{name}.marker.x/y/z) or 'tool' (the robot's tool origin)")
    return marker


# ---------------------------------------------------------------------------- labels
def label_index(labels: Sequence[str], what: str, block: str, rows: int | None = None
                ) -> tuple[tuple[str, ...], NDArray[np.intp]]:
    """Distinct labels in order of first appearance, and each row's index into them.

    ``rows``: when given, exactly one label per row is required.
    """
    if rows is not None and len(labels) != rows:
        raise KincalError(f"block {block!r}: one {what} label per row needed "
                          f"({len(labels)} labels for {rows} rows)")
    if len(labels) == 0:
        return (), np.zeros(0, dtype=np.intp)
    distinct, idx = label_index_raw([str(s).strip() for s in labels])
    names = tuple(distinct)
    for s in names:
        if not s or any(c in s for c in " ,;#\"'") or s == "marker":
            raise KincalError(f"block {block!r}: {what} label {s!r} must be a non-empty word "
                              "(letters, digits, _ - .) other than 'marker'")
    return names, idx


def label_index_raw(keys: Sequence[str]) -> tuple[list[str], NDArray[np.intp]]:
    """Distinct keys in order of first appearance and each key's index (no validation)."""
    arr = np.array(list(keys), dtype=str)
    uniq, first, inv = np.unique(arr, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return [str(u) for u in uniq[order]], rank[inv.reshape(-1)].astype(np.intp)


def as_sigma(sigma: ArrayLike, n: int, block: str) -> Array:
    """Per-row standard deviations (N,), positive and finite."""
    s = np.broadcast_to(np.asarray(sigma, dtype=float), (n,)).copy()
    if not np.all(np.isfinite(s) & (s > 0)):
        raise KincalError(f"block {block!r}: every standard deviation must be positive")
    return s


def as_q(q: ArrayLike) -> Array:
    q = np.asarray(q, dtype=float)
    if q.ndim != 2:
        raise KincalError(f"joint readings must be (N, n); got shape {q.shape}")
    return q


# ---------------------------------------------------------------------------- tool point
def tool_point(robot: Robot, q: Array, m: Array | None, jacobian: bool
               ) -> tuple[Array, Array, Array | None, Array | None]:
    """World position of the marker ``p = p_e + R_e m`` and its Jacobians.

    Args:
        m: marker in the tool frame (3,) [m], or None for the tool origin.

    Returns:
        ``(p (N, 3), R_e (N, 3, 3), dp/d(robot) (N, 3, P), dp/dm = R_e (N, 3, 3))``;
        the Jacobians are None when ``jacobian`` is False.
    """
    T, _, Jp = robot.fk_with_jacobians(q, joints=False, params=jacobian)
    R = T[:, :3, :3]
    p = T[:, :3, 3]
    if m is None:
        return p, R, (Jp[:, :3] if Jp is not None else None), None
    Rm = R @ m
    p = p + Rm
    if Jp is None:                 # jacobian False
        return p, R, None, None
    dp = Jp[:, :3] + np.cross(Jp[:, 3:], Rm[:, :, None], axis=1)
    return p, R, dp, R


# ---------------------------------------------------------------------------- frames
def frame_rotation(rz: ArrayLike, ry: ArrayLike, rx: ArrayLike) -> Array:
    """``R = Rz(rz) Ry(ry) Rx(rx)``."""
    return rotz(rz) @ roty(ry) @ rotx(rx)


def frame_axes(rz: ArrayLike, ry: ArrayLike) -> Array:
    """World axes ``[a_rz, a_ry, a_rx]`` (..., 3, 3) (columns) of the frame's three angles."""
    Rz = rotz(rz)
    Rzy = Rz @ roty(ry)
    return np.stack([np.broadcast_to([0.0, 0.0, 1.0], Rz.shape[:-1]), Rz[..., :, 1],
                     Rzy[..., :, 0]], -1)


def to_local(frames: Array, which: NDArray[np.intp], p: Array, jacobian: bool
             ) -> tuple[Array, Array | None, Array | None]:
    """Express world points in instrument frames: ``x = R_s^T (p - t_s)``.

    Args:
        frames: (K, 6) frame parameters ``x y z rz ry rx`` [m, rad].
        which: (N,) index of the frame of each point.
        p: (N, 3) world points [m].

    Returns:
        ``x`` (N, 3), ``dx/dp = R_s^T`` (N, 3, 3), ``dx/d(frame params)`` (N, 3, 6).
    """
    frames = np.asarray(frames, dtype=float).reshape(-1, 6)
    R = frame_rotation(frames[:, 3], frames[:, 4], frames[:, 5])       # (K, 3, 3)
    Rt = np.swapaxes(R, 1, 2)[which]                                    # (N, 3, 3)
    d = p - frames[which, :3]
    x = np.einsum("nij,nj->ni", Rt, d)
    if not jacobian:
        return x, None, None
    axes = frame_axes(frames[:, 3], frames[:, 4])[which]                # (N, 3, 3)
    dframe = np.empty((p.shape[0], 3, 6))
    dframe[:, :, :3] = -Rt
    dframe[:, :, 3:] = Rt @ np.cross(d[:, :, None], axes, axis=1)
    return x, Rt, dframe


def to_world(frame: Array, s: Array, jacobian: bool) -> tuple[Array, Array | None]:
    """Points ``w = R s + t`` of a frame (6,) given in that frame (N, 3); dw/d(frame) (N, 3, 6)."""
    R = frame_rotation(frame[3], frame[4], frame[5])
    Rs = s @ R.T
    w = Rs + frame[:3]
    if not jacobian:
        return w, None
    axes = frame_axes(frame[3], frame[4])                               # (3, 3)
    dw = np.empty((s.shape[0], 3, 6))
    dw[:, :, :3] = np.eye(3)
    dw[:, :, 3:] = np.cross(axes.T[None, :, :], Rs[:, None, :], axis=2).transpose(0, 2, 1)
    return w, dw






# ---------------------------------------------------------------------------- closed forms




def direction_pose(directions: Array, points: Array) -> Array:
    """Instrument frame from directions seen in it to known world points (linear DLT).

    Solves ``u_i x (R^T p_i - R^T t) = 0`` for the 3x4 matrix ``[R^T | -R^T t]`` up to
    scale (homogeneous least squares), fixes the scale and sign so that the points lie in
    front (``u_i . x_i > 0``) and projects onto a rotation.  Needs >= 6 points not on one
    plane.  Returns frame parameters ``x y z rz ry rx``.

    The system's rows are folded into their QR triangle in pieces (its right singular
    vectors are the system's): memory independent of the number of points.
    """
    def pieces() -> Iterator[tuple[Array, Array]]:
        for cs in configuration_slices(points.shape[0], 3):
            u = directions[cs] / np.linalg.norm(directions[cs], axis=1, keepdims=True)
            yield u, np.hstack([points[cs], np.ones((cs.stop - cs.start, 1))])  # (n, 4)

    tri = Triangle(12)
    for u, ph in pieces():
        # rows of u x (P ph): for components (a, b) -> u_a (P ph)_b - u_b (P ph)_a
        rows = []
        for a, b in ((1, 2), (2, 0), (0, 1)):
            row = np.zeros((ph.shape[0], 3, 4))
            row[:, b] = u[:, a, None] * ph
            row[:, a] = -u[:, b, None] * ph
            rows.append(row.reshape(ph.shape[0], 12))
        tri.add(np.vstack(rows))
    P = np.linalg.svd(tri.R)[2][-1].reshape(3, 4)
    if sum(float(np.sum((ph @ P.T) * u)) for u, ph in pieces()) < 0:
        P = -P
    scale = np.cbrt(np.linalg.det(P[:, :3]))
    if not np.isfinite(scale) or abs(scale) < 1e-300:
        raise KincalError("cannot place the instrument: the points are degenerate")
    Rt = project_so3(P[:, :3] / scale)
    R = Rt.T
    t = -R @ (P[:, 3] / scale)
    return rotation_to_rpy_frame(R, t)


def check_shapes(what: str, block: str, n: int, **arrays: Array) -> None:
    """Every array must have ``n`` rows."""
    for key, a in arrays.items():
        if a.shape[0] != n:
            raise KincalError(f"block {block!r}: {what}: {key} has {a.shape[0]} rows, "
                              f"the joint readings have {n}")


def chain_rows(dobs_dp: Array, dp: Array, sigma: Array) -> Array:
    """``(d obs/d p) (d p/d theta) / sigma`` flattened to (N k, P)."""
    J = np.einsum("nkj,njp->nkp", dobs_dp, dp) / sigma[:, None, None]
    value: Array = J.reshape(-1, J.shape[2])
    return value


def station_columns(station_index: NDArray[np.intp], local: Array, size: int) -> Array:
    """Scatter per-station derivatives into the block's parameter columns.

    ``local`` (N, k, 6) holds d obs / d(station pose) of each row's own station; station
    ``s`` owns columns ``6 s .. 6 s + 5``.  Returns d obs / d(own params), (N, k, size).
    """
    out = np.zeros((local.shape[0], local.shape[1], size))
    cols = 6 * station_index[:, None] + np.arange(6)
    for c in range(local.shape[1]):
        np.put_along_axis(out[:, c], cols, local[:, c], axis=1)
    return out


def station_poses_from_directions(stations: Sequence[str], station_index: NDArray[np.intp],
                                  directions: Array, p: Array, what: str, block: str) -> Array:
    """Each station's pose (x y z rz ry rx) from unit viewing directions to known points.

    Uses :func:`direction_pose` per station on its rows; a station needs 6 readings.
    """
    out = []
    for k, name in enumerate(stations):
        rows = station_index == k
        if np.count_nonzero(rows) < 6:
            raise KincalError(f"block {block!r}: {what} {name!r} has fewer than 6 readings; "
                              "cannot place it")
        out.append(direction_pose(directions[rows], p[rows]))
    return np.concatenate(out)


def rotation_to_rpy_frame(R: Array, t: Array) -> Array:
    """Frame parameters ``x y z rz ry rx`` of ``(R, t)``
    (:func:`~kincal.spatial.frame_from_matrix`)."""
    return frame_from_matrix(homogeneous(R, t))


# ------------------------------------------------------------ rotations, shared checks
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


def sigma_array(sigma: ArrayLike, shape: tuple[int, ...], what: str) -> Array:
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


def check_configurations(q: ArrayLike, name: str) -> Array:
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if q.ndim != 2:
        raise KincalError(f"measurements {name!r}: joint readings must be (N, n)")
    if not np.all(np.isfinite(q)):
        row = int(np.argwhere(~np.isfinite(q))[0, 0])
        raise KincalError(f"measurements {name!r}: joint reading in row {row} is not finite")
    return q


def rotate_twists(G: Array, Jp: Array, ws: ChainWorkspace) -> tuple[Array, Array]:
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
