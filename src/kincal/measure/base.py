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

Array = NDArray[np.float64]


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
