"""The artifact measurement block: a probe seated in the sockets of a rigid artifact.

Data: joint readings ``q_i`` (N, n), each with the label of the artifact *placement*
and of the *socket* the probe tip was seated in.  The tip of row ``i`` is
``P_i = p_e(q_i) + R_e(q_i) t`` (:mod:`.probe`).  Rows of the same placement and
socket form a *site* with one point ``X_k`` (:mod:`.coincidence`): the mean of its
rows (``sockets="eliminate"``, the default) or block parameters
``{name}.{placement}.{socket}.x .y .z`` (``sockets="parameters"``).

Residuals, whitened by their standard deviations and stacked in this order:

1. coincidence (sites with several rows; 3 per row, or per Helmert contrast ``h``),
   expressed in the site's *socket frame* ``R_k``:
   ``R_k^T (P_i - X_k)`` or ``R_k^T h_j``                                       [m]
2. distances (:mod:`.distance`), one per placement and known distance:
   ``|X_b - X_a| - L``                                                         [m]
3. perpendicularity (:mod:`.perpendicularity`), one per placement and pair:
   ``cos angle(X_c - X_a, X_d - X_b)``                                   [1 ~ rad]

Socket frames.  A seated ball has no orientation, and the cost is unchanged when the
tips of one socket turn about their mean (``|R h| = |h|``); yet the Gauss-Newton
matrix ``J^T J`` sees such a turn through the residual vectors themselves (the
column of a turn ``w`` is ``w x h``, zero only for perfect data).  Without a remedy
every parameter that just turns all tips about a point (the robot's base angles, the
first joint's origin angles) would look identifiable from coincidence data, with a
meaningless estimate.  So every site seated more than once has a frame orientation
``{name}.{placement}.{socket}.rz .ry .rx`` (``R = Rz Ry Rx``, role ``artifact``,
initial 0) in which its residual vectors are expressed: it changes nothing in the cost,
and the identifiability analysis finds those parameters *dependent on the socket
frames*, by name.  Derivative: ``d(R^T h) = R^T dh + R^T (h x a_c) d(angle_c)`` with the
rotation axes ``a_c`` of :func:`rotation_axes_rzyx`.

Noise model (fixed once, at construction).  Each seated tip has the covariance
``C_i = point_std^2 I + joint_std^2 J_q,i J_q,i^T`` [m^2]: the seating repeatability
plus the encoder noise propagated through the tip's joint Jacobian ``J_q`` (evaluated
with ``robot``, normally the nominal model; without a robot only ``point_std``
counts).  A site point has ``C_X = sum C_i / n^2`` (eliminated) or 0 (parameters).
Coincidence residuals use ``sigma_i^2 = trace(C_i) / 3``; a distance
``sigma^2 = std_L^2 + u^T (C_Xa + C_Xb) u``; a right angle
``sigma^2 = std_angle^2 + sum g^T C_X g`` (``g`` the cosine's gradients).  A
constraint with zero variance (an exact artifact between socket parameters) gets the
standard deviation ``1e-3`` times the smallest point standard deviation (divided by
the artifact length for an angle): a nearly hard constraint.  Correlations between the
distance and angle residuals of one placement are neglected (first order they are
zero for isotropic tips: the angle sees the motions across the arms, the distance
along them).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.measure.artifacts.coincidence import (
    Contrasts,
    Sites,
    check_mode,
    site_means,
)
from kincal.measure.artifacts.distance import distance_residuals, distance_variance
from kincal.measure.artifacts.geometry import ArtifactGeometry
from kincal.measure.artifacts.perpendicularity import (
    angle_deviation,
    perpendicularity_residuals,
    perpendicularity_variance,
)
from kincal.measure.artifacts.probe import Probe
from kincal.measure.base import MeasurementModel, ParamSpec, configuration_slices
from kincal.robots.chain import Robot
from kincal.spatial import rotx, roty, rotz

Array = NDArray[np.float64]
IntArray = NDArray[np.intp]

#: Weight of an exact constraint relative to the smallest point standard deviation.
EXACT_FRACTION = 1e-3


def rotation_rzyx(angles: Array) -> Array:
    """``R = Rz(rz) Ry(ry) Rx(rx)`` for angles (G, 3) ordered ``rz, ry, rx``: (G, 3, 3)."""
    return rotz(angles[:, 0]) @ roty(angles[:, 1]) @ rotx(angles[:, 2])


def rotation_axes_rzyx(angles: Array) -> Array:
    """Axes (G, 3, 3) (columns ``a_rz, a_ry, a_rx``) with ``dR = [a_c]x R d(angle_c)``.

    ``a_rz = e_z``, ``a_ry = Rz(rz) e_y``, ``a_rx = Rz(rz) Ry(ry) e_x``.
    """
    cz, sz = np.cos(angles[:, 0]), np.sin(angles[:, 0])
    cy, sy = np.cos(angles[:, 1]), np.sin(angles[:, 1])
    zero, one = np.zeros_like(cz), np.ones_like(cz)
    return np.stack([np.stack([zero, zero, one], 1), np.stack([-sz, cz, zero], 1),
                     np.stack([cz * cy, sz * cy, -sy], 1)], axis=2)


@dataclass(frozen=True)
class ConstraintValues:
    """A constraint evaluated for every placement (for reports and the bar-length figures).

    Attributes:
        placement: (K,) placement label of each value.
        label: (K,) constraint label (``AC``, ``BD``, ``AC.BD``).
        value: (K,) distance [m] or deviation from a right angle [rad].
        target: (K,) the known length [m] (0 for angles).
    """

    placement: tuple[str, ...]
    label: tuple[str, ...]
    value: Array
    target: Array

    @property
    def error(self) -> Array:
        """``value - target`` (K,) [m or rad]."""
        return self.value - self.target


class ArtifactMeasurement(MeasurementModel):
    """A probe seated in the sockets of a rigid artifact (cross-bar, ball-bar, two sockets).

    Args:
        q: (N, n) joint readings [rad / m].
        placement: (N,) placement label of each row (any strings / numbers).
        socket: (N,) socket label of each row (one of ``geometry.sockets``).
        geometry: the artifact (:class:`~.geometry.ArtifactGeometry`).
        probe: the tip (:class:`~.probe.Probe`); default the robot's tool origin.
        sockets: ``"eliminate"`` (socket points are the means of their rows) or
            ``"parameters"`` (socket points are block parameters).
        name: block name, prefix of its parameters.
        joint_std: encoder noise, standard deviation per joint [rad / m].
        point_std: seating repeatability of the tip, per coordinate [m].
        robot: the model through which ``joint_std`` is propagated (normally the
            nominal robot); also gives the directions of the distance / angle
            variances.  Optional when ``joint_std == 0``.

    Parameters (in order): the probe's (``{name}.probe.l`` or ``.x .y .z``, when
    estimated; role ``tool_point``); with ``sockets="parameters"`` the site points
    ``{name}.{placement}.{socket}.x .y .z`` [m]; the socket frames
    ``{name}.{placement}.{socket}.rz .ry .rx`` [rad] of sites seated more than once
    (role ``artifact``).
    """

    def __init__(self, q: ArrayLike, placement: Sequence[object], socket: Sequence[object],
                 geometry: ArtifactGeometry, probe: Probe | None = None,
                 sockets: str = "eliminate", name: str = "artifact", joint_std: float = 0.0,
                 point_std: float = 1e-5, robot: Robot | None = None) -> None:
        self.name = str(name)
        if not self.name or any(c in self.name for c in " ,;#"):
            raise KincalError(f"artifact block name {self.name!r} must be a word")
        q = np.asarray(q, dtype=float)
        if q.ndim != 2 or not np.all(np.isfinite(q)):
            raise KincalError(f"block {self.name!r}: joint readings must be a finite (N, n) "
                              f"array, got shape {q.shape}")
        self.q = q
        self.placement_labels = tuple(str(p) for p in placement)
        self.socket_labels = tuple(str(s) for s in socket)
        if not (len(self.placement_labels) == len(self.socket_labels) == len(q)):
            raise KincalError(f"block {self.name!r}: {len(q)} joint rows but "
                              f"{len(self.placement_labels)} placement and "
                              f"{len(self.socket_labels)} socket labels")
        known = set(geometry.sockets)
        for i, s in enumerate(self.socket_labels):
            if s not in known:
                raise KincalError(f"block {self.name!r}: row {i + 1} names socket {s!r}; the "
                                  f"{geometry.kind} has sockets {', '.join(geometry.sockets)}")
        self.geometry = geometry
        self.probe = probe if probe is not None else Probe.tool()
        self.sockets = check_mode(sockets)
        self.joint_std = float(joint_std)
        self.point_std = float(point_std)
        if not (self.joint_std >= 0 and self.point_std >= 0):
            raise KincalError(f"block {self.name!r}: joint_std and point_std must be >= 0")
        if self.joint_std > 0 and robot is None:
            raise KincalError(f"block {self.name!r}: propagating joint_std needs the robot "
                              "model (robot=...)")
        self.noise_robot = robot
        self.sites = Sites.from_labels(self.placement_labels, self.socket_labels)
        self.contrasts = Contrasts.build(self.sites)
        self._build_constraints()
        self._build_sigmas()

    # ------------------------------------------------------------------ structure
    def _build_constraints(self) -> None:
        sites, g = self.sites, self.geometry
        lookup = {(p, s): k for k, (p, s) in enumerate(zip(sites.placement, sites.socket,
                                                             strict=True))}
        dist, dl, ds, dlab, dpl = [], [], [], [], []
        perp, ps, plab, ppl = [], [], [], []
        for ip, p in enumerate(sites.placements):
            for d in g.distances:
                ka, kb = lookup.get((p, d.a), -1), lookup.get((p, d.b), -1)
                if ka >= 0 and kb >= 0:
                    dist.append((ka, kb))
                    dl.append(d.length)
                    ds.append(d.std)
                    dlab.append(d.label)
                    dpl.append(ip)
            for c in g.perpendiculars:
                ks = [lookup.get((p, s), -1) for s in (c.a, c.c, c.b, c.d)]
                if min(ks) >= 0:
                    perp.append(ks)
                    ps.append(c.std)
                    plab.append(c.label)
                    ppl.append(ip)
        self._dist = np.array(dist, dtype=np.intp).reshape(-1, 2)
        self._dist_L = np.array(dl, dtype=float)
        self._dist_std = np.array(ds, dtype=float)
        self._dist_label = tuple(dlab)
        self._dist_place = np.array(dpl, dtype=np.intp)
        self._perp = np.array(perp, dtype=np.intp).reshape(-1, 4)
        self._perp_std = np.array(ps, dtype=float)
        self._perp_label = tuple(plab)
        self._perp_place = np.array(ppl, dtype=np.intp)
        pidx = {p: i for i, p in enumerate(sites.placements)}
        row_place = np.array([pidx[p] for p in self.placement_labels], dtype=np.intp)
        first = np.full(len(sites.placements), -1, dtype=np.intp)
        first[row_place[::-1]] = np.arange(len(row_place))[::-1]
        self._row_place = row_place
        self._place_first_row = first

    @property
    def N(self) -> int:
        return int(self.q.shape[0])

    @property
    def placements(self) -> tuple[str, ...]:
        """Distinct placement labels in order of first appearance."""
        return self.sites.placements

    @property
    def num_coincidence(self) -> int:
        """Number of coincidence residual vectors (3 components each)."""
        if self.sockets == "parameters":
            return self.N
        return self.contrasts.size

    # ------------------------------------------------------------------ noise model
    def _row_covariance(self) -> Array:
        N = self.N
        C = np.broadcast_to(self.point_std**2 * np.eye(3), (N, 3, 3)).copy()
        if self.joint_std > 0 and self.noise_robot is not None:
            Jq = self.probe.joint_jacobian(self.noise_robot, self.q)
            C += self.joint_std**2 * Jq @ np.swapaxes(Jq, 1, 2)
        return C

    def _build_sigmas(self) -> None:
        C = self._row_covariance()
        self.row_covariance = C
        s2 = np.trace(C, axis1=1, axis2=2) / 3.0
        if self.sockets == "parameters":
            sc = s2
            CX = np.zeros((self.sites.S, 3, 3))
        else:
            sc = self.contrasts.variance(s2)
            CX = site_means(C, self.sites) / self.sites.count[:, None, None]
        if self.noise_robot is not None:
            X = site_means(self.probe.points(self.noise_robot, self.q, jacobian=False)[0],
                           self.sites)
        else:
            X = self._layout_points()
        a, b = self._dist[:, 0], self._dist[:, 1]
        vd = self._dist_std**2 + distance_variance(X[a], X[b], CX[a], CX[b])
        k = self._perp
        vp = self._perp_std**2 + perpendicularity_variance(
            X[k[:, 0]], X[k[:, 1]], X[k[:, 2]], X[k[:, 3]],
            CX[k[:, 0]], CX[k[:, 1]], CX[k[:, 2]], CX[k[:, 3]])
        point = np.sqrt(s2)
        floor_m = EXACT_FRACTION * (float(point.min()) if point.size and point.min() > 0
                                    else np.nan)
        self.sigma_coincidence = np.sqrt(sc)
        self.sigma_distance = np.sqrt(vd)
        self.sigma_angle = np.sqrt(vp)
        for what, s, floor in (("distance", self.sigma_distance, floor_m),
                               ("right-angle", self.sigma_angle, floor_m / self._scale())):
            zero = s <= 0
            if np.any(zero):
                if not np.isfinite(floor):
                    raise KincalError(f"block {self.name!r}: every {what} constraint has zero "
                                      "uncertainty and the points have none: give point_std, "
                                      "joint_std or the artifact's std")
                s[zero] = floor
        if np.any(self.sigma_coincidence <= 0):
            raise KincalError(f"block {self.name!r}: the seated points have zero uncertainty; "
                              "give point_std > 0 or joint_std > 0")

    def _scale(self) -> float:
        """A characteristic artifact length [m] (first distance, else 1 m)."""
        L = self.geometry.length
        return float(L) if np.isfinite(L) and L > 0 else 1.0

    def _layout_points(self) -> Array:
        """Site points from the artifact layout (only directions matter; no robot given)."""
        if self.geometry.layout:
            L = dict(zip(self.geometry.sockets, self.geometry.layout_array(), strict=True))
            return np.array([L[s] for s in self.sites.socket])
        if len(self._perp):
            raise KincalError(f"block {self.name!r}: right-angle constraints without a socket "
                              "layout need robot=... to weight them")
        X = np.zeros((self.sites.S, 3))
        X[:, 0] = np.arange(self.sites.S)
        return X

    # ------------------------------------------------------------------ contract
    @property
    def framed_sites(self) -> IntArray:
        """Sites seated more than once: they carry a socket frame orientation."""
        return np.flatnonzero(self.sites.count > 1)

    def parameters(self) -> ParamSpec:
        spec = self.probe.parameters(self.name)
        names: list[str] = []
        units: list[str] = []
        if self.sockets == "parameters":
            for p, s in zip(self.sites.placement, self.sites.socket, strict=True):
                names += [f"{self.name}.{p}.{s}.{c}" for c in "xyz"]
                units += ["m"] * 3
        for k in self.framed_sites:
            names += [f"{self.name}.{self.sites.placement[k]}.{self.sites.socket[k]}.{c}"
                      for c in ("rz", "ry", "rx")]
            units += ["rad"] * 3
        return spec + ParamSpec(tuple(names), np.zeros(len(names)), tuple(units),
                                ("artifact",) * len(names))

    def initial_guess(self, robot: Robot) -> Array:
        """Probe: its given value; sockets: the means of the tips under ``robot``;
        socket frames: zero."""
        parts = [np.asarray(self.probe.value if self.probe.estimate else (), dtype=float)]
        if self.sockets == "parameters":
            P = np.empty((self.N, 3))                          # tips, in pieces of rows
            for cs in configuration_slices(self.N, 3):
                P[cs] = self.probe.points(robot, self.q[cs], jacobian=False)[0]
            parts.append(site_means(P, self.sites).reshape(-1))
        parts.append(np.zeros(3 * len(self.framed_sites)))
        return np.concatenate(parts)

    def residual_owner(self) -> IntArray:
        """Coincidence residuals: their row; constraints: the placement's first row."""
        rows = (np.arange(self.N, dtype=np.intp) if self.sockets == "parameters"
                else self.contrasts.rows)
        return np.concatenate([np.repeat(rows, 3),
                               self._place_first_row[self._dist_place],
                               self._place_first_row[self._perp_place]]).astype(np.intp)

    def residual_placement(self) -> IntArray:
        """(M,) index into :attr:`placements` of every residual."""
        return self._row_place[self.residual_owner()]

    def _split(self, extra: ArrayLike) -> tuple[Array, Array, Array]:
        """Probe values, socket positions (S, 3) or empty, frame angles (G, 3) rz ry rx."""
        extra = np.asarray(extra, dtype=float).reshape(-1)
        k = self.probe.size
        npos = 3 * self.sites.S if self.sockets == "parameters" else 0
        return extra[:k], extra[k:k + npos].reshape(-1, 3), extra[k + npos:].reshape(-1, 3)

    def _sites(self, robot: Robot, extra: ArrayLike, jacobian: bool
               ) -> tuple[Array, Array | None, Array, Array | None]:
        """Tips ``P`` (N, 3), site points ``X`` (S, 3) and their Jacobians over
        ``[robot params, block params]`` ((N or S), 3, P + E)."""
        pv, sv, _ = self._split(extra)
        P, dPr, dPp = self.probe.points(robot, self.q, pv, jacobian)
        S, E = self.sites.S, len(np.asarray(extra).reshape(-1))
        if not jacobian:
            X = sv if self.sockets == "parameters" else site_means(P, self.sites)
            return P, None, X, None
        Pr = robot.num_params
        dP = np.zeros((self.N, 3, Pr + E))
        dP[:, :, :Pr] = dPr
        dP[:, :, Pr:Pr + self.probe.size] = dPp
        if self.sockets == "parameters":
            X = sv
            dX = np.zeros((S, 3, Pr + E))
            cols = Pr + self.probe.size + 3 * np.arange(S)
            for c in range(3):
                dX[np.arange(S), c, cols + c] = 1.0
        else:
            X = site_means(P, self.sites)
            dX = site_means(dP, self.sites)
        return P, dP, X, dX

    def _coincidence(self, P: Array, dP: Array | None, X: Array, dX: Array | None,
                     angles: Array, P_r: int) -> tuple[Array, Array | None, IntArray]:
        """Coincidence residual vectors in their socket frames, ``R_k^T (P_i - X_k)`` or
        ``R_k^T h_j`` (K, 3), their Jacobian (K, 3, T) and the site of each."""
        if self.sockets == "parameters":
            site = self.sites.index
            rc = P - X[site]
            Jc = dP - dX[site] if dP is not None and dX is not None else None
        else:
            site = self.sites.index[self.contrasts.rows]
            rc = self.contrasts.apply(P)
            Jc = self.contrasts.apply(dP) if dP is not None else None
        G = self.framed_sites
        slot = np.full(self.sites.S, -1, dtype=np.intp)
        slot[G] = np.arange(len(G))
        g = slot[site]
        framed = g >= 0
        if not len(G):
            return rc, Jc, site
        R = rotation_rzyx(angles)                              # (G, 3, 3)
        Rk = R[g[framed]]
        rc = rc.copy()
        h = rc[framed]
        rc[framed] = np.einsum("kji,kj->ki", Rk, h)             # R^T h
        if Jc is None:
            return rc, None, site
        Jc = Jc.copy()
        Jc[framed] = np.einsum("kji,kjp->kip", Rk, Jc[framed])
        axes = rotation_axes_rzyx(angles)[g[framed]]           # (K', 3, 3) columns
        col0 = P_r + self.probe.size + (3 * self.sites.S if self.sockets == "parameters"
                                        else 0)
        d = np.einsum("kji,kjc->kic", Rk, np.cross(h[:, :, None], axes, axis=1))
        rows = np.flatnonzero(framed)
        for c in range(3):
            Jc[rows, :, col0 + 3 * g[framed] + c] = d[:, :, c]
        return rc, Jc, site

    def evaluate(self, robot: Robot, extra: Array, jacobian: bool = True
                 ) -> tuple[Array, Array | None, Array | None]:
        P, dP, X, dX = self._sites(robot, extra, jacobian)
        rc, Jc, _ = self._coincidence(P, dP, X, dX, self._split(extra)[2], robot.num_params)
        wc = 1.0 / self.sigma_coincidence
        a, b = self._dist[:, 0], self._dist[:, 1]
        k = self._perp
        if jacobian:
            assert dX is not None and dP is not None
            ed, Jd = distance_residuals(X[a], X[b], self._dist_L, dX[a], dX[b])
            ep, Jpp = perpendicularity_residuals(X[k[:, 0]], X[k[:, 1]], X[k[:, 2]],
                                                 X[k[:, 3]], dX[k[:, 0]], dX[k[:, 1]],
                                                 dX[k[:, 2]], dX[k[:, 3]])
        else:
            ed, _ = distance_residuals(X[a], X[b], self._dist_L)
            ep, _ = perpendicularity_residuals(X[k[:, 0]], X[k[:, 1]], X[k[:, 2]], X[k[:, 3]])
        wd, wp = 1.0 / self.sigma_distance, 1.0 / self.sigma_angle
        r = np.concatenate([(rc * wc[:, None]).reshape(-1), ed * wd, ep * wp])
        if not jacobian:
            return r, None, None
        assert dP is not None and Jc is not None and Jd is not None and Jpp is not None
        J = np.concatenate([(Jc * wc[:, None, None]).reshape(-1, dP.shape[2]),
                            Jd * wd[:, None], Jpp * wp[:, None]])
        Pr = robot.num_params
        return r, J[:, :Pr], J[:, Pr:]

    # ------------------------------------------------------------------ reports
    def points(self, robot: Robot, extra: ArrayLike | None = None) -> Array:
        """Probe tips (N, 3) [m] under ``robot`` (probe value from ``extra`` if estimated)."""
        extra = self.initial_guess(robot) if extra is None else extra
        return self.probe.points(robot, self.q, self._split(extra)[0], jacobian=False)[0]

    def socket_points(self, robot: Robot, extra: ArrayLike | None = None) -> Array:
        """Site points (S, 3) [m]: means of the tips, or the socket parameters."""
        extra = self.initial_guess(robot) if extra is None else extra
        return self._sites(robot, extra, False)[2]

    def socket_spread(self, robot: Robot, extra: ArrayLike | None = None) -> Array:
        """Per site, the RMS distance of its tips to their mean (S,) [m] (0 for one row)."""
        P = self.points(robot, extra)
        d2 = np.sum((P - site_means(P, self.sites)[self.sites.index]) ** 2, axis=1)
        return np.sqrt(np.bincount(self.sites.index, d2, self.sites.S) / self.sites.count)

    def lengths(self, robot: Robot, extra: ArrayLike | None = None) -> ConstraintValues:
        """Every known distance as computed from the joint readings with ``robot``.

        Uses the site means of the tips (never socket parameters), so the same numbers
        come out for any socket mode: what the readings say about the artifact.
        """
        X = site_means(self.points(robot, extra), self.sites)
        d = np.linalg.norm(X[self._dist[:, 1]] - X[self._dist[:, 0]], axis=1)
        pl = tuple(self.placements[i] for i in self._dist_place)
        return ConstraintValues(pl, self._dist_label, d, self._dist_L.copy())

    def angles(self, robot: Robot, extra: ArrayLike | None = None) -> ConstraintValues:
        """Deviation from the right angle [rad] of every perpendicular pair (site means)."""
        X = site_means(self.points(robot, extra), self.sites)
        k = self._perp
        c, _ = perpendicularity_residuals(X[k[:, 0]], X[k[:, 1]], X[k[:, 2]], X[k[:, 3]])
        pl = tuple(self.placements[i] for i in self._perp_place)
        return ConstraintValues(pl, self._perp_label, angle_deviation(c), np.zeros(len(c)))

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        """``coincidence_m`` (rows of multi-row sites), ``distance_m``, ``perpendicularity_rad``."""
        P, _, X, _ = self._sites(robot, extra, False)
        out: dict[str, Array] = {}
        rows = (np.ones(self.N, dtype=bool) if self.sockets == "parameters"
                else self.sites.count[self.sites.index] > 1)
        if np.any(rows):
            out["coincidence_m"] = np.linalg.norm(P - X[self.sites.index], axis=1)[rows]
        a, b = self._dist[:, 0], self._dist[:, 1]
        if len(a):
            out["distance_m"] = distance_residuals(X[a], X[b], self._dist_L)[0]
        k = self._perp
        if len(k):
            c, _ = perpendicularity_residuals(X[k[:, 0]], X[k[:, 1]], X[k[:, 2]], X[k[:, 3]])
            out["perpendicularity_rad"] = angle_deviation(c)
        return out

    # ------------------------------------------------------------------ copies
    def replace(self, **changes: object) -> ArtifactMeasurement:
        """A copy with some constructor arguments changed (``name``, ``probe``, ``sockets`` ...)."""
        args: dict[str, object] = dict(
            q=self.q, placement=self.placement_labels, socket=self.socket_labels,
            geometry=self.geometry, probe=self.probe, sockets=self.sockets, name=self.name,
            joint_std=self.joint_std, point_std=self.point_std, robot=self.noise_robot)
        args.update(changes)
        out = ArtifactMeasurement(**args)  # type: ignore[arg-type]
        out.provenance = self.provenance                # the same file's rows
        return out

    def with_q(self, q: Array) -> ArtifactMeasurement:
        """The same rows measured at joint readings ``q``."""
        return self.replace(q=q)

    def subset_placements(self, placements: Sequence[str]) -> ArtifactMeasurement:
        """A block with the same name holding only the rows of ``placements``."""
        want = {str(p) for p in placements}
        unknown = want - set(self.placements)
        if unknown:
            raise KincalError(f"block {self.name!r} has no placement {sorted(unknown)[0]!r}")
        rows = np.array([p in want for p in self.placement_labels])
        return self.replace(q=self.q[rows],
                            placement=[p for p, k in zip(self.placement_labels, rows,
                                                         strict=True) if k],
                            socket=[s for s, k in zip(self.socket_labels, rows,
                                                      strict=True) if k])

    def __repr__(self) -> str:
        return (f"ArtifactMeasurement({self.name!r}, {self.geometry.kind}, {self.N} rows, "
                f"{len(self.placements)} placements, {self.sites.S} sockets seated, "
                f"{len(self._dist)} distances, {len(self._perp)} right angles, "
                f"sockets={self.sockets!r}, {self.probe.describe()})")
