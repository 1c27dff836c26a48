"""The five-bar / dual SCARA parallel robot as an immutable value.

Two proximal links l1, l2 turn about the base points B1, B2 (motor angles
beta1, beta2 = encoder reading + offset); distal links l3 (from elbow J1) and
l4 (from elbow J2) meet at the end point J3.  Direct kinematics intersects two
circles (two assembly modes), inverse kinematics solves one triangle per arm
(four working modes).  The formulas and sign conventions are in
:mod:`kincal.parallel.kinematics`; this module wraps them with names,
units, shapes and errors for people.

Corrections to the thesis (Pittr 2012, sections 3.2-3.3): the inverse angle
alpha1 uses l3, not l2 (eq. 3.3.4); the four working modes are chosen by the
side of each elbow relative to the line B_i -> J3 rather than by comparing x
coordinates; the assembly mode is the side of J3 relative to J1 -> J2 rather
than a comparison of y coordinates.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np

from kincal.errors import KincalError, UnreachableError
from kincal.parallel import kinematics as kin
from kincal.parallel.mobility import planar_five_bar

_FIELDS = (
    "l1",
    "l2",
    "l3",
    "l4",
    "base1_x",
    "base1_y",
    "base2_x",
    "base2_y",
    "offset1",
    "offset2",
)


@dataclass(frozen=True)
class ActuatedJoint:
    """An actuated revolute joint of the five-bar with its reading limits [rad]."""

    name: str
    lower: float = -np.inf
    upper: float = np.inf
    kind: str = "revolute"


def _batch(a: Any, what: str) -> tuple[np.ndarray, bool]:
    """(N,2) float array from (2,) or (N,2) input, and whether the input was single."""
    arr = np.asarray(a, dtype=float)
    if arr.ndim == 1 and arr.shape[0] == 2:
        return arr[None, :], True
    if arr.ndim == 2 and arr.shape[1] == 2:
        return arr, False
    raise KincalError(f"{what} must have shape (2,) or (N, 2), got {arr.shape}")


def _fmt(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{float(c):.6g}" for c in np.ravel(v)) + "]"


@dataclass(frozen=True)
class FiveBar:
    """Planar five-bar robot; lengths in m, angles in rad, SI throughout.

    Attributes:
        l1, l2: proximal link lengths B_i -> J_i [m].
        l3, l4: distal link lengths J1 -> J3, J2 -> J3 [m].
        base1_x, base1_y, base2_x, base2_y: base joints B1, B2 [m].
        offset1, offset2: encoder offsets [rad], ``beta_i = q_i + offset_i``.
        assembly: default assembly mode, +1 (J3 left of J1->J2) or -1.
        working_mode: default working mode, e.g. ``"+-"`` (elbow i left of B_i->J3 is +).
        limits: optional reading limits ((q1_min, q1_max), (q2_min, q2_max)) [rad].
        name, source, description: identification and the origin of the numbers.
    """

    l1: float
    l2: float
    l3: float
    l4: float
    base1_x: float = 0.0
    base1_y: float = 0.0
    base2_x: float = 1.0
    base2_y: float = 0.0
    offset1: float = 0.0
    offset2: float = 0.0
    assembly: int = 1
    working_mode: str = "+-"
    limits: tuple[tuple[float, float], tuple[float, float]] | None = None
    name: str = "fivebar"
    source: str = ""
    description: str = ""

    def __repr__(self) -> str:
        """Lengths in mm and offsets in degrees (the units people read them in)."""
        mm = ", ".join(f"{v * 1e3:.4g}" for v in (self.l1, self.l2, self.l3, self.l4))
        return (f"FiveBar({self.name!r}, l1..l4 = {mm} mm, B1 = ({self.base1_x * 1e3:.4g}, "
                f"{self.base1_y * 1e3:.4g}) mm, B2 = ({self.base2_x * 1e3:.4g}, "
                f"{self.base2_y * 1e3:.4g}) mm, offsets {np.degrees(self.offset1):.4g}, "
                f"{np.degrees(self.offset2):.4g} deg, mode {self.working_mode}, "
                f"assembly {self.assembly:+d})")

    def _repr_html_(self) -> str:
        """The five-bar in a notebook: one row per geometric quantity, mm and degrees."""
        from html import escape

        rows = [("l1, l2 (proximal)", f"{self.l1 * 1e3:.4g}, {self.l2 * 1e3:.4g} mm"),
                ("l3, l4 (distal)", f"{self.l3 * 1e3:.4g}, {self.l4 * 1e3:.4g} mm"),
                ("base B1", f"({self.base1_x * 1e3:.4g}, {self.base1_y * 1e3:.4g}) mm"),
                ("base B2", f"({self.base2_x * 1e3:.4g}, {self.base2_y * 1e3:.4g}) mm"),
                ("encoder offsets", f"{np.degrees(self.offset1):.4g}, "
                                    f"{np.degrees(self.offset2):.4g} deg"),
                ("working mode, assembly", f"{self.working_mode}, {self.assembly:+d}")]
        body = "".join(f"<tr><th style='text-align:left'>{escape(k)}</th><td>{escape(v)}</td>"
                       "</tr>" for k, v in rows)
        return (f"<table><caption style='text-align:left'><b>FiveBar {escape(self.name)}</b>"
                f"</caption>{body}</table>")

    def __post_init__(self) -> None:
        for field in _FIELDS:
            object.__setattr__(self, field, float(getattr(self, field)))
        for field in ("l1", "l2", "l3", "l4"):
            if not getattr(self, field) > 0.0:
                raise KincalError(f"five-bar link length {field} must be positive")
        if self.assembly not in (1, -1):
            raise KincalError(f"five-bar assembly must be +1 or -1, not {self.assembly!r}")
        if self.working_mode not in kin.MODES:
            raise KincalError(
                f"five-bar working mode must be one of {', '.join(kin.MODES)}, "
                f"not {self.working_mode!r}"
            )

    # ----------------------------------------------------------- parameters
    param_names: ClassVar[tuple[str, ...]] = kin.PARAM_NAMES
    param_units: ClassVar[tuple[str, ...]] = kin.PARAM_UNITS
    n: ClassVar[int] = 2  # actuated joints

    @property
    def param_values(self) -> np.ndarray:
        """Parameter vector in the order of :attr:`param_names` (SI)."""
        return np.array([getattr(self, f) for f in _FIELDS])

    def parameter_table(self) -> list[tuple[str, float, str]]:
        """Rows (name, value, unit) of the geometric parameters."""
        return list(
            zip(self.param_names, self.param_values.tolist(), self.param_units, strict=True)
        )

    def with_params(self, values: Mapping[str, float] | Sequence[float] | np.ndarray) -> FiveBar:
        """A new FiveBar with some (dict by name) or all (array, 10 values) parameters set."""
        if isinstance(values, Mapping):
            unknown = sorted(set(values) - set(self.param_names))
            if unknown:
                raise KincalError(
                    f"unknown five-bar parameter(s) {', '.join(unknown)}; "
                    f"known: {', '.join(self.param_names)}"
                )
            changes: dict[str, Any] = {_FIELDS[self.param_names.index(k)]: float(v)
                                       for k, v in values.items()}
        else:
            arr = np.asarray(values, dtype=float).ravel()
            if arr.shape != (len(_FIELDS),):
                raise KincalError(f"five-bar needs {len(_FIELDS)} parameter values, got {arr.size}")
            changes = dict(zip(_FIELDS, arr.tolist(), strict=True))
        return replace(self, **changes)

    def with_defaults(
        self, assembly: int | None = None, working_mode: str | None = None
    ) -> FiveBar:
        """A new FiveBar with other default assembly / working modes."""
        return replace(
            self,
            assembly=self.assembly if assembly is None else assembly,
            working_mode=self.working_mode if working_mode is None else working_mode,
        )

    @property
    def joints(self) -> tuple[ActuatedJoint, ActuatedJoint]:
        """The two actuated (encoder) joints, for generic joint-vector helpers."""
        lim = self.limits or ((-np.inf, np.inf), (-np.inf, np.inf))
        return (ActuatedJoint("q1", *lim[0]), ActuatedJoint("q2", *lim[1]))

    @property
    def joint_names(self) -> tuple[str, str]:
        """Names of the actuated joints."""
        return ("q1", "q2")

    @property
    def meta(self) -> dict[str, str]:
        """Descriptive fields, as serial robots carry them."""
        return {"source": self.source, "description": self.description, "convention": "fivebar"}

    def mobility(self) -> int:
        """Kutzbach mobility of the planar five-bar (2)."""
        return planar_five_bar().kutzbach()

    # ----------------------------------------------------------- kinematics
    def elbows(self, q: Any) -> tuple[np.ndarray, np.ndarray]:
        """Elbow positions J1, J2 [m] for readings q [rad], (N,2) each (or (2,))."""
        qb, single = _batch(q, "q")
        _, j1, j2 = kin.elbows(self.param_values, qb)
        return (j1[0], j2[0]) if single else (j1, j2)

    def fk_masked(self, q: Any, assembly: int | str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """J3 [m] and the closure mask for readings q [rad]; NaN rows where the loop fails.

        ``assembly``: +1, -1, None (the default) or ``"continuous"``: start in the
        default, then follow the rows of q as a path, each row taking the branch
        nearest the J3 extrapolated from the two rows before, so a path through a
        Type-2 singularity carries on across it
        (:func:`kincal.parallel.kinematics.continuous_assembly`).
        """
        qb, single = _batch(q, "q")
        p = self.param_values
        x_plus, x_minus, ok = kin.fk_both(p, qb)
        if assembly is None:
            assembly = self.assembly
        if assembly == "continuous":
            sigma = kin.continuous_assembly(x_plus, x_minus, self.assembly)
        elif assembly in (1, -1):
            sigma = np.full(qb.shape[0], int(assembly))
        else:
            raise KincalError(f"assembly must be +1, -1 or 'continuous', not {assembly!r}")
        x = np.where((sigma > 0)[:, None], x_plus, x_minus)
        return (x[0], ok[0]) if single else (x, ok)

    def fk(
        self, q: Any, assembly: int | str | None = None, unreachable: str = "raise"
    ) -> np.ndarray:
        """End point J3 [m], (N,2) or (2,), from readings q [rad] by circle intersection.

        J3 = J1 + l3 u(atan2(J2 - J1) + sigma gamma1), gamma1 the angle at J1 of
        the triangle (l3, |J1J2|, l4).  Where the loop cannot close
        (|J1J2| outside [|l3 - l4|, l3 + l4]) raise :class:`UnreachableError`,
        or give NaN rows with ``unreachable="nan"`` (mask: :meth:`fk_masked`).
        """
        _check_unreachable(unreachable)
        x, ok = self.fk_masked(q, assembly)
        if unreachable == "raise" and not np.all(ok):
            qb, _ = _batch(q, "q")
            bad = np.flatnonzero(~np.atleast_1d(ok))
            _, j1, j2 = kin.elbows(self.param_values, qb[bad[:1]])
            r = float(np.linalg.norm(j2 - j1))
            raise UnreachableError(
                f"five-bar loop cannot close at configuration {bad[0]} "
                f"(q = {_fmt(qb[bad[0]])} rad): |J1J2| = {r:.6g} m is outside "
                f"[{abs(self.l3 - self.l4):.6g}, {self.l3 + self.l4:.6g}] m; "
                f"{bad.size} of {qb.shape[0]} fail (unreachable='nan' gives NaN and a mask)"
            )
        return x

    def ik_masked(
        self, x: Any, mode: str | np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Readings q [rad] and the reach mask for end points x [m]; NaN rows out of reach.

        ``mode``: ``"++" | "+-" | "-+" | "--"``, an (N,2) array of +-1 per row, or
        None (the default working mode).
        """
        xb, single = _batch(x, "x")
        modes = self._modes(mode, xb.shape[0])
        q, ok = kin.ik(self.param_values, xb, modes)
        return (q[0], ok[0]) if single else (q, ok)

    def ik(
        self, x: Any, mode: str | np.ndarray | None = None, unreachable: str = "raise"
    ) -> np.ndarray:
        """Readings q [rad] in [-pi, pi), (N,2) or (2,), that put J3 at x [m].

        beta_i = atan2(x - B_i) + s_i alpha_i, alpha_i the angle at B_i of the
        triangle (l_i, |x - B_i|, l_{i+2}); q_i = beta_i - offset_i.
        """
        _check_unreachable(unreachable)
        q, ok = self.ik_masked(x, mode)
        if unreachable == "raise" and not np.all(ok):
            xb, _ = _batch(x, "x")
            bad = np.flatnonzero(~np.atleast_1d(ok))
            rho = np.linalg.norm(
                xb[bad[0]] - np.array([[self.base1_x, self.base1_y], [self.base2_x, self.base2_y]]),
                axis=1,
            )
            raise UnreachableError(
                f"five-bar cannot reach point {bad[0]} (x = {_fmt(xb[bad[0]])} m): "
                f"distances to B1, B2 {_fmt(rho)} m must lie in "
                f"[{abs(self.l1 - self.l3):.6g}, {self.l1 + self.l3:.6g}] and "
                f"[{abs(self.l2 - self.l4):.6g}, {self.l2 + self.l4:.6g}] m; "
                f"{bad.size} of {xb.shape[0]} fail (unreachable='nan' gives NaN and a mask)"
            )
        return q

    def ik_with_passive(
        self, x: Any, mode: str | np.ndarray | None = None, unreachable: str = "raise"
    ) -> tuple[np.ndarray, np.ndarray]:
        """Readings q and absolute passive angles (beta3, beta4) [rad] that put J3 at x [m]."""
        q = self.ik(x, mode, unreachable)
        qb, single = _batch(q, "q")
        xb, _ = _batch(x, "x")
        passive = kin.passive(self.param_values, np.nan_to_num(qb), xb)
        passive = np.where(np.isnan(qb), np.nan, passive)
        return (q, passive[0]) if single else (q, passive)

    def _modes(self, mode: str | np.ndarray | None, n: int) -> np.ndarray:
        if mode is None:
            mode = self.working_mode
        if isinstance(mode, str):
            if mode not in kin.MODES:
                raise KincalError(
                    f"working mode must be one of {', '.join(kin.MODES)}, not {mode!r}"
                )
            return np.tile(kin.mode_signs(mode), (n, 1))
        modes = np.asarray(mode)
        if modes.shape not in ((n, 2), (2,)):
            raise KincalError(f"working modes must have shape (N, 2) or (2,), got {modes.shape}")
        return np.broadcast_to(np.where(modes >= 0, 1, -1), (n, 2))

    def _x_for(self, qb: np.ndarray, x: Any, assembly: int | str | None) -> np.ndarray:
        if x is None:
            return self.fk(qb, assembly)
        xb, _ = _batch(x, "x")
        return xb

    def passive_angles(
        self, q: Any, x: Any = None, assembly: int | str | None = None
    ) -> np.ndarray:
        """Absolute passive angles (beta3, beta4) [rad] of the distal links.

        ``J3 = J1 + l3 u(beta3) = J2 + l4 u(beta4)``; J3 is x when given, else
        FK(q, assembly).  The thesis's relative DH angle is beta3 - beta1.
        """
        qb, single = _batch(q, "q")
        out = kin.passive(self.param_values, qb, self._x_for(qb, x, assembly))
        return out[0] if single else out

    def configuration_signs(
        self, q: Any, x: Any = None, assembly: int | str | None = None
    ) -> tuple[np.ndarray, np.ndarray] | tuple[int, str]:
        """(assembly sigma (N,), working modes as strings (N,)) of configurations (q, J3)."""
        qb, single = _batch(q, "q")
        sigma, s = kin.signs(self.param_values, qb, self._x_for(qb, x, assembly))
        text = np.where(s > 0, "+", "-")
        modes = np.char.add(text[:, 0], text[:, 1])
        return (int(sigma[0]), str(modes[0])) if single else (sigma, modes)

    def singularity_measures(
        self, q: Any, x: Any = None, assembly: int | str | None = None
    ) -> dict[str, np.ndarray]:
        """``{"type1": (N,2) |sin(beta_{i+2} - beta_i)|, "type2": (N,) |sin(beta4 - beta3)|}``.

        Type 1 (inverse-kinematics) singularity: an arm stretched or folded,
        type1_i = 0.  Type 2 (direct-kinematics) singularity: the distal links
        aligned, type2 = 0.  Both are in [0, 1], 1 best.
        """
        qb, single = _batch(q, "q")
        t1, t2 = kin.singularity_measures(self.param_values, qb, self._x_for(qb, x, assembly))
        if single:
            return {"type1": t1[0], "type2": t2[0]}
        return {"type1": t1, "type2": t2}

    def singular(
        self, q: Any, x: Any = None, assembly: int | str | None = None, tol: float = 1e-3
    ) -> dict[str, np.ndarray]:
        """Boolean masks ``{"type1": (N,), "type2": (N,)}``: measure below ``tol``."""
        m = self.singularity_measures(q, x, assembly)
        return {"type1": np.min(m["type1"], axis=-1) < tol, "type2": m["type2"] < tol}


def _check_unreachable(unreachable: str) -> None:
    """``unreachable`` must say what to do with unreachable rows: 'raise' or 'nan'."""
    if unreachable not in ("raise", "nan"):
        raise KincalError(f"unreachable must be 'raise' or 'nan', not {unreachable!r}")
