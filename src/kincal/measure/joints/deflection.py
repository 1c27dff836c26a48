"""Joint deflection: a non-geometric error model wrapped around any measurement block.

A geometric model (DH / URDF parameters) describes where the joint axes
are, not how the link side of a joint follows its motor-side encoder.  Gear and
harmonic-drive elasticity, or backlash taken up by gravity or by the direction the
joint last moved in, put the link at

    q_eff = q + c (.) u(row)

where ``q`` [rad / m] is the encoder reading, ``u`` a known per-configuration
regressor (the static load ``tau`` of :mod:`kincal.measure.joints.compliance`, the approach
direction of :mod:`kincal.measure.joints.hysteresis`) and ``c`` one unknown coefficient per
joint.  :class:`JointDeflection` evaluates an inner measurement block (a tracker,
motion capture ...) at ``q_eff`` instead of ``q`` and adds the coefficients as
parameters ``{name}.{symbol}[<joint>]`` (initial value 0).  Subclasses say what ``u``
is, its symbol, role and unit.  Deflection models nest: a compliance around a
hysteresis around a tracker block deflects the joints by the sum of both terms.

``u`` is computed once, when the model is built, and held fixed: a calibration moves
the geometry by millimetres, which changes a gravity load by a relative ``1e-3`` or so,
a second-order effect on ``c u``.

Jacobians, analytic.  The robot and block columns are the inner block's, at ``q_eff``
(``u`` does not depend on them).  For ``c_j``, ``dr/dc_j = (dr/dq_j) u_j``.  The joint
variable enters its elementary transform exactly as the transform's constant does,
``X(o_j + s_j q_j)``, so ``dr/dq_j = s_j dr/do_j``: the inner block's column of the
joint's offset parameter ``o_j``, at ``q_eff``, times ``s_j`` and the row's regressor::

    dr_i/dc_j = s_j (dr_i/do_j)(q_eff) u_j[row(i)]

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
from collections.abc import Iterator, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.measure.base import CHUNK_ROWS, BlockWrapper, MeasurementModel, ParamSpec
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["JointDeflection"]


class JointDeflection(BlockWrapper):
    """Evaluate ``block`` at ``q + c (.) u`` and estimate one coefficient ``c`` per joint.

    Args:
        block: the inner measurement block (its ``q`` are the encoder readings).
        robot: the robot the block measures (its joint names and kinds; the robot
            passed to :meth:`evaluate` must have the same joints).
        regressor: (N, n) values ``u`` at the N configurations, one column per joint of
            ``robot`` (columns of joints without a coefficient are ignored).
        joints: names of the joints that get a coefficient (default: all).

    Parameters: the inner block's, then ``{name}.{SYMBOL}[<joint>]`` per joint in
    ``joints`` (unit :meth:`unit`, role :attr:`ROLE`, initial value 0).  The block's
    ``name`` is the inner block's.  Subclasses set :attr:`SYMBOL`, :attr:`ROLE`,
    :attr:`WHAT` (for messages) and :meth:`unit`.
    """

    #: Parameter symbol: ``{name}.{SYMBOL}[<joint>]``.
    SYMBOL = "c"
    #: Parameter role (a block role: kept before robot parameters in the
    #: identifiability priority, like the other block parameters).
    ROLE = "deflection"
    #: What the model is called in error messages.
    WHAT = "joint deflection"
    #: What the regressor is called in error messages.
    REGRESSOR = "regressor"

    def __init__(self, block: MeasurementModel, robot: Robot, regressor: ArrayLike,
                 joints: Sequence[str] | None = None) -> None:
        self.inner = block
        self.name = block.name
        self.q = np.asarray(block.q, dtype=float)
        self.robot = robot
        u = np.asarray(regressor, dtype=float)
        if u.shape != (self.q.shape[0], robot.n):
            raise KincalError(f"{self.WHAT} of {self.name!r}: the {self.REGRESSOR} must be "
                              f"(N, n) = ({self.q.shape[0]}, {robot.n}), got {u.shape}")
        if not np.all(np.isfinite(u)):
            row = int(np.argwhere(~np.isfinite(u))[0, 0])
            raise KincalError(f"{self.WHAT} of {self.name!r}: the {self.REGRESSOR} in row "
                              f"{row} is not finite")
        self.regressor = u
        names = list(robot.joint_names) if joints is None else [str(j) for j in joints]
        if not names:
            raise KincalError(f"{self.WHAT} of {self.name!r}: no joints given")
        unknown = [j for j in names if j not in robot.joint_names]
        if unknown:
            raise KincalError(f"{self.WHAT} of {self.name!r}: {unknown[0]!r} is not a joint "
                              f"of robot {robot.name!r} (joints: {', '.join(robot.joint_names)})")
        if len(set(names)) != len(names):
            raise KincalError(f"{self.WHAT} of {self.name!r}: a joint is listed twice")
        self.joints = tuple(names)
        self._columns = np.array([robot.joint_names.index(j) for j in names], dtype=np.intp)
        self._checked = False

    def unit(self, kind: str) -> str:
        """Unit of the coefficient of a joint of ``kind`` (``revolute``/``prismatic``)."""
        return "rad" if kind == "revolute" else "m"

    def coefficient_names(self) -> tuple[str, ...]:
        """``{name}.{SYMBOL}[<joint>]`` per joint with a coefficient."""
        return tuple(f"{self.name}.{self.SYMBOL}[{j}]" for j in self.joints)

    # ------------------------------------------------------------------ contract
    @property
    def N(self) -> int:
        """Number of configurations."""
        return int(self.q.shape[0])

    def parameters(self) -> ParamSpec:
        kinds = {j.name: j.kind for j in self.robot.joints}
        names = self.coefficient_names()
        units = tuple(self.unit(kinds[j]) for j in self.joints)
        return self.inner.parameters() + ParamSpec(names, np.zeros(len(names)), units,
                                                   (self.ROLE,) * len(names))

    def initial_guess(self, robot: Robot) -> Array:
        """The inner block's guess (at the readings, i.e. ``c = 0``), then ``c = 0``."""
        inner = np.asarray(self.inner.initial_guess(robot), dtype=float).reshape(-1)
        return np.concatenate([inner, np.zeros(len(self.joints))])

    def residual_owner(self) -> NDArray[np.intp]:
        return self.inner.residual_owner()

    def num_residuals(self) -> int:
        return self.inner.num_residuals()

    def _with(self, inner: MeasurementModel, regressor: Array) -> JointDeflection:
        """The same model around ``inner`` with ``regressor`` (used by :meth:`subset`)."""
        out = copy.copy(self)
        out.inner, out.q, out.regressor = inner, np.asarray(inner.q, dtype=float), regressor
        out._checked = False
        return out

    def subset(self, rows: ArrayLike) -> JointDeflection:
        """The same model on ``rows`` of the inner block (which must support ``subset``);
        each row keeps its regressor value."""
        if not hasattr(self.inner, "subset"):
            raise KincalError(f"block {self.name!r} cannot be split into rows")
        rows = np.asarray(rows)
        return self._with(self.inner.subset(rows), self.regressor[rows])

    def subset_inner_placements(self, placements: Sequence[str]) -> JointDeflection:
        """The same model on the rows of artifact ``placements`` of the (possibly nested)
        inner block, which must hold placements (``subset_placements``); each row keeps
        its regressor value."""
        inner = self.inner
        if hasattr(inner, "subset_placements"):
            sub = inner.subset_placements(placements)
        elif isinstance(inner, JointDeflection):
            sub = inner.subset_inner_placements(placements)
        else:
            raise KincalError(f"block {self.name!r} has no artifact placements to split")
        base: MeasurementModel = inner
        while isinstance(base, JointDeflection):
            base = base.inner
        labels: Sequence[str] = getattr(base, "placement_labels", ())
        want = {str(p) for p in placements}
        rows = np.array([str(p) in want for p in labels], dtype=bool)
        return self._with(sub, self.regressor[rows])

    def effective_q(self, robot: Robot, extra: ArrayLike) -> Array:
        """Link-side joint values ``q + c (.) u`` (N, n) [rad / m] at ``extra``."""
        c = np.asarray(extra, dtype=float).reshape(-1)[-len(self.joints):]
        q = self.q.copy()
        q[:, self._columns] += c * self.regressor[:, self._columns]
        return q

    # ------------------------------------------------------------------ evaluation
    def _split(self, robot: Robot, extra: ArrayLike) -> tuple[Array, Array]:
        extra = np.asarray(extra, dtype=float).reshape(-1)
        E = extra.size - len(self.joints)
        if robot.joint_names != self.robot.joint_names:
            raise KincalError(f"{self.WHAT} of {self.name!r}: robot {robot.name!r} has "
                              f"joints {robot.joint_names}, the model was built for "
                              f"{self.robot.joint_names}")
        return extra[:E], self.effective_q(robot, extra)

    def _at(self, q: Array) -> MeasurementModel:
        """The inner block with joint readings ``q`` (a copy; the inner block is unchanged)."""
        if isinstance(self.inner, JointDeflection):  # an inner joint-model term
            return self.inner.with_q(q)
        blk = copy.copy(self.inner)      # a plain copy: the inner block keeps its weights
        blk.q = q
        return blk

    def with_q(self, q: ArrayLike) -> JointDeflection:
        """This model with encoder readings ``q`` (what an outer deflection model uses)."""
        out = copy.copy(self)
        out.q = np.asarray(q, dtype=float)
        return out

    def _offset_columns(self, robot: Robot) -> tuple[NDArray[np.intp], Array]:
        """Per joint with a coefficient: the index of its offset parameter ``o_j``, ``s_j``."""
        params, scales = [], []
        uses = np.bincount([et.param for et in robot.ets if et.param >= 0],
                           minlength=robot.num_params)
        for j in self._columns:
            et = next(e for e in robot.ets if e.joint == j)
            name = robot.joints[j].name
            if et.param < 0:
                raise KincalError(f"{self.WHAT} of {self.name!r}: joint {name!r} has no "
                                  "offset parameter in its elementary transform (a fixed "
                                  "constant), so dr/dq cannot be formed; build the robot with "
                                  "an offset parameter for it")
            if uses[et.param] != 1:
                raise KincalError(f"{self.WHAT} of {self.name!r}: the offset parameter "
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
            raise KincalError(f"{self.WHAT} of {self.name!r}: the inner block's residuals "
                              "are not owned by rows of its joint readings")
        r0 = self._at(self.q).evaluate(robot, inner_extra, jacobian=False)[0]
        half = np.asarray(np.random.default_rng(0).random(N) < 0.5, dtype=bool)
        for moved in (half, ~half):
            q = self.q.copy()
            q[moved] += 1e-3
            dr = np.abs(self._at(q).evaluate(robot, inner_extra, jacobian=False)[0] - r0)
            scale = float(dr.max()) if dr.size else 0.0
            if np.any(dr[~moved[owner]] > 1e-6 * scale):
                raise KincalError(f"{self.WHAT} of {self.name!r}: some residuals of the "
                                  "inner block depend on configurations other than the one "
                                  "that owns them (e.g. artifact constraints between "
                                  f"postures); {type(self).__name__} needs one configuration "
                                  "per residual")
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
        Jc = self._c_columns(robot, Jr, np.asarray(self.inner.residual_owner(), np.intp))
        return r, Jr, np.concatenate([Je, Jc], axis=1)

    def evaluate_chunks(self, robot: Robot, extra: Array, rows: int = CHUNK_ROWS
                        ) -> Iterator[tuple[slice, Array, Array, Array]]:
        """The inner block's pieces at ``q_eff`` with the coefficient columns appended."""
        inner_extra, q = self._split(robot, extra)
        self._check_rows(robot, inner_extra)
        owner = np.asarray(self.inner.residual_owner(), dtype=np.intp)
        cols = self._offset_columns(robot)
        for sl, r, Jr, Je in self._at(q).evaluate_chunks(robot, inner_extra, rows):
            Jc = self._c_columns(robot, Jr, owner[sl], cols)
            yield sl, r, Jr, np.concatenate([Je, Jc], axis=1)

    def _c_columns(self, robot: Robot, Jr: Array, owner: NDArray[np.intp],
                   cols: tuple[NDArray[np.intp], Array] | None = None) -> Array:
        """``dr/dc_j = s_j (dr/do_j) u_j[owner]`` for the rows of ``Jr``."""
        params, scales = self._offset_columns(robot) if cols is None else cols
        value: Array = Jr[:, params] * scales * self.regressor[owner][:, self._columns]
        return value

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        inner_extra, q = self._split(robot, extra)
        return self._at(q).errors(robot, inner_extra)

    def __repr__(self) -> str:
        return (f"{type(self).__name__}({self.inner!r}, joints={list(self.joints)}, "
                f"N={self.q.shape[0]})")
