"""The probe tip: the point of the tool that is seated in the artifact's sockets.

With ``T_e(q) = (R_e, p_e)`` the robot's end frame (its ``tool.*`` frame included) and
``t`` the tip in that frame [m], the tip is

    P(q) = p_e(q) + R_e(q) t.

Modes:

* ``"length"``: a straight probe of length ``l`` along the flange's z axis,
  ``t = (0, 0, l)``; known, or identified as ``{block}.probe.l`` (``dP/dl = R_e e_z``);
* ``"vector"``: a general tip ``t = (x, y, z)``; known, or identified as
  ``{block}.probe.x .y .z`` (``dP/dt = R_e``);
* ``"tool"``: the tip *is* the robot's end-frame origin (``t = 0``): the robot's own
  parameters (``tool.x/y/z``, a URDF ``ball_joint.origin.*``) describe it.  Use this
  when several blocks see the same physical probe, so they share its parameters.

Derivatives: a parameter twist ``[v; w]`` of the end frame (base frame, from
:meth:`~kincal.robots.chain.Robot.fk_with_jacobians`) moves the tip by ``v + w x (R_e t)``;
the joint twists likewise give ``dP/dq`` for the propagation of encoder noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.measure.base import ParamSpec
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

PROBE_MODES = ("length", "vector", "tool")


@dataclass(frozen=True)
class Probe:
    """A probe tip on the robot's end frame.

    Attributes:
        mode: ``"length"``, ``"vector"`` or ``"tool"`` (see the module docstring).
        value: ``(l,)`` for ``length``, ``(x, y, z)`` for ``vector``, ``()`` for ``tool``
            [m]: the known value, or the initial guess when ``estimate``.
        estimate: identify the tip (block parameters) instead of holding it known.
    """

    mode: str = "tool"
    value: tuple[float, ...] = ()
    estimate: bool = False

    def __post_init__(self) -> None:
        if self.mode not in PROBE_MODES:
            raise KincalError(f"unknown probe mode {self.mode!r}; use length, vector or tool")
        want = {"length": 1, "vector": 3, "tool": 0}[self.mode]
        v = tuple(float(x) for x in self.value)
        if len(v) != want or not all(np.isfinite(v)):
            raise KincalError(f"a {self.mode!r} probe needs {want} finite value(s), got "
                              f"{list(self.value)}")
        if self.mode == "tool" and self.estimate:
            raise KincalError("a 'tool' probe is described by the robot's own tool "
                              "parameters; it has nothing of its own to estimate")
        object.__setattr__(self, "value", v)

    # ------------------------------------------------------------------ constructors
    @staticmethod
    def length(l: float, estimate: bool = False) -> Probe:
        """A straight probe of length ``l`` [m] along the flange z axis."""
        return Probe("length", (float(l),), estimate)

    @staticmethod
    def vector(t: ArrayLike, estimate: bool = False) -> Probe:
        """A tip at ``t = (x, y, z)`` [m] in the end frame."""
        return Probe("vector", tuple(np.asarray(t, dtype=float).reshape(3)), estimate)

    @staticmethod
    def tool() -> Probe:
        """The tip is the robot's end-frame origin (its tool parameters describe it)."""
        return Probe("tool", (), False)

    # ------------------------------------------------------------------ parameters
    @property
    def size(self) -> int:
        """Number of block parameters (0 when known or ``tool``)."""
        return len(self.value) if self.estimate else 0

    def parameters(self, block: str) -> ParamSpec:
        """``{block}.probe.l`` or ``{block}.probe.x .y .z`` when estimated (role tool_point)."""
        if not self.estimate:
            return ParamSpec.empty()
        fields = ("l",) if self.mode == "length" else ("x", "y", "z")
        return ParamSpec(tuple(f"{block}.probe.{f}" for f in fields), np.array(self.value),
                         ("m",) * len(fields), ("tool_point",) * len(fields))

    def tip(self, values: ArrayLike | None = None) -> Array:
        """The tip ``t`` in the end frame (3,) [m]; ``values`` are the estimated ones."""
        v = np.asarray(self.value if values is None or not self.estimate else values,
                       dtype=float).reshape(-1)
        if self.mode == "length":
            return np.array([0.0, 0.0, v[0]])
        if self.mode == "vector":
            return v.reshape(3)
        return np.zeros(3)

    def with_value(self, values: ArrayLike) -> Probe:
        """The same probe with a new value (e.g. the calibrated one)."""
        return Probe(self.mode, tuple(np.asarray(values, dtype=float).reshape(-1)),
                     self.estimate)

    # ------------------------------------------------------------------ kinematics
    def points(self, robot: Robot, q: Array, values: ArrayLike | None = None,
               jacobian: bool = True) -> tuple[Array, Array | None, Array | None]:
        """Tip positions and their Jacobians.

        Returns:
            ``P`` (N, 3) [m]; ``dP/d(robot params)`` (N, 3, P); ``dP/d(probe params)``
            (N, 3, size) -- the Jacobians are None when ``jacobian`` is False.
        """
        T, _, Jp = robot.fk_with_jacobians(q, joints=False, params=jacobian)
        R = T[:, :3, :3]
        a = R @ self.tip(values)                                   # R_e t (N, 3)
        P = T[:, :3, 3] + a
        if Jp is None:             # jacobian False
            return P, None, None
        dr = Jp[:, :3] + np.cross(Jp[:, 3:], a[:, :, None], axis=1)
        if self.size == 0:
            de = np.zeros((len(q), 3, 0))
        elif self.mode == "length":
            de = R[:, :, 2:3]
        else:
            de = R
        return P, dr, de

    def joint_jacobian(self, robot: Robot, q: Array) -> Array:
        """``dP/dq`` (N, 3, n) at the probe's own value [m/rad or m/m]."""
        T, J, _ = robot.fk_with_jacobians(q, joints=True, params=False)
        assert J is not None                           # joints=True
        a = T[:, :3, :3] @ self.tip()
        return J[:, :3] + np.cross(J[:, 3:], a[:, :, None], axis=1)

    def describe(self) -> str:
        if self.mode == "tool":
            return "the robot's end-frame origin (tool parameters)"
        what = (f"length {self.value[0] * 1e3:g} mm along the flange z axis"
                if self.mode == "length" else
                "tip (" + ", ".join(f"{v * 1e3:g}" for v in self.value) + ") mm")
        return f"probe {what}, " + ("identified" if self.estimate else "known")
