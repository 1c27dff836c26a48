"""The contract between measurements and the identification machinery.

A calibration problem is a robot plus one or more *measurement blocks*.  Each block
holds the data of one instrument (joint readings ``q`` (N, n), observations, their
standard deviations) and has its own unknown parameters: the instrument's frame, the
measured point on the tool, artifact geometry, socket positions ...  Their names carry
the block's prefix (``tracker.x``, ``marker.z``, ``bar.L``) so that one parameter
vector ``theta = [robot params; block 1 params; block 2 params; ...]`` always
travels with its names.

Every block returns *whitened* residuals ``r_i = (model_i(theta) - observed_i) / sigma_i``
and their analytic Jacobian with respect to **all** robot parameters and **all** of
its own parameters.  The solver, the identifiability analysis, the uncertainty
propagation and the experiment design work only on the stacked whitened system
built by :func:`stack`, so any new instrument plugs in by implementing
:class:`MeasurementModel`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.robots.chain import Robot
from kincal.spatial import homogeneous, rpy_to_matrix

Array = NDArray[np.float64]

#: Field order of a 6-parameter frame, as in the robot's ``base.*`` / ``tool.*``:
#: ``T = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)``.
FRAME_FIELDS = ("x", "y", "z", "rz", "ry", "rx")


@dataclass(frozen=True)
class ParamSpec:
    """Named parameters of a measurement block.

    Attributes:
        names: full names including the block prefix (``tracker.rz``).
        values: nominal / default values [m or rad].
        units: ``"m"``, ``"rad"`` (or ``"1"`` for dimensionless).
        roles: free-form role per parameter (``"instrument"``, ``"tool_point"``,
            ``"artifact"``, ``"target"``); used for reports and staging.
    """

    names: tuple[str, ...]
    values: Array
    units: tuple[str, ...]
    roles: tuple[str, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "values", np.asarray(self.values, dtype=float).reshape(-1))
        if not (len(self.names) == len(self.values) == len(self.units) == len(self.roles)):
            raise ValueError("ParamSpec fields differ in length")

    def __len__(self) -> int:
        return len(self.names)

    @staticmethod
    def empty() -> ParamSpec:
        return ParamSpec((), np.zeros(0), (), ())

    @staticmethod
    def frame(prefix: str, values: Array | None = None, role: str = "instrument") -> ParamSpec:
        """The six parameters ``{prefix}.x .y .z .rz .ry .rx`` of a frame (:data:`FRAME_FIELDS`)."""
        v = np.zeros(6) if values is None else np.asarray(values, dtype=float)
        return ParamSpec(tuple(f"{prefix}.{f}" for f in FRAME_FIELDS), v,
                         ("m", "m", "m", "rad", "rad", "rad"), (role,) * 6)

    @staticmethod
    def point(prefix: str, values: Array | None = None, role: str = "tool_point") -> ParamSpec:
        """The three parameters ``{prefix}.x .y .z`` of a point [m]."""
        v = np.zeros(3) if values is None else np.asarray(values, dtype=float)
        return ParamSpec(tuple(f"{prefix}.{f}" for f in "xyz"), v, ("m",) * 3, (role,) * 3)

    def __add__(self, other: ParamSpec) -> ParamSpec:
        return ParamSpec(self.names + other.names, np.concatenate([self.values, other.values]),
                         self.units + other.units, self.roles + other.roles)


# --------------------------------------------------------------------------- frame helpers
def frame_matrix(values: Array) -> Array:
    """``T = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)`` from ``(x, y, z, rz, ry, rx)`` [m, rad].

    Note the order: parameters follow :data:`FRAME_FIELDS`, unlike
    :func:`kincal.spatial.xyzrpy_to_matrix` which takes ``(x, y, z, roll, pitch, yaw)``.
    """
    v = np.asarray(values, dtype=float)
    return homogeneous(rpy_to_matrix(v[..., [5, 4, 3]]), v[..., :3])


def frame_values(T: Array) -> Array:
    """Inverse of :func:`frame_matrix`: (4, 4) -> ``(x, y, z, rz, ry, rx)``."""
    from kincal.spatial import matrix_to_rpy

    rpy = matrix_to_rpy(np.asarray(T)[..., :3, :3])
    return np.concatenate([np.asarray(T)[..., :3, 3], rpy[..., ::-1]], -1)


def frame_rotation_axes(values: Array) -> Array:
    """Columns ``d omega / d(rz, ry, rx)`` of a frame's rotation, in its parent frame: (3, 3).

    With ``R = Rz(rz) Ry(ry) Rx(rx)``, ``dR = [omega]x R`` and
    ``omega = e_z drz + Rz(rz) e_y dry + Rz(rz) Ry(ry) e_x drx``, i.e. the columns are
    ``[0, 0, 1]``, ``[-sin rz, cos rz, 0]`` and
    ``[cos rz cos ry, sin rz cos ry, -sin ry]`` (dimensionless, rad/rad).
    """
    v = np.asarray(values, dtype=float)
    cz, sz = np.cos(v[3]), np.sin(v[3])
    cy, sy = np.cos(v[4]), np.sin(v[4])
    return np.array([[0.0, -sz, cz * cy],
                     [0.0, cz, sz * cy],
                     [1.0, 0.0, -sy]])


class MeasurementModel(ABC):
    """One instrument's block of measurements and its unknown parameters.

    Subclasses hold their data (``q`` (N, n) joint readings plus observations and
    standard deviations) and implement:

    * :meth:`parameters` - the block's own named parameters with defaults;
    * :meth:`initial_guess` - closed-form values of those parameters from the data
      and a robot model (e.g. Kabsch registration of the instrument frame), so the
      user never supplies one;
    * :meth:`evaluate` - whitened residuals and their analytic Jacobian.

    Attributes:
        name: the block's prefix for its parameter names and for reports.
        q: (N, n) joint readings [rad / m].
    """

    name: str
    q: Array

    @abstractmethod
    def parameters(self) -> ParamSpec:
        """The block's own parameters (names prefixed by ``self.name``) with defaults."""

    @abstractmethod
    def initial_guess(self, robot: Robot) -> Array:
        """Values for :meth:`parameters` estimated in closed form from the data."""

    @abstractmethod
    def evaluate(self, robot: Robot, extra: Array, jacobian: bool = True
                 ) -> tuple[Array, Array | None, Array | None]:
        """Whitened residuals and Jacobians.

        Args:
            robot: the robot with its current parameter values.
            extra: current values of this block's parameters (order of :meth:`parameters`).
            jacobian: when False only the residuals are computed.

        Returns:
            ``(r, J_robot, J_extra)``: ``r`` (M,) = (predicted - observed) / sigma;
            ``J_robot`` (M, robot.num_params) = dr / d(robot params);
            ``J_extra`` (M, len(parameters())) = dr / d(block params).
        """

    @abstractmethod
    def residual_owner(self) -> NDArray[np.intp]:
        """For each residual, the row (measurement) it comes from: (M,) ints.

        Used to flag outlier measurements by index and to hold out rows.
        """

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        """Physical errors per measurement for reports, e.g. ``{"position_m": (N,)}``.

        The keys end in their unit (``_m``, ``_rad``).  Default: none.
        """
        return {}


@dataclass
class StackedProblem:
    """All blocks of a calibration stacked into one whitened least-squares problem.

    ``theta`` = robot parameters followed by every block's parameters; ``free`` is a
    boolean mask over ``theta`` naming what is estimated.
    """

    robot: Robot
    blocks: list[MeasurementModel]
    names: tuple[str, ...]
    units: tuple[str, ...]
    roles: tuple[str, ...]
    slices: list[slice]          # slice of theta owned by each block

    @property
    def num_robot(self) -> int:
        return self.robot.num_params

    def split(self, theta: Array) -> tuple[Robot, list[Array]]:
        """The robot with ``theta``'s robot part, and each block's parameter values."""
        theta = np.asarray(theta, dtype=float)
        robot = self.robot.with_params(theta[: self.num_robot])
        return robot, [theta[s] for s in self.slices]

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            import difflib

            close = difflib.get_close_matches(name, self.names, n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise KincalError(f"no parameter named {name!r} in this problem{hint}") from None

    @property
    def block_names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.blocks)

    def block(self, name: str) -> MeasurementModel:
        """The block called ``name``."""
        for b in self.blocks:
            if b.name == name:
                return b
        raise KincalError(f"no measurement block named {name!r}; blocks: "
                          f"{', '.join(self.block_names)}")

    def block_slice(self, name: str) -> slice:
        """The slice of ``theta`` holding block ``name``'s parameters."""
        return self.slices[self.block_names.index(self.block(name).name)]

    def owners(self) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """For every stacked residual: (index of its block, row within that block)."""
        bi = [np.full(len(b.residual_owner()), i, dtype=np.intp)
              for i, b in enumerate(self.blocks)]
        rows = [np.asarray(b.residual_owner(), dtype=np.intp) for b in self.blocks]
        return np.concatenate(bi), np.concatenate(rows)

    def measurement_ids(self) -> NDArray[np.intp]:
        """A unique integer per (block, row) for every residual, 0 .. num_measurements - 1.

        Residuals with the same id belong to one physical measurement (the three
        coordinates of a point, the six of a pose).
        """
        bi, rows = self.owners()
        _, ids = np.unique(np.stack([bi, rows], 1), axis=0, return_inverse=True)
        return ids.reshape(-1).astype(np.intp)

    def errors(self, theta: Array) -> dict[str, dict[str, Array]]:
        """Physical errors of every block at ``theta``: ``{block name: block.errors(...)}``."""
        robot, extras = self.split(theta)
        return {b.name: b.errors(robot, e) for b, e in zip(self.blocks, extras, strict=True)}

    def residuals(self, theta: Array) -> Array:
        """Stacked whitened residuals r(theta): (M,)."""
        robot, extras = self.split(theta)
        return np.concatenate([b.evaluate(robot, e, jacobian=False)[0]
                               for b, e in zip(self.blocks, extras, strict=True)])

    def residuals_and_jacobian(self, theta: Array) -> tuple[Array, Array]:
        """Stacked ``r`` (M,) and the full Jacobian ``dr/dtheta`` (M, len(theta))."""
        robot, extras = self.split(theta)
        rs, Js = [], []
        total = len(self.names)
        for b, e, s in zip(self.blocks, extras, self.slices, strict=True):
            r, Jr, Je = b.evaluate(robot, e, jacobian=True)
            J = np.zeros((r.size, total))
            J[:, : self.num_robot] = Jr
            J[:, s] = Je
            rs.append(r)
            Js.append(J)
        return np.concatenate(rs), np.vstack(Js)


def stack(robot: Robot, blocks: Sequence[MeasurementModel]) -> tuple[StackedProblem, Array]:
    """Stack ``blocks`` measured on ``robot``.

    Returns the problem and the initial ``theta``: the robot's current parameters
    followed by each block's :meth:`~MeasurementModel.initial_guess`.
    """
    if not blocks:
        raise KincalError("no measurements given")
    names = list(robot.param_names)
    units = list(robot.param_units)
    roles = list(robot.param_roles)
    theta = [np.asarray(robot.param_values, dtype=float)]
    slices = []
    seen_prefix: set[str] = set()
    for b in blocks:
        if b.name in seen_prefix:
            raise KincalError(f"two measurement blocks are both named {b.name!r}; give each "
                              "instrument its own name")
        seen_prefix.add(b.name)
        if b.q.ndim != 2 or b.q.shape[1] != robot.n:
            raise KincalError(f"measurements {b.name!r} have {b.q.shape[-1]} joint values per "
                              f"row; robot {robot.name!r} has {robot.n} joints")
        spec = b.parameters()
        clash = set(spec.names) & set(names)
        if clash:
            raise KincalError(f"parameter name {sorted(clash)[0]!r} of block {b.name!r} is "
                              "already used")
        start = len(names)
        names += spec.names
        units += spec.units
        roles += spec.roles
        slices.append(slice(start, len(names)))
        theta.append(np.asarray(b.initial_guess(robot), dtype=float).reshape(-1))
    prob = StackedProblem(robot, list(blocks), tuple(names), tuple(units), tuple(roles), slices)
    return prob, np.concatenate(theta)


# --------------------------------------------------------------------------- linear algebra
def svd_thin(A: Array) -> tuple[Array, Array, Array]:
    """Thin SVD ``A = U diag(S) V^T`` of a tall (M, p) matrix through its QR factor.

    ``A = Q R``, ``R = U_r S V^T``, ``U = Q U_r``.  Same result as
    ``numpy.linalg.svd(A, full_matrices=False)`` but LAPACK's tall SVD is slow when
    the BLAS threads compete for few cores; the QR + small SVD path is not.
    """
    A = np.asarray(A, dtype=float)
    M, p = A.shape
    if M < p or p == 0:
        return np.linalg.svd(A, full_matrices=False)
    Q, R = np.linalg.qr(A, mode="reduced")
    Ur, S, Vt = np.linalg.svd(R)
    return Q @ Ur, S, Vt


def singular_values(A: Array) -> Array:
    """Singular values of ``A`` (descending), via the R factor for tall matrices."""
    A = np.asarray(A, dtype=float)
    if A.size == 0:
        return np.zeros(0)
    if A.shape[0] > A.shape[1]:
        A = np.linalg.qr(A, mode="r")
    return np.linalg.svd(A, compute_uv=False)


def lstsq(A: Array, b: Array, rcond: float = 1e-10) -> Array:
    """Minimum-norm least-squares solution of ``A x = b`` (singular values below
    ``rcond * S_max`` are treated as zero), via :func:`svd_thin`."""
    U, S, Vt = svd_thin(A)
    keep = S > rcond * (S[0] if S.size else 0.0)
    return Vt[keep].T @ ((U[:, keep].T @ b) / S[keep])
