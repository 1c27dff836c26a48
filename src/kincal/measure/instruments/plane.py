"""Plane contact: the tool point touches planes (probing a surface plate, a cube).

Each row says: at joint readings ``q_i`` the tool point lies on plane ``k``.  With the
plane's unit normal ``n_k`` and offset ``d_k`` [m] (``{p : n.p = d}`` in the world), the
measurement equation is the signed distance, observed as zero::

    e_i = n_k . p(q_i) - d_k = 0          residual e_i / sigma_i

(for a ball-tipped probe, ``p`` is the ball centre and a known plane's ``d`` includes the
radius.)  ``d e/dp = n^T``.

A plane is either **known** (``n``, ``d`` given, no parameters) or **unknown**, with
three parameters relative to a nominal normal ``n0`` (from the file):
``{name}.{plane}.rx``, ``{name}.{plane}.ry`` [rad] tilt the normal and ``{name}.{plane}.d``
[m] is the offset::

    n = B (cos rx sin ry, -sin rx, cos rx cos ry),    B = [e1, e2, n0]

(``Ry(ry) Rx(rx) e_z`` in the orthonormal basis ``B``; ``e1`` is ``e_x`` -- or ``e_y`` when
``n0`` is close to ``e_x`` -- made orthogonal to ``n0``, ``e2 = n0 x e1``).  Then
``de/d rx = p . B (-sin rx sin ry, -cos rx, -sin rx cos ry)``,
``de/d ry = p . B (cos rx cos ry, 0, -cos rx sin ry)``, ``de/dd = -1``.  The marker
``{name}.marker.x, y, z`` follows (``marker="own"``).

What a plane cannot see: the tool point's motion within the plane -- one plane fixes one
direction only.  Three planes (known or not) meet in a corner, and scaling the scene
about that corner keeps every contact on its plane: the scale is lost; four known planes
not through one point fix it.  Unknown planes lose the scale whatever their number (their
offsets follow any scaling) and hide the robot's base frame.  Because shrinking the whole
scene shrinks every contact distance, the scale looks identifiable away from the
solution: with unknown planes hold one robot length (``--fix 'd[4]'`` for a PUMA, or
``calibrate(..., fixed=[...])``) -- the identifiability of noise-free simulated data names
it.

File columns: ``plane, mode, n_az, n_el, d, sigma`` per contact.  Simulator:
:func:`simulate_plane` (contacts solved on the true robot, noise in the contact).
The module registers the ``plane`` instrument (:mod:`kincal.measure.registry`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError, MeasurementFileError
from kincal.measure.base import ParamSpec
from kincal.measure.files import Field
from kincal.measure.instruments.common import (
    MARKER_MODES,
    label_index,
)
from kincal.measure.instruments.csvio import (
    block_name,
    block_tags,
    build_block,
    choice_column,
    label_column,
    one_block,
    per_group,
    read_block_table,
    stack_columns,
    text_per_group,
    write_block_table,
)
from kincal.measure.instruments.placement import (
    POINT_OPTIONS,
    as_flag,
    labels_for,
    marker_truth,
    solve_contacts,
    stated_sigma,
    workspace,
)
from kincal.measure.instruments.pointblock import PointBlock
from kincal.measure.registry import Instrument, register
from kincal.measure.simulate import random_configurations
from kincal.robots.chain import Robot
from kincal.spatial import exp_so3

Array = NDArray[np.float64]
MODES = ("known", "unknown")


def plane_basis(n0: Array) -> Array:
    """``B = [e1, e2, n0]`` (3, 3), a right-handed orthonormal basis with ``n0`` last."""
    n0 = n0 / np.linalg.norm(n0)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n0[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = helper - (helper @ n0) * n0
    e1 /= np.linalg.norm(e1)
    return np.column_stack([e1, np.cross(n0, e1), n0])


def normal_from_angles(az: ArrayLike, el: ArrayLike) -> Array:
    """Unit normal from azimuth and elevation [rad]: ``(cos el cos az, cos el sin az, sin el)``."""
    az, el = np.asarray(az, float), np.asarray(el, float)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)


def angles_from_normal(n: Array) -> Array:
    """``(az, el)`` [rad] of unit normals (..., 3)."""
    n = np.asarray(n, dtype=float)
    return np.stack([np.arctan2(n[..., 1], n[..., 0]),
                     np.arctan2(n[..., 2], np.hypot(n[..., 0], n[..., 1]))], -1)


class PlaneMeasurement(PointBlock):
    """Contacts of the tool point with known or unknown planes.

    Args:
        name: block name (parameter prefix).
        q: (N, n) joint readings [rad / m] at contact.
        plane: (N,) plane label of each contact.
        sigma: standard deviation of the contact distance [m], scalar or (N,).
        planes: ``{plane: (normal (3,), d [m], known: bool)}``: the plane (known) or its
            nominal normal (unknown; ``d`` is then only a default).
        marker: ``"own"`` or ``"tool"`` (see :mod:`.common`).
    """

    row_fields = PointBlock.row_fields + ("plane_index", "plane_labels")

    def __init__(self, name: str, q: ArrayLike, plane: Sequence[str], sigma: ArrayLike,
                 planes: Mapping[str, tuple[ArrayLike, float, bool]],
                 marker: str = "own") -> None:
        N = self._init_rows("plane", name, q, None, 1, "contacts", sigma, marker)
        self.plane_labels = [str(s) for s in plane]
        if len(self.plane_labels) != N:
            raise KincalError(f"block {name!r}: one plane label per row needed")
        self.planes, self.plane_index = label_index(self.plane_labels, "plane", name)
        missing = [s for s in self.planes if s not in planes]
        if missing:
            raise KincalError(f"block {name!r}: plane {missing[0]!r} is not described")
        self.plane_defs: dict[str, tuple[Array, float, bool]] = {}
        for s in self.planes:
            given, d0, known = planes[s]
            n0 = np.asarray(given, dtype=float).reshape(3)
            norm = np.linalg.norm(n0)
            if not np.isfinite(norm) or norm < 1e-12:
                raise KincalError(f"block {name!r}: plane {s!r} has no normal direction")
            self.plane_defs[s] = (n0 / norm, float(d0), bool(known))
        self.unknown = [s for s in self.planes if not self.plane_defs[s][2]]
        self.bases = np.array([plane_basis(self.plane_defs[s][0]) for s in self.planes])
        # column of each plane's first parameter (-1 if known)
        self.first = np.full(len(self.planes), -1, dtype=np.intp)
        for j, s in enumerate(self.unknown):
            self.first[self.planes.index(s)] = 3 * j

    def own_parameters(self) -> ParamSpec:
        names, vals = [], []
        for s in self.unknown:
            names += [f"{self.name}.{s}.rx", f"{self.name}.{s}.ry", f"{self.name}.{s}.d"]
            vals += [0.0, 0.0, self.plane_defs[s][1]]
        k = len(names)
        return ParamSpec(tuple(names), np.array(vals), ("rad", "rad", "m") * (k // 3),
                         ("artifact",) * k)

    def _normals(self, own: Array) -> tuple[Array, Array, Array]:
        """Per plane: normal (G, 3), offset (G,), dn/d(rx, ry) (G, 3, 2)."""
        G = len(self.planes)
        n = np.array([self.plane_defs[s][0] for s in self.planes]).reshape(G, 3)
        d = np.array([self.plane_defs[s][1] for s in self.planes])
        dn = np.zeros((G, 3, 2))
        unk = self.first >= 0
        if np.any(unk):
            P = own.reshape(-1, 3)
            a, b = P[:, 0], P[:, 1]
            ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
            B = self.bases[unk]
            n[unk] = np.einsum("gij,gj->gi", B, np.column_stack([ca * sb, -sa, ca * cb]))
            d[unk] = P[:, 2]
            dn[unk, :, 0] = np.einsum("gij,gj->gi", B, np.column_stack([-sa * sb, -ca, -sa * cb]))
            dn[unk, :, 1] = np.einsum("gij,gj->gi", B,
                                      np.column_stack([ca * cb, np.zeros_like(a), -ca * sb]))
        return n, d, dn

    def observe(self, p: Array, own: Array, jacobian: bool
                ) -> tuple[Array, Array | None, Array | None]:
        n, d, dn = self._normals(own)
        k = self.plane_index
        e = np.einsum("ni,ni->n", n[k], p) - d[k]
        if not jacobian:
            return e[:, None], None, None
        N = p.shape[0]
        dod = np.zeros((N, 1, own.size))
        rows = np.flatnonzero(self.first[k] >= 0)
        c0 = self.first[k[rows]]
        dod[rows, 0, c0] = np.einsum("ni,ni->n", dn[k[rows], :, 0], p[rows])
        dod[rows, 0, c0 + 1] = np.einsum("ni,ni->n", dn[k[rows], :, 1], p[rows])
        dod[rows, 0, c0 + 2] = -1.0
        return e[:, None], n[k][:, None, :], dod

    def own_guess(self, robot: Robot, p: Array) -> Array:
        """Each unknown plane fitted to the contact points (SVD), normal on ``n0``'s side."""
        out = []
        for s in self.unknown:
            g = self.planes.index(s)
            pts = p[self.plane_index == g]
            if pts.shape[0] < 3:
                raise KincalError(f"block {self.name!r}: unknown plane {s!r} has fewer than 3 "
                                  "contacts")
            c = pts.mean(0)
            nf = np.linalg.svd(pts - c, full_matrices=False)[2][-1]
            B = self.bases[g]
            if nf @ B[:, 2] < 0:
                nf = -nf
            nl = B.T @ nf
            out += [-np.arcsin(np.clip(nl[1], -1, 1)), np.arctan2(nl[0], nl[2]), nf @ c]
        return np.array(out)

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        r = self.evaluate(robot, extra, jacobian=False)[0]
        return {"distance_m": r * self.sigma}


# ---------------------------------------------------------------------------- file columns
PLANE_FIELDS = (Field("n_az", "angle", "n_az (azimuth of the plane normal)"),
                Field("n_el", "angle", "n_el (elevation of the plane normal)"),
                Field("d", "length", "d (plane offset: n.p = d)"),
                Field("sigma", "length", "sigma (standard deviation of the contact)"))


def write_plane(blocks: Sequence[Any], path: str | Path, units: Mapping[str, str] | None = None,
                robot: Any = None) -> None:
    """``plane, mode, n_az, n_el, d, sigma`` per contact (the plane, or its nominal)."""
    b: PlaneMeasurement = one_block(blocks, "plane")
    defs = [b.plane_defs[s] for s in b.planes]
    ang = angles_from_normal(np.array([d[0] for d in defs]))[b.plane_index]
    d = np.array([x[1] for x in defs])[b.plane_index]
    mode = ["known" if defs[g][2] else "unknown" for g in b.plane_index]
    cols = [("plane", b.plane_labels, "text"), ("mode", mode, "text"),
            ("n_az", ang[:, 0], "angle"), ("n_el", ang[:, 1], "angle"), ("d", d, "length"),
            ("sigma", b.sigma, "length")]
    write_block_table(path, block_tags("plane", b, marker=b.marker), b.q, cols, units, robot,
                      ["contact: n.p = d, n = (cos el cos az, cos el sin az, sin el); an "
                       "unknown plane's n and d are nominal values"])


def read_plane(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
               ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    """Read a ``plane`` CSV into one block (SI units); a bad file raises one line
    naming the file and the line (:class:`~kincal.errors.MeasurementFileError`)."""
    tab = read_block_table(path, robot, "plane", PLANE_FIELDS, ("n_az", "n_el", "d", "sigma"),
                           {"plane": None, "mode": "unknown"}, units, ignore)
    planes, idx = label_column(tab, "plane", "plane")
    choice_column(tab, "mode", ("known", "unknown"))
    g = per_group(tab, idx, stack_columns(tab.values, ("n_az", "n_el", "d")), "plane n_az, n_el, d")
    modes = text_per_group(tab, idx, tab.text["mode"], "plane mode")
    defs = {s: (normal_from_angles(g[k, 0], g[k, 1]), float(g[k, 2]), modes[k] == "known")
            for k, s in enumerate(planes)}
    marker = tab.option("marker", "own", MARKER_MODES)
    return [build_block(tab, lambda: PlaneMeasurement(
        block_name(tab, name, "plane"), tab.q, tab.text["plane"], tab.values["sigma"], defs,
        marker))]


# ---------------------------------------------------------------------------- simulation
def simulate_plane(true_robot: Robot, rng: np.random.Generator, n_poses: int, noise: float,
                   planes: int = 4, known: bool = False, marker: str = "own",
                   name: str = "plane", margin: float = 0.05) -> tuple[list[Any], dict[str, float]]:
    """Contacts of the tool marker with ``planes`` planes, ``n_poses`` in all.

    The planes cut the workspace with normals spread over directions; the contact
    distance has noise N(0, noise^2) [m].  Unknown planes are written with a nominal
    normal ~1 deg off the true one (the reference of their tilt parameters), so every
    simulation has its own planes (no ``truth=`` re-measurement).
    """
    G = int(planes)
    if G < 1:
        raise MeasurementFileError("option planes must be >= 1")
    known = as_flag(known, "known")
    labels = labels_for(G, "p")
    centre, radius = workspace(true_robot, rng, margin)
    axes = exp_so3(rng.normal(0, 0.5, 3))
    normals = np.vstack([axes.T, rng.normal(size=(max(G - 3, 0), 3))])[:G]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    d = normals @ centre + rng.uniform(-0.3, 0.3, G) * radius
    nominal = normals + rng.normal(0, 0.015, normals.shape)
    nominal /= np.linalg.norm(nominal, axis=1, keepdims=True)
    m = marker_truth(rng) if marker == "own" else None
    defs = {s: (normals[g] if known else nominal[g], d[g], bool(known))
            for g, s in enumerate(labels)}
    probe = PlaneMeasurement(name, np.zeros((G, true_robot.n)), labels, 1.0, defs, marker)
    own: list[float] = []
    if not known:
        for g in range(G):
            nl = probe.bases[g].T @ normals[g]
            own += [-np.arcsin(nl[1]), np.arctan2(nl[0], nl[2]), d[g]]
    values = np.array(own + ([] if m is None else list(m)))
    which = np.arange(4 * n_poses) % G
    q0 = random_configurations(true_robot, len(which), rng, margin)
    eps = rng.normal(0.0, noise, len(which)) if noise > 0 else np.zeros(len(which))
    q, ok = solve_contacts(true_robot, q0, m, normals[which][:, None, :],
                           (d[which] + eps)[:, None])
    keep = np.concatenate([np.flatnonzero(ok & (which == g))[: (n_poses + g) // G]
                           for g in range(G)])
    keep.sort()
    if len(keep) < n_poses:
        raise KincalError(f"only {len(keep)} of {n_poses} plane contacts are reachable")
    block = PlaneMeasurement(name, q[keep], [labels[g] for g in which[keep]],
                             stated_sigma(noise, "m"), defs, marker)
    return [block], dict(zip(probe.parameters().names, values.tolist(), strict=True))


register(Instrument(
    name="plane",
    description="contacts of the tool point with known or unknown planes",
    simulate=simulate_plane, write=write_plane, read=read_plane,
    options={"planes": (4, "number of planes"),
             "known": (False, "planes known (True) or estimated (False)"),
             "name": ("plane", "block name (prefix of its parameters)"), **POINT_OPTIONS},
    noise_unit="m", same_placement=False))
