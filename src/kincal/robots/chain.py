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
vectorised over the N configurations.  For speed, each robot compiles its chain once
(:class:`_Plan`): the constant transforms between two joints are multiplied into one
4x4 block, applied as a single matrix product, and the configurations are processed in
blocks of a few thousand so that the temporaries stay in the CPU caches (the Python
loops run over the joints and over those blocks, never over configurations).

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
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property, lru_cache
from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.robots.workspace import ChainWorkspace
from kincal.spatial import FRAME_FIELDS, matrix_to_angles, rate_matrix

Array = NDArray[np.float64]

__all__ = ["ROTATIONS", "TRANSLATIONS", "KINDS", "ROLES", "ElementaryTransform", "Joint", "Robot",
           "ChainBuilder", "ChainWorkspace", "elementary_matrix"]

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
    :func:`kincal.robots.urdf.load_urdf`, :func:`kincal.robots.files.load_serial_robot`) or
    with :class:`ChainBuilder`.  ``robot.with_params(...)`` returns a new robot.

    The kernel's interface (everything else in this module is private):

    * :meth:`fk` ``T(q)``; :meth:`jacobian` the geometric Jacobian (base or tool frame);
      :meth:`param_jacobian` ``d[p; phi]/d(param)``; :meth:`fk_with_jacobians` all three
      from one pass; :meth:`point_jacobian` points on the tool and their parameter
      Jacobian, configurations last (the fast path of the measurement blocks);
    * :meth:`with_params` a robot with other parameter values (the compiled chain's
      shape is shared, only the numbers are compiled again); :meth:`frame_parameters`
      the 6 values of the base or tool frame in :data:`kincal.spatial.FRAME_FIELDS`
      order; :meth:`params`, :meth:`param_index`, :meth:`param_indices`.

    Like Pinocchio's ``Model`` and ``Data``, the robot is the immutable model (shareable
    between threads) and the working memory is separate: the evaluation methods take
    a :class:`~kincal.robots.workspace.ChainWorkspace` owned by a caller that evaluates
    repeatedly (a fresh one per call by default).  A workspace is never shared between
    threads.  The checks in ``tests/test_kernel_reference.py`` hold the tuned kernel to
    a ten-line reference forward kinematics and parameter Jacobian.

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
            return self._index[name]
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
        return self._with_values(new)

    def _with_values(self, values: Array) -> Robot:
        """This robot with the parameter vector ``values``: the chain's shape, names and
        checks carried over (only the numbers are new, so only they are checked)."""
        vals = np.array(values, dtype=float).reshape(-1)
        if vals.shape != self.param_values.shape:
            raise ValueError("param_values has the wrong length")
        if not np.all(np.isfinite(vals)):
            bad = [n for n, v in zip(self.param_names, vals, strict=True) if not np.isfinite(v)]
            raise KincalError(f"robot {self.name!r}: parameter {bad[0]} is not finite")
        vals.setflags(write=False)
        out = object.__new__(type(self))
        out.__dict__.update({k: v for k, v in self.__dict__.items() if k != "_plan"})
        object.__setattr__(out, "param_values", vals)
        if "calibration" in self.meta and not np.array_equal(vals, self.param_values):
            # a calibration envelope describes these values only (kincal.identify.envelope)
            object.__setattr__(out, "meta", {k: v for k, v in self.meta.items()
                                             if k not in ("calibration", "calibration_source")})
        return out

    def frame_parameters(self, prefix: str) -> Array:
        """The 6 values ``(x, y, z, rz, ry, rx)`` [m, rad] of the frame ``prefix`` (``"base"``,
        ``"tool"``), in :data:`kincal.spatial.FRAME_FIELDS` order (the order
        :meth:`ChainBuilder.frame` and :func:`kincal.robots.dh.from_dh` take)."""
        return np.array([self.param_values[self.param_index(f"{prefix}.{f}")]
                         for f in FRAME_FIELDS])

    def with_name(self, name: str) -> Robot:
        return replace(self, name=name)

    def __repr__(self) -> str:
        kinds = "".join("R" if j.kind == "revolute" else "P" for j in self.joints)
        return (f"Robot({self.name!r}, {kinds}, {self.num_params} parameters, "
                f"{len(self.ets)} elementary transforms)")

    def _repr_html_(self) -> str:
        """The robot in a notebook: its joints with their limits (deg, mm), then its
        parameters with values in mm / deg, units and roles (folded)."""
        from html import escape

        def shown(value: float, unit: str) -> str:
            if not np.isfinite(value):
                return "-"
            return f"{np.degrees(value):.4g} deg" if unit == "rad" else f"{value * 1e3:.4g} mm"

        joints = "".join(f"<tr><td>{escape(j.name)}</td><td>{j.kind}</td>"
                         f"<td>{shown(j.lower, j.unit)}</td><td>{shown(j.upper, j.unit)}</td>"
                         "</tr>" for j in self.joints)
        params = "".join(f"<tr><td>{escape(n)}</td><td>{shown(float(v), u)}</td>"
                         f"<td>{escape(r)}</td></tr>"
                         for n, v, u, r in zip(self.param_names, self.param_values,
                                               self.param_units, self.param_roles,
                                               strict=True))
        return (f"<table><caption style='text-align:left'><b>Robot {escape(self.name)}</b>"
                f" ({self.n} joints)</caption><tr><th>joint</th><th>kind</th>"
                f"<th>lower</th><th>upper</th></tr>{joints}</table><details><summary>"
                f"{self.num_params} parameters</summary><table><tr><th>parameter</th>"
                f"<th>value</th><th>role</th></tr>{params}</table></details>")

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

    @cached_property
    def _index(self) -> dict[str, int]:
        """Position of each parameter name (set in ``__post_init__``)."""
        return {n: i for i, n in enumerate(self.param_names)}

    @cached_property
    def _structure(self) -> _Structure:
        """The chain's shape, compiled (shared with the robots :meth:`with_params` makes)."""
        return _Structure(self)

    @cached_property
    def _plan(self) -> _Plan:
        """The chain compiled for batched evaluation (built on first use, per robot)."""
        return _Plan(self, self._structure)

    def fk(self, q: ArrayLike, workspace: ChainWorkspace | None = None) -> Array:
        """Forward kinematics ``T(q) = E_1 ... E_K``: (N, n) -> (N, 4, 4); (n,) -> (4, 4).

        ``workspace``: the caller's working memory when it evaluates repeatedly
        (:class:`~kincal.robots.workspace.ChainWorkspace`); default a fresh one.
        """
        q2, single = self._check_q(q)
        T, _, _ = self._plan.evaluate(q2, False, False, workspace or ChainWorkspace())
        return T[0] if single else T

    def fk_with_jacobians(
        self, q: ArrayLike, joints: bool = True, params: bool = True,
        workspace: ChainWorkspace | None = None
    ) -> tuple[Array, Array | None, Array | None]:
        """Forward kinematics plus the geometric and parameter Jacobians in one pass.

        Returns ``(T, J, Jp)`` with ``T`` (N, 4, 4), ``J`` (N, 6, n) the geometric
        Jacobian in the base frame and ``Jp`` (N, 6, P) the parameter Jacobian
        ``d[p_end; phi_end] / d(param)`` in the base frame (rows vx vy vz wx wy wz;
        columns in ``param_names`` order).  Always batched (N >= 1).  ``J`` is None
        unless ``joints``, ``Jp`` None unless ``params``.  ``workspace``: the caller's
        working memory (:class:`~kincal.robots.workspace.ChainWorkspace`; default a
        fresh one); the results never live in it.
        """
        q2, _ = self._check_q(q)
        return self._plan.evaluate(q2, joints, params, workspace or ChainWorkspace())

    def jacobian(self, q: ArrayLike, frame: Literal["base", "tool"] = "base",
                 workspace: ChainWorkspace | None = None) -> Array:
        """Geometric Jacobian ``[v; omega] = J(q) q_dot``: (N, 6, n), or (6, n) for (n,).

        ``frame="base"``: velocity of the tool origin and angular velocity in the base
        frame.  ``frame="tool"``: the same two vectors expressed in the tool frame,
        ``J_e = diag(R^T, R^T) J_0``.  ``workspace`` as in :meth:`fk_with_jacobians`.
        """
        q2, single = self._check_q(q)
        T, J, _ = self.fk_with_jacobians(q2, joints=True, params=False, workspace=workspace)
        assert J is not None
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
        assert J is not None
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

    def param_jacobian(self, q: ArrayLike, names: Sequence[str] | None = None,
                       workspace: ChainWorkspace | None = None) -> Array:
        """Identification Jacobian ``d[p; phi]/d(param)`` in the base frame.

        (N, n) -> (N, 6, P) (or (6, P) for (n,)), columns for ``names`` (all
        parameters by default), computed analytically from unit twists.  ``workspace``
        as in :meth:`fk_with_jacobians`.
        """
        q2, single = self._check_q(q)
        _, _, Jp = self.fk_with_jacobians(q2, joints=False, params=True, workspace=workspace)
        assert Jp is not None
        if names is not None:
            Jp = Jp[:, :, self.param_indices(names)]
        return Jp[0] if single else Jp

    def point_jacobian(self, q: ArrayLike, points: ArrayLike, left: ArrayLike | None = None,
                       columns: Sequence[int] | None = None, rotation: bool = False,
                       out: tuple[Array, Array, Array | None] | None = None,
                       workspace: ChainWorkspace | None = None
                       ) -> tuple[Array, Array, Array | None]:
        """Points fixed on the tool and their parameter Jacobian, configurations last.

        ``y_k(q) = H T(q) m_k`` for the points ``m_k`` (K, 3) in the tool frame [m] and
        a constant frame ``H`` (4, 4) in front of the chain (``left``, e.g. the inverse
        of an instrument's frame; default identity).  The derivative with respect to
        parameter ``c`` is the unit twist of its transform evaluated at the point,
        ``a x (y_k - o)`` for a rotation and ``a`` for a translation (axis ``a`` and
        origin ``o`` in ``H``'s frame): one chain pass gives the points and only the
        parameter columns asked for, without the 6-row parameter Jacobian.

        Args:
            q: (N, n) configurations.
            points: (K, 3) (or (3,)) points in the tool frame [m].
            left: the frame ``H``; default identity.
            columns: parameter indices of the Jacobian columns (default all).
            rotation: also return the tool rotation.
            out: arrays ``(Y, D, Rot)`` of the shapes below to write the results into
                (``Rot`` None when not ``rotation``), e.g. working arrays reused from
                call to call; default fresh ones.
            workspace: the caller's working memory for the chain's temporaries
                (:class:`~kincal.robots.workspace.ChainWorkspace`, reused between
                calls; default a fresh one).  ``out`` may be arrays of the same
                workspace under other names.

        Returns:
            ``Y`` (K, 3, N) [m], ``D`` (C, K, 3, N) with ``D[j, k, i, l] = d y_{l,k,i} /
            d param_{columns[j]}`` [m/m or m/rad], and ``Rot`` (3, 3, N) with
            ``Rot[c, i, l] = (R_H R_e(q_l))[i, c]`` (or None).  This layout (the
            configuration index last) lets a least-squares solver take whole columns.
        """
        q2, _ = self._check_q(q)
        m = np.asarray(points, dtype=float).reshape(-1, 3)
        cols = tuple(range(self.num_params)) if columns is None else \
            tuple(int(c) for c in columns)
        return self._plan.points(q2, m, None if left is None else np.asarray(left, float),
                                 cols, rotation, out, workspace or ChainWorkspace())

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
# Batched evaluation


#: Working memory per block of configurations [bytes]: blocks of a few thousand
#: configurations keep the temporaries in the CPU caches and amortise the Python
#: overhead (a performance setting only; the results do not depend on it).
_BLOCK_BYTES = 1 << 23
_BLOCK_MIN, _BLOCK_MAX = 512, 8192


def elementary_matrix(kind: str, v: float) -> Array:
    """4x4 homogeneous matrix of one elementary transform with value ``v``."""
    T = np.eye(4)
    ax = _AXIS[kind]
    if kind in ROTATIONS:
        c, s = math.cos(v), math.sin(v)
        i, j = (ax + 1) % 3, (ax + 2) % 3
        T[i, i] = T[j, j] = c
        T[j, i], T[i, j] = s, -s
    else:
        T[ax, 3] = v
    return T


class _ColumnRows(NamedTuple):
    """The parameter rows of one set of Jacobian columns (:meth:`_Structure.selection`).

    Attributes:
        n: how many rows belong to the columns.
        dest: (n,) the column each row's derivative goes to.
        direct: rows and columns coincide (row k is column k).
        pre: the rows before the first joint (constant axis and origin).
        groups: per joint frame ``m``: ``(m, the rows' slice among the n, their indices
            among all the chain's rows)``.
    """

    n: int
    dest: NDArray[np.intp]
    direct: bool
    pre: NDArray[np.intp]
    groups: list[tuple[int, slice, NDArray[np.intp]]]


class _PointRows(NamedTuple):
    """:class:`_ColumnRows` with the numbers :meth:`_Plan.points` needs (per plan).

    Attributes:
        n, dest, direct: as in :class:`_ColumnRows`.
        pre: the number of rows before the first joint.
        pre_ax, pre_org: (pre, 3) their axes and origins; pre_rot: (pre,) rotation or not.
        groups: per joint frame ``m``: ``(m, rows' slice, C (k, 6))`` with ``C`` the
            coefficients of the rows' derivatives (see :meth:`_Plan.points`).
    """

    n: int
    dest: NDArray[np.intp]
    direct: bool
    pre: int
    pre_ax: Array
    pre_org: Array
    pre_rot: NDArray[np.bool_]
    groups: list[tuple[int, slice, Array]]


class _BlockStep(NamedTuple):
    """How a constant block ``G`` is applied to the running frame (:func:`_block_step`).

    Attributes:
        kind: ``"identity"`` (nothing), ``"shift"`` (a translation: ``p <- p + v x_i``
            for each ``(i, v)`` of ``shifts``) or ``"matrix"`` (``F <- matrix F``, the
            transposed 4x4 of ``G``).
    """

    kind: Literal["identity", "shift", "matrix"]
    matrix: Array | None = None
    shifts: tuple[tuple[int, float], ...] = ()


class _Structure:
    """What a compiled chain (:class:`_Plan`) takes from the chain's *shape* alone.

    Which transforms carry joints, which carry parameters, the parameter rows in chain
    order grouped by the joint frame they follow, and the rows :meth:`_Plan.points`
    needs per set of columns.  None of it depends on the parameter values, so a robot
    made by :meth:`Robot.with_params` shares its parent's (a calibration compiles the
    chain at every trial point; only the numbers are computed again).
    """

    def __init__(self, robot: Robot) -> None:
        ets = robot.ets
        self.carriers = [k for k, et in enumerate(ets) if et.joint >= 0]
        self.bounds = self.carriers + [len(ets)]
        self.n, self.P = robot.n, robot.num_params
        self.J = len(self.carriers)
        cj = [ets[k] for k in self.carriers]
        self.axes = np.array([_AXIS[et.kind] for et in cj], dtype=np.intp)
        self.rot = np.array([et.is_rotation for et in cj], dtype=bool)
        self.all_rot = bool(self.rot.all())
        self.joint_of = np.array([et.joint for et in cj], dtype=np.intp)
        self.scales = np.array([et.scale for et in cj], dtype=float)
        self.negative = np.flatnonzero(self.scales != 1.0)
        self.in_joint_order = bool(np.array_equal(self.joint_of, np.arange(self.J)))
        self.same_axis = bool(self.J and np.all(self.axes == self.axes[0]))
        # parameter rows: the transforms with a parameter, in chain order, with the frame
        # they are measured from (-1: the constant prefix, m: joint m's frame)
        first = self.bounds[0]
        group = []
        m = -1
        for k, et in enumerate(ets):
            if et.joint >= 0:
                m += 1
            if et.param >= 0:
                group.append(-1 if k < first else m)
        pk = [k for k, et in enumerate(ets) if et.param >= 0]
        self.R = len(pk)
        self.rows_rot = np.array([ets[k].is_rotation for k in pk], dtype=bool)
        self.rows_tra = np.flatnonzero(~self.rows_rot)
        self.row_param = np.array([ets[k].param for k in pk], dtype=np.intp)
        self.rows_are_params = bool(np.array_equal(self.row_param, np.arange(self.P)))
        self.rows_unique = len(set(self.row_param.tolist())) == self.R
        g = np.array(group, dtype=np.intp)
        self.pre = np.flatnonzero(g == -1)
        self.groups: list[tuple[int, slice, NDArray[np.intp]]] = []
        for j in range(self.J):
            idx = np.flatnonzero(g == j)
            if len(idx):
                self.groups.append((j, slice(int(idx[0]), int(idx[-1]) + 1), idx))
        self.rows_rot_idx = np.flatnonzero(self.rows_rot)
        self.selections: dict[tuple[int, ...], _ColumnRows] = {}

    def selection(self, columns: tuple[int, ...]) -> _ColumnRows:
        """The rows of the parameters ``columns`` (kept per column set): in chain order,
        where each one's derivative goes, the constant-prefix rows, and per joint frame
        the rows that follow it (see :meth:`_Plan.points`)."""
        sel = self.selections.get(columns)
        if sel is not None:
            return sel
        pos = {c: k for k, c in enumerate(columns)}
        rows = [r for r in range(self.R) if int(self.row_param[r]) in pos]
        dest = np.array([pos[int(self.row_param[r])] for r in rows], dtype=np.intp)
        where = {r: k for k, r in enumerate(rows)}
        pre = np.array([r for r in self.pre.tolist() if r in where], dtype=np.intp)
        groups: list[tuple[int, slice, NDArray[np.intp]]] = []
        for m, rs, _ in self.groups:
            idx = np.array([r for r in range(rs.start, rs.stop) if r in where], dtype=np.intp)
            if not idx.size:
                continue
            k0 = where[int(idx[0])]
            groups.append((m, slice(k0, k0 + idx.size), idx))
        sel = _ColumnRows(len(rows), dest, bool(np.array_equal(dest, np.arange(len(columns)))),
                          pre, groups)
        self.selections[columns] = sel
        return sel


@lru_cache(maxsize=64)
def _block_layout(L: int, J: int, R: int, record: bool
                  ) -> tuple[int, tuple[tuple[str, int, int, tuple[int, ...]], ...]]:
    """Where each working array of a block of ``L`` configurations lies in one flat
    array: ``(total size, ((name, offset, size, shape), ...))``; the parameter rows'
    arrays only when ``R`` (their number) is not 0."""
    shapes: dict[str, tuple[int, ...]] = {
        "t1": (3, L), "t2": (3, L), "V": (J, L), "cos": (J, L), "sin": (J, L)}
    if record:
        shapes.update(S=(J + 1, 4, 3, L), D=(J, 3, L), tmp=(J, L), Jb=(6, J, L))
    else:
        shapes.update(X=(4, 3, L), Y=(4, 3, L))
    if R:
        shapes.update(AX=(R, 3, L), OR=(R, 3, L), TW=(6, R, L), tmpR=(R, L))
    layout, o = [], 0
    for name, shape in shapes.items():
        n = math.prod(shape)
        layout.append((name, o, n, shape))
        o += n
    return o, tuple(layout)


def _constant_run(ets: Sequence[ElementaryTransform], value: list[float], start: int,
                  stop: int, axes: list[list[float]], origins: list[list[float]]
                  ) -> list[list[float]]:
    """The product ``G`` of the constant transforms ``start .. stop - 1`` as three rows
    of four floats (the last row of a homogeneous matrix is ``0 0 0 1``), appending the
    axis and origin (homogeneous 4-vectors in the frame at ``start``) of each one that is
    a parameter, at the point where it acts.

    Plain floats: a rotation mixes two columns of ``G``, a translation adds a column to
    its origin, the arithmetic of :meth:`_Plan._sweep` on a single frame (compiling a
    chain is then a few microseconds per transform, not a 4x4 product each).
    """
    G = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
    for k in range(start, stop):
        et = ets[k]
        ax = _AXIS[et.kind]
        if et.param >= 0:
            axes.append([G[0][ax], G[1][ax], G[2][ax], 0.0])
            origins.append([G[0][3], G[1][3], G[2][3], 1.0])
        v = value[k]
        if et.kind in ROTATIONS:
            c, s = math.cos(v), math.sin(v)
            i, j = (ax + 1) % 3, (ax + 2) % 3
            for row in G:
                a, b = row[i], row[j]
                row[i] = c * a + s * b
                row[j] = c * b - s * a
        else:
            for row in G:
                row[3] += v * row[ax]
    return G


def _block_step(G: list[list[float]]) -> _BlockStep:
    """How to apply the constant block ``G`` (three rows of a 4x4) to the running frame."""
    rot = [row[:3] for row in G]
    shift = [row[3] for row in G]
    if rot == [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]:
        if shift == [0.0, 0.0, 0.0]:
            return _BlockStep("identity")
        return _BlockStep("shift", shifts=tuple((i, v) for i, v in enumerate(shift) if v != 0.0))
    return _BlockStep("matrix", np.ascontiguousarray(np.array(G + [[0.0, 0.0, 0.0, 1.0]]).T))


class _Plan:
    """A robot's chain compiled for batched evaluation.

    The chain is ``P E_1 C_1 E_2 C_2 ... E_J C_J``: ``E_m`` the elementary transforms
    that carry a joint, ``P`` and ``C_m`` the products of the constant transforms
    between them (4x4, computed once here).  A block of configurations holds the running
    frame as ``F`` (4, 3, L): its three rotation columns and its origin, each a 3-vector
    per configuration.  A joint rotation mixes two of the columns, a joint translation adds
    a column to the origin, and a constant block is one matrix product ``F <- C^T F``
    (``F`` flattened to (4, 3L)).

    Jacobians come from the frame ``S_m`` just after each joint: the frame at any
    elementary transform ``k`` of the block that follows joint ``m`` is ``S_m G_k`` with
    ``G_k`` the constant product between them, so its axis and origin are the fixed
    combinations ``S_m G_k[:, axis]`` and ``S_m G_k[:, 3]`` of ``S_m``'s four columns,
    again a matrix product for all the transforms of a block at once.

    The chain's shape (:class:`_Structure`) is shared by the robots that differ only in
    their parameter values; the numbers are computed here.
    """

    def __init__(self, robot: Robot, structure: _Structure) -> None:
        ets = robot.ets
        st = self.st = structure
        pv = robot.param_values.tolist()
        value = [pv[et.param] if et.param >= 0 else et.constant for et in ets]
        # the shape's numbers the hot loops read, as attributes of the plan
        self.n: int = st.n
        self.P: int = st.P
        self.J: int = st.J
        self.R: int = st.R
        self.axes: NDArray[np.intp] = st.axes
        self.rot: NDArray[np.bool_] = st.rot
        self.all_rot: bool = st.all_rot
        self.joint_of: NDArray[np.intp] = st.joint_of
        self.scales: Array = st.scales
        self.negative: NDArray[np.intp] = st.negative
        self.in_joint_order: bool = st.in_joint_order
        self.same_axis: bool = st.same_axis
        self.rows_rot: NDArray[np.bool_] = st.rows_rot
        self.rows_tra: NDArray[np.intp] = st.rows_tra
        self.row_param: NDArray[np.intp] = st.row_param
        self.rows_are_params: bool = st.rows_are_params
        self.rows_unique: bool = st.rows_unique
        self._selections: dict[tuple[int, ...], _PointRows] = {}
        # rows: axis and origin of every parameter's transform (homogeneous), in the
        # frame of the constant prefix (prefix rows) or of the joint before it
        u_ax: list[list[float]] = []
        u_org: list[list[float]] = []
        prefix = _constant_run(ets, value, 0, st.bounds[0], u_ax, u_org)
        self.prefix = np.array(prefix).T[:, :, None].copy()               # (4, 3, 1)
        self.posts: list[_BlockStep] = []
        offsets = []
        for m, k in enumerate(st.carriers):
            et = ets[k]
            if et.param >= 0:
                ax = _AXIS[et.kind]
                u_ax.append([1.0 if c == ax else 0.0 for c in range(4)])
                u_org.append([0.0, 0.0, 0.0, 1.0])
            self.posts.append(_block_step(_constant_run(ets, value, k + 1, st.bounds[m + 1],
                                                        u_ax, u_org)))
            offsets.append(value[k])
        self.offsets = np.array(offsets, dtype=float)
        self.identity_q = bool(np.all(self.scales == 1.0) and np.all(self.offsets == 0.0))
        UA = np.array(u_ax, dtype=float).reshape(-1, 4)
        UO = np.array(u_org, dtype=float).reshape(-1, 4)
        # constant prefix rows: axis and origin are fixed vectors
        self.pre_rows = slice(0, len(st.pre))
        self.pre_ax = UA[st.pre, :3][:, :, None]
        self.pre_org = UO[st.pre, :3][:, :, None]
        self.groups = [(m, rs, np.ascontiguousarray(UA[idx]), np.ascontiguousarray(UO[idx]))
                       for m, rs, idx in st.groups]
        # each row's derivative at a point y in its joint's frame (S_0 S_1 S_2 p_m):
        # a x (y - o) = sum_c A_c [S_c x (y - p_m)] - sum_c (A x O)_c S_c (see points)
        C6 = self.C6 = np.zeros((self.R, 6))
        rot, tra = st.rows_rot_idx, self.rows_tra
        a, o = UA[rot], UO[rot]
        C6[rot, :3] = a[:, :3]
        for i in range(3):                          # -(a x o)_i
            j, k = (i + 1) % 3, (i + 2) % 3
            C6[rot, 3 + i] = a[:, k] * o[:, j] - a[:, j] * o[:, k]
        C6[tra, 3:] = UA[tra, :3]

    # ------------------------------------------------------------------ sweep
    def _block_size(self, N: int, joints: bool, params: bool) -> int:
        """Configurations per block: the block's arrays fit in ``_BLOCK_BYTES``."""
        per = 8 * (12 * 2 + 6 + 3 * self.J)                   # frames, temporaries, trig
        if joints or params:
            per += 8 * (12 * self.J + 10 * self.J)             # joint frames, Jacobian block
        if params:
            per += 8 * 16 * self.R                             # axes, arms, twists
        L = 1 << max((_BLOCK_BYTES // per).bit_length() - 1, 0)
        return max(1, min(N, max(_BLOCK_MIN, min(_BLOCK_MAX, L))))

    def _joint_values(self, q: Array, sl: slice, V: Array) -> Array:
        """Joint transform values ``c_m + s_m q_j`` of a block into ``V`` (J, L), chain order."""
        np.copyto(V, (q[sl] if self.in_joint_order else q[sl][:, self.joint_of]).T)
        if not self.identity_q:
            V *= self.scales[:, None]
            V += self.offsets[:, None]
        return V

    def evaluate(self, q: Array, joints: bool, params: bool, workspace: ChainWorkspace
                 ) -> tuple[Array, Array | None, Array | None]:
        """Frames (N, 4, 4) and, when asked, the geometric (N, 6, n) and parameter
        (N, 6, P) Jacobians of the configurations ``q`` (N, n), block by block; the
        temporaries come from ``workspace``."""
        N = q.shape[0]
        record = joints or params
        # Jacobians are stored (6, columns, N) and returned as (N, 6, columns) views: every
        # block then writes whole rows, never a transposed copy
        T = np.empty((N, 4, 4))
        J = np.empty((6, self.n, N)) if joints else None
        Jp = np.empty((6, self.P, N)) if params else None
        out = (T, None if J is None else J.transpose(2, 0, 1),
               None if Jp is None else Jp.transpose(2, 0, 1))
        if N == 0:
            return out
        L = self._block_size(N, joints, params)
        for start in range(0, N, L):
            sl = slice(start, min(N, start + L))
            b = self._block_arrays(sl.stop - sl.start, record, params, workspace)
            F, S = self._sweep(q, sl, b, record)
            Tb = T[sl]
            for c in range(4):
                for r in range(3):
                    Tb[:, r, c] = F[c, r]
            Tb[:, 3, :3] = 0.0
            Tb[:, 3, 3] = 1.0
            if J is not None:
                assert S is not None
                self._joint_columns(F, S, b, J[:, :, sl])
            if Jp is not None:
                assert S is not None
                self._param_columns(F, S, b, Jp[:, :, sl])
        return out

    def _block_arrays(self, L: int, record: bool, params: bool, workspace: ChainWorkspace
                      ) -> dict[str, Array]:
        """Working arrays for a block of ``L`` configurations, carved out of one array of
        ``workspace`` (reused from call to call; never part of a result)."""
        total, layout = _block_layout(L, self.J, self.R if params else 0, record)
        flat = workspace.array("chain.block", (total,))
        return {k: flat[o:o + n].reshape(shape) for k, o, n, shape in layout}

    def _trig(self, V: Array, b: dict[str, Array]) -> tuple[Array, Array]:
        """``cos v, sin v`` of the joint values from one tangent of the half angle.

        With ``t = tan(v / 2)``: ``cos v = 2 / (1 + t^2) - 1`` and ``sin v = t (1 + cos v)``
        (one transcendental call instead of two; a few ulp of error at most).
        Prismatic rows are left at ``cos = 1, sin = 0`` and not used.
        """
        c, s = b["cos"], b["sin"]
        np.multiply(V, 0.5, out=s)
        if not self.all_rot:
            s[~self.rot] = 0.0
        np.tan(s, out=s)
        np.multiply(s, s, out=c)
        c += 1.0
        np.divide(2.0, c, out=c)
        s *= c
        c -= 1.0
        return c, s

    def _sweep(self, q: Array, sl: slice, b: dict[str, Array], record: bool,
               prefix: Array | None = None) -> tuple[Array, Array | None]:
        """Run one block of configurations.

        Returns the end frame (4, 3, L) and, when ``record``, the frames ``S`` (J + 1, 4,
        3, L) with ``S[m]`` the frame just after joint ``m``.  ``prefix`` (4, 3, 1)
        replaces the chain's constant prefix (e.g. with a frame in front of it).
        """
        L = sl.stop - sl.start
        S = b["S"] if record else None
        cur = b["X"] if S is None else S[0]
        spare = b["Y"] if S is None else cur      # the other frame buffer (not recording)
        np.copyto(cur, self.prefix if prefix is None else prefix)
        if self.J == 0:
            return cur, S
        V = self._joint_values(q, sl, b["V"])
        cos, sin = self._trig(V, b)
        t1, t2 = b["t1"], b["t2"]
        for m in range(self.J):
            ax = self.axes[m]
            if self.rot[m]:                       # X <- X Rot(v): mix two columns
                A, B = cur[(ax + 1) % 3], cur[(ax + 2) % 3]
                c, s = cos[m], sin[m]
                np.multiply(A, s, out=t1)
                np.multiply(B, s, out=t2)
                A *= c
                A += t2
                B *= c
                B -= t1
            else:                                 # X <- X Trans(v): move the origin
                np.multiply(cur[ax], V[m], out=t1)
                cur[3] += t1
            kind, matrix, shifts = self.posts[m]
            if kind == "identity" and (m == self.J - 1 or not record):
                continue
            nxt = cur if S is None else S[m + 1]
            if matrix is not None:                # X <- X C: one matrix product
                if S is None:
                    nxt, spare = spare, cur
                np.matmul(matrix, cur.reshape(4, 3 * L), out=nxt.reshape(4, 3 * L))
            else:
                if S is not None:
                    np.copyto(nxt, cur)
                for i, v in shifts:               # translation only: p <- p + v x_i
                    np.multiply(nxt[i], v, out=t1)
                    nxt[3] += t1
            cur = nxt
        return cur, S

    # ------------------------------------------------------------- tool points
    def _selection(self, columns: tuple[int, ...]) -> _PointRows:
        """What :meth:`points` needs for the parameters ``columns`` (kept per column set).

        The rows (parameter transforms) of those parameters in chain order and where
        each one's derivative goes (:meth:`_Structure.selection`), the constant-prefix
        rows' axes and origins and, per joint frame ``S_m``, the coefficients ``C``
        (k, 6) that give the rows' derivatives as one matrix product with
        ``[S_c x (y - p_m) (c = 0, 1, 2); S_c]`` (see :meth:`points`).
        """
        sel = self._selections.get(columns)
        if sel is not None:
            return sel
        shape = self.st.selection(columns)
        pre = shape.pre
        sel = _PointRows(shape.n, shape.dest, shape.direct, len(pre), self.pre_ax[pre, :, 0],
                         self.pre_org[pre, :, 0], self.rows_rot[pre],
                         [(m, rows, self.C6[idx]) for m, rows, idx in shape.groups])
        self._selections[columns] = sel
        return sel

    def points(self, q: Array, points: Array, left: Array | None, columns: tuple[int, ...],
               rotation: bool, out: tuple[Array, Array, Array | None] | None,
               workspace: ChainWorkspace) -> tuple[Array, Array, Array | None]:
        """Tool points, their parameter Jacobian and the tool rotation, configurations last.

        For the points ``m_k`` (K, 3) in the tool frame and a constant frame ``H`` in
        front of the chain (``left``; identity when None), ``y_k = H T(q) m_k``.  The
        chain runs from ``H``'s frame, so every axis ``a`` and origin ``o`` of a
        parameter's transform is already in it and the derivative is the unit twist
        evaluated at the point: ``dy_k / dc = a x (y_k - o)`` (rotation), ``a``
        (translation).  Only the parameters ``columns`` are computed.

        A transform after joint ``m`` has ``a = sum_c A_c S_c`` and ``o = p_m + sum_c
        O_c S_c`` in that joint's frame ``(S_0, S_1, S_2, p_m)`` (constants ``A``, ``O``),
        and ``S_c x S_d = S_e`` for (c, d, e) cyclic, so

            a x (y - o) = sum_c A_c [S_c x (y - p_m)] - sum_c (A x O)_c S_c :

        all the rows after one joint are one (k, 6) x (6, 3L) matrix product with the six
        vectors ``S_c x (y - p_m)``, ``S_c``.  Rows before the first joint have constant
        ``a``, ``o``: ``a x y - a x o``.

        Returns ``Y`` (K, 3, N), ``D`` (C, K, 3, N) (``D[j, k, i, l] = dy_{l,k,i} /
        dc_{columns[j]}``) and, when ``rotation``, ``Rot`` (3, 3, N): the columns of the
        tool rotation in ``H``'s frame (``Rot[c, i, l] = (R_H R_e(q_l))[i, c]``).
        """
        N, K, C = q.shape[0], points.shape[0], len(columns)
        if out is None:
            Y, Dout = np.empty((K, 3, N)), np.empty((C, K, 3, N))
            Rot = np.empty((3, 3, N)) if rotation else None
        else:
            Y, Dout, Rot = out
            if (Y.shape != (K, 3, N) or Dout.shape != (C, K, 3, N)
                    or (Rot is None) == rotation or (Rot is not None and Rot.shape != (3, 3, N))
                    or not (Y.flags.c_contiguous and Dout.flags.c_contiguous)):
                raise ValueError(f"out: C-ordered arrays of shapes {(K, 3, N)}, {(C, K, 3, N)}"
                                 f" and {(3, 3, N) if rotation else None} expected")
        if N == 0:
            return Y, Dout, Rot
        sel = self._selection(columns) if C else None
        H = np.eye(4) if left is None else np.asarray(left, dtype=float)
        full = H @ np.concatenate([self.prefix[:, :, 0].T, [[0.0, 0.0, 0.0, 1.0]]])
        prefix = np.ascontiguousarray(full[:3, :].T)[:, :, None]
        if sel is not None and sel.pre:
            a = sel.pre_ax @ H[:3, :3].T                       # (kp, 3) in H's frame
            o = sel.pre_org @ H[:3, :3].T + H[:3, 3]
            rot = sel.pre_rot
            M = np.zeros((len(a), 3, 3))                         # a x y = M y, M = [a]x
            M[:, 0, 1], M[:, 0, 2], M[:, 1, 2] = -a[:, 2], a[:, 1], -a[:, 0]
            M[:, 1, 0], M[:, 2, 0], M[:, 2, 1] = a[:, 2], -a[:, 1], a[:, 0]
            M[~rot] = 0.0
            const = np.where(rot[:, None], -np.cross(a, o), a)
            pre = (M, const[:, :, None])
        record = C > 0
        # configurations per block: the frames, the cross-product table and one block of
        # output rows within _BLOCK_BYTES (a piece of a few thousand is one block, whose
        # rows are then written in place)
        per = 8 * (15 * self.J + 42 + 24 * K)
        L = max(1, min(N, max(_BLOCK_MIN, min(_BLOCK_MAX, _BLOCK_BYTES // per))))
        for start in range(0, N, L):
            sl = slice(start, min(N, start + L))
            Lb = sl.stop - sl.start
            b = self._block_arrays(Lb, record, False, workspace)
            F, S = self._sweep(q, sl, b, record, prefix)
            Yb = Y[:, :, sl]
            for k in range(K):                                   # y_k = p + R m_k
                np.copyto(Yb[k], F[3])
                for c in range(3):
                    if points[k, c] != 0.0:
                        Yb[k] += points[k, c] * F[c]
            if Rot is not None:
                Rot[:, :, sl] = F[:3]
            if sel is None:
                continue
            Db = Dout[..., sl]
            if sel.n < C or not sel.direct:
                Db[...] = 0.0
            if sel.n == 0:
                continue
            assert S is not None                                 # recorded: C > 0
            Z = workspace.array("chain.Z", (6, K, 3, Lb))
            d = workspace.array("chain.dY", (K, 3, Lb))
            tmp = workspace.array("chain.tZ", (3, K, Lb))
            # all markers at once: rows written in place (one block) or into a buffer
            one_block = Lb == N and sel.direct
            base = Dout if one_block else workspace.array("chain.out", (self.R, K, 3, Lb))
            if sel.pre:
                for k in range(K):
                    rows_k = base[: sel.pre, k]
                    np.matmul(pre[0], Yb[k], out=rows_k)
                    rows_k += pre[1]
            for m, rows, Cg in sel.groups:
                np.subtract(Yb, S[m][3], out=d)                  # y_k - p_m
                Sm = S[m][:3]                                    # (3 columns, 3, L)
                for i in range(3):                               # Z[c] = S_c x (y_k - p_m)
                    j, l = (i + 1) % 3, (i + 2) % 3
                    np.multiply(Sm[:, None, j], d[None, :, l], out=Z[:3, :, i])
                    np.multiply(Sm[:, None, l], d[None, :, j], out=tmp)
                    Z[:3, :, i] -= tmp
                Z[3:] = Sm[:, None]
                np.matmul(Cg, Z.reshape(6, K * 3 * Lb),
                          out=base[rows].reshape(rows.stop - rows.start, K * 3 * Lb))
            if not one_block:
                part = base[: sel.n]
                if sel.direct:
                    Db[...] = part
                else:
                    np.add.at(Db, sel.dest, part)
        return Y, Dout, Rot

    # ------------------------------------------------------------- jacobians
    @staticmethod
    def _cross_into(out: Array, A: Array, D: Array, tmp: Array) -> None:
        """``out[i] = (A x D)_i`` for stacks ``A, D`` (K, 3, L); ``out`` (3, K, L)."""
        for i in range(3):
            j, k = (i + 1) % 3, (i + 2) % 3
            np.multiply(A[:, j], D[:, k], out=out[i])
            np.multiply(A[:, k], D[:, j], out=tmp)
            out[i] -= tmp

    def _joint_columns(self, F: Array, S: Array, b: dict[str, Array], out: Array) -> None:
        """Geometric Jacobian of a block into ``out`` (6, n, L)."""
        if self.J == 0:
            return
        Sj = S[: self.J]
        A = Sj[:, self.axes[0]] if self.same_axis else Sj[np.arange(self.J), self.axes]
        D = b["D"]
        np.subtract(F[3], Sj[:, 3], out=D)                  # arms p_end - o_m
        Jb = out if self.in_joint_order else b["Jb"]
        self._cross_into(Jb, A, D, b["tmp"])
        Jb[3:] = A.transpose(1, 0, 2)
        if not self.all_rot:
            pr = np.flatnonzero(~self.rot)
            Jb[:3, pr] = A[pr].transpose(1, 0, 2)
            Jb[3:, pr] = 0.0
        if self.negative.size:
            Jb[:, self.negative] *= -1.0
        if not self.in_joint_order:
            out[:, self.joint_of] = Jb

    def _param_columns(self, F: Array, S: Array, b: dict[str, Array], out: Array) -> None:
        """Parameter Jacobian of a block into ``out`` (6, P, L)."""
        if self.R == 0:
            out[...] = 0.0
            return
        L = F.shape[2]
        AX, OR = b["AX"], b["OR"]
        AX[self.pre_rows] = self.pre_ax
        OR[self.pre_rows] = self.pre_org
        for m, rows, UA, UO in self.groups:
            k = rows.stop - rows.start
            src = S[m].reshape(4, 3 * L)
            np.matmul(UA, src, out=AX[rows].reshape(k, 3 * L))
            np.matmul(UO, src, out=OR[rows].reshape(k, 3 * L))
        np.subtract(F[3], OR, out=OR)                        # arms p_end - o_k
        TW = out if self.rows_are_params else b["TW"]
        self._cross_into(TW, AX, OR, b["tmpR"])
        TW[3:] = AX.transpose(1, 0, 2)
        if len(self.rows_tra):
            tr = self.rows_tra
            TW[:3, tr] = AX[tr].transpose(1, 0, 2)
            TW[3:, tr] = 0.0
        if self.rows_are_params:
            return
        out[...] = 0.0
        if self.rows_unique:
            out[:, self.row_param] = TW
        else:
            np.add.at(out.transpose(1, 0, 2), self.row_param, TW.transpose(1, 0, 2))


# ---------------------------------------------------------------------------
# Building chains


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

    def frame(self, prefix: str, values: Sequence[float] | Array = (0, 0, 0, 0, 0, 0),
              role: str | None = None) -> None:
        """Append a 6-parameter frame ``Tx Ty Tz Rz Ry Rx`` named ``prefix.x`` ... ``prefix.rx``.

        ``values`` are ``(x, y, z, rz, ry, rx)`` [m, rad] (:data:`kincal.spatial.FRAME_FIELDS`):
        ``T = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)``, the parameters in that order.
        """
        if len(values) != 6:
            raise ValueError(f"a frame has 6 values {FRAME_FIELDS}, got {len(values)}")
        role = role or ("base" if prefix == "base" else "tool" if prefix == "tool" else "length")
        for kind, fld, v in zip(("Tx", "Ty", "Tz", "Rz", "Ry", "Rx"), FRAME_FIELDS, values,
                                strict=True):
            self.transform(kind, f"{prefix}.{fld}", float(v), role=role)

    def build(self, meta: Mapping[str, Any] | None = None) -> Robot:
        return Robot(self.name, tuple(self.ets), tuple(self.joints), tuple(self.names),
                     np.array(self.values), tuple(self.units), tuple(self.roles),
                     dict(meta or {}))
