"""Artifact geometry: named sockets, known distances between them, perpendicular segments.

An *artifact* is a rigid part with cup-shaped sockets in which the probe tip on the
robot's flange is seated by hand or by jogging.  Nothing measures positions; the data
are joint readings, and the artifact contributes only what is known about it:

* **distances** ``|X_b - X_a| = L`` between two sockets ``a``, ``b`` [m], with the
  uncertainty ``std`` of ``L`` (machining / caliper) [m];
* **perpendicular segments** ``(X_c - X_a) . (X_d - X_b) = 0``, with the uncertainty
  ``std`` of the right angle [rad].

Built-in artifacts (:meth:`ArtifactGeometry.cross_bar`, :meth:`~ArtifactGeometry.ball_bar`,
:meth:`~ArtifactGeometry.two_socket`):

* ``cross-bar``: sockets A, B, C, D at the ends of two arms crossing at
  their middles, ``|AC| = |BD| = L``, ``AC`` perpendicular to ``BD``;
* ``ball-bar``: two sockets A, B at a known distance, usually probed once each per
  placement;
* ``two-socket``: the same two-socket constraint, usually probed many times per socket
  in one or two placements (the MUKCa tool of ``shared/data/panda_two_socket``).

``layout`` holds the socket coordinates in the artifact's own frame [m] (z along the
socket axes, pointing out of the cups); simulation uses it to place the artifact.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from kincal.errors import KincalError, MeasurementFileError
from kincal.units import UNITS

Array = NDArray[np.float64]

KINDS = ("cross-bar", "ball-bar", "two-socket", "custom")


@dataclass(frozen=True)
class Distance:
    """``|X_b - X_a| = length`` between sockets ``a`` and ``b``.

    Attributes:
        a, b: socket labels.
        length: the known distance [m].
        std: its standard uncertainty [m] (0 = exact).
    """

    a: str
    b: str
    length: float
    std: float = 0.0

    @property
    def label(self) -> str:
        return f"{self.a}{self.b}" if len(self.a) == len(self.b) == 1 else f"{self.a}-{self.b}"


@dataclass(frozen=True)
class Perpendicular:
    """``(X_c - X_a) . (X_d - X_b) = 0``: segment ``a -> c`` perpendicular to ``b -> d``.

    Attributes:
        a, c: the first segment's sockets.
        b, d: the second segment's sockets.
        std: standard uncertainty of the right angle [rad] (0 = exact).
    """

    a: str
    c: str
    b: str
    d: str
    std: float = 0.0

    @property
    def label(self) -> str:
        return f"{self.a}{self.c}.{self.b}{self.d}"


@dataclass(frozen=True)
class ArtifactGeometry:
    """What is known about an artifact.

    Attributes:
        kind: one of :data:`KINDS`.
        sockets: socket labels, in order.
        distances: the known distances.
        perpendiculars: the perpendicular segment pairs.
        layout: socket -> coordinates in the artifact frame [m] (for simulation).
    """

    kind: str
    sockets: tuple[str, ...]
    distances: tuple[Distance, ...] = ()
    perpendiculars: tuple[Perpendicular, ...] = ()
    layout: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise KincalError(f"unknown artifact kind {self.kind!r}; use one of "
                              f"{', '.join(KINDS)}")
        if len(set(self.sockets)) != len(self.sockets) or not self.sockets:
            raise KincalError(f"artifact {self.kind}: socket labels must be unique and "
                              f"non-empty, got {list(self.sockets)}")
        for s in self.sockets:
            if not s or any(c in s for c in " ,;#=\"'") or s in ("x", "y", "z"):
                raise KincalError(f"artifact {self.kind}: socket label {s!r} must be a word "
                                  "(letters, digits, _ - .) other than x, y, z")
        known = set(self.sockets)
        for d in self.distances:
            for s in (d.a, d.b):
                if s not in known:
                    raise KincalError(f"artifact {self.kind}: distance {d.label} names an "
                                      f"unknown socket {s!r}")
            if d.a == d.b or not (np.isfinite(d.length) and d.length > 0):
                raise KincalError(f"artifact {self.kind}: distance {d.label} needs two "
                                  "different sockets and a positive length")
            if not (np.isfinite(d.std) and d.std >= 0):
                raise KincalError(f"artifact {self.kind}: distance {d.label}: std must be >= 0")
        for p in self.perpendiculars:
            for s in (p.a, p.b, p.c, p.d):
                if s not in known:
                    raise KincalError(f"artifact {self.kind}: perpendicular {p.label} names "
                                      f"an unknown socket {s!r}")
            if p.a == p.c or p.b == p.d:
                raise KincalError(f"artifact {self.kind}: perpendicular {p.label} needs "
                                  "segments between two different sockets")
        if self.layout and set(self.layout) != known:
            raise KincalError(f"artifact {self.kind}: the layout must place every socket "
                              f"({', '.join(self.sockets)})")

    # ------------------------------------------------------------------ built-ins
    @staticmethod
    def cross_bar(length: float, length_std: float = 0.0, angle_std: float = 0.0
                  ) -> ArtifactGeometry:
        """The cross: ``|AC| = |BD| = length`` [m], ``AC`` perpendicular to ``BD``.

        Layout: A, C on the x axis and B, D on the y axis at ``+-length/2``.
        """
        h = 0.5 * float(length)
        return ArtifactGeometry(
            "cross-bar", ("A", "B", "C", "D"),
            (Distance("A", "C", float(length), length_std),
             Distance("B", "D", float(length), length_std)),
            (Perpendicular("A", "C", "B", "D", angle_std),),
            {"A": (-h, 0.0, 0.0), "B": (0.0, -h, 0.0), "C": (h, 0.0, 0.0), "D": (0.0, h, 0.0)})

    @staticmethod
    def ball_bar(length: float, length_std: float = 0.0,
                 sockets: Sequence[str] = ("A", "B"), kind: str = "ball-bar"
                 ) -> ArtifactGeometry:
        """Two sockets at a known distance ``length`` [m] (layout on the x axis)."""
        a, b = (str(s) for s in sockets)
        h = 0.5 * float(length)
        return ArtifactGeometry(kind, (a, b), (Distance(a, b, float(length), length_std),), (),
                                {a: (-h, 0.0, 0.0), b: (h, 0.0, 0.0)})

    @staticmethod
    def two_socket(length: float, length_std: float = 0.0,
                   sockets: Sequence[str] = ("hole_0", "hole_1")) -> ArtifactGeometry:
        """The two-socket tool: like :meth:`ball_bar`, sockets named ``hole_0, hole_1``."""
        return ArtifactGeometry.ball_bar(length, length_std, sockets, kind="two-socket")

    @staticmethod
    def builtin(kind: str, length: float, length_std: float = 0.0, angle_std: float = 0.0
                ) -> ArtifactGeometry:
        """One of the built-in artifacts by ``kind`` with its characteristic length [m]."""
        if kind == "cross-bar":
            return ArtifactGeometry.cross_bar(length, length_std, angle_std)
        if kind == "ball-bar":
            return ArtifactGeometry.ball_bar(length, length_std)
        if kind == "two-socket":
            return ArtifactGeometry.two_socket(length, length_std)
        raise KincalError(f"no built-in artifact {kind!r}; use cross-bar, ball-bar or "
                          "two-socket, or describe it in a geometry YAML")

    # ------------------------------------------------------------------ queries
    @property
    def length(self) -> float:
        """The first distance [m] (the bar length of the built-ins)."""
        return self.distances[0].length if self.distances else float("nan")

    def layout_array(self) -> Array:
        """(K, 3) socket coordinates in the artifact frame [m], in ``sockets`` order."""
        if not self.layout:
            raise KincalError(f"artifact {self.kind}: no socket layout (needed to simulate "
                              "it); add 'layout' to the geometry")
        return np.array([self.layout[s] for s in self.sockets], dtype=float)

    def segment_length(self, a: str, b: str) -> float | None:
        """The known distance between ``a`` and ``b`` [m], from the distances or the layout."""
        for d in self.distances:
            if {d.a, d.b} == {a, b}:
                return d.length
        if self.layout:
            return float(np.linalg.norm(np.subtract(self.layout[b], self.layout[a])))
        return None

    # ------------------------------------------------------------------ YAML
    def to_dict(self, length_unit: str = "mm", angle_unit: str = "deg") -> dict[str, Any]:
        """A YAML-able description in the given units (see :func:`geometry_from_dict`)."""
        fl, fa = 1.0 / UNITS[length_unit][1], 1.0 / UNITS[angle_unit][1]
        out: dict[str, Any] = {"artifact": self.kind,
                               "units": {"length": length_unit, "angle": angle_unit},
                               "sockets": list(self.sockets)}
        out["distances"] = [{"between": [d.a, d.b], "length": d.length * fl,
                             "std": d.std * fl} for d in self.distances]
        out["perpendicular"] = [{"segments": [[p.a, p.c], [p.b, p.d]], "std": p.std * fa}
                                for p in self.perpendiculars]
        if self.layout:
            out["layout"] = {s: [float(v) * fl for v in self.layout[s]] for s in self.sockets}
        return out


def _unit(units: Mapping[str, Any], key: str, default: str, dim: str, src: str) -> float:
    u = str(units.get(key, default))
    if u not in UNITS or UNITS[u][0] != dim:
        raise MeasurementFileError(f"units: {key}={u!r} is not {dim} unit", source=src)
    return UNITS[u][1]


def geometry_from_dict(data: Mapping[str, Any], source: str = "geometry") -> ArtifactGeometry:
    """Build a geometry from a parsed YAML mapping.

    Format (lengths in ``units.length``, angles in ``units.angle``; both required when
    a length or angle is given)::

        artifact: cross-bar          # cross-bar | ball-bar | two-socket | custom
        units: {length: mm, angle: deg}
        length: 300                  # built-ins: |AC| = |BD| (cross-bar) or |AB|
        length_std: 0.01             # optional
        angle_std: 0.002             # optional (cross-bar)
        # custom artifacts instead list everything:
        sockets: [A, B, C]
        distances: [{between: [A, B], length: 120, std: 0.01}, ...]
        perpendicular: [{segments: [[A, B], [A, C]], std: 0.001}]
        layout: {A: [0, 0, 0], B: [120, 0, 0], C: [0, 80, 0]}
    """
    if not isinstance(data, Mapping):
        raise MeasurementFileError("the geometry must be a mapping", source=source)
    kind = str(data.get("artifact", "custom"))
    units = data.get("units") or {}
    if not isinstance(units, Mapping):
        raise MeasurementFileError("'units' must be a mapping {length: mm, angle: deg}",
                                   source=source)
    if ("length" in data or "distances" in data or "layout" in data) and "length" not in units:
        raise MeasurementFileError("give the length unit: units: {length: mm}", source=source)
    fl = _unit(units, "length", "m", "length", source)
    fa = _unit(units, "angle", "rad", "angle", source)
    try:
        if kind != "custom" and "distances" not in data:
            if "length" not in data:
                raise MeasurementFileError(f"artifact {kind}: missing 'length'", source=source)
            geom = ArtifactGeometry.builtin(kind, float(data["length"]) * fl,
                                            float(data.get("length_std", 0.0)) * fl,
                                            float(data.get("angle_std", 0.0)) * fa)
            if "sockets" in data and kind != "cross-bar":
                names = [str(s) for s in data["sockets"]]
                geom = ArtifactGeometry.ball_bar(geom.length, geom.distances[0].std, names,
                                                 kind=kind)
            return geom
        sockets = tuple(str(s) for s in data.get("sockets", ()))
        dists = tuple(Distance(str(d["between"][0]), str(d["between"][1]),
                               float(d["length"]) * fl, float(d.get("std", 0.0)) * fl)
                      for d in data.get("distances") or ())
        perps = tuple(Perpendicular(str(p["segments"][0][0]), str(p["segments"][0][1]),
                                    str(p["segments"][1][0]), str(p["segments"][1][1]),
                                    float(p.get("std", 0.0)) * fa)
                      for p in data.get("perpendicular") or ())
        layout = {str(k): tuple(float(x) * fl for x in v)
                  for k, v in (data.get("layout") or {}).items()}
        return ArtifactGeometry(kind, sockets, dists, perps, layout)  # type: ignore[arg-type]
    except MeasurementFileError:
        raise
    except KincalError as exc:
        raise MeasurementFileError(str(exc), source=source) from None
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise MeasurementFileError(f"malformed geometry ({exc.__class__.__name__}: {exc})",
                                   source=source) from None


def read_geometry(path: str | Path) -> ArtifactGeometry:
    """Read an artifact geometry YAML (see :func:`geometry_from_dict`)."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise MeasurementFileError("no such geometry file", source=str(path)) from None
    except yaml.YAMLError as exc:
        raise MeasurementFileError(f"not valid YAML ({exc.__class__.__name__})",
                                   source=str(path)) from None
    return geometry_from_dict(data, str(path))


def write_geometry(geometry: ArtifactGeometry, path: str | Path, length_unit: str = "mm",
                   angle_unit: str = "deg") -> None:
    """Write a geometry YAML atomically."""
    from kincal.io import atomic_write_text

    atomic_write_text(path, yaml.safe_dump(geometry.to_dict(length_unit, angle_unit),
                                           sort_keys=False))
