"""Joint compliance: a non-geometric error model wrapped around any measurement block.

A geometric model (seed 000's DH / URDF parameters) cannot describe a joint that
yields under load: gear and harmonic-drive elasticity, or backlash preloaded by
gravity (seed 004's non-geometric errors, "level 3").  The simplest physical model
is a linear torsion (or axial) spring at each joint: the link side sits at

    q_eff = q + k (.) tau(q)

where ``q`` [rad / m] is the motor-side encoder reading, ``tau`` [N m / N] the static
load on the joint (:func:`kincal.robots.gravity.gravity_torques`: the torque gravity
applies, positive along ``+q``) and ``k`` [rad/(N m) or m/N] the compliance.
:class:`JointCompliance` evaluates an inner measurement block (a tracker, motion
capture ...) at ``q_eff`` instead of ``q`` and adds one parameter per joint,
``{name}.k[<joint>]``, to the block's own (initial value 0).

The loads are computed once, from the nominal robot and the measured readings, and
held fixed: a calibration moves the geometry by millimetres, which changes the loads
by a relative ``1e-3`` or so, a second-order effect on ``k tau``.

Jacobians, analytic.  The robot and block columns are the inner block's, at ``q_eff``
(``tau`` does not depend on them).  For ``k_j``, ``dr/dk_j = (dr/dq_j) tau_j``.  The
joint variable enters its elementary transform exactly as the transform's constant
does, ``X(c_j + s_j q_j)``, so ``dr/dq_j = s_j dr/dc_j``: the inner block's column of
the joint's offset parameter ``c_j``, at ``q_eff``, times ``s_j`` and the row's load::

    dr_i/dk_j = s_j (dr_i/dc_j)(q_eff) tau_j[row(i)]

``row(i)`` is the configuration of residual ``i`` (the inner block's
``residual_owner()``).  This requires every residual of the inner block to depend on
the one configuration it is owned by (true of position, pose and camera blocks; not
of artifact constraints that join several configurations): it is checked numerically
the first time the block is evaluated, and a clear error is raised otherwise.

The inner block is never modified: it is evaluated through a shallow copy whose
``q`` is ``q_eff`` (or, if the inner class defines ``with_q(q)``, through that; a
block that derives cached data from ``q`` in its constructor must define it).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterator, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.measure.base import CHUNK_ROWS, MeasurementModel, ParamSpec
from kincal.robots.chain import Robot
from kincal.robots.gravity import STANDARD_GRAVITY, PointMass, gravity_torques

Array = NDArray[np.float64]

__all__ = ["JointCompliance", "compliance_unit"]

#: Role of the compliance parameters (a block role: kept before robot parameters in the
#: identifiability priority, like the other block parameters).
ROLE = "compliance"


def compliance_unit(kind: str) -> str:
    """Unit of a compliance: ``rad/(N m)`` for revolute joints, ``m/N`` for prismatic."""
    return "rad/(N m)" if kind == "revolute" else "m/N"


class JointCompliance(MeasurementModel):
    """Evaluate ``block`` at ``q + k (.) tau`` and estimate the joint compliances ``k``.

    Args:
        block: the inner measurement block (its ``q`` are the encoder readings).
        robot: the robot the block measures (its joint names and kinds; the robot
            passed to :meth:`evaluate` must have the same joints).
        torques: (N, n) loads on every joint of ``robot`` at the N configurations
            [N m / N], or a callable ``torques(q) -> (N, n)`` evaluated once on
            ``block.q``.  See :meth:`gravity` for gravity loads.
        joints: names of the joints that get a compliance (default: all).

    Parameters: the inner block's, then ``{name}.k[<joint>]`` per joint in
    ``joints`` [rad/(N m) or m/N], role ``"compliance"``, initial value 0.  The block's
    ``name`` is the inner block's.
    """

    def __init__(self, block: MeasurementModel, robot: Robot,
                 torques: ArrayLike | Callable[[Array], ArrayLike],
                 joints: Sequence[str] | None = None) -> None:
        self.inner = block
        self.name = block.name
        self.q = np.asarray(block.q, dtype=float)
        self.robot = robot
        tau = torques(self.q) if callable(torques) else torques
        tau = np.asarray(tau, dtype=float)
        if tau.shape != (self.q.shape[0], robot.n):
            raise KincalError(f"joint compliance of {self.name!r}: the loads must be (N, n) = "
                              f"({self.q.shape[0]}, {robot.n}), got {tau.shape}")
        if not np.all(np.isfinite(tau)):
            row = int(np.argwhere(~np.isfinite(tau))[0, 0])
            raise KincalError(f"joint compliance of {self.name!r}: the load in row {row} is "
                              "not finite")
        self.torques = tau
        names = list(robot.joint_names) if joints is None else [str(j) for j in joints]
        if not names:
            raise KincalError(f"joint compliance of {self.name!r}: no joints given")
        unknown = [j for j in names if j not in robot.joint_names]
        if unknown:
            raise KincalError(f"joint compliance of {self.name!r}: {unknown[0]!r} is not a joint "
                              f"of robot {robot.name!r} (joints: {', '.join(robot.joint_names)})")
        if len(set(names)) != len(names):
            raise KincalError(f"joint compliance of {self.name!r}: a joint is listed twice")
        self.joints = tuple(names)
        self._columns = np.array([robot.joint_names.index(j) for j in names], dtype=np.intp)
        self._checked = False

    @classmethod
    def gravity(cls, block: MeasurementModel, robot: Robot, masses: Sequence[PointMass],
                joints: Sequence[str] | None = None, g: ArrayLike = STANDARD_GRAVITY
                ) -> JointCompliance:
        """Compliance under gravity: loads ``gravity_torques(robot, block.q, masses, g)``.

        ``masses`` e.g. from :func:`kincal.robots.urdf.load_urdf_inertials`; ``g``
        [m/s^2] in the robot's reference frame.
        """
        return cls(block, robot, gravity_torques(robot, block.q, masses, g), joints)

    # ------------------------------------------------------------------ contract
    @property
    def N(self) -> int:
        """Number of configurations."""
        return int(self.q.shape[0])

    def parameters(self) -> ParamSpec:
        kinds = {j.name: j.kind for j in self.robot.joints}
        names = tuple(f"{self.name}.k[{j}]" for j in self.joints)
        units = tuple(compliance_unit(kinds[j]) for j in self.joints)
        return self.inner.parameters() + ParamSpec(names, np.zeros(len(names)), units,
                                                   (ROLE,) * len(names))

    def initial_guess(self, robot: Robot) -> Array:
        """The inner block's guess (at the readings, i.e. ``k = 0``), then ``k = 0``."""
        inner = np.asarray(self.inner.initial_guess(robot), dtype=float).reshape(-1)
        return np.concatenate([inner, np.zeros(len(self.joints))])

    def residual_owner(self) -> NDArray[np.intp]:
        return self.inner.residual_owner()

    def num_residuals(self) -> int:
        return self.inner.num_residuals()

    def subset(self, rows: ArrayLike) -> JointCompliance:
        """The same model on ``rows`` of the inner block (which must support ``subset``)."""
        if not hasattr(self.inner, "subset"):
            raise KincalError(f"block {self.name!r} cannot be split into rows")
        rows = np.asarray(rows)
        return JointCompliance(self.inner.subset(rows), self.robot, self.torques[rows],
                               self.joints)

    def effective_q(self, robot: Robot, extra: ArrayLike) -> Array:
        """Link-side joint values ``q + k (.) tau`` (N, n) [rad / m] at ``extra``."""
        k = np.asarray(extra, dtype=float).reshape(-1)[-len(self.joints):]
        q = self.q.copy()
        q[:, self._columns] += k * self.torques[:, self._columns]
        return q

    # ------------------------------------------------------------------ evaluation
    def _split(self, robot: Robot, extra: ArrayLike) -> tuple[Array, Array]:
        extra = np.asarray(extra, dtype=float).reshape(-1)
        E = extra.size - len(self.joints)
        if robot.joint_names != self.robot.joint_names:
            raise KincalError(f"joint compliance of {self.name!r}: robot {robot.name!r} has "
                              f"joints {robot.joint_names}, the model was built for "
                              f"{self.robot.joint_names}")
        return extra[:E], self.effective_q(robot, extra)

    def _at(self, q: Array) -> MeasurementModel:
        """The inner block with joint readings ``q`` (a copy; the inner block is unchanged)."""
        with_q = getattr(self.inner, "with_q", None)
        if callable(with_q):
            return with_q(q)  # type: ignore[no-any-return]
        blk = copy.copy(self.inner)
        blk.q = q
        return blk

    def _offset_columns(self, robot: Robot) -> tuple[NDArray[np.intp], Array]:
        """Per compliant joint: the index of its offset parameter ``c_j`` and ``s_j``."""
        params, scales = [], []
        uses = np.bincount([et.param for et in robot.ets if et.param >= 0],
                           minlength=robot.num_params)
        for j in self._columns:
            et = next(e for e in robot.ets if e.joint == j)
            name = robot.joints[j].name
            if et.param < 0:
                raise KincalError(f"joint compliance of {self.name!r}: joint {name!r} has no "
                                  "offset parameter in its elementary transform (a fixed "
                                  "constant), so dr/dq cannot be formed; build the robot with "
                                  "an offset parameter for it")
            if uses[et.param] != 1:
                raise KincalError(f"joint compliance of {self.name!r}: the offset parameter "
                                  f"{robot.param_names[et.param]!r} of joint {name!r} is shared "
                                  "with other elementary transforms, so its column is not "
                                  "dr/dq")
            params.append(et.param)
            scales.append(et.scale)
        return np.array(params, dtype=np.intp), np.array(scales, dtype=float)

    def _check_rows(self, robot: Robot, inner_extra: Array) -> None:
        """Each residual must depend only on its own configuration (``residual_owner``).

        Perturbs the joints of a random half of the configurations, then of the other
        half: residuals owned by an unperturbed configuration must not change.
        """
        if self._checked:
            return
        owner = np.asarray(self.inner.residual_owner(), dtype=np.intp)
        N = self.q.shape[0]
        if owner.size and (owner.min() < 0 or owner.max() >= N):
            raise KincalError(f"joint compliance of {self.name!r}: the inner block's residuals "
                              "are not owned by rows of its joint readings")
        r0 = self._at(self.q).evaluate(robot, inner_extra, jacobian=False)[0]
        half = np.random.default_rng(0).random(N) < 0.5
        for moved in (half, ~half):
            q = self.q.copy()
            q[moved] += 1e-3
            dr = np.abs(self._at(q).evaluate(robot, inner_extra, jacobian=False)[0] - r0)
            scale = float(dr.max()) if dr.size else 0.0
            if np.any(dr[~moved[owner]] > 1e-6 * scale):
                raise KincalError(f"joint compliance of {self.name!r}: some residuals of the "
                                  "inner block depend on configurations other than the one "
                                  "that owns them (e.g. artifact constraints between "
                                  "postures); JointCompliance needs one configuration per "
                                  "residual")
        self._checked = True

    def evaluate(self, robot: Robot, extra: Array, jacobian: bool = True
                 ) -> tuple[Array, Array | None, Array | None]:
        """Inner residuals at ``q_eff``; Jacobians as in the module docstring."""
        inner_extra, q = self._split(robot, extra)
        blk = self._at(q)
        if not jacobian:
            return blk.evaluate(robot, inner_extra, jacobian=False)
        self._check_rows(robot, inner_extra)
        r, Jr, Je = blk.evaluate(robot, inner_extra, jacobian=True)
        assert Jr is not None and Je is not None
        Jk = self._k_columns(robot, Jr, np.asarray(self.inner.residual_owner(), np.intp))
        return r, Jr, np.concatenate([Je, Jk], axis=1)

    def evaluate_chunks(self, robot: Robot, extra: Array, rows: int = CHUNK_ROWS
                        ) -> Iterator[tuple[slice, Array, Array, Array]]:
        """The inner block's pieces at ``q_eff`` with the ``k`` columns appended."""
        inner_extra, q = self._split(robot, extra)
        self._check_rows(robot, inner_extra)
        owner = np.asarray(self.inner.residual_owner(), dtype=np.intp)
        cols = self._offset_columns(robot)
        for sl, r, Jr, Je in self._at(q).evaluate_chunks(robot, inner_extra, rows):
            Jk = self._k_columns(robot, Jr, owner[sl], cols)
            yield sl, r, Jr, np.concatenate([Je, Jk], axis=1)

    def _k_columns(self, robot: Robot, Jr: Array, owner: NDArray[np.intp],
                   cols: tuple[NDArray[np.intp], Array] | None = None) -> Array:
        """``dr/dk_j = s_j (dr/dc_j) tau_j[owner]`` for the rows of ``Jr``."""
        params, scales = self._offset_columns(robot) if cols is None else cols
        return Jr[:, params] * scales * self.torques[owner][:, self._columns]

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        inner_extra, q = self._split(robot, extra)
        return self._at(q).errors(robot, inner_extra)

    def __repr__(self) -> str:
        return (f"JointCompliance({self.inner!r}, joints={list(self.joints)}, "
                f"N={self.q.shape[0]})")
