"""The elementary-transform chain: one kinematic engine for every serial robot.

A serial robot is the product

    T(q) = E_1 E_2 ... E_K,     E_k = X_k(c_k + s_k q_{j(k)})

of elementary transforms ``X_k`` in {Rx, Ry, Rz, Tx, Ty, Tz}.  Each ``E_k`` has a
constant value ``c_k`` that is a *named parameter* of the robot (``theta_offset[2]``,
``d[3]``, ``base.x``, ``arm_3_joint.origin.y`` ...) and, when it is a joint, the joint
variable ``q_j`` times ``s_k = +-1`` (the joint axis direction).  DH, modified DH,
Hayati and URDF descriptions all compile to this sequence (see :mod:`kincal.robots.dh`
and :mod:`kincal.robots.urdf`); base and tool frames are ``Tx Ty Tz Rz Ry Rx`` at the two
ends.

Forward kinematics applies the transforms to a running frame ``(R, p)``: a rotation
mixes two columns of ``R``, a translation adds a column of ``R`` to ``p``; everything is
vectorised over the N configurations (the only Python loop runs over the K
transforms).

Derivatives need no differentiation.  Perturbing the value of ``E_k`` by ``dv`` moves
the end frame by the unit twist of ``E_k``'s axis ``a_k`` (a column of the running
rotation, in the base frame) placed at the running origin ``o_k``:

* rotation:    ``[dp; dphi] = [a_k x (p_end - o_k); a_k] dv``
* translation: ``[dp; dphi] = [a_k; 0] dv``

That gives the geometric Jacobian (joint values) and the parameter (identification)
Jacobian (constant values) from one pass.  Units: metres and radians throughout.
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.spatial import matrix_to_angles, rate_matrix

Array = NDArray[np.float64]

ROTATIONS = ("Rx", "Ry", "Rz")
TRANSLATIONS = ("Tx", "Ty", "Tz")
KINDS = ROTATIONS + TRANSLATIONS
_AXIS = {"Rx": 0, "Ry": 1, "Rz": 2, "Tx": 0, "Ty": 1, "Tz": 2}

#: Roles of parameters, used for staging (offsets first) and for simulated errors.
ROLES = ("base", "tool", "offset", "length", "angle")


@dataclass(frozen=True)
class ElementaryTransform:
    """One factor ``X(c + s q_j)`` of the chain.

    Attributes:
        kind: one of ``Rx Ry Rz Tx Ty Tz``.
        param: index of its constant value in the robot's parameter vector, or -1
            for a fixed constant that is not a parameter (e.g. an axis alignment).
        constant: the value used when ``param == -1`` [m or rad].
        joint: index of the joint variable added to it, or -1.
        scale: multiplier of the joint variable (+1 or -1: the axis direction).
    """

    kind: str
    param: int = -1
    constant: float = 0.0
    joint: int = -1
    scale: float = 1.0

    @property
    def is_rotation(self) -> bool:
        return self.kind in ROTATIONS


@dataclass(frozen=True)
class Joint:
    """A joint of the chain.

    Attributes:
        name: the user's name (``q1``, ``arm_3_joint``).
        kind: ``"revolute"`` (variable in rad) or ``"prismatic"`` (variable in m).
        lower, upper: joint limits [rad or m]; infinite when unlimited.
    """

    name: str
    kind: Literal["revolute", "prismatic"]
    lower: float = -np.inf
    upper: float = np.inf

    @property
    def unit(self) -> str:
        return "rad" if self.kind == "revolute" else "m"


@dataclass(frozen=True, eq=False)
class Robot:
    """An immutable serial robot: elementary transforms, named parameters, joints.

    Build robots with the front ends (:func:`kincal.robots.dh.from_dh`,
    :func:`kincal.robots.urdf.load_urdf`, :func:`kincal.robots.files.load_robot`) or
    with :class:`ChainBuilder`.  ``robot.with_params(...)`` returns a new robot.

    Attributes:
        name: display name.
        ets: the elementary transforms, base first, tool last.
        joints: the joints in the order of the configuration vector ``q``.
        param_names: one name per parameter (unique).
        param_values: the parameter vector [m / rad], read-only.
        param_units: ``"m"`` or ``"rad"`` per parameter.
        param_roles: one of :data:`ROLES` per parameter.
        meta: free-form description: ``source`` of the numbers, ``convention``, the
            front end's data needed to write the robot back in its own format.
    """

    name: str
    ets: tuple[ElementaryTransform, ...]
    joints: tuple[Joint, ...]
    param_names: tuple[str, ...]
    param_values: Array
    param_units: tuple[str, ...]
    param_roles: tuple[str, ...]
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        values = np.array(self.param_values, dtype=float).reshape(-1)
        values.setflags(write=False)
        object.__setattr__(self, "param_values", values)
        P = len(self.param_names)
        if not (len(values) == len(self.param_units) == len(self.param_roles) == P):
            raise ValueError("param_names, param_values, param_units and param_roles differ "
                             "in length")
        if len(set(self.param_names)) != P:
            dup = sorted({n for n in self.param_names if self.param_names.count(n) > 1})
            raise KincalError(f"robot {self.name!r}: duplicate parameter names {dup}")
        if not np.all(np.isfinite(values)):
            bad = [n for n, v in zip(self.param_names, values, strict=True) if not np.isfinite(v)]
            raise KincalError(f"robot {self.name!r}: parameter {bad[0]} is not finite")
        for et in self.ets:
            if et.kind not in KINDS:
                raise ValueError(f"unknown elementary transform {et.kind!r}")
            if et.param >= P or et.joint >= len(self.joints):
                raise ValueError("elementary transform refers to a missing parameter or joint")
        object.__setattr__(self, "_index", {n: i for i, n in enumerate(self.param_names)})
        # For each joint, the transform that carries it.
        carriers = [-1] * len(self.joints)
        for k, et in enumerate(self.ets):
            if et.joint >= 0:
                if carriers[et.joint] >= 0:
                    raise ValueError(f"joint {self.joints[et.joint].name} appears twice")
                carriers[et.joint] = k
                want = "revolute" if et.is_rotation else "prismatic"
                if self.joints[et.joint].kind != want:
                    raise ValueError(f"joint {self.joints[et.joint].name} is {want} in the chain")
        if -1 in carriers:
            raise ValueError(f"joint {self.joints[carriers.index(-1)].name} is not in the chain")

    # ------------------------------------------------------------------ basics
    @property
    def n(self) -> int:
        """Number of joints (degrees of freedom)."""
        return len(self.joints)

    @property
    def num_params(self) -> int:
        """Number of named parameters."""
        return len(self.param_names)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def joint_limits(self) -> Array:
        """(n, 2) array of [lower, upper] joint limits [rad or m]."""
        return np.array([[j.lower, j.upper] for j in self.joints], dtype=float)

    def param_index(self, name: str) -> int:
        """Index of the parameter ``name``; a clear error naming close matches if unknown."""
        try:
            return self._index[name]  # type: ignore[attr-defined]
        except KeyError:
            close = difflib.get_close_matches(name, self.param_names, n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise KincalError(f"robot {self.name!r} has no parameter {name!r}{hint}") from None

    def param_indices(self, names: Sequence[str] | None) -> NDArray[np.intp]:
        """Indices of several parameters (all when ``names`` is None)."""
        if names is None:
            return np.arange(self.num_params)
        return np.array([self.param_index(n) for n in names], dtype=np.intp)

    def params(self) -> dict[str, float]:
        """The parameters as an ordered ``{name: value}`` dict [m / rad]."""
        return dict(zip(self.param_names, self.param_values.tolist(), strict=True))

    def with_params(self, values: ArrayLike | Mapping[str, float]) -> Robot:
        """A new robot with some or all parameter values replaced.

        Args:
            values: a full parameter vector (length ``num_params``) or a mapping
                ``{name: value}`` for the parameters to change [m / rad].
        """
        new = np.array(self.param_values, dtype=float)
        if isinstance(values, Mapping):
            for k, v in values.items():
                new[self.param_index(k)] = float(v)
        else:
            arr = np.asarray(values, dtype=float).reshape(-1)
            if arr.shape != new.shape:
                raise KincalError(f"robot {self.name!r} has {self.num_params} parameters, "
                                  f"got a vector of {arr.size}")
            new = arr
        return replace(self, param_values=new)

    def with_name(self, name: str) -> Robot:
        return replace(self, name=name)

    def __repr__(self) -> str:
        kinds = "".join("R" if j.kind == "revolute" else "P" for j in self.joints)
        return (f"Robot({self.name!r}, {kinds}, {self.num_params} parameters, "
                f"{len(self.ets)} elementary transforms)")

    # ------------------------------------------------------------- evaluation
    def _check_q(self, q: ArrayLike) -> tuple[Array, bool]:
        q = np.asarray(q, dtype=float)
        single = q.ndim == 1
        q2 = np.atleast_2d(q)
        if q2.ndim != 2 or q2.shape[1] != self.n:
            raise KincalError(f"robot {self.name!r} has {self.n} joints; got configurations "
                              f"of shape {q.shape}")
        return q2, single

    def _values(self, q: Array) -> list[Array | float]:
        """Value of every elementary transform: a float, or (N,) when it carries a joint."""
        pv = self.param_values
        out: list[Array | float] = []
        for et in self.ets:
            c = pv[et.param] if et.param >= 0 else et.constant
            out.append(c + et.scale * q[:, et.joint] if et.joint >= 0 else float(c))
        return out

    def _sweep(self, q: Array, record: bool) -> tuple[list[Array], Array, list[tuple]]:
        """Run the chain over all configurations.

        Returns the end rotation columns ``[x, y, z]`` (each (3, N)), the end position
        (3, N) and, when ``record``, for every transform its (axis (3, N), origin (3, N)).
        """
        N = q.shape[0]
        cols = [np.zeros((3, N)) for _ in range(3)]
        for i in range(3):
            cols[i][i] = 1.0
        p = np.zeros((3, N))
        rec: list[tuple] = []
        for et, v in zip(self.ets, self._values(q), strict=True):
            ax = _AXIS[et.kind]
            if record:
                rec.append((cols[ax], p))
            if et.kind in ROTATIONS:
                if isinstance(v, float) and v == 0.0:
                    continue
                c, s = np.cos(v), np.sin(v)
                i, j = (ax + 1) % 3, (ax + 2) % 3
                ci, cj = cols[i], cols[j]
                cols[i] = c * ci + s * cj
                cols[j] = c * cj - s * ci
            else:
                if isinstance(v, float) and v == 0.0:
                    continue
                p = p + v * cols[ax]
        return cols, p, rec

    @staticmethod
    def _assemble(cols: list[Array], p: Array) -> Array:
        N = p.shape[1]
        T = np.empty((N, 4, 4))
        for i in range(3):
            T[:, :3, i] = cols[i].T
        T[:, :3, 3] = p.T
        T[:, 3, :3] = 0.0
        T[:, 3, 3] = 1.0
        return T

    def fk(self, q: ArrayLike) -> Array:
        """Forward kinematics ``T(q) = E_1 ... E_K``: (N, n) -> (N, 4, 4); (n,) -> (4, 4)."""
        q2, single = self._check_q(q)
        cols, p, _ = self._sweep(q2, record=False)
        T = self._assemble(cols, p)
        return T[0] if single else T

    def _twists(self, rec: list[tuple], p_end: Array, ks: Sequence[int]) -> Array:
        """Unit twists ``[dp; dphi]`` of transforms ``ks`` at the end point: (6, len(ks), N)."""
        N = p_end.shape[1]
        out = np.zeros((6, len(ks), N))
        rot = [c for c, k in enumerate(ks) if self.ets[k].is_rotation]
        tra = [c for c, k in enumerate(ks) if not self.ets[k].is_rotation]
        if rot:
            axes = np.stack([rec[ks[c]][0] for c in rot], 1)          # (3, R, N)
            arms = p_end[:, None, :] - np.stack([rec[ks[c]][1] for c in rot], 1)
            out[:3, rot] = np.cross(axes, arms, axis=0)
            out[3:, rot] = axes
        if tra:
            out[:3, tra] = np.stack([rec[ks[c]][0] for c in tra], 1)
        return out

    def _scatter(self, tw: Array, ks: Sequence[int], attr: str, width: int) -> Array:
        """Sum twists (6, K, N) into columns ``et.<attr>`` -> (N, 6, width)."""
        N = tw.shape[2]
        targets = [getattr(self.ets[k], attr) for k in ks]
        if attr == "joint":
            tw = tw * np.array([self.ets[k].scale for k in ks])[None, :, None]
        if targets == list(range(width)):
            return np.transpose(tw, (2, 0, 1))
        out = np.zeros((6, width, N))
        np.add.at(out, (slice(None), np.array(targets, dtype=np.intp)), tw)
        return np.transpose(out, (2, 0, 1))

    def fk_with_jacobians(
        self, q: ArrayLike, joints: bool = True, params: bool = True
    ) -> tuple[Array, Array | None, Array | None]:
        """Forward kinematics plus the geometric and parameter Jacobians in one pass.

        Returns ``(T, J, Jp)`` with ``T`` (N, 4, 4), ``J`` (N, 6, n) the geometric
        Jacobian in the base frame and ``Jp`` (N, 6, P) the parameter Jacobian
        ``d[p_end; phi_end] / d(param)`` in the base frame (rows vx vy vz wx wy wz;
        columns in ``param_names`` order).  Always batched (N >= 1).
        """
        q2, _ = self._check_q(q)
        cols, p, rec = self._sweep(q2, record=True)
        T = self._assemble(cols, p)
        J = Jp = None
        if joints:
            ks = [k for k, et in enumerate(self.ets) if et.joint >= 0]
            J = self._scatter(self._twists(rec, p, ks), ks, "joint", self.n)
        if params:
            ks = [k for k, et in enumerate(self.ets) if et.param >= 0]
            Jp = self._scatter(self._twists(rec, p, ks), ks, "param", self.num_params)
        return T, J, Jp

    def jacobian(self, q: ArrayLike, frame: Literal["base", "tool"] = "base") -> Array:
        """Geometric Jacobian ``[v; omega] = J(q) q_dot``: (N, 6, n), or (6, n) for (n,).

        ``frame="base"``: velocity of the tool origin and angular velocity in the base
        frame.  ``frame="tool"``: the same two vectors expressed in the tool frame,
        ``J_e = diag(R^T, R^T) J_0``.
        """
        q2, single = self._check_q(q)
        T, J, _ = self.fk_with_jacobians(q2, joints=True, params=False)
        if frame == "tool":
            J = _to_tool_frame(T, J)
        elif frame != "base":
            raise KincalError(f"unknown Jacobian frame {frame!r}; use 'base' or 'tool'")
        return J[0] if single else J

    def jacobian_analytic(self, q: ArrayLike, representation: Literal["zyz", "rpy"] = "zyz"
                          ) -> Array:
        """Analytic Jacobian ``[p_dot; phi_dot] = J_A(q) q_dot`` for minimal angles ``phi``.

        ``J_A = diag(I, E(phi)^-1) J_0`` with ``omega = E(phi) phi_dot`` (see
        :func:`kincal.spatial.rate_matrix`); ``phi`` are the ZYZ Euler angles or
        roll-pitch-yaw of the end frame.  Raises a :class:`KincalError` at a
        representation singularity (ZYZ: theta = 0 or pi; RPY: pitch = +-pi/2).
        """
        q2, single = self._check_q(q)
        T, J, _ = self.fk_with_jacobians(q2, joints=True, params=False)
        angles = matrix_to_angles(T[:, :3, :3], representation)
        E = rate_matrix(angles, representation)
        det = np.abs(np.linalg.det(E))
        if np.any(det < 1e-10):
            i = int(np.argmin(det))
            raise KincalError(f"the {representation.upper()} angles are singular at configuration "
                              f"{i} (angles {np.round(angles[i], 6).tolist()} rad); use the "
                              "geometric Jacobian there")
        JA = J.copy()
        JA[:, 3:, :] = np.linalg.solve(E, J[:, 3:, :])
        return JA[0] if single else JA

    def param_jacobian(self, q: ArrayLike, names: Sequence[str] | None = None) -> Array:
        """Identification Jacobian ``d[p; phi]/d(param)`` in the base frame.

        (N, n) -> (N, 6, P) (or (6, P) for (n,)), columns for ``names`` (all
        parameters by default), computed analytically from unit twists.
        """
        q2, single = self._check_q(q)
        _, _, Jp = self.fk_with_jacobians(q2, joints=False, params=True)
        if names is not None:
            Jp = Jp[:, :, self.param_indices(names)]
        return Jp[0] if single else Jp

    def frames(self, q: ArrayLike) -> Array:
        """Frames after every joint (for plotting): (N, n + 2, 4, 4) base, joints, tool."""
        q2, single = self._check_q(q)
        N = q2.shape[0]
        out = np.zeros((N, self.n + 2, 4, 4))
        out[:, :, 3, 3] = 1.0
        cols = [np.zeros((3, N)) for _ in range(3)]
        for i in range(3):
            cols[i][i] = 1.0
        p = np.zeros((3, N))
        slot = 0
        first_joint = min(k for k, et in enumerate(self.ets) if et.joint >= 0) if self.n else 0
        for k, (et, v) in enumerate(zip(self.ets, self._values(q2), strict=True)):
            if k == first_joint:
                out[:, 0] = self._assemble(cols, p)
            ax = _AXIS[et.kind]
            if et.kind in ROTATIONS:
                c, s = np.cos(v), np.sin(v)
                i, j = (ax + 1) % 3, (ax + 2) % 3
                cols[i], cols[j] = c * cols[i] + s * cols[j], c * cols[j] - s * cols[i]
            else:
                p = p + v * cols[ax]
            if et.joint >= 0:
                slot += 1
                out[:, slot] = self._assemble(cols, p)
        out[:, -1] = self._assemble(cols, p)
        return out[0] if single else out


def _to_tool_frame(T: Array, J: Array) -> Array:
    """Express base-frame Jacobian rows in the tool frame: ``diag(R^T, R^T) J``."""
    Rt = np.swapaxes(T[:, :3, :3], 1, 2)
    out = np.empty_like(J)
    out[:, :3] = Rt @ J[:, :3]
    out[:, 3:] = Rt @ J[:, 3:]
    return out


# ---------------------------------------------------------------------------
# Building chains


FRAME_FIELDS = ("x", "y", "z", "rx", "ry", "rz")


class ChainBuilder:
    """Accumulates elementary transforms, parameters and joints, then builds a Robot.

    Example::

        b = ChainBuilder("arm")
        b.frame("base", [0, 0, 0, 0, 0, 0])
        j = b.joint("q1", "revolute", -3, 3)
        b.transform("Rz", "theta_offset[1]", 0.0, role="offset", joint=j)
        ...
        b.frame("tool", [0, 0, 0.1, 0, 0, 0])
        robot = b.build(meta={...})
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self.ets: list[ElementaryTransform] = []
        self.joints: list[Joint] = []
        self.names: list[str] = []
        self.values: list[float] = []
        self.units: list[str] = []
        self.roles: list[str] = []

    def parameter(self, name: str, value: float, unit: str, role: str) -> int:
        """Add a named parameter and return its index."""
        if name in self.names:
            raise KincalError(f"robot {self.name!r}: parameter {name!r} defined twice")
        if role not in ROLES:
            raise ValueError(f"unknown parameter role {role!r}")
        self.names.append(name)
        self.values.append(float(value))
        self.units.append(unit)
        self.roles.append(role)
        return len(self.names) - 1

    def joint(self, name: str, kind: str, lower: float = -np.inf, upper: float = np.inf) -> int:
        """Add a joint and return its index (attach it with ``transform(..., joint=j)``)."""
        if kind not in ("revolute", "prismatic"):
            raise KincalError(f"robot {self.name!r}: joint {name!r} has unknown type {kind!r}")
        if any(j.name == name for j in self.joints):
            raise KincalError(f"robot {self.name!r}: joint {name!r} defined twice")
        self.joints.append(Joint(name, kind, float(lower), float(upper)))  # type: ignore[arg-type]
        return len(self.joints) - 1

    def transform(self, kind: str, name: str | None, value: float, role: str = "length",
                  joint: int = -1, scale: float = 1.0) -> None:
        """Append ``kind(value + scale q_joint)``; ``name=None`` makes it a fixed constant."""
        unit = "rad" if kind in ROTATIONS else "m"
        if name is None:
            self.ets.append(ElementaryTransform(kind, -1, float(value), joint, scale))
        else:
            k = self.parameter(name, value, unit, role)
            self.ets.append(ElementaryTransform(kind, k, 0.0, joint, scale))

    def frame(self, prefix: str, xyzrpy: Sequence[float] = (0, 0, 0, 0, 0, 0),
              role: str | None = None) -> None:
        """Append a 6-parameter frame ``Tx Ty Tz Rz Ry Rx`` named ``prefix.x`` ... ``prefix.rz``.

        The rotation is roll-pitch-yaw: ``Rz(rz) Ry(ry) Rx(rx)`` (URDF order).
        """
        x, y, z, rx, ry, rz = (float(v) for v in xyzrpy)
        role = role or ("base" if prefix == "base" else "tool" if prefix == "tool" else "length")
        for kind, fld, v in (("Tx", "x", x), ("Ty", "y", y), ("Tz", "z", z),
                             ("Rz", "rz", rz), ("Ry", "ry", ry), ("Rx", "rx", rx)):
            self.transform(kind, f"{prefix}.{fld}", v, role=role)

    def build(self, meta: Mapping[str, Any] | None = None) -> Robot:
        return Robot(self.name, tuple(self.ets), tuple(self.joints), tuple(self.names),
                     np.array(self.values), tuple(self.units), tuple(self.roles),
                     dict(meta or {}))
